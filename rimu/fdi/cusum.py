"""CUSUM bank on the parity vector for soft faults (small biases, slow drifts), threshold from ARL0.

For a bias ``b`` on sensor j the normalised parity is ``p ~ N(b v_j, I)``. With ``X_j = u_j^T p``
(``u_j = v_j / |v_j|``, unit variance under no fault) and ``delta_j = b |v_j|`` the log-likelihood ratio of
one sample is ``delta_j (X_j - delta_j / 2)``; Page's CUSUM accumulates it (Page 1954)::

    S_j+ = max(0, S_j+ + delta_j (X_j - delta_j / 2)),   S_j- the same with -X_j

and alarms when any statistic of the bank crosses its threshold; the sensor of that statistic is isolated.
Each threshold comes from the in-control average run length (ARL0, the mean number of samples between false
alarms) through Siegmund's approximation for Gaussian CUSUMs (Siegmund 1985, Eq. 2.57)::

    ARL(Delta) ~ (exp(-2 Delta b) + 2 Delta b - 1) / (2 Delta^2),   b = h + 1.166

in units of X (reference value k = delta / 2, Delta = mean of X - k). The bank has 2 n_active one-sided
statistics; each is designed for ``2 n_active * ARL0`` so that the bank's rate of false alarms is at most
1 / ARL0 (false alarms of the members are rare, nearly independent events). For a fault the expected delay
approaches ``ln(ARL0) / I`` with ``I = delta^2 / 2`` the Kullback-Leibler information per sample (Lorden 1971).

:func:`markov_arl` (Brook & Evans 1972) computes the run length of any CUSUM numerically; it checks
Siegmund's formula in the tests and designs the dead-band baseline (:mod:`rimu.fdi.baseline`).

Coloured noise (``noise=``, :mod:`rimu.fdi.whitening`). Bias instability and rate random walk make X_j's
mean wander; a CUSUM designed for white X then alarms far more often than 1/ARL0 over a long run. Over one
false-alarm excursion (about ``M = h / k`` samples) the slow part is nearly constant: X_j ~ N(mu, 1) with a
mean ``mu ~ N(0, sigma_mu,j^2)`` that changes slowly from excursion to excursion, ``sigma_mu,j^2 =
u_j^T C_slow(M) u_j`` (the bias-instability and random-walk part of the covariance of an M-sample mean of the
parity, over the stated horizon). The long-run rate of false alarms is then the average of the rates
(renewal: one alarm per ARL)::

    1 / ARL0_eff = E_mu[ 1 / ARL(mu - k, h) ]     (Siegmund's ARL, Gauss-Hermite quadrature over mu)

and each threshold is the h that makes this the design rate (:func:`cusum_threshold_mixture`), with M from
the white design. The white-noise design is the special case ``sigma_mu = 0``. Where sigma_mu approaches k
the threshold grows fast: the bank cannot tell a fault of the design size from the sensors' own wander.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable

import numpy as np
from scipy.optimize import brentq
from scipy.stats import norm  # noqa: F401  (used by the doctests)

from .whitening import window_covariance

__all__ = ["siegmund_arl", "cusum_threshold", "cusum_threshold_mixture", "markov_arl", "CusumBank"]


def siegmund_arl(drift: float, h: float) -> float:
    """Siegmund's approximation of the ARL of ``S = max(0, S + X - k)``, X ~ N(mu, 1), ``drift = mu - k``.

    Siegmund 1985 (Sequential Analysis, Eq. 2.57); h in units of X.

    >>> round(siegmund_arl(-0.5, 4.0))  # the exact value (Brook & Evans) is 336
    338
    """
    b = h + 1.166
    if abs(drift) < 1e-9:
        return b * b
    return float((np.exp(-2 * drift * b) + 2 * drift * b - 1) / (2 * drift * drift))


def cusum_threshold(arl0: float, k: float) -> float:
    """Threshold h (units of X) of a one-sided Gaussian CUSUM with reference k and in-control ARL ``arl0``.

    Inverts :func:`siegmund_arl` at ``drift = -k``.

    >>> h = cusum_threshold(1e4, 0.5)
    >>> round(siegmund_arl(-0.5, h))
    10000
    """
    if not arl0 > 1:
        raise ValueError(f"arl0 must exceed 1 sample, got {arl0}")
    if not k > 0:
        raise ValueError(f"the reference value k must be positive, got {k}")
    hi = 1.0
    while siegmund_arl(-k, hi) < arl0:
        hi *= 2.0
    return float(brentq(lambda h: siegmund_arl(-k, h) - arl0, 0.0, hi))


def cusum_threshold_mixture(arl0: float, k: float, sigma_mu: float, nodes: int = 40) -> float:
    """Threshold h whose false-alarm rate averaged over a slowly varying mean ``mu ~ N(0, sigma_mu^2)`` is
    ``1 / arl0`` (module docstring); :func:`cusum_threshold` when ``sigma_mu = 0``.

    >>> h0 = cusum_threshold(1e4, 0.5)
    >>> round(cusum_threshold_mixture(1e4, 0.5, 0.0), 6) == round(h0, 6), cusum_threshold_mixture(1e4, 0.5, 0.2) > h0
    (True, True)
    """
    if not sigma_mu > 0:
        return cusum_threshold(arl0, k)
    x, w = np.polynomial.hermite_e.hermegauss(nodes)
    w = w / w.sum()
    mu = sigma_mu * x

    def excess(h: float) -> float:
        with np.errstate(over="ignore"):  # a very negative drift: ARL overflows to inf, its rate is 0
            rate = sum(wi / siegmund_arl(m - k, h) for m, wi in zip(mu, w))
        return float(np.log(rate * arl0))

    lo = cusum_threshold(arl0, k)
    hi = lo
    while excess(hi) > 0:
        hi *= 2.0
        if hi > 1e9:
            raise ValueError(f"no CUSUM threshold reaches ARL0 {arl0:g} with a wander of {sigma_mu:g} against k = {k:g}")
    return float(brentq(excess, lo, hi)) if hi > lo else lo


def markov_arl(h: float, cdf: Callable[[np.ndarray], np.ndarray], states: int = 300) -> float:
    """ARL of ``S = max(0, S + X)``, alarm when ``S > h``, from zero, for increments with cumulative ``cdf``.

    Brook & Evans 1972: the interval [0, h] is cut into ``states`` cells; the transition probabilities
    between cells give the run lengths by one linear solve, ``(I - R) L = 1``.

    >>> round(markov_arl(4.0, lambda x: norm.cdf(x + 0.5)), 1)  # k = 0.5, h = 4: tables give 336
    335.4
    """
    w = h / (states - 0.5)
    centres = np.arange(states) * w  # cell 0 is the atom at 0 (width w/2)
    edges_hi = centres + w / 2
    edges_lo = centres - w / 2
    hi = cdf(edges_hi[None, :] - centres[:, None])
    lo = cdf(edges_lo[None, :] - centres[:, None])
    R = hi - lo
    R[:, 0] = hi[:, 0]  # everything below w/2 (incl. the reflection at 0)
    L = np.linalg.solve(np.eye(states) - R, np.ones(states))
    return float(L[0])


#: designs kept per detector (least recently used dropped first)
_DESIGNS_KEPT = 128


def _white_only(settings):  # type: ignore[no-untyped-def]
    """The same settings at horizon 0 (white and quantisation part only)."""
    from dataclasses import replace

    return replace(settings, horizon_s=0.0)


def cached_design(detector: object, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
    """``detector._design(Vz, dof)``, computed once per active set (keyed by the parity rows) and kept on the
    detector: designs depend only on the set, and the per-sample path must not redo them."""
    key = (np.asarray(Vz)[:dof].tobytes(), int(dof))
    cache = detector.__dict__.setdefault("_designs", OrderedDict())
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    cache[key] = detector._design(Vz, dof)  # type: ignore[attr-defined]
    while len(cache) > _DESIGNS_KEPT:  # bounded like the projection cache: many-sensor units see many sets
        cache.popitem(last=False)
    return cache[key]


class CusumBank:
    """Two one-sided CUSUMs per sensor on the normalised parity vector (see the module docstring).

    Parameters
    ----------
    bias : float or ndarray (n,)
        Design bias per sensor, in the units of the raw compensated output (SI). Use
        ``k * sigma`` for a bias of k sigma.
    arl0 : float
        In-control average run length of the whole bank, samples.
    noise : NoiseSettings or noise model, optional
        The sensors' noise model: each statistic is designed on its effective sigma (module docstring).

    Notes
    -----
    After an alarm call :meth:`reset` (the manager does, when the active set changes); the open-loop
    :meth:`block` path restarts every statistic at each alarm (renewal), so its alarm count measures ARL0.
    """

    name = "cusum"
    window = 1

    def __init__(self, bias: float | np.ndarray, arl0: float = 1e5, noise: object = None) -> None:
        from .glt import as_noise_settings

        self.bias = np.asarray(bias, dtype=float)
        if np.any(self.bias <= 0):
            raise ValueError("the design bias must be positive")
        self.arl0 = float(arl0)
        self.noise = as_noise_settings(noise)
        self._S = np.zeros((2, 0))
        self._dof = 0
        self._last = -1

    # ---------------------------------------------------------------- design per active set
    def design(self, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Unit columns U (dof, n), delta (n,), LLR thresholds (n,) and an active mask for one set."""
        return cached_design(self, Vz, dof)

    def _design(self, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
        V = Vz[:dof]
        nv = np.linalg.norm(V, axis=0)
        act = nv > 1e-12
        n = V.shape[1]
        bias = np.broadcast_to(self.bias, (n,))
        U = np.zeros_like(V)
        U[:, act] = V[:, act] / nv[act]
        delta = np.where(act, bias * nv, 0.0)
        m = 2 * int(act.sum())
        thr = np.full(n, np.inf)
        for j in np.flatnonzero(act):
            sigma_mu = self.wander(Vz, dof, U[:, j], delta[j], m * self.arl0) if self.noise is not None else 0.0
            thr[j] = delta[j] * cusum_threshold_mixture(m * self.arl0, delta[j] / 2.0, sigma_mu)
        return U, delta, thr, act

    def wander(self, Vz: np.ndarray, dof: int, u: np.ndarray, delta: float, arl: float) -> float:
        """``sigma_mu`` (units of X) of the slow mean along the unit parity direction ``u`` (module docstring)."""
        k = delta / 2.0
        M = max(cusum_threshold(arl, k) / k, 1.0)
        C = window_covariance(Vz, dof, self.noise, M) / M  # type: ignore[arg-type]  (covariance of the mean)
        C_white = window_covariance(Vz, dof, _white_only(self.noise), M) / M  # type: ignore[arg-type]
        return float(np.sqrt(max(u @ (C - C_white) @ u, 0.0)))

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        """Use the parity rows of a new active set; every statistic restarts at zero."""
        self._dof = int(dof)
        n = Vz.shape[1]
        self._n = n
        self._S = [0.0] * (2 * n)  # [S+ of every sensor, S- of every sensor], plain floats (cheap per sample)
        if dof >= 1:
            U, d, thr, _ = self.design(Vz, dof)
            self._W = np.ascontiguousarray(np.concatenate([U * d, -U * d], axis=1))  # LLR slope per statistic
            self._half = np.concatenate([d * d / 2, d * d / 2]).tolist()
            inv = np.where(np.isfinite(thr), 1.0 / thr, 0.0)
            self._inv = np.concatenate([inv, inv]).tolist()

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        """Advance the bank by one sample; returns (largest statistic / its threshold, 1.0)."""
        if self._dof < 1:
            return 0.0, float("inf")
        X = (parity[:self._dof] @ self._W).tolist()
        S, half, inv = self._S, self._half, self._inv
        best, kb = 0.0, 0
        for k in range(len(S)):
            v = S[k] + X[k] - half[k]
            if v < 0.0:
                v = 0.0
            S[k] = v
            r = v * inv[k]
            if r > best:
                best, kb = r, k
        self._last = kb % self._n
        return best, 1.0

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        """The sensor whose statistic crossed (isolable only where ``dof >= 2``)."""
        R = np.array(self._S) * np.array(self._inv) if self._dof >= 1 else np.zeros(2 * self._n)
        ratios = np.maximum(R[: self._n], R[self._n:])
        return (self._last if self._dof >= 2 else -1), ratios

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        """Run the bank over N samples of one set, restarting after each alarm; (stat/thr (N,), 1.0, sensor (N,))."""
        U, d, thr, _act = self.design(Vz, dof)
        X = P[:, :dof] @ U
        N, n = X.shape
        out = np.zeros(N)
        iso = np.full(N, -1)
        S = np.zeros((2, n))
        inc_p = d * (X - d / 2)
        inc_m = d * (-X - d / 2)
        with np.errstate(invalid="ignore"):
            for t in range(N):
                S[0] += inc_p[t]
                S[1] += inc_m[t]
                np.maximum(S, 0.0, out=S)
                r = S / thr
                k = int(np.argmax(r))
                out[t] = r.flat[k]
                if out[t] > 1.0:
                    iso[t] = k % n if dof >= 2 else -1
                    S[:] = 0.0
        return out, 1.0, iso
