"""Six axes normal to the faces of a dodecahedron: every pair at acos(1/sqrt(5)) = 63.435 deg."""

from __future__ import annotations

import math

import numpy as np

from ..base import Geometry


def dodecahedron6() -> Geometry:
    """One axis along MB z and five on a cone of half-angle atan(2) about it, 72 deg apart.

    The classic optimal six-sensor skewed configuration (Gilmore; Harrison & Gai): all pairwise angles
    equal, ``H^T H = 2 I``.

    >>> g = dodecahedron6()
    >>> np.allclose(g.H.T @ g.H, 2 * np.eye(3))
    True
    """
    theta = math.atan(2.0)
    s, c = math.sin(theta), math.cos(theta)
    rows = [[0.0, 0.0, 1.0]]
    for k in range(5):
        a = 2.0 * math.pi * k / 5.0
        rows.append([s * math.cos(a), s * math.sin(a), c])
    H = np.array(rows)
    H[np.abs(H) < 1e-15] = 0.0
    return Geometry(H, names=tuple(f"d{i + 1}" for i in range(6)), name="dodecahedron6")
