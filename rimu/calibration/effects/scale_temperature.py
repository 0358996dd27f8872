"""Temperature coefficient of scale factor, linear: the scale changes in proportion to T - T_ref."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ...units import PPM
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import axis_input, runtime_temperature_offset, temperature_offset

__all__ = ["ScaleTemperature"]


class ScaleTemperature(Effect):
    name = "scale_temperature"
    runtime_needs = ("temperature", "axis_input")
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

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(T - T_ref) s_i``, (N, n, 1): output-side, inverted with the sensor's own input."""
        return (runtime_temperature_offset(inputs, ctxs)[:, :, 0] * inputs.axis_input)[:, :, None]

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        dT = runtime_temperature_offset(inputs, ctxs)
        return np.broadcast_to(dT, (dT.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("power", len(ctxs), 1, power=1)
        form.F[:, 0, monomial("dT")] = 1.0
        return form
