"""The layout of an inertial sensor array: k triads, each with its rotation to the body frame and its position.

Frames follow :mod:`rimu.geometry`: the body frame is the master body (MB); triad j has its own sub-body frame
SB_j. ``rotations[j]`` maps an SB_j vector to MB (``mat_mb_sb``, the transpose of a sub-unit's ``mat_sb_mb``);
``positions_m[j]`` is the triad's origin in MB, in metres, relative to the array's reference point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import GeometryError, ShapeError

__all__ = ["ArrayLayout"]


@dataclass(frozen=True)
class ArrayLayout:
    """k triads on one rigid body.

    Parameters
    ----------
    rotations : array_like, shape (k, 3, 3)
        ``mat_mb_sb`` of each triad: maps a vector in the triad's own axes to the body frame. Orthonormal.
    positions_m : array_like, shape (k, 3)
        Position of each triad in the body frame [m] (lever arm from the reference point).
    names : sequence of str, optional
        Triad names (default ``T1 .. Tk``).

    Raises
    ------
    ShapeError
        Wrong shapes or fewer than two triads.
    GeometryError
        Non-finite entries or a rotation that is not orthonormal.

    Examples
    --------
    >>> lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.01)
    >>> lay.k, lay.positions_m.shape
    (4, (4, 3))
    >>> bool(np.allclose(lay.positions_m.mean(axis=0), 0.0))
    True
    """

    rotations: np.ndarray
    positions_m: np.ndarray
    names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        R = np.array(self.rotations, dtype=float)
        P = np.array(self.positions_m, dtype=float)
        if R.ndim != 3 or R.shape[1:] != (3, 3):
            raise ShapeError(f"rotations must have shape (k, 3, 3), got {R.shape}")
        k = R.shape[0]
        if k < 2:
            raise ShapeError(f"an array needs at least two triads, got {k}")
        if P.shape != (k, 3):
            raise ShapeError(f"positions_m must have shape ({k}, 3) to match the rotations, got {P.shape}")
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(P))):
            raise GeometryError("rotations and positions_m must be finite; replace NaN/inf by the mounting values")
        err = np.abs(np.einsum("kij,kil->kjl", R, R) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero(err > 1e-6)
        if bad.size:
            raise GeometryError(
                f"rotation of triad(s) {bad.tolist()} is not orthonormal (max |R^T R - I| = {err.max():.2e}); "
                "pass the mounting rotation matrices (sub-body -> body)"
            )
        names = tuple(self.names) if self.names else tuple(f"T{j + 1}" for j in range(k))
        if len(names) != k or len(set(names)) != k:
            raise ShapeError(f"names must be {k} unique strings, got {names!r}")
        R.setflags(write=False)
        P.setflags(write=False)
        object.__setattr__(self, "rotations", R)
        object.__setattr__(self, "positions_m", P)
        object.__setattr__(self, "names", names)

    @property
    def k(self) -> int:
        """Number of triads."""
        return int(self.rotations.shape[0])

    def to_body(self, y: np.ndarray) -> np.ndarray:
        """Rotate triad outputs ``y`` (..., k, 3) from each triad's axes to the body frame."""
        y = np.asarray(y, dtype=float)
        if y.shape[-2:] != (self.k, 3):
            raise ShapeError(f"triad outputs must end in shape ({self.k}, 3), got {y.shape}")
        return np.einsum("kij,...kj->...ki", self.rotations, y)

    def to_triad(self, z: np.ndarray) -> np.ndarray:
        """Rotate body-frame vectors ``z`` (..., k, 3) into each triad's own axes (inverse of :meth:`to_body`)."""
        z = np.asarray(z, dtype=float)
        if z.shape[-2:] != (self.k, 3):
            raise ShapeError(f"body-frame vectors must end in shape ({self.k}, 3), got {z.shape}")
        return np.einsum("kji,...kj->...ki", self.rotations, z)

    def with_positions(self, positions_m: np.ndarray) -> "ArrayLayout":
        """The same layout with other positions (e.g. estimated ones)."""
        return ArrayLayout(self.rotations, positions_m, self.names)

    @classmethod
    def planar_grid(cls, rows: int, cols: int, pitch_m: float = 0.01, two_sided: bool = False) -> "ArrayLayout":
        """Triads on a grid of ``rows x cols`` with pitch ``pitch_m``, centred on the origin, axes parallel to MB.

        With ``two_sided`` the second half of the triads sits on the bottom side of a 1.6 mm board, turned
        180 degrees about the body x axis (as on the OpenShoe arrays of Skog et al. 2016).
        """
        if rows < 1 or cols < 1 or rows * cols < 2:
            raise ShapeError(f"a grid needs at least two triads, got {rows} x {cols}")
        ys, xs = np.meshgrid(np.arange(rows) - (rows - 1) / 2, np.arange(cols) - (cols - 1) / 2, indexing="ij")
        pos = np.column_stack([xs.ravel() * pitch_m, ys.ravel() * pitch_m, np.zeros(rows * cols)])
        rot = np.repeat(np.eye(3)[None], rows * cols, axis=0)
        if two_sided:
            flip = np.diag([1.0, -1.0, -1.0])
            pos = np.vstack([pos + [0, 0, 0.0008], pos - [0, 0, 0.0008]])
            rot = np.vstack([rot, np.repeat(flip[None], rows * cols, axis=0)])
        return cls(rot, pos)

    @classmethod
    def from_geometry(cls, geometry: Any, positions_m: "np.ndarray | Sequence[Sequence[float]] | None" = None) -> "ArrayLayout":
        """Build the layout from a :class:`rimu.geometry.Geometry` made of triads.

        Each sub-unit must hold three sensors with orthogonal axes; triad j's output columns are its members in
        order, so its rotation (triad axes -> body) has the members' sensing axes ``H[members]`` as columns. Its
        position is the sub-unit's ``position_mb_m`` when the geometry carries one, else the row of
        ``positions_m``.

        Raises
        ------
        GeometryError
            A sub-unit is not an orthogonal triad, or a position is missing.

        Examples
        --------
        >>> from rimu.geometry import cone6
        >>> lay = ArrayLayout.from_geometry(cone6(), positions_m=[[0, 0, 0.01], [0, 0, -0.01]])
        >>> lay.names, bool(np.allclose(lay.rotations[0], cone6().H[:3].T))
        (('SB1', 'SB2'), True)
        """
        H = np.asarray(geometry.H, dtype=float)
        rots, pos, names = [], [], []
        for j, su in enumerate(geometry.subunits):
            if len(su.members) != 3:
                raise GeometryError(
                    f"sub-unit {su.name!r} has {len(su.members)} sensors; an array is made of triads (3 each)"
                )
            R = H[list(su.members)].T
            if np.abs(R.T @ R - np.eye(3)).max() > 1e-6:
                raise GeometryError(f"the axes of sub-unit {su.name!r} are not orthogonal: an array triad needs "
                                    "three orthogonal sensing axes")
            rots.append(R)
            p = getattr(su, "position_mb_m", None)
            if p is None and positions_m is not None:
                p = np.asarray(positions_m, dtype=float)[j]
            if p is None:
                raise GeometryError(
                    f"sub-unit {su.name!r} has no position: pass positions_m (k, 3) in metres, "
                    "or estimate them with rimu.array.fit_positions"
                )
            pos.append(np.asarray(p, dtype=float))
            names.append(su.name)
        return cls(np.array(rots), np.array(pos), tuple(names))

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (JSON-ready)."""
        return {"rotations": self.rotations.tolist(), "positions_m": self.positions_m.tolist(), "names": list(self.names)}
