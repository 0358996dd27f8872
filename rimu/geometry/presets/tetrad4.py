"""de Oliveira et al. 2012's tetrad: a triad of gyros plus a fourth along MB x (Eq. 1)."""

from __future__ import annotations

import math

import numpy as np

from ..base import Geometry, SubUnit

#: The angle of de Oliveira et al.'s Fig. 1 (deg): acos(1/sqrt(3)).
TETRAD_ALPHA_DEG = 54.736


def tetrad4() -> Geometry:
    """The measurement matrix of de Oliveira et al. 2012, Eq. 1 (alpha = 54.736 deg).

    Partitioned as in their Eq. 14: sub-unit ``T`` is the triad g1, g2, g3 (an orthonormal but
    left-handed basis, as the paper's rows are); sub-unit ``X`` holds g4 alone, with the identity basis
    (H_2 = I_3), so g4's misalignment row is ``[m4x, m4y, m4z]``.

    >>> g = tetrad4()
    >>> np.round(g.parity_matrix(), 5).tolist()
    [[-0.40825, -0.40825, -0.40825, 0.70711]]
    """
    r3 = 1.0 / math.sqrt(3.0)
    H = np.array(
        [
            [r3, 0.0, math.sqrt(6.0) / 3.0],
            [r3, math.sqrt(2.0) / 2.0, -math.sqrt(6.0) / 6.0],
            [r3, -math.sqrt(2.0) / 2.0, -math.sqrt(6.0) / 6.0],
            [1.0, 0.0, 0.0],
        ]
    )
    subunits = (SubUnit("T", H[0:3].copy(), (0, 1, 2)), SubUnit("X", np.eye(3), (3,)))
    return Geometry(H, names=("g1", "g2", "g3", "g4"), subunits=subunits, name="tetrad4")
