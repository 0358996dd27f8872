"""Cho & Park 2005's orthogonal-cone configuration: two tilted triads SB1, SB2 (Eq. 18)."""

from __future__ import annotations

import math

import numpy as np

from ..base import Geometry, SubUnit

#: Azimuths (deg) of the six axes, in Cho & Park's row order: x1, y1, z1 of SB1, then x2, y2, z2 of SB2.
CONE6_AZIMUTHS_DEG = (0.0, -120.0, 120.0, 180.0, 60.0, -60.0)


def cone6() -> Geometry:
    """The orthogonal cone of Cho & Park 2005, Eq. 18, built from its two sub-IMU DCMs.

    Each sub-IMU is an orthogonal triad whose three axes lie on a cone of half-angle
    ``acos(1/sqrt(3)) = 54.7356 deg`` about -z_m; SB2 is SB1 turned 180 deg about z_m. Rows of H are the
    SB axes in MB: H = [C_SB1_MB; C_SB2_MB].

    >>> g = cone6()
    >>> np.allclose(g.H[0], [math.sqrt(2 / 3), 0, -1 / math.sqrt(3)])
    True
    """
    theta = math.acos(1.0 / math.sqrt(3.0))
    s, c = math.sin(theta), math.cos(theta)
    rows = []
    for az in CONE6_AZIMUTHS_DEG:
        a = math.radians(az)
        rows.append([s * math.cos(a), s * math.sin(a), -c])
    H = np.array(rows)
    H[np.abs(H) < 1e-15] = 0.0
    mat_sb1_mb = H[0:3].copy()
    rz180 = np.diag([-1.0, -1.0, 1.0])  # SB2 = SB1 turned 180 deg about z_m
    mat_sb2_mb = mat_sb1_mb @ rz180.T
    subunits = (SubUnit("SB1", mat_sb1_mb, (0, 1, 2)), SubUnit("SB2", mat_sb2_mb, (3, 4, 5)))
    names = ("x1", "y1", "z1", "x2", "y2", "z2")
    return Geometry(np.vstack([mat_sb1_mb, mat_sb2_mb]), names=names, subunits=subunits, name="cone6")
