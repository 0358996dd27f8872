"""Cho & Park 2005, Eq. 20 taken literally, for comparison with the pipeline's least-squares form."""

from __future__ import annotations

import numpy as np

from ..calibration.result import InstrumentCalibration
from ..errors import GeometryError

__all__ = ["cho_park_eq20", "eq20_matrix"]


def eq20_matrix(cal: InstrumentCalibration) -> np.ndarray:
    """The matrix ``(H^T H)^-1 H^T M^-1`` of Cho & Park 2005, Eq. 20, shape (3, n).

    Needs every sub-unit to be a full triad (a square, invertible block of M); otherwise use the
    pipeline, which handles any partition through the calibrated axes (see :mod:`rimu.fusion.pipeline`).
    """
    g = cal.geometry
    n = g.n
    Minv = np.zeros((n, n))
    for su in g.subunits:
        idx = list(su.members)
        if len(idx) != 3:
            raise GeometryError(
                f"Eq. 20 needs square blocks of M; sub-unit {su.name!r} has {len(idx)} sensors. "
                "Use rimu.fusion.InstrumentPipeline (least squares on the calibrated axes)"
            )
        # block of M in the nominal (CSB) axis order of the members: rows m_i expressed along the
        # sub-unit axes the members nominally measure
        nominal = g.nominal_rows()[idx]
        Mj = cal.misalignment[idx] @ nominal.T
        Minv[np.ix_(idx, idx)] = np.linalg.inv(Mj)
    return g.projection() @ Minv


def cho_park_eq20(cal: InstrumentCalibration, Y: np.ndarray) -> np.ndarray:
    """MB-frame estimate ``(H^T H)^-1 H^T M^-1 (SF Y - B)`` for raw outputs Y (..., n) (Cho & Park Eq. 20)."""
    return cal.compensate(Y) @ eq20_matrix(cal).T
