"""The PX4 EKF2-selector-like rule: closed-form flag times, its blind spot below the dead band, two IMUs
ambiguous, the timeout, and the vectorised recursion against a plain loop."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.errors import ShapeError
from rimu.fdi import Px4GyroSelector

RATE = 100.0


def _three(bias_deg_s, N=3000, imus=3, seed=0):
    rng = np.random.default_rng(seed)
    W = np.repeat(rng.normal(0, 0.5, (N, 1, 3)), imus, axis=1)
    W[1000:, 1, 2] += np.radians(bias_deg_s)
    return np.arange(N) / RATE, W


@pytest.mark.parametrize("bias", [8.0, 10.0, 22.0])
def test_flag_time_is_angle_over_excess_rate(bias):
    t, W = _three(bias)
    r = Px4GyroSelector().run(t, W)
    who, tf, amb = r.first()
    assert who == 1 and not amb and r.reason[1] == "disagreement"
    assert tf - 10.0 == pytest.approx(15.0 / (bias - 7.0), abs=1.5 / RATE)
    # with three IMUs "the median of the others" of a healthy IMU is the mean of a healthy and the faulty one:
    # it disagrees by bias / 2 and is flagged too once that exceeds the dead band, 15 / (b/2 - 7) s after onset
    if bias / 2 > 7.0:
        assert r.t_flag[[0, 2]] - 10.0 == pytest.approx([15.0 / (bias / 2 - 7.0)] * 2, abs=1.5 / RATE)
    else:
        assert np.isnan(r.t_flag[[0, 2]]).all()


def test_below_the_dead_band_never_flags_and_two_imus_are_ambiguous():
    t, W = _three(6.9)
    assert Px4GyroSelector().run(t, W).first()[0] == -1
    t, W = _three(10.0, imus=2)
    _, tf, amb = Px4GyroSelector().run(t, W).first()
    assert amb and tf == pytest.approx(15.0, abs=0.02)


def test_timeout_and_shapes():
    t, W = _three(0.0)
    V = np.ones(W.shape[:2], bool)
    V[500:, 2] = False
    r = Px4GyroSelector(timeout_s=1.0).run(t, W, V)
    assert r.first()[:2] == (2, pytest.approx(4.99 + 1.0, abs=0.011)) and r.reason[2] == "timeout"
    with pytest.raises(ShapeError, match="at least two"):
        Px4GyroSelector().run(t, W[:, :1])
    with pytest.raises(ShapeError, match=r"\(N, k, 3\)"):
        Px4GyroSelector().run(t[:10], W)


def test_recursion_matches_a_plain_loop():
    rng = np.random.default_rng(3)
    N, k = 800, 4
    t = np.cumsum(rng.uniform(0.008, 0.014, N))
    W = rng.normal(0, np.radians(6.0), (N, k, 3))
    r = Px4GyroSelector().run(t, W)
    thr = np.radians(7.0)
    E = np.zeros(k)
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    for n in range(N):
        for i in range(k):
            med = np.median(np.delete(W[n], i, axis=0), axis=0)
            E[i] = max(0.0, E[i] + (np.linalg.norm(W[n, i] - med) - thr) * dt[n])
        assert np.allclose(r.accumulated[n], E, atol=1e-12)
