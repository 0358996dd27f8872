"""Scale factor and misalignment: the sensing axis a_i = C_j^T m_i and scale SF_i (Cho & Park 2005, Eq. 1-2, 10).

Linear block: the columns are the three MB components of the true input u, the raw-domain coefficients are
w_i = a_i / SF_i (Cho & Park Eq. 5: m/SF). The physical parameters follow from the unit-norm constraint
(Eq. 10): SF_i = 1 / |w_i|, m_i = C_j w_i / |w_i|; the two components of m_i off the nominal row are the
misalignment angles (rad).
"""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ...units import RAD_TO_ARCSEC
from ..model import Effect, ParamSpec, SensorContext


class ScaleMisalignment(Effect):
    name = "scale_misalignment"
    description = "scale factor of the output and tilt of the sensing axis from its nominal direction"
    physics = ("Gain of the pick-off electronics, and mounting tolerances of the sensor in its sub-unit; "
               "identified by inputs along at least three independent MB directions.")

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        unit = "count/(rad/s)" if ctx.instrument == "gyro" else "count/(m/s^2)"
        return [ParamSpec(f"w_{a}", unit) for a in "xyz"]

    def physical_parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        unit = "(rad/s)/count" if ctx.instrument == "gyro" else "(m/s^2)/count"
        _, names = ctx.geometry.off_axis_basis(ctx.index)
        return [ParamSpec("scale", unit, "ppm", 1.0)] + [ParamSpec(nm, "rad", "arcsec", RAD_TO_ARCSEC) for nm in names]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        u = ctx.input(segment)
        return None if u is None else np.asarray(u, dtype=float)

    def physical(self, w: np.ndarray, ctx: SensorContext) -> tuple[np.ndarray, np.ndarray]:
        """(scale, mis_a, mis_b) from w, and the Jacobian d(physical)/dw (3 x 3).

        scale = 1/|w|; m = C w / |w| (sub-unit basis); mis = E m with E the off-axis basis.
        """
        w = np.asarray(w, dtype=float)
        C = ctx.geometry.subunit_of(ctx.index).mat_sb_mb
        E, _ = ctx.geometry.off_axis_basis(ctx.index)
        nw = float(np.linalg.norm(w))
        u = w / nw
        scale = 1.0 / nw
        mis = E @ (C @ u)
        d_scale = -w / nw**3
        d_u = (np.eye(3) - np.outer(u, u)) / nw
        d_mis = E @ C @ d_u
        return np.concatenate([[scale], mis]), np.vstack([d_scale, d_mis])

    def misalignment_row(self, w: np.ndarray, ctx: SensorContext) -> np.ndarray:
        """Unit misalignment row m_i in the sub-unit basis."""
        C = ctx.geometry.subunit_of(ctx.index).mat_sb_mb
        return C @ (np.asarray(w, dtype=float) / np.linalg.norm(w))
