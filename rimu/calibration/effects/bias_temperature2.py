"""Temperature coefficient of bias, quadratic: a bias proportional to (T - T_ref)^2."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import output_unit, runtime_temperature_offset, temperature_offset

__all__ = ["BiasTemperature2"]


class BiasTemperature2(Effect):
    name = "bias_temperature2"
    runtime_needs = ("temperature",)
    description = "bias temperature coefficient (quadratic): bias changes in proportion to (T - T_ref)^2"
    physics = ("Curvature of the bias-temperature characteristic (MEMS bias curves are rarely straight over a "
               "wide range). Error = kb2 (T - T_ref)^2; reported in (deg/h)/K^2 or ug/K^2.")
    needs = "temperature"
    excited_by = "segments at three or more temperatures (a thermal soak over a wide range)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        si, rep, f = output_unit(ctx)
        return [ParamSpec("bias_tc2", f"{si}/K^2", f"{rep}/K^2", f)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        dT = temperature_offset(segment, ctx)
        return None if dT is None else (dT**2)[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(T - T_ref)^2`` for every sensor, (N, n, 1)."""
        dT = runtime_temperature_offset(inputs, ctxs)
        return np.broadcast_to(dT * dT, (dT.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("exogenous", len(ctxs), 1)
        form.F[:, 0, monomial("dT2")] = 1.0
        return form
