"""Generalized likelihood test on the normalised parity vector (Daly, Gai & Harrison 1979).

With the pipeline's normalised parity ``p = V_w W z`` (unit covariance without a fault, see
:mod:`rimu.fusion.projection`):

* detection: ``FD = p^T p`` against the chi-square quantile with ``dof = n_active - 3`` degrees of freedom
  at the design false-alarm probability;
* isolation: a bias ``b`` on sensor j adds ``b v_j`` to p, where v_j is column j of ``V_w W``; the
  likelihood ratio of "sensor j" is ``(v_j^T p)^2 / |v_j|^2`` and the isolated sensor is its argmax.

With a sensor noise model (``noise=``, :mod:`rimu.fdi.whitening`) the parity (or the window sum) is first
whitened with ``L = chol(M C)^-1``, C the covariance of the window mean under white noise, quantisation,
bias instability and rate random walk over the stated horizon: the statistic stays chi-square over long runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri

from .whitening import NoiseSettings, cached_whitener

__all__ = ["glt_threshold", "GltDecision", "glt_snapshot", "GltSnapshot", "GltWindow", "isolate_argmax", "block_isolate"]


def glt_threshold(p_fa: float, dof: int) -> float:
    """Chi-square threshold with false-alarm probability ``p_fa`` for ``dof`` degrees of freedom.

    >>> round(glt_threshold(1e-3, 3), 4)
    16.2662
    """
    if not 0 < p_fa < 1:
        raise ValueError(f"p_fa must be in (0, 1), got {p_fa}")
    if dof < 1:
        return float("inf")
    return float(chdtri(dof, p_fa))  # chi2.isf(p_fa, dof), without importing scipy.stats (~40 MB)


@dataclass
class GltDecision:
    statistic: float
    threshold: float
    detected: bool
    isolated: int  # -1 when not isolable or not detected
    ratios: np.ndarray


def glt_snapshot(parity: np.ndarray, Vz: np.ndarray, dof: int, p_fa: float = 1e-3,
                 active: np.ndarray | None = None) -> GltDecision:
    """One-sample GLT decision.

    Parameters
    ----------
    parity : ndarray (n - 3,)
        Normalised parity vector (zero-padded past ``dof``).
    Vz : ndarray (n - 3, n)
        The parity matrix that produced it (``ProjectionTable.Vz[entry]``).
    dof : int
    p_fa : float
    active : ndarray of bool, optional
        Candidates for isolation (default: sensors with a non-zero parity column).
    """
    p = parity[:dof]
    V = Vz[:dof]
    fd = float(p @ p)
    thr = glt_threshold(p_fa, dof)
    norms2 = np.einsum("ij,ij->j", V, V)
    cand = norms2 > 1e-12 if active is None else (np.asarray(active, bool) & (norms2 > 1e-12))
    ratios = np.zeros(V.shape[1])
    ratios[cand] = (V[:, cand].T @ p) ** 2 / norms2[cand]
    detected = fd > thr
    iso = int(np.argmax(ratios)) if (detected and dof >= 2 and cand.any()) else -1
    return GltDecision(fd, thr, detected, iso, ratios)


class GltSnapshot:
    """The one-sample GLT as a detector object (the interface every detector of :mod:`rimu.fdi` has).

    Daly, Gai & Harrison 1979: ``FD = p^T p`` against ``chi2_{1 - p_fa}(dof)``; isolation by
    ``argmax_j (v_j^T p)^2 / |v_j|^2`` (only where ``dof >= 2``).

    The detector interface: :meth:`configure` (new active set: parity rows and dof; forgets the past),
    :meth:`update` (one sample: statistic and threshold), :meth:`isolate` (after an alarm: the sensor and
    the ratios), :meth:`block` (vectorised, N samples of one set, for campaigns).

    Parameters
    ----------
    p_fa : float
        Per-sample false-alarm probability.
    noise : NoiseSettings or noise model, optional
        The sensors' noise model (:class:`rimu.noise.InstrumentNoise`, or :class:`NoiseSettings` to state
        the horizon); None: white noise of the pipeline's levels.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> V = cone6().parity_matrix()
    >>> det = GltSnapshot(1e-3)
    >>> det.configure(V, 3)
    >>> stat, thr = det.update(10 * V[:, 4])  # a 10 sigma bias on y2, no noise
    >>> stat > thr, det.isolate(10 * V[:, 4])[0]
    (True, 4)
    """

    name = "glt"
    window = 1

    def __init__(self, p_fa: float = 1e-3, noise: object = None) -> None:
        if not 0 < p_fa < 1:
            raise ValueError(f"p_fa must be in (0, 1), got {p_fa}")
        self.p_fa = p_fa
        self.noise = as_noise_settings(noise)
        self._thr = {d: glt_threshold(p_fa, d) for d in range(0, 64)}
        self._V = np.zeros((0, 0))
        self._dof = 0
        self._L: np.ndarray | None = None

    def whitening(self, Vz: np.ndarray, dof: int) -> np.ndarray | None:
        """``L`` of :mod:`rimu.fdi.whitening` for this active set and window (cached per set), or None."""
        return cached_whitener(self, Vz, dof, self.window)

    def threshold(self, dof: int) -> float:
        return self._thr[dof] if dof in self._thr else glt_threshold(self.p_fa, dof)

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        """Use the parity rows ``Vz`` (r, n) with ``dof`` valid rows from now on; forget the past."""
        self._V = np.asarray(Vz)[:dof]
        self._dof = int(dof)
        self._t = self.threshold(self._dof)
        self._L = self.whitening(Vz, dof)
        if self._L is not None:
            self._V = self._L @ self._V

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        """Statistic and threshold of one sample (the fast path: no isolation work)."""
        d = self._dof
        if d < 1:
            return 0.0, float("inf")
        if self._L is not None:
            q = self._L @ parity[:d]
            return float(q @ q), self._t
        s = 0.0
        for x in parity.tolist()[:d]:  # a few components: Python floats beat numpy's per-call overhead
            s += x * x
        return s, self._t

    def block_update(self, P: np.ndarray) -> np.ndarray | None:
        """The statistics :meth:`update` gives for the parity rows ``P`` (N, r) one after the other, bit for bit
        (the same sums in the same order), or None where it cannot promise that (a whitened statistic,
        a subclass with memory): the block fast path of :meth:`rimu.fdi.RedundancyManager.run`."""
        d = self._dof
        if type(self) is not GltSnapshot or self._L is not None or d < 1:
            return None
        s = np.zeros(len(P))
        for j in range(d):
            c = P[:, j]
            s += c * c
        return s

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        """Most likely faulty sensor for the current sample (call after an alarm), and the ratios."""
        p = parity[:self._dof]
        return isolate_argmax(p if self._L is None else self._L @ p, self._V)

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        """Vectorised statistics for N samples of one active set: (statistic (N,), threshold, isolated (N,))."""
        p = P[:, :dof]
        V = Vz[:dof]
        L = self.whitening(Vz, dof)
        if L is not None:
            p, V = p @ L.T, L @ V
        stat = np.einsum("ij,ij->i", p, p)
        return stat, self.threshold(dof), block_isolate(p, V)


class GltWindow(GltSnapshot):
    """GLT on the mean parity vector of the last ``window`` samples.

    For a bias held over the window, ``N |mean(p)|^2 ~ chi2(dof, N b^2 |v_j|^2)`` (Daly, Gai & Harrison
    1979, with the N-sample likelihood): the same threshold, a noncentrality N times larger. The window
    restarts when the active set changes (isolation, invalid sample); until it is full, the statistic uses
    the samples it has (still chi-square under no fault).

    Parameters
    ----------
    window : int
        N samples.
    p_fa : float
        False-alarm probability of each statistic (consecutive statistics overlap and are correlated).
    noise : NoiseSettings or noise model, optional
        With it the window sum is whitened with the covariance of a window mean under the model's bias
        instability and random walk (:mod:`rimu.fdi.whitening`); the first ``window - 1`` statistics use the
        full window's covariance (conservative).
    """

    name = "glt_window"

    def __init__(self, window: int = 5, p_fa: float = 1e-3, noise: object = None) -> None:
        super().__init__(p_fa, noise)
        if window < 1:
            raise ValueError(f"window must be at least 1, got {window}")
        self.window = int(window)
        self._buf = np.zeros((self.window, 0))
        self._sum = np.zeros(0)
        self._k = 0
        self._count = 0

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        super().configure(Vz, dof)
        d = max(dof, 0)
        # plain Python lists: for a parity vector of a few components they beat numpy's per-call overhead
        self._buf = [[0.0] * d for _ in range(self.window)]
        self._sum = [0.0] * d
        self._k = 0
        self._count = 0

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        d = self._dof
        if d < 1:
            return 0.0, float("inf")
        p = parity.tolist()[:d]
        k = self._k
        old = self._buf[k]
        self._buf[k] = p
        s = self._sum
        for i in range(d):
            s[i] += p[i] - old[i]
        k += 1
        if k == self.window:  # refresh the running sum once per turn (no drift)
            k = 0
            for i in range(d):
                s[i] = sum(b[i] for b in self._buf)
        self._k = k
        if self._count < self.window:
            self._count += 1
        if self._L is not None:
            q = self._L @ np.array(s)
            return float(q @ q) / self._count, self._t
        return sum(x * x for x in s) / self._count, self._t

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        S = np.array(self._sum)
        return isolate_argmax(S if self._L is None else self._L @ S, self._V)

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        """Sliding-window statistics of N samples, (N,); the first ``window - 1`` use the samples available."""
        p = P[:, :dof]
        c = np.cumsum(p, axis=0)
        S = c.copy()
        S[self.window:] -= c[:-self.window]
        cnt = np.minimum(np.arange(1, len(p) + 1), self.window)
        V = Vz[:dof]
        L = self.whitening(Vz, dof)
        if L is not None:
            S, V = S @ L.T, L @ V
        stat = np.einsum("ij,ij->i", S, S) / cnt
        return stat, self.threshold(dof), block_isolate(S, V)


def as_noise_settings(noise: object) -> NoiseSettings | None:
    """None, a :class:`NoiseSettings`, or a bare noise model (wrapped with the default horizon)."""
    if noise is None or isinstance(noise, NoiseSettings):
        return noise
    return NoiseSettings(noise)


def isolate_argmax(p: np.ndarray, V: np.ndarray) -> tuple[int, np.ndarray]:
    """``argmax_j (v_j^T p)^2 / |v_j|^2`` over the columns with a non-zero norm; -1 when ``dof < 2``.

    Daly, Gai & Harrison 1979 (isolation part of the GLT). With one parity dimension every column is
    collinear and the ratios tie: no isolation is possible, and -1 says so.
    """
    n2 = np.einsum("ij,ij->j", V, V)
    ratios = np.zeros(V.shape[1])
    ok = n2 > 1e-12
    ratios[ok] = (p @ V[:, ok]) ** 2 / n2[ok]
    if V.shape[0] < 2 or not ok.any():
        return -1, ratios
    usable = np.flatnonzero(ok)  # a column of zero norm is never the answer, even where every ratio is 0
    return int(usable[np.argmax(ratios[usable])]), ratios


def block_isolate(P: np.ndarray, V: np.ndarray) -> np.ndarray:
    """:func:`isolate_argmax` for every row of P (N, dof); -1 everywhere when ``dof < 2``."""
    N = P.shape[0]
    if V.shape[0] < 2:
        return np.full(N, -1)
    n2 = np.einsum("ij,ij->j", V, V)
    ok = np.flatnonzero(n2 > 1e-12)
    if ok.size == 0:  # no column can be told apart: argmax of the all -1 rows
        return np.zeros(N, dtype=np.intp)
    # sensors along the rows (n small, N long): one product, then a running maximum over the n rows (the first
    # index wins a tie, as argmax): a third of the time of (P @ V) ** 2 / n2 and its argmax along the short axis
    S = V[:, ok].T @ P.T
    np.square(S, out=S)
    S /= n2[ok, None]
    best = S[0].copy()
    idx = np.full(N, ok[0], dtype=np.intp)
    for j in range(1, ok.size):
        better = S[j] > best
        np.maximum(best, S[j], out=best)
        idx[better] = ok[j]
    return idx
