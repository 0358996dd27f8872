"""The MIMU4444 (OpenShoe family) board: eight MPU-9150 triads at the corners of a small circuit board.

IMUs 1, 3, 5, 7 (top side) are in the array frame; IMUs 2, 4, 6, 8 (bottom side) are rotated,
``v_array = C v_raw`` with ``C = [[0, -1, 0], [-1, 0, 0], [0, 0, -1]]`` (accelerometers and gyros alike); nominal
positions +-9.45 mm in x and y, +-1 mm in z (the board's ``IMU_positions.csv``, Carlsson, Skog & Jalden 2021).
"""

from __future__ import annotations

import numpy as np

from ..base import Geometry
from .triads import triads

__all__ = ["MAT_ARRAY_RAW_BOTTOM", "POSITIONS_M", "mimu4444"]

#: v_array = C v_raw for the bottom-side IMUs 2, 4, 6, 8
MAT_ARRAY_RAW_BOTTOM = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: nominal triad positions in the array frame, m (IMU 1 .. 8)
POSITIONS_M = np.array([[-9.45e-3, 9.45e-3, 1e-3], [-9.45e-3, 9.45e-3, -1e-3], [-9.45e-3, -9.45e-3, 1e-3],
                        [-9.45e-3, -9.45e-3, -1e-3], [9.45e-3, 9.45e-3, 1e-3], [9.45e-3, 9.45e-3, -1e-3],
                        [9.45e-3, -9.45e-3, 1e-3], [9.45e-3, -9.45e-3, -1e-3]])


def mimu4444(positions: bool = True) -> Geometry:
    """The board's eight triads ``imu1`` .. ``imu8`` (24 sensors), MB = the array frame; the bottom triads'
    ``mat_sb_mb = C^T`` (an array-frame vector in the triad's raw axes); nominal positions in metres.

    >>> g = mimu4444()
    >>> g.n, g.subunits[1].mat_sb_mb.tolist()[2], g.subunits[4].position_mb_m.tolist()
    (24, [0.0, 0.0, -1.0], [0.00945, 0.00945, 0.001])
    """
    rot = [np.eye(3) if j % 2 == 0 else MAT_ARRAY_RAW_BOTTOM.T.copy() for j in range(8)]
    geo = triads(rot, POSITIONS_M.copy() if positions else None, [f"imu{j + 1}" for j in range(8)])
    return geo
