"""Bias drift linear in time (warm-up)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import output_unit

__all__ = ["BiasDrift"]


class BiasDrift(Effect):
    name = "bias_drift"
    runtime_needs = ("time",)
    description = "bias drifting linearly in time over the session (warm-up, or a slow trend)"
    physics = ("Self-heating after switch-on and slow relaxation of the sensing element. Error = d * t with t "
               "the session time (s); reported in (deg/h)/h or ug/h.")
    excited_by = "a long session, or the same position repeated at its start and end (the time stamps must be continuous)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        si, rep, f = output_unit(ctx)
        return [ParamSpec("drift", f"{si}/s", f"{rep}/h", f * 3600.0)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        return np.asarray(segment.t, dtype=float)[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """Time since the stream started, (N, n, 1): the drift is undone as ``d * t`` (warm-up from switch-on)."""
        t = np.asarray(inputs.t, dtype=float)
        return np.broadcast_to(t[:, None, None], (t.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("exogenous", len(ctxs), 1)
        form.F[:, 0, monomial("t")] = 1.0
        return form
