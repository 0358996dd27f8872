"""Coloured noise sources of the simulator: flicker (bias instability) as a sum of Gauss-Markov processes.

A first-order Gauss-Markov process of variance ``s^2`` and time constant T has the one-sided PSD
``4 s^2 T / (1 + (2 pi f T)^2)``. Processes with time constants spaced evenly in log T, ``d`` per decade,
all of variance ``s^2 = B^2 ln 10 / (pi d)``, sum to the flicker spectrum ``S(f) = B^2 / (pi f)`` (one-sided;
IEEE Std 952's ``B^2 / (2 pi f)`` two-sided) for ``1 / (2 pi T_max) << f << 1 / (2 pi T_min)``, whose Allan
deviation is flat at ``sqrt(2 ln 2 / pi) B = 0.664 B`` for ``T_min << tau << T_max``: the bias instability B.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

__all__ = ["FlickerSource"]


class FlickerSource:
    """Flicker (bias-instability) noise of ``n`` independent sensors, continuous across calls of :meth:`draw`.

    Parameters
    ----------
    n : int
        Sensors.
    sample_rate : float
        Hz.
    bias_instability : float or ndarray (n,)
        B, SI (rad/s, m/s^2).
    band_s : (float, float), optional
        Shortest and longest time constant, s: the flat part of the Allan deviation lies well inside. Default
        ``(0.2 / sample_rate, 1e5)``: flicker down to the sample interval, so that every tau of a recording
        sees the 1/f spectrum.
    per_decade : int
        Gauss-Markov processes per decade of time constant.
    rng : numpy Generator

    Examples
    --------
    >>> src = FlickerSource(1, 10.0, 1.0, band_s=(1.0, 100.0), per_decade=6, rng=np.random.default_rng(0))
    >>> src.draw(5).shape
    (5, 1)
    >>> # (B^2 / pi) ln(band), the band widened by half a step at each end: 13 processes for 2 decades
    >>> round(float(src.variance()[0] / (np.log(100.0) / np.pi)), 4), round(13 / 12, 4)
    (1.0833, 1.0833)
    """

    def __init__(self, n: int, sample_rate: float, bias_instability: float | np.ndarray,
                 band_s: tuple[float, float] | None = None, per_decade: int = 5,
                 rng: np.random.Generator | None = None) -> None:
        lo, hi = band_s if band_s is not None else (0.2 / float(sample_rate), 1e5)
        if not (0 < lo < hi):
            raise ValueError(f"band_s must be (T_min, T_max) with 0 < T_min < T_max, got {band_s}")
        self.rng = rng if rng is not None else np.random.default_rng()
        self.dt = 1.0 / float(sample_rate)
        k = max(math.ceil(math.log10(hi / lo) * per_decade), 1)
        self.T = np.logspace(math.log10(lo), math.log10(hi), k + 1)
        b = np.broadcast_to(np.asarray(bias_instability, dtype=float), (n,))
        self.s = np.sqrt(b ** 2 * math.log(10.0) / (math.pi * per_decade))  # (n,) per process
        self.phi = np.exp(-self.dt / self.T)  # (k,)
        # stationary start
        self.state = self.rng.standard_normal((len(self.T), n)) * self.s[None, :]

    def variance(self) -> np.ndarray:
        """Stationary variance of the sum, (n,), SI^2."""
        return len(self.T) * self.s ** 2

    def skip(self, N: int) -> None:
        """Advance the state by N samples without making them (exact: ``x <- phi^N x + sqrt(1 - phi^2N) s w``)."""
        f = self.phi ** int(N)
        w = self.rng.standard_normal(self.state.shape)
        self.state = f[:, None] * self.state + np.sqrt(1.0 - f * f)[:, None] * self.s[None, :] * w

    def draw(self, N: int) -> np.ndarray:
        """The next N samples, (N, n)."""
        n = self.s.shape[0]
        out = np.zeros((N, n))
        for j, phi in enumerate(self.phi):
            e = self.rng.standard_normal((N, n)) * (self.s * math.sqrt(1.0 - phi * phi))[None, :]
            y, _zf = lfilter([1.0], [1.0, -phi], e, axis=0, zi=(phi * self.state[j])[None, :])
            self.state[j] = y[-1]
            out += y
        return out
