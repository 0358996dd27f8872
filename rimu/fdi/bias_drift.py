"""The time constant of the relative-bias tracker, from the drift the setup's own data show (issue 32).

:class:`rimu.fdi.MotionAwareGlt` follows each sensor's residual at rest with an exponential mean of time constant
tau (``bias_track_s``). Its error has two parts: the noise it lets through and the drift it lags behind. With
the residual's white noise of power spectral density ``N^2`` ((rad/s)^2 per Hz: the angle random walk
coefficient squared, ``N^2 = sigma^2 g / fs`` for a per-sample sigma, a long-run gain g of the chip's low-pass
correlation and the sample rate fs) and a relative bias that walks with variance growth ``K^2`` per second (the
rate random walk), an exponential mean of ``alpha = 1 / (tau fs)`` has the steady-state error variance::

    e^2(tau) = N^2 / (2 tau) + K^2 tau / 2          (white part sigma^2 g alpha / 2, lag part K^2 / (2 alpha fs))

smallest at::

    tau* = N / K

which is where the two asymptotes of the Allan variance of the same residual cross,
``sigma_A^2(T) = N^2 / T + K^2 T / 3`` (IEEE Std 952, Annex C): its minimum lies at ``T_min = sqrt(3) N / K``, so
``tau* = T_min / sqrt(3)``, the averaging time beyond which averaging stops helping, over sqrt(3). Nothing in it
is chosen after seeing a run: N and K are measured on the setup's fit window.

K is measured on the poses at rest of that window: the mean residual ``m_j`` of each span at rest (of at least
``min_span_s``) at its mid time ``t_j``, and for every pair of spans the variogram::

    E[(m_j - m_i)^2] = c + K^2 |t_j - t_i|

fitted by least squares over all pairs (c: the spans' own noise and any pose-dependent part, which does not
grow with time). N from the same spans: the variance of each span's residual about its mean, times the long-run
gain measured on them (the variance of 1 s means over 1/fs_per_s of the sample variance). Per sensor
``tau_i = N_i / K_i``; the tracker takes the median over the sensors (a sensor with no drift seen, ``K_i^2 <= 0``,
counts as an infinite tau), capped at the span the drift was measured over (no drift seen: that span).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError

__all__ = ["BiasDrift", "bias_drift"]


@dataclass
class BiasDrift:
    """The drift of each sensor's residual at rest and the tracker time constant it gives (module docstring).

    Attributes
    ----------
    tau_s : float
        The tracker's time constant, s: the median of ``tau_i``, capped at ``span_s``.
    tau_i_s : ndarray (n,)
        ``N_i / K_i`` per sensor, s (inf where no drift is seen).
    arw : ndarray (n,)
        N_i, the white noise density of the residual, output units per sqrt(Hz) (rad/s/sqrt(Hz) for gyros).
    rrw_var : ndarray (n,)
        K_i^2, the variance growth of the residual's bias, output units^2 per s (may be <= 0: no drift seen).
    spans : int
        Spans at rest the drift was measured on.
    span_s : float
        Time from the first to the last of them, s.
    """

    tau_s: float
    tau_i_s: np.ndarray
    arw: np.ndarray
    rrw_var: np.ndarray
    spans: int
    span_s: float

    def describe(self, unit: str = "deg/s", factor: float = 180.0 / np.pi) -> str:
        """One line: the time constant, the median N and K in ``unit`` (``factor`` converts from SI)."""
        k = np.sqrt(np.clip(np.median(self.rrw_var), 0.0, None))
        return (f"bias tracker time constant {self.tau_s:.3g} s = N/K (median over sensors; N {factor * np.median(self.arw):.3g} "
                f"{unit}/sqrt(Hz), K {factor * k:.3g} {unit}/sqrt(s) (medians), from {self.spans} spans at rest over "
                f"{self.span_s:.0f} s)")


def bias_drift(residuals: np.ndarray, rest: np.ndarray, sample_rate: float, min_span_s: float = 2.0) -> BiasDrift:
    """Measure the white noise density and the bias random walk of each sensor's residual at rest, and the
    tracker time constant ``tau = N / K`` they give (module docstring).

    Parameters
    ----------
    residuals : ndarray (N, n)
        Each sensor's parity residual (``sigma^2 V^T p``), output units, at ``sample_rate`` Hz.
    rest : ndarray (N,) of bool
        The samples at rest with every sensor valid.
    min_span_s : float
        The shortest span at rest that gives a pose mean, s.

    Raises
    ------
    ShapeError
        Fewer than three spans at rest: no drift can be told from noise.

    Examples
    --------
    A residual that walks with K = 1e-4 per sqrt(s) under white noise of N = 1e-3 per sqrt(Hz), 30 poses of 10 s
    at 10 Hz: tau near N / K = 10 s.

    >>> rng = np.random.default_rng(0)
    >>> fs, n = 10.0, 30 * 200
    >>> walk = np.cumsum(rng.standard_normal((n, 4)) * 1e-4 / np.sqrt(fs), axis=0)
    >>> res = walk + 1e-3 * np.sqrt(fs) * rng.standard_normal((n, 4))
    >>> rest = (np.arange(n) % 200) < 100                    # 10 s at rest, 10 s moving
    >>> d = bias_drift(res, rest, fs)
    >>> d.spans, 5.0 < d.tau_s < 20.0
    (30, True)
    """
    R = np.asarray(residuals, float)
    rest = np.asarray(rest, bool)
    if R.ndim != 2 or len(rest) != len(R):
        raise ShapeError(f"residuals (N, n) and rest (N,) must match, got {R.shape} and {rest.shape}")
    fs = float(sample_rate)
    n = R.shape[1]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(np.int8), [0]])))
    segs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if (b - a) / fs >= min_span_s]
    if len(segs) < 3:
        raise ShapeError(f"{len(segs)} spans at rest of at least {min_span_s:g} s: the bias drift needs three or more "
                         "(give a fit window with more poses at rest, or a fixed --bias-track)")
    m = np.array([R[a:b].mean(axis=0) for a, b in segs])
    tc = np.array([(a + b - 1) / 2.0 / fs for a, b in segs])
    # white noise density: per-sample variance about each span's mean, times the long-run gain of 1 s means
    L = max(1, int(round(fs)))
    var, num, den = np.zeros(n), np.zeros(n), np.zeros(n)
    cnt = 0
    for a, b in segs:
        x = R[a:b] - R[a:b].mean(axis=0)
        var += (x * x).sum(axis=0)
        cnt += len(x)
        if len(x) >= 4 * L:
            c = np.cumsum(np.vstack([np.zeros(n), x]), axis=0)
            mm = (c[L:] - c[:-L]) / L
            num += (mm * mm).mean(axis=0) * len(x)
            den += (x * x).mean(axis=0) * len(x)
    var /= max(cnt - len(segs), 1)
    gain = np.maximum(1.0, L * num / np.where(den > 0, den, 1.0)) if den.any() else np.ones(n)
    arw = np.sqrt(var * gain / fs)
    # variogram of the span means: (m_j - m_i)^2 = c + K^2 |t_j - t_i|, every pair
    i, j = np.triu_indices(len(segs), 1)
    X = np.column_stack([np.ones(len(i)), tc[j] - tc[i]])
    coef = np.linalg.lstsq(X, (m[j] - m[i]) ** 2, rcond=None)[0]
    k2 = coef[1]
    with np.errstate(divide="ignore"):
        tau_i = np.where(k2 > 0, arw / np.sqrt(np.where(k2 > 0, k2, 1.0)), np.inf)
    span = float(tc[-1] - tc[0])
    tau = float(min(np.median(tau_i), span))
    return BiasDrift(tau, tau_i, arw, k2, len(segs), span)
