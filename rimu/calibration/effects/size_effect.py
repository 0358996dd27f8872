"""Accelerometer size effect (lever arm): centripetal acceleration of an accelerometer off the rotation centre."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment, skew
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import geometry_cache

__all__ = ["SizeEffect"]


class SizeEffect(Effect):
    name = "size_effect"
    runtime_needs = ("angular_rate",)
    instruments = ("accel",)
    description = ("accelerometer size effect / lever arm: the sensor sits at r from the rotation centre and "
                   "measures the centripetal acceleration w x (w x r)")
    physics = ("Under a rotation w the proof mass at r (MB, from the centre of rotation) accelerates by "
               "w x (w x r) + dw/dt x r. Along the nominal axis h that is h . [w]x^2 r, linear in r: the columns "
               "are [w]x^2 h (the tangential term is zero at constant rate). The parameters are the sensor's "
               "position r_x, r_y, r_z, reported in mm.")
    excited_by = "constant-rate rotations about at least three different axes (any rate table test; faster is better)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec(f"r_{a}", "m", "mm", 1e3) for a in "xyz"]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        if segment.kind == "static":
            return np.zeros((segment.n_samples, 3))
        if segment.kind != "rate":
            return None
        W = skew(segment.table_rate())
        col = (W @ W) @ ctx.axis  # [w]x^2 is symmetric: h . [w]x^2 r = ([w]x^2 h) . r
        return np.broadcast_to(col, (segment.n_samples, 3)).copy()

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``[w]x^2 h_i = w (w . h_i) - h_i |w|^2`` for every sensor, (N, n, 3), with w the gyros' estimate of the
        epoch (the centripetal term; the tangential ``dw/dt x r`` is not modelled, as in :meth:`columns`)."""
        w = np.asarray(inputs.angular_rate, dtype=float)
        H = geometry_cache("size_effect.axes", ctxs, lambda: np.stack([c.axis for c in ctxs]))
        return w[:, None, :] * (w @ H.T)[:, :, None] - H[None] * np.einsum("nj,nj->n", w, w)[:, None, None]

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        """``w_k (w . h) - h_k |w|^2`` in the products of w."""
        form = RuntimeForm.zeros("exogenous", len(ctxs), 3)
        for i, c in enumerate(ctxs):
            h = c.axis
            for k, nk in enumerate("xyz"):
                for j, nj in enumerate("xyz"):
                    form.F[i, k, monomial("w", nk + nj)] += h[j]
                    form.F[i, k, monomial("w", nj + nj)] -= h[k]
        return form
