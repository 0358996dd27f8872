"""Cross-coupling between the sensors of one sub-unit: output error proportional to the product of the
input along the sensor's own axis and along each other axis of its sub-unit."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import geometry_cache, per_input_power

__all__ = ["CrossCoupling"]


class CrossCoupling(Effect):
    name = "cross_coupling"
    runtime_needs = ("input",)
    description = ("cross-coupling: output error proportional to the product of the input along the sensor's axis "
                   "and along each other sensor axis of the same sub-unit")
    physics = ("Second-order interaction of inputs on two axes (IEEE Std 528 cross-coupling coefficient): the "
               "sensing element, deflected by its own input, becomes sensitive to the cross input. Error = "
               "sum_j k_ij s_i s_j over the other sensors j of the sub-unit, with the inputs along the nominal "
               "axes (the directions of the case: positions with the input along one axis do not excite it, "
               "whatever the misalignment); reported in ppm per unit of input. Linear cross-axis sensitivity is "
               "misalignment, already in the base model.")
    excited_by = "inputs along directions between two axes of a sub-unit (rates or tilts at 45 deg in the axis planes)"

    def _others(self, ctx: SensorContext) -> list[int]:
        return [j for j in ctx.geometry.subunit_of(ctx.index).members if j != ctx.index]

    def applies_to(self, ctx: SensorContext) -> bool:
        return ctx.instrument in self.instruments and bool(self._others(ctx))

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        unit, rep, f = per_input_power(ctx, 1)
        return [ParamSpec(f"xc_{ctx.geometry.names[j]}", unit, rep, f) for j in self._others(ctx)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        u = ctx.input(segment)
        if u is None:
            return None
        u = np.asarray(u, dtype=float)
        s_i = u @ ctx.geometry.H[ctx.index]
        H = ctx.geometry.H[self._others(ctx)]
        return s_i[:, None] * (u @ H.T)

    def _directions(self, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """(n, k, 3): the nominal axes of each sensor's partners in its sub-unit, zero-padded."""
        def make() -> np.ndarray:
            others = [self._others(c) for c in ctxs] if ctxs[0].instrument in self.instruments else []
            k = max([len(o) for o in others] + [1])
            out = np.zeros((len(ctxs), k, 3))
            for i, o in enumerate(others):
                out[i, :len(o)] = ctxs[0].geometry.H[o]
            return out
        return geometry_cache("cross_coupling.directions", ctxs, make)

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(h_i . u)(h_j . u)`` over the partners j, (N, n, k), u the instrument's current MB estimate (the
        inversion updates it every step)."""
        u = np.asarray(inputs.input, dtype=float)
        own = u @ ctxs[0].geometry.H.T
        return own[:, :, None] * np.einsum("nj,ikj->nik", u, self._directions(ctxs))

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """Zero against the sensor's own output with u held (the inversion re-estimates u each step)."""
        u = np.asarray(inputs.input, dtype=float)
        return np.zeros((u.shape[0], len(ctxs), self._directions(ctxs).shape[1]))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        D = self._directions(ctxs)
        form = RuntimeForm.zeros("pair", len(ctxs), D.shape[1], directions=D)
        form.F[:, :, monomial("1")] = np.any(D != 0, axis=2)
        return form
