"""Residual statistics: how well a model explains the measurement, per sensor, per segment and over time.

Residuals are normalised by the white-noise level (known, or estimated from first differences within
segments, which does not need the model to be complete). For a complete model and white noise:

* chi-square per degree of freedom ``RSS / (sigma^2 dof)`` is 1 with standard deviation ``sqrt(2/dof)``
  (plus ``sqrt(3/N)`` when sigma is estimated from differences);
* the mean residual of a segment of n samples, divided by ``sigma / sqrt(n)``, is N(0, 1);
* the lag-1 autocorrelation times ``sqrt(N)`` is N(0, 1), and the Ljung-Box statistic
  ``Q = N (N + 2) sum_k rho_k^2 / (N - k)`` is chi-square with h degrees of freedom (Ljung & Box 1978).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import special

from .fitting import ModelFit, SensorFit
from .series import autocorrelation, ljung_box

__all__ = [
    "SegmentStat",
    "SensorStats",
    "autocorrelation",
    "failures",
    "input_bins",
    "ljung_box",
    "residual_statistics",
    "sensor_statistics",
]


@dataclass
class SegmentStat:
    """One sensor on one segment."""

    label: str
    n: int
    mean: float
    mean_z: float
    rms_norm: float


@dataclass
class SensorStats:
    """Residual statistics of one sensor."""

    name: str
    sigma: float
    sigma_known: bool
    rms_raw: float
    #: SI (rad/s, m/s^2); None where the scale factor is unknown (raw counts and a model without a scale block)
    rms_si: float | None
    chi2_dof: float
    chi2_z: float
    lag1: float
    lag1_z: float
    ljung_box_q: float
    ljung_box_p: float
    inflation: float = 1.0
    segments: list[SegmentStat] = field(default_factory=list)

    @property
    def white(self) -> bool:
        return self.ljung_box_p > 1e-3

    def to_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "segments"}
        d["segments"] = [s.__dict__ for s in self.segments]
        return d


def sensor_statistics(s: SensorFit, labels: list[str], lags: int = 10) -> SensorStats:
    r = s.r
    n = r.size
    z = r / s.sigma
    rho = autocorrelation(r, s.seg_index, lags)
    q, p = ljung_box(rho, n)
    var_c = 2.0 / s.dof + (0.0 if s.sigma_known else 3.0 / n)
    c = s.chi2_dof
    segs = []
    counts = np.bincount(s.seg_index, minlength=len(labels))
    sums = np.bincount(s.seg_index, weights=r, minlength=len(labels))
    sq = np.bincount(s.seg_index, weights=z**2, minlength=len(labels))
    for k, lab in enumerate(labels):
        m = counts[k]
        if m == 0:
            continue
        mean = sums[k] / m
        segs.append(SegmentStat(lab, int(m), float(mean), float(mean / (s.sigma * np.sqrt(s.inflation / m))),
                                float(np.sqrt(sq[k] / m))))
    rms = float(np.sqrt(np.mean(r**2)))
    return SensorStats(s.name, s.sigma, s.sigma_known, rms, None if s.scale is None else rms * s.scale,
                       c, float((c - 1.0) / np.sqrt(var_c)), float(rho[0]) if lags else 0.0,
                       float(rho[0] * np.sqrt(n)) if lags else 0.0, q, p, s.inflation, segs)


def residual_statistics(fit: ModelFit, lags: int = 10) -> list[SensorStats]:
    """Statistics of every sensor of a fit (rms, chi-square per dof, whiteness, per segment)."""
    return [sensor_statistics(s, fit.segment_labels, lags) for s in fit.sensors]


def failures(st: list[SensorStats], alpha: float) -> dict:
    """Where the model fails: sensors whose chi2/dof is too large, segments whose mean residual is off.

    Thresholds are Bonferroni-corrected two-sided normal quantiles at family-wise level ``alpha``.
    """
    zs = -special.ndtri(alpha / (2 * max(len(st), 1)))
    bad_sensors = [x.name for x in st if x.chi2_z > zs]
    m = sum(len(x.segments) for x in st)
    zseg = -special.ndtri(alpha / (2 * max(m, 1)))
    bad_segments: dict[str, list[tuple[str, float]]] = {}
    for x in st:
        for g in x.segments:
            if abs(g.mean_z) > zseg:
                bad_segments.setdefault(g.label, []).append((x.name, g.mean_z))
    not_white = [x.name for x in st if x.ljung_box_p < alpha / max(len(st), 1)]
    return {"sensors": bad_sensors, "segments": bad_segments, "not_white": not_white,
            "sensor_threshold_z": float(zs), "segment_threshold_z": float(zseg)}


def input_bins(s: SensorFit, nbins: int = 8) -> list[tuple[float, float, float, int]]:
    """Mean residual (in units of its standard error) binned by the input along the sensing axis.

    Returns (bin centre SI, mean residual / sigma, standard error of that mean in the same unit, count).
    """
    x = s.axis_input
    if x is None or not np.all(np.isfinite(x)):
        return []
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi - lo < 1e-12:
        return []
    edges = np.linspace(lo, hi, nbins + 1)
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, nbins - 1)
    out = []
    z = s.r / s.sigma
    for b in range(nbins):
        sel = k == b
        m = int(sel.sum())
        if m:
            out.append((float(0.5 * (edges[b] + edges[b + 1])), float(z[sel].mean()), float(1 / np.sqrt(m)), m))
    return out
