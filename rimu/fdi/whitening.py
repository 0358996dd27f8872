"""The detectors' noise model: coloured sensor noise (bias instability, rate random walk) in parity space.

The pipeline normalises the parity with each sensor's white per-sample sigma_0: ``p = Vz z`` with
``Vz = V_w W`` and ``Cov p = I`` for white noise of exactly those levels. A detector that averages (window,
CUSUM, Kalman) sees, over a long run, the sensors' slow errors as well: the bias wanders away from the value
the calibration removed. With a sensor noise model (:class:`rimu.noise.InstrumentNoise`, IEEE Std 952 terms)
the variance ``v_i(tau)`` of a window mean of ``tau`` of sensor i, ``horizon`` after the bias was set from a
reference window (:meth:`rimu.noise.InstrumentNoise.window_variance`), is the white part
``N_i^2 / tau + 2 Q_i^2 / tau^2`` plus the wander of the bias since the reference: for equal windows whose starts
are ``r tau`` apart ``(B_i^2 / pi) g(r)`` with ``g(r) ~ 2 ln r + 3`` and ``K_i^2 (r tau - tau / 3)`` (exact
expressions for any windows in :mod:`rimu.noise.model`). The mean parity over the window has the covariance::

    C(tau) = Vz diag(v(tau)) Vz^T        (= I / M for white noise of the pipeline's levels, tau = M / fs)

and a detector keeps its design false-alarm rate by whitening with ``L = chol(M C)^-1``: the statistic
``|L S|^2 / M`` (S the sum over the window) is chi-square with dof degrees of freedom again, and isolation
uses the whitened columns ``L Vz``. The detector's *effective sigma* is ``sigma_eff^2 = M v(tau)``: the
per-sample sigma that white noise would need for the same window-mean variance; it grows with the window
while the white part alone stays at sigma_0.

A noise object here is anything with ``window_variance(tau_s, horizon_s, reference_s)`` returning the n
per-sensor variances (SI^2) and a ``sample_rate`` (Hz): :class:`rimu.noise.InstrumentNoise` is one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import ShapeError

__all__ = ["NoiseSettings", "SensorNoise", "cached_whitener", "whitener", "window_covariance"]


class SensorNoise(Protocol):
    """What a detector needs from a noise model (see :class:`rimu.noise.InstrumentNoise`)."""

    sample_rate: float

    def window_variance(self, tau_s: float, horizon_s: float = 0.0,
                        reference_s: float | None = None) -> np.ndarray: ...


@dataclass(frozen=True)
class NoiseSettings:
    """A noise model with the run it is applied to.

    Attributes
    ----------
    noise : SensorNoise
    horizon_s : float
        Longest time since the biases were last estimated (mission length, recalibration interval), s: the
        design holds up to it, and is conservative before it.
    reference_s : float or None
        Length of the average the bias was estimated from, s (None: the detector's own window).
    sample_rate : float or None
        Hz of the samples the detector sees (default: the noise model's).
    """

    noise: Any
    horizon_s: float = 3600.0
    reference_s: float | None = None
    sample_rate: float | None = None

    def __post_init__(self) -> None:
        if not self.horizon_s >= 0:
            raise ValueError(f"horizon_s must be >= 0 s, got {self.horizon_s}")
        if not hasattr(self.noise, "window_variance"):
            raise TypeError("noise must be a noise model with window_variance() (rimu.noise.InstrumentNoise)")

    @property
    def fs(self) -> float:
        return float(self.sample_rate if self.sample_rate is not None else self.noise.sample_rate)

    def variance(self, samples: float) -> np.ndarray:
        """Per-sensor variance (n,), SI^2, of a mean of ``samples`` samples (at the end of the horizon)."""
        tau = max(float(samples), 1.0) / self.fs
        return np.asarray(self.noise.window_variance(tau, self.horizon_s, self.reference_s), dtype=float)


def window_covariance(Vz: np.ndarray, dof: int, settings: NoiseSettings, samples: float) -> np.ndarray:
    """``M C(tau)``, (dof, dof): the covariance of ``S / sqrt(M)`` for a window of M = ``samples`` samples.

    Identity for white noise of the pipeline's levels (module docstring).
    """
    V = np.asarray(Vz, dtype=float)[:dof]
    v = settings.variance(samples)
    if v.shape != (V.shape[1],):
        raise ShapeError(f"the noise model has {v.shape[0]} sensors, the parity rows {V.shape[1]}; give the model of "
                         "this instrument")
    return float(max(samples, 1.0)) * (V * v[None, :]) @ V.T


def whitener(Vz: np.ndarray, dof: int, settings: NoiseSettings, samples: float) -> np.ndarray:
    """``L`` (dof, dof) with ``L (M C) L^T = I`` (inverse Cholesky factor of :func:`window_covariance`)."""
    C = window_covariance(Vz, dof, settings, samples)
    return np.linalg.inv(np.linalg.cholesky(C))


def cached_whitener(detector: Any, Vz: np.ndarray, dof: int, samples: float, factor: float | None = None) -> np.ndarray | None:
    """A detector's :func:`whitener` for the active set (``Vz``, ``dof``), cached on the detector per set, times
    ``factor`` when given; None without a noise model (``detector.noise``) or parity space."""
    if detector.noise is None or dof < 1:
        return None
    key = (np.asarray(Vz)[:dof].tobytes(), int(dof))
    cache = detector.__dict__.setdefault("_whiteners", {})
    if key not in cache:
        L = whitener(Vz, dof, detector.noise, samples)
        cache[key] = L if factor is None else factor * L
    return cache[key]
