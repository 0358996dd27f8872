"""Issue 32: what the MIMU4444 accelerometers' test at rest did not state, on simulated arrays whose truth is known.

* The offset at a new pose (:func:`rimu.calibration.multi_imu.pose_uncertainty`): two triads of four carry an
  offset that changes from pose to pose (0.02 m/s^2, twice their noise per sample; what a 3 x 3 gain does not
  model); leaving each pose out measures it within 35 %, and the other triads' stays below half of it (24 poses).
  With it in the test's covariance (``extra_var``), the alarm rate at rest on 400 new poses is within the
  binomial interval of the design rate; without it, more than ten times the design rate.
* The window gain below 1 (:func:`rimu.fdi.motion._window_gain`): noise whose neighbouring samples are
  anti-correlated (MA(1), ``e_t - 0.8 e_{t-1}``: lag-1 correlation -0.488) has 6-sample means with 0.187 of the
  white variance over 6 (closed form ``1 + 2 (L - 1) / L rho_1``); measured within 5 %, no longer clamped at 1.
  The window test with the measured gains holds its design rate at rest.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom, chi2

from rimu.calibration import InstrumentCalibration
from rimu.calibration.multi_imu import pose_uncertainty
from rimu.fdi.motion import MotionAwareGlt, MotionNoiseModel, _window_gain
from rimu.fusion import InstrumentPipeline
from rimu.geometry import triads
from rimu.units import G0

K, SIG, S_POSE = 4, 0.01, 0.02


def _poses(rng, n_poses: int, per: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """k parallel accelerometer triads at rest in ``n_poses`` random attitudes, ``per`` samples each; triads 2 and 3
    with an offset per pose and axis of S_POSE (1 sigma). Returns Y (N, 3k), the pose of each sample, the truth."""
    g = rng.standard_normal((n_poses, 3))
    g = G0 * g / np.linalg.norm(g, axis=1, keepdims=True)
    ref = np.repeat(g, per, axis=0)
    Y = np.tile(ref, (1, K)) + SIG * rng.standard_normal((len(ref), 3 * K))
    off = np.zeros((n_poses, 3 * K))
    off[:, 6:] = S_POSE * rng.standard_normal((n_poses, 6))
    return Y + np.repeat(off, per, axis=0), np.repeat(np.arange(n_poses), per), off


def test_offset_at_a_new_pose_is_measured_and_its_thresholds_hold_the_design_rate():
    rng = np.random.default_rng(32)
    Y, pose, _ = _poses(rng, 24, 200)
    still = np.ones(len(Y), bool)
    still[np.flatnonzero(np.diff(pose)) + 1] = False       # one sample between the poses: 24 spans at rest
    s = pose_uncertainty(Y, still, slice(0, 3), [np.eye(3)] * K, range(K))
    assert np.all(np.abs(s[6:] / S_POSE - 1.0) < 0.35), s[6:]
    assert np.all(s[:6] < 0.5 * S_POSE), s[:6]       # separated from 24 poses: a quarter of the variance at most
    assert pose_uncertainty(Y[:1800], still[:1800], slice(0, 3), [np.eye(3)] * K, range(K)) is None  # 9 poses

    cal = InstrumentCalibration.nominal("accel", triads(K), 1.0, noise_sigma=SIG)
    pipe = InstrumentPipeline(cal)
    V = pipe.table.Vz[0]
    Yn, _, _ = _poses(rng, 400, 25)                        # 10000 samples at rest on new poses
    P = pipe.process(Yn).parity
    n, p_fa = len(Yn), 1e-3
    rates = {}
    for name, extra in (("stated", s**2), ("without", 0.0)):
        det = MotionAwareGlt(MotionNoiseModel(cal, extra_var=extra), p_fa=p_fa, input_is_rate=False)
        det.configure(V, 3 * K - 3)
        det.set_motion(np.zeros(3), np.zeros(3))
        alarms = 0
        for k in range(n):
            det.set_input(Yn[k, :3])
            st, thr = det.update(P[k])
            alarms += st > thr
        rates[name] = alarms
    lo, hi = binom.ppf(0.0005, n, p_fa), binom.isf(0.0005, n, p_fa)
    print(f"alarms at rest in {n} samples on new poses (design {n * p_fa:g}): {rates}")
    assert lo <= rates["stated"] <= hi, (rates, lo, hi)
    assert rates["without"] > 10 * n * p_fa, rates


def test_window_gain_of_anticorrelated_noise_is_below_one_and_the_test_holds_its_rate():
    rng = np.random.default_rng(5)
    L, N, theta = 6, 60000, 0.8
    e = rng.standard_normal((N + 1, 2))
    x = np.column_stack([e[1:, 0] - theta * e[:-1, 0], e[1:, 1]])
    rho1 = -theta / (1 + theta**2)
    expect = 1 + 2 * (L - 1) / L * rho1
    g = _window_gain(x, np.ones(N, bool), L)
    assert abs(g[0] / expect - 1.0) < 0.05 and abs(g[1] - 1.0) < 0.05, (g, expect)

    # the window test at rest on three triads, one sensor with that noise: its gain measured, the design rate held
    cal = InstrumentCalibration.nominal("gyro", triads(3), 1.0, noise_sigma=0.003)
    pipe = InstrumentPipeline(cal)
    n = 40000
    e = rng.standard_normal((n + 1, 9))
    Z = 0.003 * e[1:]
    Z[:, 4] = 0.003 * (e[1:, 4] - theta * e[:-1, 4]) / np.sqrt(1 + theta**2)
    V = pipe.table.Vz[0]
    P = pipe.process(Z).parity
    res = pipe.table.sigma**2 * (P @ V)
    gain = _window_gain(res[: n // 2], np.ones(n // 2, bool), L)
    assert gain[4] < 0.5, gain
    p_fa = 0.01
    det = MotionAwareGlt(MotionNoiseModel(cal), p_fa=p_fa, sample_rate=100.0, window=L, window_gain=gain)
    det.configure(V, 6)
    stats = np.empty(n // 2)
    for k in range(n // 2):
        det.set_input(np.zeros(3))
        stats[k] = det.update(P[n // 2 + k])[0]
    s = stats[L:]
    rate = float(np.mean(s > chi2.isf(p_fa, 6)))
    assert abs(rate - p_fa) < 4 * np.sqrt(p_fa * L / len(s)), rate   # overlapping windows: N / L effective
