"""An ordinary orthogonal triad (the IMU of Zhang et al. 2010)."""

from __future__ import annotations

import numpy as np

from ..base import Geometry, SubUnit


def triad3() -> Geometry:
    """Three orthogonal axes along MB x, y, z, one sub-unit.

    >>> triad3().H.tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    return Geometry(np.eye(3), names=("x", "y", "z"), subunits=(SubUnit("T", np.eye(3), (0, 1, 2)),), name="triad3")
