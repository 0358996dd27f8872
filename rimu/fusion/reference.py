"""The former projection table: every active set precomputed up front (reference for tests and benchmarks).

Kept as the reference that :class:`rimu.fusion.ProjectionTable` (sets computed when they occur, in a bounded
cache) is checked and benchmarked against. Its size grows as the sum of C(n, k) over k <= max_excluded: use it
for small units only (n <= 62; mask codes are int64).

For calibrated axes A (n x 3, rows a_i) and per-sensor noise sigma_i, with W = diag(1/sigma):

* estimate in MB (weighted least squares; Cho & Park Eq. 20, de Oliveira Eq. 3-4)::

      x = G z,   G = (A^T W^2 A)^-1 A^T W^2,   P = cov(x) = (A^T W^2 A)^-1

* normalised parity (de Oliveira Eq. 6-11 applied to the whitened rows W A)::

      p = V_w W z,   V_w = null space rows of W A,   cov(p) = I when there is no fault

  With equal sigmas V_w is the ordinary parity matrix V of A and ``p = V z / sigma``.

Isolating sensor k (Cho & Park Eq. 21: zero its row of H and its output) is the same as using the table
entry of the active set without k: G and V_w then have zero columns at k.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from ..errors import RankDeficientError, ShapeError
from ..geometry import null_space_rows
from .projection import mask_bits

__all__ = ["FullProjectionTable"]


class FullProjectionTable:
    """Precomputed ``G``, ``V_w W``, ``P`` for every active set of at least three sensors.

    Parameters
    ----------
    axes : ndarray (n, 3)
        Calibrated sensing axes in MB (need not be exactly unit: they are whatever maps the input to the
        compensated output).
    sigma : float or ndarray (n,)
        White-noise standard deviation of each compensated output, SI units.
    max_excluded : int, optional
        Largest number of excluded sensors to precompute (default n - 3: every observable set).

    Attributes
    ----------
    G : ndarray (K, 3, n)
    Vz : ndarray (K, n - 3, n)
        Normalised parity rows ``V_w W`` padded with zero rows up to n - 3.
    P : ndarray (K, 3, 3)
        Estimate covariance; ``inf`` on the diagonal for unobservable sets.
    dof : ndarray (K,)
        Parity dimension n_active - 3 (0 for unobservable sets).
    observable : ndarray (K,) of bool
    codes : ndarray (K,) of int
        Mask code of each entry.
    """

    def __init__(self, axes: np.ndarray, sigma: float | np.ndarray = 1.0, max_excluded: int | None = None) -> None:
        A = np.asarray(axes, dtype=float)
        if A.ndim != 2 or A.shape[1] != 3:
            raise ShapeError(f"axes must have shape (n, 3), got {A.shape}")
        n = A.shape[0]
        s = np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ShapeError(f"sigma must be positive and finite, got {s.tolist()}")
        if np.linalg.matrix_rank(A) < 3:
            raise RankDeficientError("the calibrated axes do not span three dimensions")
        self.n = n
        self.axes = A
        self.sigma = s
        max_ex = n - 3 if max_excluded is None else min(int(max_excluded), n)
        sets: list[tuple[int, ...]] = []
        for k in range(max_ex + 1):
            for excl in combinations(range(n), k):
                sets.append(tuple(i for i in range(n) if i not in excl))
        K = len(sets)
        r = max(n - 3, 0)
        self.G = np.zeros((K, 3, n))
        self.Vz = np.zeros((K, r, n))
        self.P = np.zeros((K, 3, 3))
        self.dof = np.zeros(K, dtype=np.int64)
        self.observable = np.zeros(K, dtype=bool)
        self.codes = np.zeros(K, dtype=np.int64)
        self._index: dict[int, int] = {}
        w = 1.0 / s
        for e, act in enumerate(sets):
            code = sum(1 << i for i in act)
            self.codes[e] = code
            self._index[code] = e
            idx = list(act)
            Aw = A[idx] * w[idx, None]
            if len(idx) < 3 or np.linalg.matrix_rank(Aw, tol=1e-9) < 3:
                self.P[e] = np.diag([np.inf] * 3)
                continue
            info = Aw.T @ Aw
            P = np.linalg.inv(info)
            P = 0.5 * (P + P.T)
            self.P[e] = P
            self.G[e][:, idx] = P @ (Aw * w[idx, None]).T
            Vw = null_space_rows(Aw)
            d = Vw.shape[0]
            self.Vz[e, :d][:, idx] = Vw * w[idx][None, :]
            self.dof[e] = d
            self.observable[e] = True
        self.full_code = (1 << n) - 1

    def __len__(self) -> int:
        return len(self.codes)

    def lookup(self, code: int) -> int:
        """Entry index of an active-set code; the unobservable entry ``-1`` when not precomputed."""
        return self._index.get(int(code), -1)

    def entry_for(self, active: np.ndarray) -> int:
        return self.lookup(mask_bits(active))
