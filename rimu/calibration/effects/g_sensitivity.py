"""Gyro g-sensitivity: a bias proportional to the specific force along each MB axis."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ...units import G0, RS_TO_DH
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial

__all__ = ["GSensitivity"]


class GSensitivity(Effect):
    name = "g_sensitivity"
    runtime_needs = ("specific_force",)
    instruments = ("gyro",)
    description = "gyro g-sensitivity: a bias proportional to the specific force (one coefficient per MB axis)"
    physics = ("Mass unbalance of a spinning rotor, or a vibrating gyro's proof mass deflected by the specific "
               "force. Error = g . f with f the specific force in MB; reported in (deg/h)/g.")
    excited_by = "static positions (or rotations) with gravity along different MB directions and a known attitude"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec(f"gsens_{a}", "(rad/s)/(m/s^2)", "(deg/h)/g", RS_TO_DH * G0) for a in "xyz"]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        f = segment.specific_force(ctx.gravity)
        return None if f is None else np.asarray(f, dtype=float)

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """The specific force in MB for every sensor, (N, n, 3) (the accelerometers' estimate of the epoch)."""
        f = np.asarray(inputs.specific_force, dtype=float)
        return np.broadcast_to(f[:, None, :], (f.shape[0], len(ctxs), 3))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("exogenous", len(ctxs), 3)
        for k, a in enumerate("xyz"):
            form.F[:, k, monomial(f"f_{a}")] = 1.0
        return form
