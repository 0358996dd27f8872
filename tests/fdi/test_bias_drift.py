"""Issue 32: the relative-bias tracker's time constant from the drift the setup measures, ``tau = N / K``
(rimu.fdi.bias_drift), in place of a 60 s chosen after seeing one run.

* closed form: an exponential mean of time constant tau over a random walk (K per sqrt(s)) under white noise
  (N per sqrt(Hz)) has the error variance ``N^2 / (2 tau) + K^2 tau / 2``, smallest at ``tau = N / K``: the
  simulated error variances at tau/2, tau and 2 tau match the formula within 15 % (500 independent series of
  3000 samples after the filter's start) and the middle one is the smallest;
* the estimator, on simulated poses of 12 s every 20 s for 600 s (24 sensors): N within 2 % (median) and 8 %
  (each); tau within [0.8, 2.2] N/K (the median of a skewed variogram slope: 1.2-1.7 N/K over seeds, where the
  error variance is at most 6 % above its minimum: the curve is flat there); no drift: tau at least ten times longer, at
  most the span measured; fewer than three spans: refused.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from rimu.errors import ShapeError
from rimu.fdi.bias_drift import bias_drift

FS, N, K = 10.0, 1e-3, 1e-4


def _series(rng, n, m, k=K):
    walk = np.cumsum(rng.standard_normal((n, m)) * k / np.sqrt(FS), axis=0)
    return walk, walk + N * np.sqrt(FS) * rng.standard_normal((n, m))


def test_the_tracker_error_is_smallest_at_n_over_k():
    rng = np.random.default_rng(3)
    walk, y = _series(rng, 4000, 500)
    tau_star = N / K
    e2 = {}
    for f in (0.5, 1.0, 2.0):
        a = 1.0 / (f * tau_star * FS)
        est = lfilter([a], [1.0, a - 1.0], y, axis=0, zi=np.zeros((1, 500)) + walk[0])[0]
        e2[f] = float(np.mean((est - walk)[1000:] ** 2))
        theory = N**2 / (2 * f * tau_star) + K**2 * f * tau_star / 2
        assert e2[f] == pytest.approx(theory, rel=0.15), (f, e2[f], theory)
    assert e2[1.0] < e2[0.5] and e2[1.0] < e2[2.0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_time_constant_is_measured_from_the_poses(seed):
    rng = np.random.default_rng(seed)
    n = int(600 * FS)
    _, res = _series(rng, n, 24)
    rest = (np.arange(n) % int(20 * FS)) < int(12 * FS)
    d = bias_drift(res, rest, FS)
    assert d.spans == 30
    assert np.median(d.arw) == pytest.approx(N, rel=0.02)          # 3600 samples a sensor, 1 s means' gain
    np.testing.assert_allclose(d.arw, N, rtol=0.08)
    assert 0.8 * N / K <= d.tau_s <= 2.2 * N / K, d.tau_s
    assert "N/K" in d.describe() and "deg/s/sqrt(Hz)" in d.describe()


def test_no_drift_gives_a_long_time_constant_and_too_few_poses_are_refused():
    rng = np.random.default_rng(5)
    n = int(600 * FS)
    _, res = _series(rng, n, 24, k=0.0)
    rest = (np.arange(n) % int(20 * FS)) < int(12 * FS)
    d = bias_drift(res, rest, FS)
    assert d.span_s == pytest.approx(580.0, abs=1.0)
    assert 10 * N / K <= d.tau_s <= d.span_s, d.tau_s                  # ten times longer than with drift, capped
    with pytest.raises(ShapeError, match="three or more"):
        bias_drift(res[:400], rest[:400], FS)


def test_a_fit_span_without_poses_has_no_tracker_and_says_why():
    from rimu.calibration import InstrumentCalibration
    from rimu.fdi.motion import fit_motion_detector
    from rimu.geometry import triads

    cal = InstrumentCalibration.nominal("gyro", triads(3), 1.0, noise_sigma=0.01)
    raw = 0.01 * np.random.default_rng(0).standard_normal((500, 9))
    det = fit_motion_detector(cal, raw, None, 100.0, bias_track_s="auto", still=np.arange(500) < 150)
    assert det.bias_track_s is None and "three or more" in det.bias_drift
