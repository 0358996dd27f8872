"""A general cone: n axes at a common half-angle from the cone axis, equally spaced in azimuth."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..base import Geometry


def cone(
    n: int = 6,
    half_angle: float = math.acos(1.0 / math.sqrt(3.0)),
    azimuths: Sequence[float] | None = None,
    axis: str = "+z",
    names: Sequence[str] | None = None,
) -> Geometry:
    """n sensing axes on a cone about the MB z axis.

    Parameters
    ----------
    n : int
        Number of sensors (at least 3).
    half_angle : float
        Angle between each axis and the cone axis, rad. 0 or pi/2 make the geometry rank deficient
        (all axes collinear, or coplanar), which is refused with the unobservable direction named.
    azimuths : sequence of float, optional
        Azimuth of each axis about z, rad, measured from MB x towards y. Default ``2 pi k / n``.
    axis : {"+z", "-z"}
        Direction of the cone axis.

    >>> g = cone(5, math.radians(60))
    >>> np.allclose(g.H.T @ g.H, np.diag([5 * 0.75 / 2, 5 * 0.75 / 2, 5 * 0.25]))
    True
    """
    if n < 3:
        from ...errors import GeometryError

        raise GeometryError(f"a cone needs at least 3 sensors to span 3 dimensions, got n={n}")
    if azimuths is None:
        azimuths = [2.0 * math.pi * k / n for k in range(n)]
    if len(azimuths) != n:
        from ...errors import GeometryError

        raise GeometryError(f"{len(azimuths)} azimuths given for n={n} sensors")
    sign = {"+z": 1.0, "-z": -1.0}[axis]
    s, c = math.sin(half_angle), math.cos(half_angle)
    H = np.array([[s * math.cos(a), s * math.sin(a), sign * c] for a in azimuths])
    H[np.abs(H) < 1e-15] = 0.0
    return Geometry(H, names=names, name=f"cone{n}")
