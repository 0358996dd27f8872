"""Projection and parity matrices of an active set of sensors, computed when the set first occurs.

For calibrated axes A (n x 3, rows a_i) and per-sensor noise sigma_i, with W = diag(1/sigma):

* estimate in MB (weighted least squares; Cho & Park Eq. 20, de Oliveira Eq. 3-4)::

      x = G z,   G = (A^T W^2 A)^-1 A^T W^2,   P = cov(x) = (A^T W^2 A)^-1

* normalised parity (de Oliveira Eq. 6-11 applied to the whitened rows W A)::

      p = V_w W z,   V_w = null space rows of W A,   cov(p) = I when there is no fault

  With equal sigmas V_w is the ordinary parity matrix V of A and ``p = V z / sigma``.

Isolating sensor k (Cho & Park Eq. 21: zero its row of H and its output) is the same as using the
matrices of the active set without k: G and V_w then have zero columns at k.

Why not a table of every set. A unit of n sensors has ``sum_k C(n, k)`` exclusion sets; for 24 axes and up
to 21 exclusions that is 16 million sets of 24 x 24 matrices (the 63 GiB of issue 19), for 96 axes more than
any memory holds. Only a handful of sets ever occur in a run (the full set, the set after each isolation,
the sets of samples with an invalid or saturated value), so :class:`ProjectionTable` computes the
matrices of a set when it first occurs -- one SVD of an n x 3 matrix, O(n^2) work and memory -- and keeps
them in a least-recently-used cache of ``cache_size`` sets. The full set is computed at construction and
never evicted. Build time and memory are therefore O(n^2) (one set), not exponential in n, and the
per-sample path stays a matrix-vector product: a set is decomposed only when it changes.

Entries are numbered in the order sets are first computed (the full set is entry 0); a number is never
reused, so an entry of an evicted set raises ``KeyError`` instead of silently pointing at another set.
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import RankDeficientError, ShapeError
from ..geometry import null_space_rows

__all__ = ["ActiveSet", "ProjectionTable", "bits_mask", "mask_bits"]

#: sets kept by default besides the full set: at least this many, and 2 n (every single exclusion fits, so a
#: sensor dropping out now and then, whichever it is, never makes the cache recompute a set per sample)
DEFAULT_CACHE_SIZE = 64


def mask_bits(active: np.ndarray) -> int:
    """Integer code of a boolean active mask (bit i set = sensor i active); any n (a Python int).

    >>> mask_bits(np.array([True, False, True])), mask_bits(np.ones(70, bool)) == (1 << 70) - 1
    (5, True)
    """
    a = np.asarray(active, dtype=bool)
    return int.from_bytes(np.packbits(a, bitorder="little").tobytes(), "little")


def bits_mask(code: int, n: int) -> np.ndarray:
    """Boolean mask of n sensors from an integer code (inverse of :func:`mask_bits`).

    >>> bits_mask(5, 3).tolist()
    [True, False, True]
    """
    code = int(code)
    if code < 0:
        return np.zeros(n, dtype=bool)
    nbytes = max(1, (n + 7) // 8)
    b = np.frombuffer((code & ((1 << n) - 1)).to_bytes(nbytes, "little"), dtype=np.uint8)
    return np.unpackbits(b, bitorder="little")[:n].astype(bool)


@dataclass(frozen=True, eq=False)
class ActiveSet:
    """What one active set needs at run time (read-only arrays).

    Attributes
    ----------
    entry : int
        Its number in the table (never reused).
    code : int
        Mask code (:func:`mask_bits`).
    active : ndarray (n,) of bool
    G : ndarray (3, n)
        Weighted least-squares projection, zero columns at inactive sensors.
    Vz : ndarray (n - 3, n)
        Normalised parity rows ``V_w W`` padded with zero rows up to n - 3.
    P : ndarray (3, 3)
        Estimate covariance; ``inf`` on the diagonal for an unobservable set.
    dof : int
        Parity dimension n_active - 3 (0 when unobservable).
    observable : bool
        The active axes span three dimensions.
    R : ndarray (n, n) or None
        ``[G; Vz] * scale``: raw outputs to (x, parity) with the scale factor folded in (a table built with
        ``scale``), so that ``R y - off`` is the whole per-sample computation.
    off : ndarray (n,) or None
        ``[G; Vz] @ bias``.
    """

    entry: int
    code: int
    active: np.ndarray
    G: np.ndarray
    Vz: np.ndarray
    P: np.ndarray
    dof: int
    observable: bool
    R: np.ndarray | None = None
    off: np.ndarray | None = None

    @property
    def n_active(self) -> int:
        return int(self.active.sum())


class _Field:
    """``table.G[e]``, ``table.Vz[e, :d]``, ``table.P[entries]``: one attribute of the cached sets by entry."""

    def __init__(self, table: ProjectionTable, name: str) -> None:
        self._table = table
        self._name = name

    def __getitem__(self, key: Any) -> Any:
        rest: tuple[Any, ...] = ()
        if isinstance(key, tuple):
            key, rest = key[0], key[1:]
        if isinstance(key, (int, np.integer)):
            v = getattr(self._table.set(int(key)), self._name)
            return v[rest] if rest else v
        keys = np.asarray(key)
        if keys.dtype == bool:
            raise TypeError("index the sets by entry numbers, not by a boolean mask")
        flat = keys.reshape(-1)
        vals = {int(e): getattr(self._table.set(int(e)), self._name) for e in np.unique(flat)}
        out = np.stack([np.asarray(vals[int(e)]) for e in flat]) if flat.size else np.zeros((0,))
        out = out.reshape(keys.shape + out.shape[1:])
        return out[(slice(None),) * keys.ndim + rest] if rest else out

    def __len__(self) -> int:
        return len(self._table)


class ProjectionTable:
    """``G``, ``V_w W``, ``P`` of the active sets that occur, computed on first use, kept in an LRU cache.

    Parameters
    ----------
    axes : ndarray (n, 3)
        Calibrated sensing axes in MB (need not be exactly unit: they are whatever maps the input to the
        compensated output).
    sigma : float or ndarray (n,)
        White-noise standard deviation of each compensated output, SI units.
    max_excluded : int, optional
        Deprecated, without effect: every set is computed when it occurs. (It bounded the former table of
        every exclusion set up front; a set beyond it was treated as unobservable.)
    cache_size : int, optional
        Sets kept besides the full set (least recently used evicted first); default ``max(64, 2 n)``. A set that
        occurs again after eviction is computed again (a new entry number).
    scale, bias : ndarray (n,), optional
        Fold the compensation ``z = scale * y - bias`` into each set (:attr:`ActiveSet.R`, :attr:`ActiveSet.off`).

    Attributes
    ----------
    G, Vz, P, dof, observable, codes, active
        Per-entry views: ``table.Vz[e]`` is the ``Vz`` of entry e (``table.set(e).Vz``); an integer array of
        entries gives the stacked arrays.
    full_code : int
        Code of the set of every sensor; its entry is 0.
    computed : int
        Sets computed so far (misses); ``hits`` and ``evictions`` count the rest.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> tab = ProjectionTable(cone6().H, 0.01)
    >>> tab.lookup(tab.full_code), int(tab.dof[0]), len(tab)
    (0, 3, 1)
    >>> e = tab.lookup(tab.full_code & ~(1 << 4))   # y2 isolated: computed now
    >>> int(tab.dof[e]), bool(tab.active[e][4]), len(tab)
    (2, False, 2)
    """

    def __init__(self, axes: np.ndarray, sigma: float | np.ndarray = 1.0, max_excluded: int | None = None, *,
                 cache_size: int | None = None, scale: np.ndarray | None = None,
                 bias: np.ndarray | None = None) -> None:
        A = np.asarray(axes, dtype=float)
        if A.ndim != 2 or A.shape[1] != 3:
            raise ShapeError(f"axes must have shape (n, 3), got {A.shape}")
        n = A.shape[0]
        s = np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ShapeError(f"sigma must be positive and finite, got {s.tolist()}")
        if np.linalg.matrix_rank(A) < 3:
            raise RankDeficientError("the calibrated axes do not span three dimensions")
        if max_excluded is not None:
            warnings.warn("max_excluded has no effect any more: active sets are computed when they occur "
                          "(rimu.fusion.ProjectionTable); drop the argument", DeprecationWarning, stacklevel=2)
        if cache_size is None:
            cache_size = max(DEFAULT_CACHE_SIZE, 2 * n)
        if int(cache_size) < 1:
            raise ValueError(f"cache_size must be at least 1 set, got {cache_size}")
        self.n = n
        self.r = max(n - 3, 0)
        self.axes = A
        self.sigma = s
        self.cache_size = int(cache_size)
        self._scale = None if scale is None else np.broadcast_to(np.asarray(scale, float), (n,)).copy()
        self._bias = None if bias is None else np.broadcast_to(np.asarray(bias, float), (n,)).copy()
        if self._bias is not None and self._scale is None:
            self._scale = np.ones(n)
        if self._scale is not None and self._bias is None:
            self._bias = np.zeros(n)
        self.full_code = (1 << n) - 1
        self._by_code: OrderedDict[int, ActiveSet] = OrderedDict()
        self._by_entry: dict[int, ActiveSet] = {}
        self._next = 0
        self.computed = 0
        self.hits = 0
        self.evictions = 0
        self._full = self._compute(self.full_code)
        self._by_entry[0] = self._full
        for name in ("G", "Vz", "P", "dof", "observable", "code", "active"):
            setattr(self, "codes" if name == "code" else name, _Field(self, name))

    # ------------------------------------------------------------------ cache
    def __len__(self) -> int:
        """Sets held now (the full set included)."""
        return 1 + len(self._by_code)

    def get(self, code: int) -> ActiveSet:
        """The :class:`ActiveSet` of a mask code, computed now if it is not cached."""
        code = int(code)
        if code == self.full_code:
            self.hits += 1
            return self._full
        s = self._by_code.get(code)
        if s is not None:
            self._by_code.move_to_end(code)
            self.hits += 1
            return s
        if code < 0 or code > self.full_code:
            raise ValueError(f"mask code {code} is not a set of {self.n} sensors")
        s = self._compute(code)
        self._by_code[code] = s
        self._by_entry[s.entry] = s
        while len(self._by_code) > self.cache_size:
            _, old = self._by_code.popitem(last=False)
            del self._by_entry[old.entry]
            self.evictions += 1
        return s

    def get_mask(self, active: np.ndarray) -> ActiveSet:
        return self.get(mask_bits(active))

    def lookup(self, code: int) -> int:
        """Entry number of an active-set code (the set is computed now if needed)."""
        return self.get(code).entry

    def entry_for(self, active: np.ndarray) -> int:
        return self.lookup(mask_bits(active))

    def set(self, entry: int) -> ActiveSet:
        """The cached set of an entry number; ``KeyError`` when it was evicted (look it up again by code)."""
        s = self._by_entry.get(int(entry))
        if s is None:
            raise KeyError(f"entry {entry} is not in the projection cache (evicted, or never computed); "
                           f"look the set up again by its code (ProjectionTable.get), or raise cache_size "
                           f"(now {self.cache_size})")
        return s

    def memory_bytes(self) -> int:
        """Bytes held by the cached arrays."""
        tot = 0
        for s in [self._full, *self._by_code.values()]:
            tot += sum(a.nbytes for a in (s.active, s.G, s.Vz, s.P) + ((s.R, s.off) if s.R is not None else ()))
        return tot

    # ------------------------------------------------------------------ one set
    def _compute(self, code: int) -> ActiveSet:
        """G, Vz, P of one set: Cho & Park Eq. 20-21 (rows removed), de Oliveira Eq. 6-11 (SVD null space)."""
        n, A, s = self.n, self.axes, self.sigma
        act = bits_mask(code, n)
        idx = np.flatnonzero(act)
        G = np.zeros((3, n))
        Vz = np.zeros((self.r, n))
        P = np.diag([np.inf] * 3)
        dof, observable = 0, False
        w = 1.0 / s
        Aw = A[idx] * w[idx, None]
        if len(idx) >= 3 and np.linalg.matrix_rank(Aw, tol=1e-9) >= 3:
            P = np.linalg.inv(Aw.T @ Aw)
            P = 0.5 * (P + P.T)
            G[:, idx] = P @ (Aw * w[idx, None]).T
            Vw = null_space_rows(Aw)
            dof = Vw.shape[0]
            Vz[:dof][:, idx] = Vw * w[idx][None, :]
            observable = True
        R = off = None
        if self._scale is not None:
            K = np.concatenate([G, Vz], axis=0)
            R = np.ascontiguousarray(K * self._scale[None, :])
            off = K @ self._bias
            R.setflags(write=False)
            off.setflags(write=False)
        for a in (act, G, Vz, P):
            a.setflags(write=False)
        entry = self._next
        self._next += 1
        self.computed += 1
        return ActiveSet(entry, code, act, G, Vz, P, dof, observable, R, off)

    def cached(self) -> list[ActiveSet]:
        """The sets held now, the full set first, then least to most recently used."""
        return [self._full, *self._by_code.values()]

    def derived(self, name: str, entry: int, compute: Callable[[ActiveSet], Any]) -> Any:
        """A quantity derived from one set (e.g. the manager's isolability), computed once per entry and
        dropped with the set."""
        s = self.set(entry)
        store = s.__dict__.setdefault("_derived", {})
        if name not in store:
            store[name] = compute(s)
        return store[name]
