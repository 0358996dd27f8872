"""The IMU fault rule of PX4's EKF2 selector, as a reference for the redundancy manager on real data.

PX4 (``EKF2Selector``) compares each gyro with the others and accumulates the excess of the disagreement over
a rate threshold: per IMU i, with ``d_i = |w_i - median_{j != i} w_j|`` (per-axis median of the other IMUs'
rates, all in the body frame; with two IMUs simply the other one)::

    E_i = max(0, E_i + (d_i - rate_threshold) dt),      IMU i faulty when E_i > angle_threshold

with ``rate_threshold`` 7 deg/s and ``angle_threshold`` 15 deg (the rule as the issue describes it;
PX4's parameters ``EKF2_SEL_IMU_RAT`` and ``EKF2_SEL_IMU_ANG``). An IMU that delivers no valid data for
``timeout_s`` is also flagged (PX4's sensor timeout). The rule sees triads, not axes: it flags an IMU.
With two IMUs both disagree equally and both accumulate: it flags both at once and cannot tell which one is
wrong (reported as ``ambiguous``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError
from ..units import DEG_TO_RAD

__all__ = ["Px4GyroSelector", "Px4SelectorResult"]


@dataclass
class Px4SelectorResult:
    """Per IMU: time of the first flag (NaN: never), why (``disagreement`` or ``timeout``), and the
    accumulated error over time (N, k), rad."""

    t_flag: np.ndarray
    reason: list[str]
    accumulated: np.ndarray

    def first(self) -> tuple[int, float, bool]:
        """The first flagged IMU, its time, and whether another IMU was flagged at the same sample
        (ambiguous). (-1, NaN, False) when none was flagged."""
        if not np.any(np.isfinite(self.t_flag)):
            return -1, float("nan"), False
        tmin = np.nanmin(self.t_flag)
        who = np.flatnonzero(self.t_flag == tmin)
        return int(who[0]), float(tmin), len(who) > 1


class Px4GyroSelector:
    """The EKF2-selector-like gyro rule (module docstring).

    Parameters
    ----------
    rate_threshold_deg_s : float
        Dead band of the disagreement, deg/s (7).
    angle_threshold_deg : float
        Accumulated excess at which an IMU is flagged, deg (15).
    timeout_s : float
        An IMU without valid data for this long is flagged.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> W = np.repeat(rng.normal(0, 0.5, (1200, 1, 3)), 3, axis=1)       # three IMUs, same motion, no noise
    >>> W[500:, 1, 0] += np.radians(10.0)           # 10 deg/s bias on IMU 1 from t = 5 s
    >>> r = Px4GyroSelector().run(np.arange(1200) / 100.0, W)
    >>> r.first()[0], round(r.first()[1], 1)       # (10 - 7) deg/s takes 5 s to reach 15 deg
    (1, 10.0)
    """

    def __init__(self, rate_threshold_deg_s: float = 7.0, angle_threshold_deg: float = 15.0,
                 timeout_s: float = 1.0) -> None:
        self.rate_threshold = float(rate_threshold_deg_s) * DEG_TO_RAD
        self.angle_threshold = float(angle_threshold_deg) * DEG_TO_RAD
        self.timeout_s = float(timeout_s)

    def run(self, t: np.ndarray, W: np.ndarray, valid: np.ndarray | None = None) -> Px4SelectorResult:
        """Apply the rule to rates ``W`` (N, k, 3), rad/s in the body frame, at times ``t`` (N,), s;
        ``valid`` (N, k) marks the IMUs that delivered a sample."""
        t = np.asarray(t, dtype=float)
        W = np.asarray(W, dtype=float)
        if W.ndim != 3 or W.shape[2] != 3 or W.shape[0] != len(t):
            raise ShapeError(f"rates must be (N, k, 3) with N = len(t) = {len(t)}, got {W.shape}")
        N, k, _ = W.shape
        if k < 2:
            raise ShapeError("the selector rule compares IMUs: it needs at least two")
        V = np.ones((N, k), bool) if valid is None else np.asarray(valid, bool)
        V = V & np.isfinite(W).all(axis=2)
        dt = np.diff(t, prepend=t[0] - (t[1] - t[0] if N > 1 else 0.0))
        Wn = np.where(V[:, :, None], W, np.nan)
        excess = np.zeros((N, k))
        for i in range(k):
            others = np.delete(Wn, i, axis=1)
            has = np.isfinite(others).all(axis=2).any(axis=1) & V[:, i]
            with warnings.catch_warnings():  # an all-NaN slice (no other IMU delivered) is handled by `has`
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(others, axis=1)
            d = np.linalg.norm(np.nan_to_num(W[:, i] - med), axis=1)
            excess[:, i] = np.where(has, (d - self.rate_threshold) * dt, 0.0)  # no comparison: E unchanged
        # E_n = max(0, E_{n-1} + x_n) is Lindley's recursion: E_n = S_n - min(0, min_{m <= n} S_m), S = cumsum x
        S = np.cumsum(excess, axis=0)
        acc = S - np.minimum(np.minimum.accumulate(S, axis=0), 0.0)
        t_flag = np.full(k, np.nan)
        reason = [""] * k
        idx = np.arange(N)
        for i in range(k):
            over = np.flatnonzero(acc[:, i] > self.angle_threshold)
            t_dis = t[over[0]] if over.size else np.inf
            last = np.maximum.accumulate(np.where(V[:, i], idx, 0))      # last valid sample (the first if none)
            stale = np.flatnonzero(t - t[last] >= self.timeout_s)
            t_out = t[stale[0]] if stale.size else np.inf
            if np.isfinite(min(t_dis, t_out)):
                t_flag[i] = min(t_dis, t_out)
                reason[i] = "disagreement" if t_dis <= t_out else "timeout"
        return Px4SelectorResult(t_flag, reason, acc)
