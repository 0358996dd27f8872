"""Gyro g^2 (anisoelastic) sensitivity: a bias proportional to products of specific-force components."""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ...units import G0, RS_TO_DH
from ..model import Effect, ParamSpec, SensorContext

__all__ = ["G2Sensitivity"]


class G2Sensitivity(Effect):
    name = "g2_sensitivity"
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
