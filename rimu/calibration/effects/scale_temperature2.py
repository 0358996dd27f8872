"""Temperature coefficient of scale factor, quadratic: the scale changes in proportion to (T - T_ref)^2."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ...units import PPM
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import axis_input, runtime_temperature_offset, temperature_offset

__all__ = ["ScaleTemperature2"]


class ScaleTemperature2(Effect):
    name = "scale_temperature2"
    runtime_needs = ("temperature", "axis_input")
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

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(T - T_ref)^2 s_i``, (N, n, 1): output-side, inverted with the sensor's own input."""
        dT = runtime_temperature_offset(inputs, ctxs)[:, :, 0]
        return (dT * dT * inputs.axis_input)[:, :, None]

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        dT = runtime_temperature_offset(inputs, ctxs)
        return np.broadcast_to(dT * dT, (dT.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("power", len(ctxs), 1, power=1)
        form.F[:, 0, monomial("dT2")] = 1.0
        return form
