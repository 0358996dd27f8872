"""Static and rotating intervals from unlabelled data, in the manner of imu_tk's static detector.

imu_tk (Tedaldi, Pretto & Menegatti 2014, Sec. III-A) marks a sample static when the variance of the
accelerometer signal over a short window is below a threshold set from an initial still period. Here:

1. the moving variance of the accelerometer magnitude (raw units, window ``window_s``), plus, when gyro data
   are given, of the gyro magnitude;
2. the threshold is ``factor`` times a robust noise floor: the 10th percentile of the moving variance (a
   record whose samples are at least 10% still needs no separate initial period);
3. runs of static samples shorter than ``min_static_s`` are dropped (counted in the result, not silently);
   the gaps between static intervals are motions; a motion whose gyro magnitude integrates to more than
   ``min_turn_deg`` (with scale ``gyro_scale`` from raw to rad/s) is reported as a rotation.

:func:`plot_detection` shows the signal, the moving variance, the threshold and the intervals found.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ShapeError
from ..session import Segment, Session

__all__ = ["Detection", "Interval", "detect_intervals", "plot_detection", "session_from_detection"]


@dataclass(frozen=True)
class Interval:
    """Samples ``start`` (inclusive) to ``end`` (exclusive) of one kind: ``"static"`` or ``"rotation"``
    (``"motion"`` when the turn is below ``min_turn_deg`` or no gyro is given)."""

    start: int
    end: int
    kind: str

    @property
    def n(self) -> int:
        return self.end - self.start


@dataclass
class Detection:
    """What :func:`detect_intervals` found."""

    intervals: list[Interval]
    moving_variance: np.ndarray
    threshold: float
    static_mask: np.ndarray
    dropped_short: int
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def static(self) -> list[Interval]:
        return [i for i in self.intervals if i.kind == "static"]

    @property
    def rotations(self) -> list[Interval]:
        return [i for i in self.intervals if i.kind == "rotation"]


def _moving_var(x: np.ndarray, w: int) -> np.ndarray:
    """Centred moving variance over ``w`` samples (edges use the nearest full window)."""
    n = x.shape[0]
    w = max(2, min(w, n))
    c1 = np.concatenate([[0.0], np.cumsum(x)])
    c2 = np.concatenate([[0.0], np.cumsum(x * x)])
    s = np.arange(n) - w // 2
    s = np.clip(s, 0, n - w)
    m = (c1[s + w] - c1[s]) / w
    v = (c2[s + w] - c2[s]) / w - m * m
    return np.maximum(v, 0.0)


def detect_intervals(accel: np.ndarray, sample_rate: float, gyro: np.ndarray | None = None,
                     window_s: float = 1.0, factor: float = 6.0, min_static_s: float = 2.0,
                     min_turn_deg: float = 45.0, gyro_scale: float | None = None) -> Detection:
    """Find static intervals and rotations in an unlabelled recording (imu_tk-style variance detector).

    Parameters
    ----------
    accel : ndarray (N, n_a)
        Raw accelerometer outputs.
    sample_rate : float
        Hz.
    gyro : ndarray (N, n_g), optional
        Raw gyro outputs; adds the gyro variance to the test and classifies motions as rotations.
    window_s, factor, min_static_s, min_turn_deg : float
        See the module docstring.
    gyro_scale : float, optional
        Raw gyro unit to rad/s (for the turn angle); default: rotations are all motions with a gyro magnitude
        integral above ``min_turn_deg`` in raw-unit degrees (right when the raw unit is deg/s).
    """
    a = np.asarray(accel, dtype=float)
    if a.ndim != 2 or a.shape[0] < 4:
        raise ShapeError(f"accel must be (N, n) with N >= 4, got {a.shape}")
    w = max(2, int(round(window_s * sample_rate)))
    var = _moving_var(np.linalg.norm(a, axis=1), w)
    var = var / max(np.percentile(var, 10), 1e-300)
    if gyro is not None:
        g = np.asarray(gyro, dtype=float)
        if g.shape[0] != a.shape[0]:
            raise ShapeError(f"gyro has {g.shape[0]} samples, accel {a.shape[0]}")
        vg = _moving_var(np.linalg.norm(g, axis=1), w)
        var = np.maximum(var, vg / max(np.percentile(vg, 10), 1e-300))
    thr = factor
    mask = var < thr
    runs = _runs(mask)
    minn = int(round(min_static_s * sample_rate))
    statics = [(s, e) for s, e, v in runs if v and e - s >= minn]
    dropped = sum(1 for s, e, v in runs if v and e - s < minn)
    intervals: list[Interval] = []
    prev = 0
    for s, e in statics:
        if s > prev:
            intervals.append(_motion(prev, s, gyro, sample_rate, min_turn_deg, gyro_scale))
        intervals.append(Interval(s, e, "static"))
        prev = e
    if prev < a.shape[0]:
        intervals.append(_motion(prev, a.shape[0], gyro, sample_rate, min_turn_deg, gyro_scale))
    return Detection(intervals, var, thr, mask, dropped,
                     {"window_s": window_s, "factor": factor, "min_static_s": min_static_s,
                      "min_turn_deg": min_turn_deg})


def _runs(mask: np.ndarray) -> list[tuple[int, int, bool]]:
    edges = np.flatnonzero(np.diff(mask.astype(int))) + 1
    bounds = np.concatenate([[0], edges, [mask.size]])
    return [(int(s), int(e), bool(mask[s])) for s, e in zip(bounds[:-1], bounds[1:])]


def _motion(s: int, e: int, gyro, fs: float, min_turn_deg: float, gyro_scale) -> Interval:
    if gyro is None:
        return Interval(s, e, "motion")
    g = np.asarray(gyro, dtype=float)[s:e]
    g = g - np.median(g, axis=0)  # crude bias removal
    ang = np.linalg.norm(g.sum(axis=0) / fs)
    ang = np.degrees(ang * gyro_scale) if gyro_scale else ang
    return Interval(s, e, "rotation" if ang >= min_turn_deg else "motion")


def session_from_detection(det: Detection, t: np.ndarray, raw: dict[str, np.ndarray], geometries: dict,
                           sample_rate: float, gravity: float = 9.80665) -> Session:
    """A session of the detected static intervals as ``static_unknown`` segments (attitude unknown: Zhang's
    norm-based calibration needs nothing more); rotations are not included (their angle is not known)."""
    segs = []
    for k, iv in enumerate(det.static, start=1):
        sl = slice(iv.start, iv.end)
        segs.append(Segment(f"D{k}", "static_unknown", t[sl], {i: y[sl] for i, y in raw.items()},
                            meta={"detected": [iv.start, iv.end]}))
    return Session(segs, geometries, sample_rate, None, gravity, "count", {"detection": det.settings})


def plot_detection(det: Detection, accel: np.ndarray, sample_rate: float, labelled: dict | None = None,
                   path: str | None = None):
    """Plot the accelerometer magnitude, the normalised moving variance and threshold, and the intervals
    (static green, rotation orange, motion grey); ``labelled`` {name: (start, end)} is drawn for comparison.
    Returns the matplotlib Figure (saved to ``path`` if given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(len(det.moving_variance)) / sample_rate
    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    ax[0].plot(t, np.linalg.norm(np.asarray(accel, float), axis=1), lw=0.6, color="k")
    ax[0].set_ylabel("|accel| (raw)")
    colours = {"static": "tab:green", "rotation": "tab:orange", "motion": "0.7"}
    for iv in det.intervals:
        for a in ax:
            a.axvspan(iv.start / sample_rate, iv.end / sample_rate, color=colours[iv.kind], alpha=0.25, lw=0)
    if labelled:
        top = ax[0].get_ylim()[1]
        for name, (s, e) in labelled.items():
            ax[0].hlines(top, s / sample_rate, e / sample_rate, color="tab:blue", lw=3)
            ax[0].annotate(name, ((s + e) / 2 / sample_rate, top), ha="center", va="top", fontsize=8)
        ax[0].set_ylim(top=top * 1.02)
    ax[1].semilogy(t, np.maximum(det.moving_variance, 1e-3), lw=0.6)
    ax[1].axhline(det.threshold, color="r", ls="--", label=f"threshold ({det.threshold:g} x noise floor)")
    ax[1].set_ylabel("moving variance / floor")
    ax[1].set_xlabel("time (s)")
    ax[1].legend(loc="upper right")
    ax[0].set_title(f"detected: {len(det.static)} static (green), {len(det.rotations)} rotations (orange); "
                    f"{det.dropped_short} short still runs dropped")
    fig.tight_layout()
    if path:
        from ..atomic import atomic_path

        with atomic_path(path) as _tmp:  # whole or not at all
            fig.savefig(_tmp, dpi=110)
    return fig
