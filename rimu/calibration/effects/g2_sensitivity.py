"""Gyro g^2 (anisoelastic) sensitivity: a bias proportional to products of specific-force components."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ...units import G0, RS_TO_DH
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import geometry_cache

__all__ = ["G2Sensitivity"]


class G2Sensitivity(Effect):
    name = "g2_sensitivity"
    runtime_needs = ("specific_force",)
    instruments = ("gyro",)
    description = ("gyro g^2 (anisoelastic) sensitivity: a bias proportional to the product of the specific force "
                   "along the sensing axis and across it")
    physics = ("Unequal compliance of the sensing element along and across its axis: under a specific force "
               "tilted from the axis the element deflects off the force's line, giving a bias "
               "k_i1 f_in f_c1 + k_i2 f_in f_c2 (f_in along the nominal axis, f_c1, f_c2 across it); "
               "reported in (deg/h)/g^2. The sum f_x^2 + f_y^2 + f_z^2 = g^2 is a bias, so only the "
               "products are kept.")
    excited_by = "static positions with gravity at 45 deg between the sensing axis and the cross axes"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec(f"aniso_{k}", "(rad/s)/(m/s^2)^2", "(deg/h)/g^2", RS_TO_DH * G0**2) for k in (1, 2)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        f = segment.specific_force(ctx.gravity)
        if f is None:
            return None
        f = np.asarray(f, dtype=float)
        E, _ = ctx.geometry.off_axis_basis(ctx.index)
        C = ctx.geometry.subunit_of(ctx.index).mat_sb_mb
        cross_mb = E @ C  # rows: the two cross axes in MB
        f_in = f @ ctx.axis
        return f_in[:, None] * (f @ cross_mb.T)

    def _axes(self, ctxs: Sequence[SensorContext]) -> tuple[np.ndarray, np.ndarray]:
        """(nominal axes (n, 3), cross axes in MB (n, 2, 3))."""
        def make() -> tuple[np.ndarray, np.ndarray]:
            g = ctxs[0].geometry
            cross = np.stack([g.off_axis_basis(c.index)[0] @ g.subunit_of(c.index).mat_sb_mb for c in ctxs])
            return np.stack([c.axis for c in ctxs]), cross
        return geometry_cache("g2_sensitivity.axes", ctxs, make)

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``f_in * f_c`` for the two cross axes of every sensor, (N, n, 2)."""
        f = np.asarray(inputs.specific_force, dtype=float)
        H, cross = self._axes(ctxs)
        return (f @ H.T)[:, :, None] * np.einsum("nj,ikj->nik", f, cross)

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        """``f_in f_ck = sum_ab h_a c_kb f_a f_b`` in the products of f."""
        H, cross = self._axes(ctxs)
        form = RuntimeForm.zeros("exogenous", len(ctxs), 2)
        for i in range(len(ctxs)):
            for k in range(2):
                for a, na in enumerate("xyz"):
                    for b, nb in enumerate("xyz"):
                        form.F[i, k, monomial("f", na + nb)] += H[i, a] * cross[i, k, b]
        return form
