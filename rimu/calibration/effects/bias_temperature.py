"""Temperature coefficient of bias, linear: a bias proportional to T - T_ref."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import output_unit, runtime_temperature_offset, temperature_offset

__all__ = ["BiasTemperature"]


class BiasTemperature(Effect):
    name = "bias_temperature"
    runtime_needs = ("temperature",)
    description = "bias temperature coefficient (linear): bias changes in proportion to T - T_ref"
    physics = ("Thermal expansion and temperature-dependent electronics offsets. Error = kb1 (T - T_ref); "
               "reported in (deg/h)/K or ug/K.")
    needs = "temperature"
    excited_by = "segments at different temperatures: a thermal soak or a temperature ramp in a chamber"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        si, rep, f = output_unit(ctx)
        return [ParamSpec("bias_tc1", f"{si}/K", f"{rep}/K", f)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        dT = temperature_offset(segment, ctx)
        return None if dT is None else dT[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``T - T_ref`` for every sensor, (N, n, 1)."""
        dT = runtime_temperature_offset(inputs, ctxs)
        return np.broadcast_to(dT, (dT.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("exogenous", len(ctxs), 1)
        form.F[:, 0, monomial("dT")] = 1.0
        return form
