"""Temperature coefficient of scale factor, linear: the scale changes in proportion to T - T_ref."""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ...units import PPM
from ..model import Effect, ParamSpec, SensorContext
from ._common import axis_input, temperature_offset

__all__ = ["ScaleTemperature"]


class ScaleTemperature(Effect):
    name = "scale_temperature"
    description = "scale-factor temperature coefficient (linear): the scale changes in proportion to T - T_ref"
    physics = ("Temperature dependence of the pick-off gain and of the reference voltage. Error = "
               "ks1 (T - T_ref) s with s the input along the sensing axis; reported in ppm/K.")
    needs = "temperature"
    excited_by = "inputs along the sensing axis at different temperatures (rate or tilt tests repeated in a thermal soak)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec("scale_tc1", "1/K", "ppm/K", 1.0 / PPM)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        dT = temperature_offset(segment, ctx)
        s = axis_input(segment, ctx)
        return None if dT is None or s is None else (dT * s)[:, None]
