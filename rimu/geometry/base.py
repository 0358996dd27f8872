"""Sensor geometry: the n x 3 matrix H of unit sensing axes in the master-body (MB) frame.

Frames (Cho & Park 2005, Section II):

* **MB**, master body: orthogonal, fixed to the case of the unit; estimates are expressed in it.
* **SB_j**, sub body j: the frame of sub-unit j (a tilted triad, or any orthonormal basis the maker
  chose). ``mat_sb_mb`` maps an MB vector into SB_j coordinates; its rows are the SB_j axes in MB.

Each sensor belongs to exactly one sub-unit. Its *nominal row* in that sub-unit is ``mat_sb_mb @ h_i``
(for a Cho & Park triad this is a unit basis vector e_x, e_y or e_z). A calibration replaces the nominal
row by the misalignment row m_i of Cho & Park Eq. 1-2 (unit norm, Eq. 10); the calibrated sensing axis in
MB is then ``mat_sb_mb.T @ m_i``.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import GeometryError, RankDeficientError

__all__ = ["SubUnit", "Geometry", "UNIT_TOL"]

#: How far a row norm may be from 1 before the geometry is refused.
UNIT_TOL = 1e-6
_AXIS_LETTERS = "xyz"


@dataclass(frozen=True)
class SubUnit:
    """A group of sensors sharing one mounting frame.

    Attributes
    ----------
    name : str
        Label, e.g. ``"SB1"``.
    mat_sb_mb : ndarray, shape (3, 3)
        Orthonormal basis of the sub-unit: maps an MB vector to SB coordinates (rows are the SB axes in
        MB). A left-handed basis is allowed (``proper`` is then False): only orthonormality matters for
        expressing misalignment rows.
    members : tuple of int
        Indices of the sensors (rows of H) in this sub-unit.
    position_mb_m : ndarray, shape (3,), or None
        Where the sub-unit sits: its origin in MB coordinates, metres (the lever arm from the MB origin).
        None (the default) when the position is not known or does not matter (gyros, co-located triads).
        Accelerometers at a lever arm ``r`` measure ``f + w' x r + w x (w x r)`` besides the MB specific
        force ``f``; rimu.array uses these positions to compensate that.

    Examples
    --------
    >>> su = SubUnit("imu1", np.eye(3), (0, 1, 2), position_mb_m=np.array([0.01, 0.0, 0.0]))
    >>> su.position_mb_m.tolist()
    [0.01, 0.0, 0.0]
    """

    name: str
    mat_sb_mb: np.ndarray
    members: tuple[int, ...]
    position_mb_m: np.ndarray | None = None

    @property
    def proper(self) -> bool:
        """True when the basis is a rotation (determinant +1)."""
        return bool(np.linalg.det(self.mat_sb_mb) > 0)


#: derived constants of geometries by content (H and the sub-units' rotations and members; :meth:`Geometry._constants`)
_CONSTANTS: dict[tuple, dict] = {}


class Geometry:
    """Sensing axes of a set of single-axis sensors, in the MB frame.

    Parameters
    ----------
    H : array_like, shape (n, 3)
        Unit sensing axes, one row per sensor, in MB coordinates.
    names : sequence of str, optional
        Sensor names (default ``s1 .. sn``). Unique.
    subunits : sequence of SubUnit, optional
        Grouping into sub-units. Default: one sub-unit ``"MB"`` with the identity basis, so nominal rows
        are the rows of H themselves.
    name : str
        Name of the geometry (a preset's key, or ``"custom"``).

    Raises
    ------
    GeometryError
        Non-finite entries, wrong shape, rows not of unit length (the message says how far off), names
        that do not match, sub-units that do not partition the sensors or whose basis is not orthonormal.
    RankDeficientError
        The axes span fewer than three dimensions; the message names the unobservable MB directions.

    Examples
    --------
    >>> g = Geometry([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0]], names=["a", "b", "c", "d"])
    >>> g.n, g.redundancy
    (4, 1)
    >>> np.allclose(g.parity_matrix() @ g.H, 0)
    True
    """

    def __init__(
        self,
        H: Any,
        names: Sequence[str] | None = None,
        subunits: Sequence[SubUnit] | None = None,
        name: str = "custom",
    ) -> None:
        H = _as_matrix(H)
        n = H.shape[0]
        if names is None:
            names = [f"s{i + 1}" for i in range(n)]
        names = tuple(str(s) for s in names)
        if len(names) != n:
            raise GeometryError(
                f"{len(names)} sensor names given for {n} rows of H; give exactly one name per row"
            )
        if len(set(names)) != n:
            dup = sorted({s for s in names if names.count(s) > 1})
            raise GeometryError(f"sensor names must be unique; repeated: {dup}")
        _check_rank(H)
        if subunits is None:
            subunits = (SubUnit("MB", np.eye(3), tuple(range(n))),)
        subunits = tuple(_check_subunit(su, H, n) for su in subunits)
        owner = np.full(n, -1)
        for j, su in enumerate(subunits):
            for i in su.members:
                if owner[i] >= 0:
                    raise GeometryError(
                        f"sensor {names[i]!r} is in sub-units {subunits[owner[i]].name!r} and {su.name!r}; "
                        "each sensor belongs to exactly one sub-unit"
                    )
                owner[i] = j
        missing = [names[i] for i in range(n) if owner[i] < 0]
        if missing:
            raise GeometryError(f"sensors {missing} belong to no sub-unit; add them to one")
        H.setflags(write=False)
        owner.setflags(write=False)
        self._H = H
        self._names = names
        self._subunits = subunits
        self._owner = owner
        self.name = str(name)

    # ------------------------------------------------------------------ basic views
    @property
    def H(self) -> np.ndarray:
        """Unit sensing axes, shape (n, 3), read-only."""
        return self._H

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    @property
    def subunits(self) -> tuple[SubUnit, ...]:
        return self._subunits

    @property
    def n(self) -> int:
        """Number of sensors."""
        return int(self._H.shape[0])

    @property
    def redundancy(self) -> int:
        """Dimension of the parity space, n - 3."""
        return self.n - 3

    def index(self, name: str) -> int:
        """Row index of the sensor called ``name``."""
        try:
            return self._names.index(name)
        except ValueError:
            raise GeometryError(f"no sensor called {name!r}; sensors are {list(self._names)}") from None

    def subunit_of(self, i: int) -> SubUnit:
        """The sub-unit of sensor ``i``."""
        return self._subunits[int(self._owner[i])]

    def nominal_rows(self) -> np.ndarray:
        """Nominal misalignment rows, shape (n, 3): each axis in its sub-unit's basis (unit vectors)."""
        const = self._constants()
        rows = const.get("nominal_rows")
        if rows is None:  # a constant of the geometry: computed once (calibration asks for it per sensor and fit)
            rows = np.empty((self.n, 3))
            for su in self._subunits:
                for i in su.members:
                    rows[i] = su.mat_sb_mb @ self._H[i]
            rows.setflags(write=False)
            const["nominal_rows"] = rows
        return rows.copy()

    def off_axis_basis(self, i: int) -> tuple[np.ndarray, tuple[str, str]]:
        """Two unit vectors (in the sub-unit basis) orthogonal to sensor ``i``'s nominal row, and their names.

        The components of a misalignment row along them are the two misalignment parameters of the
        sensor (small angles, rad). Where the nominal row is a basis axis (a triad), they are the other two
        axes and are named after them, as in Cho & Park's ``m_xy``, ``m_xz``; otherwise ``mis_1, mis_2``.
        """
        cache = self._constants().setdefault("off_axis", {})
        if i not in cache:  # a constant of the geometry: computed once per sensor
            E, names = self._off_axis_basis(i)
            E.setflags(write=False)
            cache[i] = (E, names)
        return cache[i]

    def off_axis_projections(self) -> np.ndarray:
        """``E_i C_i`` of every sensor, (n, 2, 3), read-only: its off-axis basis (:meth:`off_axis_basis`) times its
        sub-unit's rotation from MB, so that ``(E_i C_i) a`` are the misalignment components of an MB axis ``a``
        (Cho & Park 2005, Eq. 10). A constant of the geometry, computed once."""
        const = self._constants()
        P = const.get("off_axis_mb")
        if P is None:
            P = np.stack([self.off_axis_basis(i)[0] @ self.subunit_of(i).mat_sb_mb for i in range(self.n)])
            P.setflags(write=False)
            const["off_axis_mb"] = P
        return P

    def subunit_rotations(self) -> np.ndarray:
        """``mat_sb_mb`` of every sensor's sub-unit, (n, 3, 3), read-only: a constant of the geometry, computed once."""
        const = self._constants()
        C = const.get("subunit_rotations")
        if C is None:
            C = np.stack([self.subunit_of(i).mat_sb_mb for i in range(self.n)])
            C.setflags(write=False)
            const["subunit_rotations"] = C
        return C

    def _constants(self) -> dict:
        """The derived constants of this geometry (nominal rows, off-axis bases, ...), shared by every Geometry of
        the same axes and sub-units in the process (:data:`_CONSTANTS`): a loader that builds its unit's geometry
        afresh for every file does not compute them again for every fit."""
        const = self.__dict__.get("_const")
        if const is None:
            key = (self._H.tobytes(), tuple((su.mat_sb_mb.tobytes(), tuple(su.members)) for su in self._subunits))
            const = _CONSTANTS.get(key)
            if const is None:
                if len(_CONSTANTS) >= 256:  # many geometries made on the fly (tests, searches): start afresh
                    _CONSTANTS.clear()
                const = _CONSTANTS[key] = {}
            self._const = const
        return const

    def _off_axis_basis(self, i: int) -> tuple[np.ndarray, tuple[str, str]]:
        self.nominal_rows()  # (fills the cache)
        r = self._constants()["nominal_rows"][i]
        k = int(np.argmax(np.abs(r)))
        if abs(abs(r[k]) - 1.0) < 1e-9:
            others = [a for a in range(3) if a != k]
            E = np.zeros((2, 3))
            E[0, others[0]] = 1.0
            E[1, others[1]] = 1.0
            return E, (f"mis_{_AXIS_LETTERS[others[0]]}", f"mis_{_AXIS_LETTERS[others[1]]}")
        # a generic axis: complete it to an orthonormal basis deterministically
        seed = np.eye(3)[int(np.argmin(np.abs(r)))]
        e1 = seed - r * (seed @ r)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(r, e1)
        return np.vstack([e1, e2]), ("mis_1", "mis_2")

    # ------------------------------------------------------------------ algebra
    def projection(self) -> np.ndarray:
        """The least-squares projection ``(H^T H)^-1 H^T``, shape (3, n).

        de Oliveira et al. 2012, Eq. 3-4; Cho & Park 2005, Eq. 20 (without M and B).
        """
        return np.linalg.solve(self._H.T @ self._H, self._H.T)

    def parity_matrix(self) -> np.ndarray:
        """Orthonormal parity matrix V, shape (n - 3, n), with ``V @ H = 0`` and ``V @ V.T = I``.

        de Oliveira et al. 2012, Eq. 6-11: V is U_2^T, the left null space of H from its SVD. Each row's
        sign is fixed so that its largest-magnitude entry is positive (for the tetrad this gives Eq. 24,
        ``[-0.40825, -0.40825, -0.40825, 0.70711]``).
        """
        return null_space_rows(self._H)

    def fingerprint(self) -> str:
        """A short hash of H (to 1e-9), names and sub-units: calibrations are bound to it."""
        payload = {
            "H": np.round(self._H, 9).tolist(),
            "names": list(self._names),
            "subunits": [_subunit_dict(su, digits=9) for su in self._subunits],
        }
        blob = json.dumps(payload, sort_keys=True, separators=(",", ":")).replace("-0.0,", "0.0,")
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON description (used in calibration files and session sidecars)."""
        return {
            "name": self.name,
            "names": list(self._names),
            "H": self._H.tolist(),
            "subunits": [_subunit_dict(su) for su in self._subunits],
            "fingerprint": self.fingerprint(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Geometry":
        """Inverse of :meth:`to_dict`; raises GeometryError on a malformed description."""
        try:
            subunits = [
                SubUnit(str(s["name"]), np.asarray(s["mat_sb_mb"], dtype=float), tuple(int(m) for m in s["members"]),
                        None if s.get("position_mb_m") is None else np.asarray(s["position_mb_m"], dtype=float))
                for s in d.get("subunits") or []
            ] or None
            return cls(d["H"], names=d.get("names"), subunits=subunits, name=d.get("name", "custom"))
        except (KeyError, TypeError) as exc:
            raise GeometryError(f"geometry description is malformed ({exc!r}); expected keys H, names, subunits") from exc

    def positions_mb_m(self) -> np.ndarray:
        """Position of each sensor's sub-unit in MB, metres, shape (n, 3); NaN rows where none is known.

        >>> from rimu.geometry import triads
        >>> g = triads([np.eye(3), np.eye(3)], positions_mb_m=[[0, 0, 0], [0.1, 0, 0]])
        >>> g.positions_mb_m()[3].tolist()
        [0.1, 0.0, 0.0]
        """
        out = np.full((self.n, 3), np.nan)
        for su in self._subunits:
            if su.position_mb_m is not None:
                out[list(su.members)] = su.position_mb_m
        return out

    def __repr__(self) -> str:
        return f"Geometry({self.name!r}, n={self.n}, subunits={[s.name for s in self._subunits]})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Geometry) and self.fingerprint() == other.fingerprint()

    def __hash__(self) -> int:
        return hash(self.fingerprint())


# ---------------------------------------------------------------------- helpers
def null_space_rows(A: np.ndarray, rank: int = 3) -> np.ndarray:
    """Orthonormal basis of the left null space of ``A`` (n x 3) as rows, sign-normalised.

    de Oliveira et al. 2012, Eq. 6-11 (SVD of H; the last n - 3 columns of U).
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if n <= rank:
        return np.zeros((0, n))
    U, _, _ = np.linalg.svd(A, full_matrices=True)
    V = U[:, rank:].T.copy()
    for row in V:
        k = int(np.argmax(np.abs(row) - 1e-12 * np.arange(n)))  # first of the largest, robust to ties
        if row[k] < 0:
            row *= -1.0
    return V


def _as_matrix(H: Any) -> np.ndarray:
    try:
        H = np.array(H, dtype=float)
    except (TypeError, ValueError) as exc:
        raise GeometryError(f"H must be an n x 3 array of numbers: {exc}") from exc
    if H.ndim != 2 or H.shape[1] != 3:
        raise GeometryError(f"H must have shape (n, 3), one unit sensing axis per row; got shape {H.shape}")
    if H.shape[0] < 1:
        raise GeometryError("H has no rows; a geometry needs at least three sensors")
    bad = np.argwhere(~np.isfinite(H))
    if bad.size:
        r, c = bad[0]
        raise GeometryError(f"H has {len(bad)} non-finite entries, first at row {r}, column {c} ({H[r, c]})")
    norms = np.linalg.norm(H, axis=1)
    off = np.abs(norms - 1.0)
    if np.any(off > UNIT_TOL):
        i = int(np.argmax(off))
        raise GeometryError(
            f"rows of H must be unit vectors; row {i} has norm {norms[i]:.9g} (off by {norms[i] - 1:+.3g}). "
            "Normalise the row, or check the axis definition"
        )
    return H


def _check_rank(H: np.ndarray) -> None:
    _, s, Vt = np.linalg.svd(H, full_matrices=True)
    s = np.concatenate([s, np.zeros(3 - len(s))]) if len(s) < 3 else s
    small = [k for k in range(3) if s[k] <= 1e-9 * max(1.0, s[0])]
    if small:
        dirs = [np.round(Vt[k], 6).tolist() for k in small]
        raise RankDeficientError(
            f"the {H.shape[0]} sensing axes span only {3 - len(small)} dimension(s) of the MB frame; "
            f"rates or forces along these MB directions are not observed: {dirs}. "
            "Add or tilt sensors so that the axes span three dimensions",
            unobservable=dirs,
        )


def _check_subunit(su: SubUnit, H: np.ndarray, n: int) -> SubUnit:
    C = np.array(su.mat_sb_mb, dtype=float)
    if C.shape != (3, 3) or not np.all(np.isfinite(C)):
        raise GeometryError(f"sub-unit {su.name!r}: mat_sb_mb must be a finite 3 x 3 matrix, got shape {C.shape}")
    err = np.abs(C @ C.T - np.eye(3)).max()
    if err > 1e-6:
        raise GeometryError(f"sub-unit {su.name!r}: mat_sb_mb is not orthonormal (max |C C^T - I| = {err:.3g})")
    members = tuple(int(m) for m in su.members)
    if not members:
        raise GeometryError(f"sub-unit {su.name!r} has no members")
    bad = [m for m in members if not 0 <= m < n]
    if bad:
        raise GeometryError(f"sub-unit {su.name!r} names sensor indices {bad} outside 0..{n - 1}")
    C.setflags(write=False)
    pos = None
    if su.position_mb_m is not None:
        try:
            pos = np.array(su.position_mb_m, dtype=float)
        except (TypeError, ValueError) as exc:
            raise GeometryError(f"sub-unit {su.name!r}: position_mb_m must be 3 numbers (metres): {exc}") from exc
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise GeometryError(
                f"sub-unit {su.name!r}: position_mb_m must be 3 finite numbers (metres in MB), got {pos.tolist()}")
        pos.setflags(write=False)
    return SubUnit(su.name, C, members, pos)


def _subunit_dict(su: SubUnit, digits: int | None = None) -> dict[str, Any]:
    """Plain-JSON form of a sub-unit; ``position_mb_m`` only when known (old fingerprints stay the same)."""
    C = su.mat_sb_mb if digits is None else np.round(su.mat_sb_mb, digits)
    d: dict[str, Any] = {"name": su.name, "members": list(su.members), "mat_sb_mb": C.tolist()}
    if su.position_mb_m is not None:
        p = su.position_mb_m if digits is None else np.round(su.position_mb_m, digits) + 0.0
        d["position_mb_m"] = p.tolist()
    return d


def stack(rows: Iterable[Sequence[float]]) -> np.ndarray:
    """Stack axis rows into an array (convenience for presets)."""
    return np.array([list(r) for r in rows], dtype=float)
