"""From a multi-IMU recording to a calibrated unit of triads: clocks, axes, biases and noise from the data.

A unit of k triads that nobody calibrated as a whole (IMUs strapped to a drone, an autopilot's two or three
IMUs) is set up from a stretch of its own data, fault-free by assumption:

1. clock offsets of every triad against the reference (:func:`rimu.calibration.timing.estimate_offsets`;
   skipped where the recording has one clock), removed, all triads resampled to one time base;
2. optionally, block averages over ``average_s`` (vibration above a few Hz is common to no two triads; the
   averaged parity is closer to the white noise the detectors assume) - the unit then runs at the lower rate;
3. the rotation of each triad against the reference (:func:`rimu.calibration.alignment.align_triads`), with its
   covariance, and the constant gyro bias difference; the reference triad defines MB;
4. accelerometer bias differences (median of each triad's specific force minus the reference's, rotated);
5. per-sensor noise levels from the residuals against the other triads (the flight's own disagreement, which
   holds vibration and everything the model leaves out), for the pipeline's weights and the detectors.

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
from ..errors import ShapeError
from ..units import RAD_TO_DEG
from .alignment import AlignmentResult, align_triads
from .result import Calibration, InstrumentCalibration
from .timing import TimingResult, estimate_offsets

__all__ = ["MultiImuSetup", "average_block", "setup_multi_imu", "triad_noise"]


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
    #: per unit with its own clock: offset and rate against the reference (rimu.calibration.timing.estimate_clocks)
    clocks: list = field(default_factory=list)

    def average(self, full_block: EpochBlock) -> EpochBlock:
        """Average a block on the full-rate time base (e.g. one with injected faults) as :attr:`block` was."""
        return average_block(full_block, self.n_average)

    def report(self) -> str:
        """Human-readable summary: offsets (ms), clock rates (ppm), rotations (deg with 1-sigma), noise levels."""
        lines = []
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
            lines.append(f"{k} noise per sensor ({unit}): " + " ".join(f"{v * f:.3g}" for v in s))
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
                    clock_checks: str = "strict") -> MultiImuSetup:
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
    """
    names = recording.names
    k = len(names)
    own = bool(recording.meta.get("own_clocks", False)) if estimate_clocks is None else bool(estimate_clocks)
    timing = estimate_offsets(recording, reference, max_lag_s) if (own and k > 1) else None
    # a rate as well as an offset: refused where the drift exceeds what resampling on one offset absorbs
    clocks = _clocks(recording, reference, max_lag_s, clock_checks) if (own and k > 1) else []
    full = recording.to_block(offsets_s=None if timing is None else timing.offsets_s, reference=reference)
    n_avg = 1
    if average_s:
        n_avg = max(1, round(average_s / float(np.median(np.diff(full.t)))))
    block = average_block(full, n_avg)
    lo, hi = (-np.inf, np.inf) if fit_window_s is None else (float(fit_window_s[0]), float(fit_window_s[1]))
    win = (block.t >= lo) & (block.t <= hi)
    insts = recording.instruments()
    from ..geometry import triads

    v0 = block.valid[insts[0]]
    delivering = [nm for j, nm in enumerate(names) if v0[:, 3 * j].mean() >= 0.5]
    rotations = [np.eye(3) for _ in range(k)]
    alignments: list[AlignmentResult] = []
    gyro_bias = np.zeros(3 * k)
    ref_cols = slice(3 * reference, 3 * reference + 3)
    align = (not recording.meta.get("body_frame", False)) if align_axes is None else bool(align_axes)
    if "gyro" in insts:
        G = np.where(block.valid["gyro"], block.raw["gyro"], np.nan)[win]
        for j in range(k):
            if j == reference or names[j] not in delivering:
                continue
            if align:
                a = align_triads(G[:, ref_cols], G[:, 3 * j:3 * j + 3], min_rate_rad_s=min_rate_rad_s,
                                 name=names[j])
                alignments.append(a)
                rotations[j] = a.mat_unit_ref
                gyro_bias[3 * j:3 * j + 3] = a.offsets["rate"]
            else:
                gyro_bias[3 * j:3 * j + 3] = np.nanmedian(G[:, 3 * j:3 * j + 3] - G[:, ref_cols], axis=0)
    geo = triads(rotations, None, names)
    cals = {}
    for inst in insts:
        Y = np.where(block.valid[inst], block.raw[inst], np.nan)[win]
        bias = gyro_bias.copy() if inst == "gyro" else np.zeros(3 * k)
        if inst == "accel":
            for j in range(k):
                if j != reference and names[j] in delivering:
                    d = Y[:, 3 * j:3 * j + 3] - Y[:, ref_cols] @ rotations[j].T
                    bias[3 * j:3 * j + 3] = np.nanmedian(d, axis=0)
        # compensated outputs expressed in MB (the reference's axes) for the disagreement
        live = [j for j in range(k) if names[j] in delivering]
        Zmb = np.column_stack([(Y[:, 3 * j:3 * j + 3] - bias[3 * j:3 * j + 3]) @ rotations[j] for j in live])
        sig = np.full(3 * k, np.nan)
        if len(live) >= 2:
            s_live = triad_noise(Zmb)
            for q, j in enumerate(live):
                sig[3 * j:3 * j + 3] = s_live[3 * q:3 * q + 3]
        finite = sig[np.isfinite(sig)]
        sig[~np.isfinite(sig)] = finite.max() if finite.size else 1.0
        cals[inst] = InstrumentCalibration.nominal(inst, geo, scale=1.0, bias=bias, noise_sigma=sig)
    meta: dict[str, Any] = {"source": recording.meta.get("source") or recording.meta.get("folder"),
                            "averaged": n_avg, "reference": names[reference]}
    cal = Calibration(cals, raw_unit="SI", method="multi-imu-setup", metadata=meta)
    return MultiImuSetup(cal, block, timing, alignments, delivering, (lo, hi), full, n_avg, clocks)
