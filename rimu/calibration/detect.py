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

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ShapeError
from ..session import Segment, Session

__all__ = ["Detection", "Interval", "detect_intervals", "detect_poses", "detect_session", "plot_detection",
           "session_from_detection"]


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
    w = max(2, round(window_s * sample_rate))
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
    minn = round(min_static_s * sample_rate)
    statics = [(s, e) for s, e, v in runs if v and e - s >= minn]
    dropped = sum(1 for s, e, v in runs if v and e - s < minn)
    intervals = _alternate(statics, a.shape[0], gyro, sample_rate, min_turn_deg, gyro_scale)
    return Detection(intervals, var, thr, mask, dropped,
                     {"window_s": window_s, "factor": factor, "min_static_s": min_static_s,
                      "min_turn_deg": min_turn_deg})


def _alternate(statics: list[tuple[int, int]], n: int, gyro: np.ndarray | None, sample_rate: float,
               min_turn_deg: float, gyro_scale: float | None) -> list[Interval]:
    """The recording of ``n`` samples as alternating intervals: the static ones given (start, end), in order,
    and a motion (rotation or not, :func:`_motion`) in every gap before, between and after them."""
    intervals: list[Interval] = []
    prev = 0
    for s, e in statics:
        if s > prev:
            intervals.append(_motion(prev, s, gyro, sample_rate, min_turn_deg, gyro_scale))
        intervals.append(Interval(s, e, "static"))
        prev = e
    if prev < n:
        intervals.append(_motion(prev, n, gyro, sample_rate, min_turn_deg, gyro_scale))
    return intervals


def _runs(mask: np.ndarray) -> list[tuple[int, int, bool]]:
    edges = np.flatnonzero(np.diff(mask.astype(int))) + 1
    bounds = np.concatenate([[0], edges, [mask.size]])
    return [(int(s), int(e), bool(mask[s])) for s, e in itertools.pairwise(bounds)]


def _motion(s: int, e: int, gyro, fs: float, min_turn_deg: float, gyro_scale) -> Interval:
    if gyro is None:
        return Interval(s, e, "motion")
    g = np.asarray(gyro, dtype=float)[s:e]
    g = g - np.median(g, axis=0)  # crude bias removal
    ang = np.linalg.norm(g.sum(axis=0) / fs)
    ang = np.degrees(ang * gyro_scale) if gyro_scale else ang
    return Interval(s, e, "rotation" if ang >= min_turn_deg else "motion")


def session_from_detection(det: Detection, t: np.ndarray, raw: dict[str, np.ndarray], geometries: dict,
                           sample_rate: float, gravity: float = 9.80665, motions: bool = False) -> Session:
    """A session of the detected static intervals as ``static_unknown`` segments (attitude unknown: Zhang's
    norm-based calibration needs nothing more). With ``motions`` the intervals between them become ``motion``
    segments (contiguous in time: the hand-held gyro calibration integrates over them); otherwise they are left
    out (their angle is not known)."""
    segs = []
    k = 0
    for iv in det.intervals:
        sl = slice(iv.start, iv.end)
        if iv.kind == "static":
            k += 1
            segs.append(Segment(f"P{k}" if motions else f"D{k}", "static_unknown", t[sl],
                                {i: y[sl] for i, y in raw.items()}, meta={"detected": [iv.start, iv.end]}))
        elif motions and k > 0:
            segs.append(Segment(f"M{k}", "motion", t[sl], {i: y[sl] for i, y in raw.items()},
                                meta={"detected": [iv.start, iv.end], "kind": iv.kind}))
    if motions:
        while segs and segs[-1].kind == "motion":
            segs.pop()
    return Session(segs, geometries, sample_rate, None, gravity, "count", {"detection": det.settings})


def detect_poses(raw: dict[str, np.ndarray], sample_rate: float, window_s: float = 0.5,
                 factor: float | str = "auto",
                 init_still_s: float | None = None, min_static_s: float = 1.0, min_motion_s: float = 0.2,
                 margin_s: float | None = None, min_turn_deg: float = 20.0) -> Detection:
    """Poses and motions of a hand-held recording, with thresholds that adapt to the data, per axis.

    Tedaldi, Pretto & Menegatti 2014, Sec. IV-A: a sample is static when the variance over a window is below a
    multiple of the variance of an initial still period. Here, per axis of every instrument in ``raw``:

    1. the centred moving variance over ``window_s``;
    2. its noise floor: the median over the initial still period (``init_still_s`` seconds at the start), or,
       when no such period is given, the 10th percentile over the record (a recording of poses is mostly still);
    3. a sample is static when every axis is below ``factor`` times its floor. ``factor="auto"`` does what
       imu_tk does (Tedaldi et al. 2014, Sec. IV-A): it tries factors from 3 to 10000 (a hand held still shakes
       tens of times more than a unit lying on a table during the initial period) and keeps the one whose poses
       the accelerometer norm model fits best: of the factors whose residual standard deviation (norm fit,
       degrees of freedom counted) is within 20 % of the smallest, the one giving most poses;
    4. motions shorter than ``min_motion_s`` between two still runs are a bump, not a new pose: they are merged
       into the pose; still runs shorter than ``min_static_s`` are dropped (counted); every pose is trimmed by
       ``margin_s`` (default half a window) at both ends, so that no sample of a motion enters a pose mean.

    The detection statistic ``moving_variance`` is the largest ratio over the axes (1 = the floor).

    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(0, 1, (3000, 3)); a[1000:1300] += rng.normal(0, 30, (300, 3))
    >>> det = detect_poses({"accel": a}, 100.0, factor=8.0)
    >>> [(iv.kind, iv.start // 100, iv.end // 100) for iv in det.intervals if iv.kind == "static"]
    [('static', 0, 9), ('static', 13, 30)]
    """
    if not raw:
        raise ShapeError("detect_poses needs at least one instrument's raw samples")
    N = None
    ratios = []
    w = max(2, round(window_s * sample_rate))
    for k, y in raw.items():
        y = np.asarray(y, dtype=float)
        if y.ndim != 2 or y.shape[0] < max(4, w):
            raise ShapeError(f"{k}: raw must be (N, n) with N >= {max(4, w)} (one window), got {y.shape}")
        if N is not None and y.shape[0] != N:
            raise ShapeError(f"{k} has {y.shape[0]} samples, another instrument {N}")
        N = y.shape[0]
        mv = np.column_stack([_moving_var(y[:, j], w) for j in range(y.shape[1])])
        if init_still_s:
            ni = round(init_still_s * sample_rate)
            if ni < w:
                raise ShapeError(f"init_still_s = {init_still_s} s is shorter than one window ({window_s} s)")
            floor = np.median(mv[:ni], axis=0)
        else:
            floor = np.percentile(mv, 10, axis=0)
        floor = np.maximum(floor, 1e-12 * max(float(np.max(mv)), 1e-300))
        ratios.append(mv / floor)
    stat = np.max(np.hstack(ratios), axis=1)
    kw = {"window_s": window_s, "init_still_s": init_still_s, "min_static_s": min_static_s, "min_motion_s": min_motion_s,
              "margin_s": margin_s, "min_turn_deg": min_turn_deg}
    if isinstance(factor, str):
        if factor != "auto":
            raise ValueError(f"factor must be a number or 'auto', got {factor!r}")
        return _auto_factor(raw, sample_rate, stat, kw)
    return _classify(raw, sample_rate, stat, float(factor), **kw)


def _auto_factor(raw: dict[str, np.ndarray], fs: float, stat: np.ndarray, kw: dict) -> Detection:
    from ..errors import IdentifiabilityError
    from .handheld import fit_accel

    a = np.asarray(raw["accel"] if "accel" in raw else next(iter(raw.values())), float)[:, :3]
    trials = []
    seen: dict[tuple, float] = {}
    for f in np.geomspace(3.0, 10000.0, 22):
        det = _classify(raw, fs, stat, float(f), **kw)
        st = det.static
        K = len(st)
        score = np.inf
        key = tuple((iv.start, iv.end) for iv in st)
        if key in seen:
            score = seen[key]
        elif K >= 10:
            ybar = np.array([a[iv.start:iv.end].mean(axis=0) for iv in st])
            sd = np.array([a[iv.start:iv.end].std(axis=0) / np.sqrt(iv.n) for iv in st]) + 1e-12
            try:
                af = fit_accel(ybar, sd, np.eye(3), 1.0, ["x", "y", "z"], quick=True)
                score = float(np.sqrt(np.sum(af.norm_residual**2) / (K - 9)))
            except (IdentifiabilityError, np.linalg.LinAlgError, ValueError):  # rules this factor out
                score = np.inf
        seen[key] = score
        trials.append((float(f), K, score, det))
    finite = [x for x in trials if np.isfinite(x[2])]
    if not finite:
        f, _, _, det = max(trials, key=lambda x: (len(x[3].static), -x[0]))
        det.settings["factor"] = "auto"
        det.settings["factor_chosen"] = f
        det.settings["factor_trials"] = [(f, K, None) for f, K, _, _ in trials]
        return det
    best = min(x[2] for x in finite)
    f, K, score, det = max((x for x in finite if x[2] <= 1.2 * best), key=lambda x: (x[1], -x[0]))
    det.settings["factor"] = "auto"
    det.settings["factor_chosen"] = f
    det.settings["factor_trials"] = [(ff, KK, None if not np.isfinite(sc) else sc) for ff, KK, sc, _ in trials]
    return det


def _classify(raw: dict[str, np.ndarray], sample_rate: float, stat: np.ndarray, factor: float, window_s: float,
              init_still_s: float | None, min_static_s: float, min_motion_s: float, margin_s: float | None,
              min_turn_deg: float) -> Detection:
    N = len(stat)
    mask = stat < factor
    # merge short motions between still runs, then drop short still runs
    mm = round(min_motion_s * sample_rate)
    for s, e, v in _runs(mask):
        if not v and s > 0 and e < N and e - s < mm:
            mask[s:e] = True
    minn = round(min_static_s * sample_rate)
    dropped = 0
    for s, e, v in _runs(mask):
        if v and e - s < minn:
            mask[s:e] = False
            dropped += 1
    mg = round((window_s / 2 if margin_s is None else margin_s) * sample_rate)
    statics = []
    for s, e, v in _runs(mask):
        if v:
            s2 = s + (mg if s > 0 else 0)
            e2 = e - (mg if e < N else 0)
            if e2 - s2 >= max(minn, 2):
                statics.append((s2, e2))
            else:
                dropped += 1
    intervals = _alternate(statics, N, raw.get("gyro"), sample_rate, min_turn_deg, None)
    return Detection(intervals, stat, float(factor), mask, dropped,
                     {"window_s": window_s, "factor": factor, "init_still_s": init_still_s,
                      "min_static_s": min_static_s, "min_motion_s": min_motion_s,
                      "margin_s": window_s / 2 if margin_s is None else margin_s})


def detect_session(t: np.ndarray, raw: dict[str, np.ndarray], sample_rate: float,
                   geometries: dict | None = None, gravity: float = 9.80665, **kwargs: Any) -> tuple[Session, Detection]:
    """:func:`detect_poses` then :func:`session_from_detection` with the motions: a hand-held session (poses
    ``static_unknown`` P1.., motions M1.. between them) ready for :class:`~rimu.calibration.handheld.HandHeld`.
    Geometries default to a triad per instrument with three columns."""
    from ..geometry import triad3

    if geometries is None:
        geometries = {}
        for k, y in raw.items():
            if np.asarray(y).shape[1] != 3:
                raise ShapeError(f"{k} has {np.asarray(y).shape[1]} columns; give its geometry (rimu detect --geometry; a triad is assumed "
                                 "only for three columns)")
            geometries[k] = triad3()
    det = detect_poses(raw, sample_rate, **kwargs)
    if len(det.static) < 2:
        from ..errors import IdentifiabilityError

        raise IdentifiabilityError(f"found {len(det.static)} still poses; check the thresholds (factor "
                                   f"{det.threshold:g}, min_static_s {det.settings['min_static_s']}) or the data",
                                   [])
    return session_from_detection(det, np.asarray(t, float), raw, geometries, sample_rate, gravity,
                                  motions=True), det


def plot_detection(det: Detection, accel: np.ndarray, sample_rate: float, labelled: dict | None = None,
                   path: str | None = None):
    """Plot the accelerometer magnitude, the normalised moving variance and threshold, and the intervals
    (static green, rotation orange, motion grey); ``labelled`` {name: (start, end)} is drawn for comparison.
    Returns the matplotlib Figure (saved to ``path`` if given)."""
    from ..plotting import pyplot

    plt = pyplot()

    t = np.arange(len(det.moving_variance)) / sample_rate
    step = max(1, len(t) // 4000)  # enough points for the eye
    fig, ax = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    ax[0].plot(t[::step], np.linalg.norm(np.asarray(accel, float), axis=1)[::step], lw=0.6, color="k")
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
    ax[1].semilogy(t[::step], np.maximum(det.moving_variance, 1e-3)[::step], lw=0.6)
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
