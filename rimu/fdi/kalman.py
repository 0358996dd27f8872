"""A steady-state Kalman filter tracking slowly varying sensor biases in parity space, testing its estimate
(filterpy's KalmanFilter is the reference engine).

State: the parity-space bias ``beta`` (dof,), a random walk ``beta_k = beta_{k-1} + w``, ``w ~ N(0, q I)``;
measurement: the normalised parity ``p_k = beta_k + e``, ``e ~ N(0, I)``. The filter runs at its steady-state
gain ``K = (-q + sqrt(q^2 + 4 q)) / 2`` (scalar Riccati; the filter starts from the steady covariance), so
``beta_hat_k = (1 - K) beta_hat_{k-1} + K p_k``: an exponential average with time constant ``~ 1/K`` samples.

Tests (thresholds from the design false-alarm probability, per sample):

* the bias estimate: without a fault ``beta_hat`` is stationary with covariance ``K / (2 - K) I``, so
  ``T = (2 - K) / K |beta_hat|^2 ~ chi2(dof)``; isolation by ``argmax_j (v_j^T beta_hat)^2 / |v_j|^2``;
* the innovations ``nu = p - beta_pred``. The filter's own ``S = P_pred + I = (1 + K / (1 - K)) I`` assumes a
  wandering bias; without a fault the innovations are white with covariance ``(1 + K / (2 - K)) I``, so the
  test uses ``T_nu = (2 - K) / 2 |nu|^2 ~ chi2(dof)`` (exact per sample), :attr:`ParityKalman.innovation_statistic`,
  and ``test="innovation"`` makes it the detector's statistic (sensitive to abrupt changes; the estimate test
  to slow ones).

``p_fa`` is the marginal probability per sample. The estimate statistic is correlated over about ``tau``
samples, so false alarms come in episodes of several samples, and the manager's confirmation (consecutive
alarms) does little against them: in closed loop choose ``p_fa`` about ``tau`` times lower than for the snapshot
GLT (at 1e-3 and tau = 20 a replay of 8400 samples showed two false isolations; at 1e-4, none in 24 000).

A persistent bias b on sensor j makes ``beta_hat -> b v_j``; a drift (ramp) is followed with a lag of about
``rate / K``. The detector restarts when the active set changes.

Coloured noise (``noise=``, :mod:`rimu.fdi.whitening`): the estimate is an exponential average whose white
variance ``K / (2 - K)`` equals that of a boxcar of ``M = (2 - K) / K`` samples; under bias instability and
rate random walk its covariance is taken as that of an M-sample mean, ``C(M)`` of the noise model, and the
estimate test becomes ``T = |L beta_hat|^2`` with ``L = chol(C(M))^-1`` (the white case gives back
``(2 - K) / K |beta_hat|^2``). The innovation test is a difference of consecutive samples and their
average: the slow terms cancel in it, and it is left as it is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import NonFiniteError, ShapeError
from ..fusion.backend import resolve_backend
from .glt import as_noise_settings, block_isolate, glt_threshold, isolate_argmax
from .whitening import cached_whitener

__all__ = ["ParityKalman", "steady_gain"]


def steady_gain(q: float) -> float:
    """Steady-state Kalman gain of a random walk of variance q per step observed in unit noise.

    >>> round(steady_gain(0.01), 6)
    0.095125
    """
    return float((-q + np.sqrt(q * q + 4 * q)) / 2)


class ParityKalman:
    """Kalman filter of parity-space biases with a chi-square test on its estimate (see module doc).

    Parameters
    ----------
    tau : float
        Time constant of the bias estimate, samples (sets ``q = K^2 / (1 - K)`` with ``K = 1 / tau``).
    p_fa : float
        Per-sample false-alarm probability of the test on the estimate.
    engine : {"steady", "filterpy"}
        ``steady`` (default): the filter written out at its steady-state gain on Python floats,
        ``beta_hat = (1 - K) beta_hat + K p`` in the order of operations of :meth:`block` (``scipy.signal.lfilter``),
        so the per-sample and block statistics agree to rounding (the tests check 1e-12, alarms identical);
        ``filterpy``: the reference, a ``filterpy.kalman.KalmanFilter`` per active set (predict/update each
        sample; the tests check the steady engine against it), some 8x dearer per sample.
    noise : NoiseSettings or noise model, optional
        The sensors' noise model: the estimate test whitens with the covariance of the exponential average
        under it (module docstring).
    backend : {"auto", "numpy", "numba"}, optional
        Implementation of :meth:`block` (:mod:`rimu.fusion.backend`; default ``RIMU_BACKEND``, else ``auto``):
        numba runs the filter, its statistic and the isolation in one compiled pass
        (:func:`rimu.fdi._kernels.kalman_block`), numpy with ``scipy.signal.lfilter`` and
        :func:`rimu.fdi.glt.block_isolate`; the same statistics bit for bit, the same isolations (the whitened
        estimate test always takes numpy).
    """

    name = "kalman"
    window = 1

    def __init__(self, tau: float = 20.0, p_fa: float = 1e-3, engine: str = "steady",
                 test: str = "estimate", noise: object = None, backend: str | None = None) -> None:
        if engine not in ("filterpy", "steady"):
            raise ValueError(f"engine must be 'filterpy' or 'steady', got {engine!r}")
        if test not in ("estimate", "innovation"):
            raise ValueError(f"test must be 'estimate' or 'innovation', got {test!r}")
        self.engine = engine
        self.test = test
        if not tau > 1:
            raise ValueError(f"tau must exceed one sample, got {tau}")
        self.tau = float(tau)
        K = 1.0 / tau
        self.q = K * K / (1 - K)
        self.K = steady_gain(self.q)
        self.p_fa = p_fa
        self.noise = as_noise_settings(noise)
        self.backend = resolve_backend(backend)
        self._L: np.ndarray | None = None
        self._dof = 0
        self.kf: Any = None  # filterpy.kalman.KalmanFilter with engine="filterpy"
        self.innovation_statistic = 0.0

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        """New active set: a fresh filter in the new parity basis."""
        self._dof = int(dof)
        self._V = np.asarray(Vz)[:dof]
        self._thr = glt_threshold(self.p_fa, dof) if dof >= 1 else float("inf")
        self._x = [0.0] * max(dof, 0)
        self._nu = [0.0] * max(dof, 0)
        if dof < 1:
            self.kf = None
            return
        self._L = self.whitening(Vz, dof)
        self._VL = self._V if self._L is None else self._L @ self._V
        self._S_inv = (2.0 - self.K) / 2.0  # inverse of the innovations' variance without a fault
        self._scale = (2 - self.K) / self.K
        if self.engine == "steady":
            self.kf = None
            return
        from filterpy.kalman import KalmanFilter  # the reference engine only

        kf = KalmanFilter(dim_x=dof, dim_z=dof)
        kf.F = np.eye(dof)
        kf.H = np.eye(dof)
        kf.R = np.eye(dof)
        kf.Q = self.q * np.eye(dof)
        kf.P = self.K * np.eye(dof)  # steady state: P = K for unit measurement noise
        kf.x = np.zeros(dof)
        self.kf = kf

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        kf = self.kf
        if kf is None:
            d = self._dof
            if d < 1:
                return 0.0, float("inf")
            x, nuv = self._x, self._nu
            K, a = self.K, 1.0 - self.K
            t = nu2 = 0.0
            for i, z in enumerate(parity.tolist()[:d]):
                nuv[i] = nu = z - x[i]
                nu2 += nu * nu
                x[i] = xi = a * x[i] + K * z  # the steady filter, as lfilter([K], [1, -(1 - K)]) computes it
                t += xi * xi
            self.innovation_statistic = nu2 * self._S_inv
            if self.test == "innovation":
                return self.innovation_statistic, self._thr
            if self._L is not None:
                q = self._L @ np.array(x)
                return float(q @ q), self._thr
            return t * self._scale, self._thr
        z = parity[:self._dof]
        kf.predict()
        kf.update(z)
        y = kf.y
        self.innovation_statistic = float(y @ y) * self._S_inv
        if self.test == "innovation":
            return self.innovation_statistic, self._thr
        x = kf.x
        if self._L is not None:
            q = self._L @ x
            return float(q @ q), self._thr
        return float(x @ x) * self._scale, self._thr

    @property
    def equivalent_window(self) -> float:
        """Samples of the boxcar with the white variance of the estimate: ``(2 - K) / K``."""
        return (2.0 - self.K) / self.K

    def whitening(self, Vz: np.ndarray, dof: int) -> np.ndarray | None:
        """``L`` (dof, dof) of the estimate under the noise model (module docstring), cached per set; or None."""
        M = self.equivalent_window
        # whitener() whitens M C(M); the estimate's covariance is C(M) itself
        return cached_whitener(self, Vz, dof, M, np.sqrt(M))

    @property
    def bias(self) -> np.ndarray:
        """Current parity-space bias estimate (dof,)."""
        return np.array(self._x) if self.kf is None else self.kf.x.copy()

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        """The sensor that best explains what the test saw: the bias estimate (``test="estimate"``) or the
        last innovation (``test="innovation"``), as :meth:`block` isolates."""
        if self._dof < 1:
            return -1, np.zeros(self._V.shape[1])
        if self.test == "innovation":
            nu = np.array(self._nu) if self.kf is None else np.asarray(self.kf.y, dtype=float).copy()
            return isolate_argmax(nu, self._V)
        if self._L is not None:
            return isolate_argmax(self._L @ self.bias, self._VL)
        return isolate_argmax(self.bias, self._V)

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        """The same filter over N samples from a fresh start (steady gain, vectorised): (statistic, threshold,
        isolated). Like :meth:`configure` then :meth:`update` per sample: the statistic is a filter state, so
        an alarm restarts nothing (the manager restarts the filter when the active set changes). The statistics
        are those of :meth:`update` bit for bit (``nu_k = p_k - beta_{k-1}``, ``beta`` in lfilter's order, the
        squares summed in component order), except with a noise model (the whitening is a matrix product, to
        rounding).

        Raises
        ------
        ShapeError
            ``P`` is not (N, >= dof).
        NonFiniteError
            ``P`` holds NaN or inf in its first ``dof`` columns.
        """
        K = self.K
        thr = glt_threshold(self.p_fa, dof) if dof >= 1 else float("inf")
        if dof < 1:
            return np.zeros(len(P)), thr, np.full(len(P), -1)
        P = np.asarray(P, dtype=float)
        if P.ndim != 2 or P.shape[1] < dof:
            raise ShapeError(f"the parity block must be (N, >= dof = {dof}), got shape {P.shape}")
        L = self.whitening(Vz, dof) if self.test == "estimate" else None
        if self.backend == "numba" and L is None:
            from ._kernels import kalman_block

            V = np.ascontiguousarray(Vz[:dof], dtype=float)
            stat, iso = np.empty(len(P)), np.empty(len(P), dtype=np.int64)
            scale = (2.0 - K) / 2.0 if self.test == "innovation" else (2 - K) / K
            if not kalman_block(P, dof, K, self.test == "innovation", scale, V, np.einsum("ij,ij->j", V, V), stat,
                                iso):
                raise _non_finite()
            return stat, thr, iso
        # time along the contiguous axis: lfilter, the differences and the sums of squares run over rows of
        # N samples (the isolation takes the transposed view, as BLAS does without a copy)
        ZT = P[:, :dof].T
        with np.errstate(invalid="ignore", over="ignore"):     # checked once, on the statistic
            from scipy.signal import lfilter  # imported where used: scipy.signal brings scipy.stats (~40 MB)

            BT = lfilter([K], [1.0, -(1.0 - K)], ZT, axis=1)   # beta_k = (1 - K) beta_{k-1} + K p_k
            if self.test == "innovation":                       # nu_k = p_k - beta_{k-1}, as update(), into BT:
                for e in range(BT.shape[1], 1, -_CHUNK):          # backwards, each chunk reads beta before it is
                    s = max(e - _CHUNK, 1)                        # overwritten (no fresh N-sample array: page
                    np.subtract(ZT[:, s:e], BT[:, s - 1:e - 1], out=BT[:, s:e])   # faults cost more than the pass)
                BT[:, :1] = ZT[:, :1]
                stat = _row_sum_squares(BT)
                stat *= (2.0 - K) / 2.0
                X, V = BT.T, Vz[:dof]
            elif L is not None:
                X, V = BT.T @ L.T, L @ Vz[:dof]
                stat = _row_sum_squares(np.ascontiguousarray(X.T))
            else:
                stat = _row_sum_squares(BT)
                stat *= (2 - K) / K
                X, V = BT.T, Vz[:dof]
        if not np.isfinite(stat).all():                        # a filter state carries it to every later sample
            raise _non_finite()
        return stat, thr, block_isolate(X, V)


def _non_finite() -> NonFiniteError:
    return NonFiniteError("the parity block holds a non-finite value (NaN or inf); the Kalman filter would carry it "
                          "to every later sample: leave invalid samples out of the block (or set their parity to 0, "
                          "as the campaign does) before calling block()")


#: samples per step of the in-place innovations (numpy copies an overlapping input: a small copy per chunk)
_CHUNK = 4096


def _row_sum_squares(T: np.ndarray) -> np.ndarray:
    """Column sums of squares of T (d, N), summed in row order (the order of the per-sample path)."""
    s = T[0] * T[0]
    for i in range(1, T.shape[0]):
        s += T[i] * T[i]
    return s
