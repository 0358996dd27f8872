"""Time-series statistics of residuals, pooled over segments: autocorrelation and the Ljung-Box test."""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["autocorrelation", "ljung_box"]


def autocorrelation(r: np.ndarray, seg_index: np.ndarray, lags: int) -> np.ndarray:
    """Autocorrelation of the residual at lags 1..h, pooled over segments (pairs never span two segments)."""
    r = r - np.mean(r)
    den = float(r @ r)
    out = np.zeros(lags)
    if den == 0:
        return out
    starts = np.flatnonzero(np.diff(seg_index) != 0) + 1  # first sample of each later segment
    n = r.size
    for k in range(1, min(lags, n - 1) + 1):
        acc = float(r[k:] @ r[:-k])
        for b in starts:  # remove the pairs (t, t + k) that straddle a segment boundary
            lo = max(b - k, 0)
            hi = min(b, n - k)
            if hi > lo:
                acc -= float(r[lo:hi] @ r[lo + k:hi + k])
        out[k - 1] = acc / den
    return out


def ljung_box(rho: np.ndarray, n: int) -> tuple[float, float]:
    """Ljung-Box statistic and p-value for autocorrelations ``rho`` (lags 1..h) of n samples."""
    h = rho.size
    k = np.arange(1, h + 1)
    q = float(n * (n + 2) * np.sum(rho**2 / (n - k)))
    return q, float(special.chdtrc(h, q))  # the chi-square(h) survival function
