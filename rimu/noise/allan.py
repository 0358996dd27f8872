"""Overlapping Allan deviation of every sensor, with confidence intervals (allantools, optional extra ``noise``).

For rate-type samples ``y_k`` (rad/s, m/s^2) at ``fs`` the overlapping Allan variance at ``tau = m / fs`` is
(IEEE Std 952-1997, Annex C; NIST SP 1065, Eq. 11)::

    AVAR(tau) = 1 / (2 (N - 2m + 1)) sum_k (ybar_{k+m} - ybar_k)^2,   ybar_k the mean of y_k .. y_{k+m-1}

computed by :func:`allantools.oadev` (``data_type="freq"``). Its confidence interval uses the equivalent
degrees of freedom of Greenhall & Riley (allantools ``edf_greenhall``, overlapping, d = 2) for the power-law
noise type ``alpha`` (frequency PSD ``S_y ~ f^alpha``: 2 quantisation, 0 white rate noise, -1 flicker,
-2 rate random walk) and the chi-square interval ``edf AVAR / chi2_{(1 +/- ci) / 2}(edf)`` (NIST SP 1065,
Eq. 45). The noise type of each tau comes from the local slope of the measured curve unless given (the fit
of :mod:`rimu.noise.fit` passes the dominant term of its model).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.stats import chi2

from ..errors import NonFiniteError, ShapeError

__all__ = ["ALPHA_OF_SLOPE", "AllanDeviation", "allan_deviation", "edf", "require_allantools", "tau_grid"]

#: allantools' alpha of each power-law term (frequency noise S_y(f) ~ f^alpha)
ALPHA_OF_TERM = {"quantization": 2, "white": 0, "bias_instability": -1, "rate_random_walk": -2}
#: AVAR slope mu (AVAR ~ tau^mu) -> alpha, for the slopes of the four terms
ALPHA_OF_SLOPE = {-2: 2, -1: 0, 0: -1, 1: -2}
#: one-sigma confidence level
ONE_SIGMA = 0.6826894921370859


def require_allantools() -> Any:
    """Import allantools, or raise an ImportError that names the extra to install."""
    try:
        import allantools
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("the Allan deviation needs allantools: pip install 'rimu[noise]'") from exc
    return allantools


def tau_grid(n_samples: int, per_decade: int = 8, max_fraction: float = 0.25) -> np.ndarray:
    """Cluster sizes m (integers, log-spaced, ``per_decade`` per decade) from 1 to ``max_fraction * N``.

    >>> tau_grid(1000, per_decade=2).tolist()
    [1, 3, 10, 32, 100]
    """
    top = max(int(n_samples * max_fraction), 1)
    k = np.arange(int(np.floor(np.log10(top) * per_decade + 1e-9)) + 1)
    m = np.unique(np.round(10.0 ** (k / per_decade)).astype(int))
    return m[(m >= 1) & (m <= top)]


@lru_cache(maxsize=4096)
def edf(alpha: int, m: int, n_samples: int) -> float:
    """Equivalent degrees of freedom of the overlapping AVAR at cluster size m (Greenhall & Riley, allantools).

    Falls back to the simple estimate of NIST SP 1065 (Eq. 47 family, ``edf_simple``) where Greenhall's
    algorithm does not apply.
    """
    at = require_allantools()
    try:
        v = float(at.edf_greenhall(alpha=int(alpha), d=2, m=int(m), N=int(n_samples) + 1, overlapping=True))
    except Exception:  # allantools raises plain exceptions for unsupported corners
        v = float(at.edf_simple(int(n_samples) + 1, int(m), int(alpha)))
    return max(v, 1.0)


def interval(avar: np.ndarray, dof: np.ndarray, ci: float = ONE_SIGMA) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) of the deviation from AVAR estimates and their degrees of freedom (NIST SP 1065, Eq. 45)."""
    lo_q, hi_q = (1 - ci) / 2, (1 + ci) / 2
    return np.sqrt(dof * avar / chi2.ppf(hi_q, dof)), np.sqrt(dof * avar / chi2.ppf(lo_q, dof))


@dataclass
class AllanDeviation:
    """Overlapping Allan deviation of n sensors.

    Attributes
    ----------
    tau : ndarray (m,)
        Averaging times, s.
    cluster : ndarray (m,) of int
        Samples per cluster.
    adev : ndarray (n, m)
        Overlapping Allan deviation, SI (rad/s, m/s^2).
    alpha : ndarray (n, m) of int
        Noise type used for the interval.
    dof : ndarray (n, m)
        Equivalent degrees of freedom.
    lo, hi : ndarray (n, m)
        One-sigma (68.3 %) confidence interval of ``adev``.
    sample_rate : float
    n_samples : int
    names : list of str
    """

    tau: np.ndarray
    cluster: np.ndarray
    adev: np.ndarray
    alpha: np.ndarray
    dof: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    sample_rate: float
    n_samples: int
    names: list[str] = field(default_factory=list)

    def with_alpha(self, alpha: np.ndarray) -> AllanDeviation:
        """The same curve with the intervals recomputed for the noise types ``alpha`` (n, m)."""
        alpha = np.asarray(alpha, dtype=int)
        dof = np.array([[edf(int(a), int(m), self.n_samples) for a, m in zip(row, self.cluster)] for row in alpha])
        lo, hi = interval(self.adev ** 2, dof)
        return AllanDeviation(self.tau, self.cluster, self.adev, alpha, dof, lo, hi, self.sample_rate,
                              self.n_samples, list(self.names))

    def to_dict(self) -> dict[str, Any]:
        """``tau``, ``adev``, ``lo``, ``hi`` (SI) for the noise file."""
        return {"tau": self.tau.tolist(), "adev": self.adev.tolist(), "lo": self.lo.tolist(), "hi": self.hi.tolist()}


def allan_deviation(z: np.ndarray, sample_rate: float, names: list[str] | None = None, per_decade: int = 8,
                    max_fraction: float = 0.25) -> AllanDeviation:
    """Overlapping Allan deviation of every column of ``z`` (N, n) with one-sigma confidence intervals.

    Parameters
    ----------
    z : ndarray (N, n)
        Rate-type samples of a static recording, SI (a constant input such as gravity or the Earth rate
        does not change the result).
    sample_rate : float
        Hz.
    names : list of str, optional
    per_decade : int
        Averaging times per decade of tau.
    max_fraction : float
        Longest cluster as a fraction of the record (0.25: at least 4 clusters).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = allan_deviation(rng.standard_normal((100000, 1)), 100.0, per_decade=1)
    >>> a.tau.tolist()
    [0.01, 0.1, 1.0, 10.0, 100.0]
    >>> np.round(a.adev[0, :3] * np.sqrt(a.cluster[:3]), 1).tolist()    # white: sigma(tau) = sigma / sqrt(m)
    [1.0, 1.0, 1.0]
    >>> round(float(a.dof[0, -1]), 1)     # 10 clusters of 100 s; the overlapping estimate has 12.8 edf
    12.8
    """
    at = require_allantools()
    z = np.asarray(z, dtype=float)
    if z.ndim == 1:
        z = z[:, None]
    if z.ndim != 2 or z.shape[0] < 16:
        raise ShapeError(f"the Allan deviation needs an (N, n) block of at least 16 samples, got shape {z.shape}")
    if not np.all(np.isfinite(z)):
        bad = int((~np.isfinite(z)).any(axis=1).sum())
        raise NonFiniteError(f"{bad} samples hold non-finite values; cut the recording to a clean static stretch")
    if not (sample_rate > 0 and np.isfinite(sample_rate)):
        raise ShapeError(f"sample_rate must be a positive number of Hz, got {sample_rate}")
    N, n = z.shape
    m = tau_grid(N, per_decade, max_fraction)
    taus = m / sample_rate
    adev = np.empty((n, len(m)))
    for i in range(n):
        # remove the mean first: a large constant input (gravity) costs digits in the phase cumulative sum
        t_out, dev, _, _ = at.oadev(z[:, i] - z[:, i].mean(), rate=sample_rate, data_type="freq", taus=taus)
        if len(t_out) != len(m):
            keep = np.isin(np.round(taus, 12), np.round(t_out, 12))
            m, taus, adev = m[keep], taus[keep], adev[:, keep]
        adev[i] = dev
    slope = np.gradient(np.log(adev ** 2), np.log(taus), axis=1) if len(m) > 1 else np.full((n, 1), -1.0)
    mu = np.clip(np.round(slope), -2, 1).astype(int)
    alpha = np.vectorize(ALPHA_OF_SLOPE.get)(mu)
    out = AllanDeviation(taus, m, adev, alpha, np.ones_like(adev), adev, adev, float(sample_rate), N,
                         list(names) if names is not None else [f"s{i}" for i in range(n)])
    return out.with_alpha(alpha)
