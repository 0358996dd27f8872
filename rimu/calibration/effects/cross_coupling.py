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
    runtime_needs = ("axis_input",)
    description = ("cross-coupling: output error proportional to the product of the input along the sensor's axis "
                   "and along each other sensor axis of the same sub-unit")
    physics = ("Second-order interaction of inputs on two axes (IEEE Std 528 cross-coupling coefficient): the "
               "sensing element, deflected by its own input, becomes sensitive to the cross input. Error = "
               "sum_j k_ij s_i s_j over the other sensors j of the sub-unit (nominal axes); reported in "
               "ppm per unit of input. Linear cross-axis sensitivity is misalignment, already in the base model.")
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
        s_i = u @ ctx.axis
        H = np.array([ctx.axis_of(j) for j in self._others(ctx)]).reshape(-1, 3)
        return s_i[:, None] * (u @ H.T)

    def _partners(self, ctxs: Sequence[SensorContext]) -> tuple[np.ndarray, np.ndarray]:
        """(index (n, k), mask (n, k)): the other sensors of each sensor's sub-unit, zero-padded."""
        def make() -> tuple[np.ndarray, np.ndarray]:
            others = [self._others(c) for c in ctxs]
            k = max([len(o) for o in others] + [1])
            idx = np.zeros((len(ctxs), k), dtype=np.intp)
            mask = np.zeros((len(ctxs), k))
            for i, o in enumerate(others):
                idx[i, :len(o)] = o
                mask[i, :len(o)] = 1.0
            return idx, mask
        return geometry_cache("cross_coupling.partners", ctxs, make)

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``s_i s_j`` over the other sensors j of the sub-unit, (N, n, k): output-side (inverted jointly with
        the partners' inputs, which the inversion updates every iteration)."""
        s = inputs.axis_input
        idx, mask = self._partners(ctxs)
        return s[:, :, None] * s[:, idx] * mask

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        idx, mask = self._partners(ctxs)
        return inputs.axis_input[:, idx] * mask

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        idx, mask = self._partners(ctxs)
        form = RuntimeForm.zeros("pair", len(ctxs), idx.shape[1], partners=idx)
        form.F[:, :, monomial("1")] = mask
        return form
