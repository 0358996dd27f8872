"""A unit of k orthogonal triads, each with its own rotation to the body frame and its own position.

This is what most real redundant units are: autopilots with two or three IMUs, boards with 4 to 32 MEMS
triads, IMUs strapped to a vehicle. Triad k is the sub-unit ``names[k]`` with basis ``rotations[k]`` (its
``mat_sb_mb``: maps an MB vector into the triad's axes, whose rows are the triad's x, y, z axes in MB) and,
where known, position ``positions_mb_m[k]`` (its origin in MB, metres: the lever arm). Its three sensors are
rows ``3k, 3k+1, 3k+2`` of H, named ``<triad>_x``, ``<triad>_y``, ``<triad>_z``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...errors import GeometryError
from ..base import Geometry, SubUnit

__all__ = ["triads"]


def triads(
    rotations: int | Sequence[Any] = 2,
    positions_mb_m: Sequence[Any] | None = None,
    names: Sequence[str] | None = None,
) -> Geometry:
    """A geometry of k triads.

    Parameters
    ----------
    rotations : int or sequence of (3, 3) array_like
        Each triad's ``mat_sb_mb`` (orthonormal; rows are the triad's axes in MB). An integer k gives k
        triads parallel to MB (identity rotations), as on a board whose chips are all mounted alike.
    positions_mb_m : sequence of (3,) array_like or None, optional
        Each triad's origin in MB, metres; None (default) when not known. An entry may itself be None.
    names : sequence of str, optional
        Triad names (default ``imu0 .. imu{k-1}``); sensors are ``<name>_x`` etc.

    Returns
    -------
    Geometry
        ``3k`` sensors in ``k`` sub-units, name ``"triads"``. Parallel triads (same rotation) detect a fault
        but, with k = 2, cannot tell which of the two is wrong: :func:`rimu.fdi.isolability` says so.

    Raises
    ------
    GeometryError
        Fewer than one triad, a rotation that is not an orthonormal 3 x 3 matrix, a position that is not
        three finite numbers, or lists of different lengths.

    Examples
    --------
    >>> g = triads(2, positions_mb_m=[[0, 0, 0], [0.05, 0, 0]])
    >>> g.n, g.names[:4], [s.name for s in g.subunits]
    (6, ('imu0_x', 'imu0_y', 'imu0_z', 'imu1_x'), ['imu0', 'imu1'])
    >>> g.subunits[1].position_mb_m.tolist()
    [0.05, 0.0, 0.0]
    """
    if isinstance(rotations, (int, np.integer)):
        if rotations < 1:
            raise GeometryError(f"a unit of triads needs at least one triad, got {rotations}")
        mats = [np.eye(3) for _ in range(int(rotations))]
    else:
        try:
            mats = [np.array(r, dtype=float) for r in rotations]
        except (TypeError, ValueError) as exc:
            raise GeometryError(f"rotations must be 3 x 3 matrices: {exc}") from exc
        if not mats:
            raise GeometryError("a unit of triads needs at least one triad; rotations is empty")
    k = len(mats)
    for j, m in enumerate(mats):
        if m.shape != (3, 3):
            raise GeometryError(f"rotation {j} must be a 3 x 3 matrix (the triad's mat_sb_mb), got shape {m.shape}")
        err = float(np.abs(m @ m.T - np.eye(3)).max()) if np.all(np.isfinite(m)) else np.inf
        if err > 1e-6:
            raise GeometryError(f"rotation {j} is not orthonormal (max |R R^T - I| = {err:.3g}); give a rotation "
                                "matrix whose rows are the triad's axes in MB")
    if names is None:
        names = [f"imu{j}" for j in range(k)]
    names = [str(s) for s in names]
    if len(names) != k:
        raise GeometryError(f"{len(names)} triad names for {k} rotations; give one name per triad")
    if positions_mb_m is None:
        pos: list[Any] = [None] * k
    else:
        pos = list(positions_mb_m)
        if len(pos) != k:
            raise GeometryError(f"{len(pos)} positions for {k} triads; give one position (or None) per triad")
    subunits = [SubUnit(names[j], mats[j], (3 * j, 3 * j + 1, 3 * j + 2), None if pos[j] is None else
                        np.asarray(pos[j], dtype=float)) for j in range(k)]
    sensor_names = [f"{nm}_{a}" for nm in names for a in "xyz"]
    return Geometry(np.vstack(mats), names=sensor_names, subunits=subunits, name="triads")
