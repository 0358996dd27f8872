"""From a multi-IMU recording to a calibrated unit of triads: clocks, axes, biases and noise from the data.

A unit of k triads that nobody calibrated as a whole (IMUs strapped to a drone, an autopilot's two or three
IMUs) is set up from a stretch of its own data, fault-free by assumption:

1. clock offsets of every triad against the reference (:func:`rimu.calibration.timing.estimate_offsets`;
   skipped where the recording has one clock), removed, all triads resampled to one time base;
2. optionally, block averages over ``average_s`` (vibration above a few Hz is common to no two triads; the
   averaged parity is closer to the white noise the detectors assume) - the unit then runs at the lower rate;
3. the spans at rest (:func:`still_epochs`: the imu_tk-style variance detector of
   :func:`rimu.calibration.detect.detect_intervals` on every triad at once, with absolute guards);
4. the rotation of each triad against the reference (:func:`rimu.calibration.alignment.align_triads`), with its
   covariance, from the rates **in motion** (rates measured from the reference's bias at rest, so a gyro bias
   above ``min_rate_rad_s`` is never taken for motion); with no motion, from gravity at rest when it was seen
   in two directions at least, else refused (:class:`~rimu.errors.IdentifiabilityError` naming the reason);
   the reference triad defines MB;
5. gyro and accelerometer bias differences **from the spans at rest** (median of each triad minus the
   reference, rotated; their 1-sigma from the spread and the effective sample count); where the rest holds
   gravity in three directions (poses), each accelerometer triad's gain against the reference too
   (``y_j = G_j y_ref + c_j``, least squares at rest: relative scale and misalignment), or, without enough rest
   (``min_still_s``), the gyro offset fitted with the rotation and the median of the accelerometers;
6. per-sensor noise levels from the residuals against the other triads (at rest when there is enough rest,
   else over the whole window: the flight's own disagreement), for the pipeline's weights and the detectors;
   the motion terms are the business of :func:`rimu.fdi.fit_motion_detector`, on the moving spans.

Samples that are not measurements are invalid before any averaging: a triad whose accelerometer vector is
exactly zero (a placeholder record: impossible for a unit on Earth) is invalid in every instrument at that
sample, as a clipped sample is (the readers mark those), and an average holding one is invalid
(:func:`average_block`).

The result holds the :class:`~rimu.calibration.result.Calibration` (geometry :func:`rimu.geometry.triads`
with the fitted rotations), the averaged :class:`~rimu.epoch.EpochBlock` of the whole recording, and the
timing and alignment reports.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..epoch import EpochBlock
from ..errors import IdentifiabilityError, ShapeError
from ..units import G0, RAD_TO_DEG
from .alignment import AlignmentResult, VectorSet, align_triads, effective_fraction, fit_rotation
from .detect import _moving_var, detect_intervals
from .result import Calibration, InstrumentCalibration
from .timing import TimingResult, estimate_offsets

__all__ = ["MultiImuSetup", "average_block", "pose_uncertainty", "setup_multi_imu", "still_epochs", "triad_noise"]


@dataclass
class MultiImuSetup:
    """What :func:`setup_multi_imu` found.

    Attributes
    ----------
    calibration : Calibration
        Scale 1 (the epochs carry SI values), misalignment rows from the fitted rotations, biases relative to
        the reference triad, noise per sensor.
    block : EpochBlock
        The whole recording on one time base (averaged when ``average_s`` was given).
    full_block : EpochBlock
        The same before averaging (clock offsets removed), ``n_average`` epochs per epoch of ``block``.
    timing : TimingResult or None
        Clock offsets (None for a recording with one clock).
    alignments : list of AlignmentResult
        One per non-reference triad.
    delivering : list of str
        Triads with valid data in at least half of the epochs.
    """

    calibration: Calibration
    block: EpochBlock
    timing: TimingResult | None
    alignments: list[AlignmentResult] = field(default_factory=list)
    delivering: list[str] = field(default_factory=list)
    fit_window_s: tuple[float, float] = (float("-inf"), float("inf"))
    full_block: EpochBlock | None = None
    n_average: int = 1
    still: np.ndarray | None = None
    bias_sigma: dict[str, np.ndarray] = field(default_factory=dict)
    spans: dict[str, float] = field(default_factory=dict)
    #: per unit with its own clock: offset and rate against the reference (rimu.calibration.timing.estimate_clocks)
    clocks: list = field(default_factory=list)
    #: per instrument, each sensor's offset 1-sigma at a pose the relative gains were not fitted on (SI):
    #: :func:`pose_uncertainty` (accelerometers with gains from ten poses or more)
    pose_sigma: dict[str, np.ndarray] = field(default_factory=dict)

    def average(self, full_block: EpochBlock) -> EpochBlock:
        """Average a block on the full-rate time base (e.g. one with injected faults) as :attr:`block` was."""
        return average_block(full_block, self.n_average)

    def report(self) -> str:
        """Human-readable summary: offsets (ms), rotations (deg with 1-sigma), noise levels."""
        lines = []
        if self.spans:
            sp = self.spans
            lines.append(f"spans of the fit window: at rest {sp['still_s']:.1f} s (biases{', noise' if sp.get('noise_at_rest') else ''}), "
                         f"in motion {sp['motion_s']:.1f} s (rotations{'' if sp['motion_s'] else ': from gravity'})")
        if self.timing is not None:
            lines.append(self.timing.table())
        if self.clocks:
            lines.append("clock rates against the reference (ppm; drift left at the ends after one offset, ms)")
            lines += [f"  {c.name:>8}: {c.rate_ppm:+9.3g} +- {c.rate_sigma_ppm:.2g} ppm   (drift {1e3 * c.drift_s:.3g})"
                      for c in self.clocks]
        for a in self.alignments:
            lines.append("rotation " + a.table())
        for k in self.calibration.instruments:
            cal = self.calibration[k]
            s = cal.noise_sigma
            unit, f = ("deg/s", RAD_TO_DEG) if k == "gyro" else ("m/s^2", 1.0)
            per = (f", per epoch of the {self.n_average}-sample averages; x sqrt({self.n_average}) per raw sample"
                   if self.n_average > 1 else "")
            two = len(s) == 6  # two triads: only the sum of their variances is seen (triad_noise)
            lines.append(f"{k} noise per sensor ({unit}{per}): " + " ".join(f"{v * f:.3g}" for v in s)
                         + ("  (two triads: their disagreement split equally)" if two else ""))
            if k in self.bias_sigma:
                lines.append(f"{k} bias difference 1-sigma ({unit}): "
                             + " ".join(f"{v * f:.2g}" for v in self.bias_sigma[k]))
            if k in self.pose_sigma:
                lines.append(f"{k} offset 1-sigma at a new pose (leave-one-pose-out, beyond the pose means' noise; "
                             f"{unit}): " + " ".join(f"{v * f:.2g}" for v in self.pose_sigma[k]))
        return "\n".join(lines)


def average_block(block: EpochBlock, n: int) -> EpochBlock:
    """Means of consecutive blocks of ``n`` epochs; a sensor is valid in a block only if valid in all of its
    epochs (so a gap never shows as a smaller value)."""
    if n <= 1:
        return block
    m = (len(block) // n) * n
    if m == 0:
        raise ShapeError(f"cannot average blocks of {n} epochs from {len(block)} epochs")
    raw, valid = {}, {}
    for k, y in block.raw.items():
        v = block.valid.get(k, np.ones(y.shape, bool))[:m].reshape(-1, n, y.shape[1])
        yy = np.where(v, y[:m].reshape(-1, n, y.shape[1]), 0.0)
        ok = v.all(axis=1)
        raw[k] = np.where(ok, yy.mean(axis=1), 0.0)
        valid[k] = ok
    temp = None if block.temperature is None else block.temperature[:m].reshape(-1, n).mean(axis=1)
    meta = dict(block.meta)
    meta["averaged"] = n
    return EpochBlock(block.t[:m].reshape(-1, n).mean(axis=1), raw, valid, temp, meta)


def triad_noise(Z: np.ndarray) -> np.ndarray:
    """Per-sensor noise of k aligned triads from their disagreement, (N, 3k) -> (3k,).

    For each axis, the difference of triad i from the mean of the others has variance
    ``s_i^2 + sum_{j != i} s_j^2 / (k - 1)^2``; the k equations are solved for the ``s_i^2`` (k >= 3). Two
    triads give only ``s_1^2 + s_2^2``: it is split equally. Rows with a non-finite value are skipped.

    >>> rng = np.random.default_rng(0)
    >>> s = np.array([1.0, 2.0, 3.0])
    >>> Z = np.repeat(rng.normal(size=(200000, 1)), 9, axis=1) + rng.normal(size=(200000, 9)) * np.repeat(s, 3)
    >>> np.round(triad_noise(Z)[::3], 1).tolist()
    [1.0, 2.0, 3.0]
    """
    Z = np.asarray(Z, dtype=float)
    Z = Z[np.isfinite(Z).all(axis=1)]
    k = Z.shape[1] // 3
    if k < 2 or len(Z) < 10:
        raise ShapeError(f"noise from disagreement needs at least two triads and ten samples, got {k}, {len(Z)}")
    out = np.zeros(3 * k)
    for a in range(3):
        X = Z[:, a::3]
        X = X - X.mean(axis=0)
        if k == 2:
            v = np.var(X[:, 0] - X[:, 1])
            out[a::3] = np.sqrt(v / 2.0)
            continue
        d = np.array([np.var(X[:, i] - np.delete(X, i, axis=1).mean(axis=1)) for i in range(k)])
        A = np.full((k, k), 1.0 / (k - 1) ** 2)
        np.fill_diagonal(A, 1.0)
        s2 = np.linalg.solve(A, d)
        out[a::3] = np.sqrt(np.clip(s2, 0.05 * d.min(), None))
    return out


def still_epochs(block: EpochBlock, sample_rate: float | None = None, window_s: float = 1.0, factor: float = 6.0,
                 min_still_s: float = 2.0, max_accel_std: float = 0.3, max_gravity_error: float = 0.1,
                 max_gyro_std: float = 0.03) -> np.ndarray:
    """Epochs at rest of a block of triads: every triad still at once.

    The imu_tk-style detector (:func:`rimu.calibration.detect.detect_intervals`, Tedaldi et al. 2014) on the
    magnitude of all accelerometers (and gyros) together marks windows whose variance is below ``factor`` times
    its 10th percentile, in runs of at least ``min_still_s``; that threshold is relative, so two absolute
    guards keep a recording that is never still (a flight) from calling its calmest part rest: every
    accelerometer's moving standard deviation stays below ``max_accel_std`` (m/s^2) and its magnitude within
    ``max_gravity_error`` (relative) of its own median magnitude (g, as a raw triad with a scale error reads it:
    a real MPU-9250 reading 0.82 g at rest is still at rest), and every gyro's below ``max_gyro_std`` (rad/s).
    Invalid samples are never still.

    Parameters
    ----------
    block : EpochBlock
        SI values (m/s^2, rad/s), ``3k`` columns per instrument; needs ``accel``.
    sample_rate : float, optional
        Hz (default: from the time stamps).

    Returns
    -------
    ndarray (N,) of bool

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> n = 1000
    >>> a = np.tile([0.0, 0.0, G0], (n, 2)) + 0.02 * rng.normal(size=(n, 6))
    >>> a[400:600] += 3.0 * rng.normal(size=(200, 6))       # handled in the middle
    >>> b = EpochBlock(np.arange(n) / 100.0, {"accel": a}, {"accel": np.ones((n, 6), bool)})
    >>> m = still_epochs(b)
    >>> bool(m[:350].all()), bool(m[420:580].any()), bool(m[700:].all())
    (True, False, True)
    """
    if "accel" not in block.raw:
        return np.zeros(len(block), bool)
    fs = sample_rate or 1.0 / float(np.median(np.diff(block.t)))
    A = block.raw["accel"]
    ok = block.valid["accel"].all(axis=1)
    G = None
    if "gyro" in block.raw:
        G = np.where(block.valid["gyro"], block.raw["gyro"], 0.0)
        ok &= block.valid["gyro"].all(axis=1)
    A0 = np.where(block.valid["accel"], A, 0.0)
    if len(block) < 4 or not ok.any():
        return np.zeros(len(block), bool)
    det = detect_intervals(A0, fs, G, window_s=window_s, factor=factor, min_static_s=min_still_s)
    still = np.zeros(len(block), bool)
    for iv in det.static:
        still[iv.start:iv.end] = True
    w = max(2, round(window_s * fs))
    k = A.shape[1] // 3
    for j in range(k):
        aj = A0[:, 3 * j:3 * j + 3]
        nrm = np.linalg.norm(aj, axis=1)
        sd = np.sqrt(sum(_moving_var(aj[:, c], w) for c in range(3)))
        level = float(np.median(nrm[ok])) if ok.any() else G0  # the triad's own 1 g (a raw triad's scale error)
        still &= (sd < max_accel_std) & (np.abs(nrm / level - 1.0) < max_gravity_error)
        if G is not None:
            gj = G[:, 3 * j:3 * j + 3]
            still &= np.sqrt(sum(_moving_var(gj[:, c], w) for c in range(3))) < max_gyro_std
    # an invalid sample, or one within half a window of it, is not rest
    bad = np.convolve((~ok).astype(float), np.ones(w), mode="same") > 0
    return still & ~bad


def _median_sigma(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median of each column of ``d`` (N, 3) and its 1-sigma: 1.2533 std / sqrt(n_eff) (the median's
    efficiency for Gaussian samples; n_eff from the autocorrelation, Bartlett)."""
    d = d[np.isfinite(d).all(axis=1)]
    med = np.median(d, axis=0)
    frac = effective_fraction(d - med) if len(d) > 20 else 1.0
    return med, 1.2533 * d.std(axis=0) / np.sqrt(max(1.0, frac * len(d)))


def _chi2_scale(Yc: np.ndarray, axes: np.ndarray, sig: np.ndarray, q: float = 0.999) -> float:
    """Variance factor that makes the parity statistic at rest chi-square: the ``q`` quantile of
    ``T = r^T W r`` (r the weighted least-squares residual of the compensated outputs ``Yc`` (N, n) on their
    axes ``axes`` (n, 3), W = diag(sigma^-2), Cho & Park 2005, Eq. 13) over the chi-square quantile with
    ``n - 3`` degrees of freedom; at least 1.

    ``triad_noise`` gives each sensor's own variance; what it leaves out (noise correlated between sensors,
    tails) shows in T, and the detectors' thresholds assume T is chi-square.
    """
    from scipy.stats import chi2

    Z = Yc[np.isfinite(Yc).all(axis=1)]
    n = Z.shape[1]
    if len(Z) < 100 or n < 6:
        return 1.0
    w = 1.0 / sig**2
    Aw = axes * w[:, None]
    x = Z @ Aw @ np.linalg.inv(axes.T @ Aw)
    r = Z - x @ axes.T
    T = (r * r * w).sum(axis=1)
    return float(max(1.0, np.quantile(T, q) / chi2.ppf(q, n - 3)))


def _clocks(recording: Any, reference: int, max_lag_s: float, checks: str) -> list:
    import logging

    from .timing import estimate_clocks

    clocks = estimate_clocks(recording, reference, max_lag_s=max_lag_s, checks=checks)
    log = logging.getLogger(__name__)
    for c in clocks[:reference] + clocks[reference + 1:]:
        log.info("clock of %s: offset %+.3f ms, rate %+.3g +- %.2g ppm (drift %.3g ms at the ends)", c.name,
                 1e3 * c.offset_s, c.rate_ppm, c.rate_sigma_ppm, 1e3 * c.drift_s)
        if checks != "strict" and c.drift_s > 0.5 * float(np.median(np.diff(recording.units[reference].t))):
            log.warning("clock of %s runs %+.3g ppm fast: %.3g ms of drift that one offset does not remove",
                        c.name, c.rate_ppm, 1e3 * c.drift_s)
    return clocks


def setup_multi_imu(recording: Any, average_s: float | None = 0.1, reference: int = 0,
                    fit_window_s: Sequence[float] | None = None, estimate_clocks: bool | None = None,
                    max_lag_s: float = 0.5, min_rate_rad_s: float = 0.05, align_axes: bool | None = None,
                    min_still_s: float = 2.0, clock_checks: str = "strict") -> MultiImuSetup:
    """Set up a unit of triads from its own recording (see the module docstring).

    Parameters
    ----------
    recording : rimu.io.multiimu.MultiImuRecording
        (or anything with its ``names``, ``units``, ``meta``, ``instruments()`` and ``to_block()``: calibration
        does not import io)
    average_s : float or None
        Block-average length, s (None or 0: none).
    reference : int
        The triad that defines MB.
    fit_window_s : (start, end), optional
        Fit clocks, axes, biases and noise on this time window only (s, on the reference's clock); default
        the whole recording.
    estimate_clocks : bool, optional
        Estimate clock offsets; default: when the recording says its IMUs have their own clocks
        (``meta["own_clocks"]``).
    min_rate_rad_s : float
        Rates below this are not used for the axis alignment.
    clock_checks : {"strict", "warn"}
        A unit's clock rate (:func:`rimu.calibration.timing.estimate_clocks`, in ``clocks``) whose drift over the
        record exceeds half a sample period after the offset is removed: refused, or logged as a warning.
    align_axes : bool, optional
        Fit the triads' rotations; default: unless the recording says its triads are already in one body frame
        (``meta["body_frame"]``, as an autopilot logs them). The gyro bias differences are fitted either way.
        Nearly parallel triads (rotations of a fraction of a degree) cannot isolate a fault in practice: keep
        them parallel rather than let a tiny fitted angle pretend they can.
    min_still_s : float
        Rest needed in the fit window (s) for the biases and the noise to come from the spans at rest.

    Raises
    ------
    IdentifiabilityError
        No motion and gravity in one direction only (units lying level): the rotation about the vertical is
        not observed; the message says so and what to do.
    """
    names = recording.names
    k = len(names)
    own = bool(recording.meta.get("own_clocks", False)) if estimate_clocks is None else bool(estimate_clocks)
    timing = estimate_offsets(recording, reference, max_lag_s) if (own and k > 1) else None
    # a rate as well as an offset: refused where the drift exceeds what resampling on one offset absorbs
    clocks = _clocks(recording, reference, max_lag_s, clock_checks) if (own and k > 1) else []
    full = _placeholders_invalid(recording.to_block(offsets_s=None if timing is None else timing.offsets_s,
                                                    reference=reference))
    fs_full = 1.0 / float(np.median(np.diff(full.t)))
    n_avg = 1
    if average_s:
        n_avg = max(1, round(average_s * fs_full))
    block = average_block(full, n_avg)
    still_full = still_epochs(full, fs_full)
    m = (len(still_full) // n_avg) * n_avg
    still = still_full[:m].reshape(-1, n_avg).all(axis=1) if n_avg > 1 else still_full
    lo, hi = (-np.inf, np.inf) if fit_window_s is None else (float(fit_window_s[0]), float(fit_window_s[1]))
    win = (block.t >= lo) & (block.t <= hi)
    st = still[win]
    dt_avg = n_avg / fs_full
    use_rest = float(st.sum()) * dt_avg >= min_still_s
    insts = recording.instruments()
    from ..geometry import triads

    v0 = block.valid[insts[0]]
    delivering = [nm for j, nm in enumerate(names) if v0[:, 3 * j].mean() >= 0.5]
    rotations = [np.eye(3) for _ in range(k)]
    alignments: list[AlignmentResult] = []
    gyro_bias = np.zeros(3 * k)
    bias_sigma: dict[str, np.ndarray] = {}
    ref_cols = slice(3 * reference, 3 * reference + 3)
    align = (not recording.meta.get("body_frame", False)) if align_axes is None else bool(align_axes)
    motion_s = 0.0
    if "gyro" in insts:
        G = np.where(block.valid["gyro"], block.raw["gyro"], np.nan)[win]
        # the reference's own bias at rest: rates are measured from it, so a large bias is never "motion"
        b_ref = np.nanmedian(G[st][:, ref_cols], axis=0) if use_rest else np.zeros(3)
        moving = (np.linalg.norm(np.nan_to_num(G[:, ref_cols] - b_ref), axis=1) >= min_rate_rad_s) & ~st
        motion_s = float(moving.sum()) * dt_avg
        # rates are informative about a rotation when they vary in two directions at least by more than the
        # motion threshold (a constant rate, or a turn about one axis, leaves a rotation about it unobserved)
        Rm = G[moving][:, ref_cols]
        Rm = Rm[np.isfinite(Rm).all(axis=1)]
        informative = len(Rm) >= 3 and float(np.sqrt(np.linalg.eigvalsh(np.cov(Rm.T))[1])) >= min_rate_rad_s
        A = np.where(block.valid["accel"], block.raw["accel"], np.nan)[win] if "accel" in insts else None
        for j in range(k):
            if j == reference or names[j] not in delivering:
                continue
            cols = slice(3 * j, 3 * j + 3)
            if align:
                if informative:
                    a = align_triads(G[:, ref_cols], G[:, cols], static=~moving, name=names[j])
                else:
                    a = _align_from_gravity(A, st, ref_cols, cols, names[j], min_rate_rad_s)
                alignments.append(a)
                rotations[j] = a.mat_unit_ref
                gyro_bias[cols] = a.offsets.get("rate", np.zeros(3))
            elif not use_rest:
                gyro_bias[cols] = np.nanmedian(G[:, cols] - G[:, ref_cols], axis=0)
            if use_rest:
                d = G[st][:, cols] - G[st][:, ref_cols] @ rotations[j].T
                gyro_bias[cols], sg = _median_sigma(d)
                bias_sigma.setdefault("gyro", np.zeros(3 * k))[cols] = sg
    geo = triads(rotations, None, names)
    cals = {}
    noise_scale: dict[str, float] = {}
    pose_sigma: dict[str, np.ndarray] = {}
    gains = [rotations[j] for j in range(k)]   # each triad's axes in MB (rows); accelerometers: refined below
    accel_gains = False
    for inst in insts:
        Y = np.where(block.valid[inst], block.raw[inst], np.nan)[win]
        bias = gyro_bias.copy() if inst == "gyro" else np.zeros(3 * k)
        axes = rotations
        if inst == "accel":
            fitted = _accel_gains(Y, st, ref_cols, k, reference, [nm in delivering for nm in names]) if use_rest \
                else None
            accel_gains = fitted is not None
            axes = list(fitted) if fitted is not None else rotations
            for j in range(k):
                if j != reference and names[j] in delivering:
                    rows = st if use_rest else np.ones(len(Y), bool)
                    d = Y[rows][:, 3 * j:3 * j + 3] - Y[rows][:, ref_cols] @ axes[j].T
                    if use_rest:
                        bias[3 * j:3 * j + 3], sa = _median_sigma(d)
                        bias_sigma.setdefault("accel", np.zeros(3 * k))[3 * j:3 * j + 3] = sa
                    else:
                        bias[3 * j:3 * j + 3] = np.nanmedian(d, axis=0)
            gains = axes
        # compensated outputs expressed in MB (the reference's axes) for the disagreement
        live = [j for j in range(k) if names[j] in delivering]
        rows = st if (use_rest and st.sum() >= 50) else np.ones(len(Y), bool)
        Zmb = np.column_stack([(Y[rows][:, 3 * j:3 * j + 3] - bias[3 * j:3 * j + 3]) @ np.linalg.inv(axes[j]).T
                               for j in live])
        sig = np.full(3 * k, np.nan)
        if len(live) >= 2:
            s_live = triad_noise(Zmb)           # per MB axis of each triad: back to the triad's own axes
            for q, j in enumerate(live):
                sig[3 * j:3 * j + 3] = np.sqrt(axes[j] ** 2 @ s_live[3 * q:3 * q + 3] ** 2)
        finite = sig[np.isfinite(sig)]
        sig[~np.isfinite(sig)] = finite.max() if finite.size else 1.0
        if rows is st and len(live) >= 3:
            cols = np.concatenate([np.arange(3 * j, 3 * j + 3) for j in live])
            Yc = np.column_stack([Y[rows][:, 3 * j:3 * j + 3] - bias[3 * j:3 * j + 3] for j in live])
            c = _chi2_scale(Yc, np.vstack([axes[j] for j in live]), sig[cols])
            sig *= np.sqrt(c)
            noise_scale[inst] = c
        if inst == "accel" and accel_gains:
            ps = pose_uncertainty(Y, st, ref_cols, axes, [j for j in range(k) if names[j] in delivering],
                                  min_still_s / dt_avg)
            if ps is not None:
                pose_sigma[inst] = ps
        cals[inst] = InstrumentCalibration.nominal(inst, geo, scale=1.0, bias=bias, noise_sigma=sig)
        if inst == "accel" and accel_gains:  # each triad's gain: unit rows m_i (a_i = m_i C_j), norms into SF
            ci = cals[inst]
            for j in range(k):
                rows = gains[j] @ rotations[j].T
                nrm = np.linalg.norm(rows, axis=1)
                sl = slice(3 * j, 3 * j + 3)
                ci.misalignment[sl] = rows / nrm[:, None]
                ci.scale[sl] = 1.0 / nrm           # SF y = m.(C u) + b: y = g.u + c -> SF = 1/|g|, b = SF c
                ci.bias[sl] = ci.bias[sl] / nrm
        cals[inst].noise_period_s = dt_avg  # the noise of the epochs it was measured on (the averages')
    spans = {"still_s": float(st.sum()) * dt_avg if use_rest else 0.0, "motion_s": motion_s,
             "accel_gains_from_rest": accel_gains,
             "noise_at_rest": bool(use_rest and st.sum() >= 50), "noise_scale": noise_scale}
    meta: dict[str, Any] = {"source": recording.meta.get("source") or recording.meta.get("folder"),
                            "averaged": n_avg, "reference": names[reference]}
    cal = Calibration(cals, raw_unit="SI", method="multi-imu-setup", metadata=meta)
    meta["spans_s"] = spans
    return MultiImuSetup(cal, block, timing, alignments, delivering, (lo, hi), full, n_avg, still, bias_sigma,
                         spans, clocks, pose_sigma)


#: the least spread of the reference accelerometer at rest, in its weakest direction, for the relative gains (m/s^2
#: rms): gravity seen in three directions (poses), else the accelerometers keep the gyros' rotations
MIN_POSE_SPREAD_M_S2 = 2.0


def _accel_gains(Y: np.ndarray, still: np.ndarray, ref_cols: slice, k: int, reference: int, live: list[bool]
                 ) -> list[np.ndarray] | None:
    """Each accelerometer triad's gain against the reference triad from the spans at rest (Cho & Park 2005,
    Eq. 1 with the reference as input): ``y_j = G_j y_ref + c_j`` by least squares over the samples at rest, so
    that a triad's relative scale and misalignment (about 1 % and 18 mrad between the MIMU4444's triads) are not
    seen as a pose-dependent bias. Needs gravity in three directions (the reference's spread at rest above
    :data:`MIN_POSE_SPREAD_M_S2` in its weakest direction); None otherwise. The reference's gain is I (it
    defines MB)."""
    R = Y[still][:, ref_cols]
    ok = np.isfinite(R).all(axis=1)
    if ok.sum() < 50:
        return None
    ev = np.linalg.eigvalsh(np.cov(R[ok].T))
    if np.sqrt(max(ev[0], 0.0)) < MIN_POSE_SPREAD_M_S2:
        return None
    out = []
    for j in range(k):
        if j == reference or not live[j]:
            out.append(np.eye(3))
            continue
        Zj = Y[still][:, 3 * j:3 * j + 3]
        m = ok & np.isfinite(Zj).all(axis=1)
        X = np.column_stack([R[m], np.ones(m.sum())])
        coef = np.linalg.lstsq(X, Zj[m], rcond=None)[0]
        out.append(coef[:3].T)
    return out


#: poses at rest needed for the offset uncertainty at a new pose (:func:`pose_uncertainty`): the per-sensor levels
#: are separated from the triads' disagreement over the poses (:func:`triad_noise` needs ten rows)
MIN_POSES = 10


def pose_uncertainty(Y: np.ndarray, still: np.ndarray, ref_cols: slice, gains: Sequence[np.ndarray],
                     live: Sequence[int], min_len: float = 20.0) -> np.ndarray | None:
    """Each accelerometer's offset 1-sigma at a pose the relative gains were not fitted on, (3k,) output units.

    The gains ``y_j = G_j y_ref + c_j`` fitted on the poses at rest (:func:`setup_multi_imu`) leave, at a pose
    they have not seen, an offset that no noise figure states: the gain's own error, and what a 3 x 3 gain does
    not model (pose-dependent or slowly drifting terms). It acts on the parity at rest as an unknown constant,
    which averaging does not remove. Measured by leaving each pose out: the gain fitted on the other poses
    predicts the left-out pose's mean, ``e_pj = mean_p(y_j) - G_j^(-p) mean_p(y_ref) - c_j^(-p)``; its spread
    over the poses holds that offset (triad j's and the reference's) plus the noise of a pose mean, measured
    from the same poses as half the difference of their two halves' means (any correlation of the noise
    included). Both are expressed on the reference's axes, separated per triad from the triads' disagreement
    (:func:`triad_noise`, the reference's column 0), subtracted, and taken back to each sensor's axes.

    Parameters
    ----------
    Y : ndarray (N, 3k)
        Accelerometer samples (NaN where invalid) of the fit window.
    still : ndarray (N,) of bool
        The samples at rest; each run of at least ``min_len`` samples is a pose.
    gains : sequence of ndarray (3, 3)
        Each triad's gain against the reference (the reference's: I).
    live : sequence of int
        The triads that deliver (the others get the largest level).

    Returns
    -------
    ndarray (3k,) or None
        None with fewer than :data:`MIN_POSES` poses (or fewer than three live triads).

    Examples
    --------
    Three triads in twelve poses; triad 2 carries a pose-dependent offset of 0.02 (a nonlinearity no gain
    models) under noise of 0.01 per sample, 200 samples per pose:

    >>> rng = np.random.default_rng(1)
    >>> g = rng.normal(size=(12, 3)); g = 9.8 * g / np.linalg.norm(g, axis=1, keepdims=True)
    >>> ref = np.repeat(g, 200, axis=0)
    >>> off = np.repeat(0.02 * rng.standard_normal((12, 3)), 200, axis=0)
    >>> Y = np.hstack([ref, ref, ref + off]) + 0.01 * rng.standard_normal((2400, 9))
    >>> still = (np.arange(2400) % 200) < 190            # 190 samples at rest per pose
    >>> s = pose_uncertainty(Y, still, slice(0, 3), [np.eye(3)] * 3, [0, 1, 2])
    >>> bool(np.all(s[:6] < 0.006)), bool(np.all((s[6:] > 0.012) & (s[6:] < 0.04)))
    (True, True)
    """
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(still, bool).astype(np.int8), [0]])))
    segs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= max(4, min_len)]
    live = list(live)
    if len(segs) < MIN_POSES or len(live) < 3:
        return None
    n = Y.shape[1]
    R = Y[:, ref_cols]
    P = len(segs)
    Zloo = np.zeros((P, n))
    Zhalf = np.zeros((P, n))
    for j in live:
        cols = slice(3 * j, 3 * j + 3)
        if cols == ref_cols:
            continue
        XtX, XtZ, mean_x, mean_z, halves = [], [], [], [], []
        for a, b in segs:
            X = np.column_stack([R[a:b], np.ones(b - a)])
            Z = Y[a:b, cols]
            ok = np.isfinite(X).all(axis=1) & np.isfinite(Z).all(axis=1)
            X, Z = X[ok], Z[ok]
            XtX.append(X.T @ X)
            XtZ.append(X.T @ Z)
            mean_x.append(X.mean(axis=0))
            mean_z.append(Z.mean(axis=0))
            halves.append((X[: len(X) // 2], Z[: len(X) // 2], X[len(X) // 2:], Z[len(X) // 2:]))
        SX, SZ = sum(XtX), sum(XtZ)
        coef = np.linalg.lstsq(SX, SZ, rcond=None)[0]
        inv = np.linalg.inv(gains[j])  # to the reference's axes (as the noise levels are separated)
        for p in range(P):  # (a pose alone in its direction: the others' fit extrapolates, and its error says so)
            c = np.linalg.lstsq(SX - XtX[p], SZ - XtZ[p], rcond=None)[0]
            Zloo[p, cols] = (mean_z[p] - mean_x[p] @ c) @ inv.T
            X1, Z1, X2, Z2 = halves[p]
            Zhalf[p, cols] = ((Z1 - X1 @ coef).mean(axis=0) - (Z2 - X2 @ coef).mean(axis=0)) / 2.0 @ inv.T
    lc = np.concatenate([np.arange(3 * j, 3 * j + 3) for j in live])
    v = np.clip(triad_noise(Zloo[:, lc]) ** 2 - triad_noise(Zhalf[:, lc]) ** 2, 0.0, None)
    out = np.full(n, np.nan)
    for q, j in enumerate(live):
        out[3 * j:3 * j + 3] = np.sqrt(np.asarray(gains[j]) ** 2 @ v[3 * q:3 * q + 3])
    out[~np.isfinite(out)] = np.nanmax(out)
    return out


def _placeholders_invalid(block: EpochBlock) -> EpochBlock:
    """A triad whose accelerometer vector is exactly zero is a placeholder record, not a measurement (a unit
    on Earth at rest reads 1 g): invalid in every instrument at that sample."""
    if "accel" not in block.raw:
        return block
    A = block.raw["accel"]
    k = A.shape[1] // 3
    zero = np.all(A.reshape(len(A), k, 3) == 0.0, axis=2) & block.valid["accel"].reshape(len(A), k, 3).all(axis=2)
    if not zero.any():
        return block
    bad = np.repeat(zero, 3, axis=1)
    valid = {name: v & ~bad if v.shape[1] == 3 * k else v for name, v in block.valid.items()}
    meta = dict(block.meta)
    meta["placeholder_samples"] = int(zero.sum())
    return EpochBlock(block.t, block.raw, valid, block.temperature, meta)


def _align_from_gravity(A: np.ndarray | None, still: np.ndarray, ref_cols: slice, cols: slice, name: str,
                        min_rate_rad_s: float) -> AlignmentResult:
    """The rotation from gravity alone (a recording without motion), or the reason it cannot be found."""
    why = (f"no motion in the fit window that turns about two axes (the rates, measured from the bias at rest, "
           f"vary by less than {min_rate_rad_s:g} rad/s in a second direction)")
    if A is None or still.sum() < 3:
        raise IdentifiabilityError(f"triad {name!r}: {why} and no accelerometers at rest: the rotation between "
                                   "the triads cannot be found; give align_axes=False (rimu setup --parallel) to keep them parallel, or "
                                   "a recording with motion", ["rotation"])
    try:
        return fit_rotation([VectorSet("gravity", A[still][:, ref_cols], A[still][:, cols])], name=name)
    except IdentifiabilityError as exc:
        raise IdentifiabilityError(
            f"triad {name!r}: {why}, and gravity was seen in one direction only ({exc}); rotate the unit, or "
            "give align_axes=False (rimu setup --parallel) to keep the triads parallel", ["rotation"]) from None
