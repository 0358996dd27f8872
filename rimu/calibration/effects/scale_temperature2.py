"""Temperature coefficient of scale factor, quadratic: the scale changes in proportion to (T - T_ref)^2."""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ...units import PPM
from ..model import Effect, ParamSpec, SensorContext
from ._common import axis_input, temperature_offset

__all__ = ["ScaleTemperature2"]


class ScaleTemperature2(Effect):
    name = "scale_temperature2"
    description = "scale-factor temperature coefficient (quadratic): the scale changes in proportion to (T - T_ref)^2"
    physics = "Curvature of the scale-temperature characteristic. Error = ks2 (T - T_ref)^2 s; reported in ppm/K^2."
    needs = "temperature"
    excited_by = "inputs along the sensing axis at three or more temperatures (a wide thermal soak)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec("scale_tc2", "1/K^2", "ppm/K^2", 1.0 / PPM)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        dT = temperature_offset(segment, ctx)
        s = axis_input(segment, ctx)
        return None if dT is None or s is None else (dT**2 * s)[:, None]
