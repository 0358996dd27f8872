"""Detectors against their design: chi-square false alarms, window equivalence, CUSUM ARL and delay,
Kalman filter step/block identity, the dead-band baseline, online noise estimation."""

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from rimu.experiments.campaign import clopper_pearson
from rimu.fdi import (
    CusumBank,
    GltSnapshot,
    GltWindow,
    MeanDisagreement,
    NoiseEstimator,
    ParityKalman,
    glt_threshold,
    markov_arl,
    siegmund_arl,
)
from rimu.fdi.cusum import bias_delays
from rimu.geometry import cone6, dodecahedron6

V6 = cone6().parity_matrix()


def test_glt_snapshot_false_alarm_rate():
    rng = np.random.default_rng(0)
    P = rng.standard_normal((300_000, 3))
    stat, thr, _ = GltSnapshot(1e-3).block(P, V6, 3)
    lo, hi = clopper_pearson(int((stat > thr).sum()), len(P))
    assert lo <= 1e-3 <= hi
    assert thr == pytest.approx(chi2.isf(1e-3, 3))


def test_window_step_equals_block_and_restarts():
    rng = np.random.default_rng(1)
    P = rng.standard_normal((200, 3)) + 0.3
    det = GltWindow(5)
    det.configure(V6, 3)
    step = np.array([det.update(p)[0] for p in P])
    block, _, _iso = det.block(P, V6, 3)
    np.testing.assert_allclose(step, block, rtol=1e-10)
    det.configure(V6, 3)  # a new active set: the window starts empty
    assert det.update(P[0])[0] == pytest.approx(P[0] @ P[0])


def test_siegmund_agrees_with_brook_evans():
    # within 1 % for the small references the CUSUM bank uses (k = delta / 2 ~ 0.35 for 1 sigma on cone6);
    # Siegmund's approximation is known to drift for large k (5 % at k = 1)
    for k, h, tol in ((0.25, 8.0, 0.01), (0.35, 13.0, 0.01), (0.5, 4.0, 0.01), (0.5, 5.0, 0.01), (1.0, 3.0, 0.06)):
        ratio = markov_arl(h, lambda x, k=k: norm.cdf(x + k)) / siegmund_arl(-k, h)
        assert abs(ratio - 1) < tol


def test_cusum_delay_matches_lorden_at_arl0_1e5():
    """Mean delay for a 1 sigma bias within 15 % of ln(ARL0) / I, I = b^2 |v_j|^2 / 2."""
    bank = CusumBank(1.0, 1e5)
    rng = np.random.default_rng(2)
    delays = bias_delays(bank, V6, 3, 240, rng, length=300)
    assert np.isfinite(delays).all()
    info = 1.0**2 * (V6[:, 0] @ V6[:, 0]) / 2
    lorden = math.log(1e5) / info
    assert abs(np.mean(delays) / lorden - 1) < 0.15


def test_cusum_step_equals_block_until_the_first_alarm():
    rng = np.random.default_rng(7)
    P = rng.standard_normal((400, 3))
    P[200:] += 1.5 * V6[:, 3]
    bank = CusumBank(1.0, 1e4)
    blk, _, iso = bank.block(P, V6, 3)
    first = int(np.argmax(blk > 1))
    bank.configure(V6, 3)
    step = np.array([bank.update(p)[0] for p in P[: first + 1]])
    np.testing.assert_allclose(step, blk[: first + 1], rtol=1e-10)
    assert bank.isolate(P[first])[0] == iso[first] == 3


def test_cusum_bank_in_control_run_length():
    """The bank designed for ARL0 = 300 alarms no more often than that (members' union is conservative)."""
    rng = np.random.default_rng(3)
    P = rng.standard_normal((60_000, 3))
    s, _, _ = CusumBank(1.0, 300).block(P, V6, 3)
    arl = len(P) / max((s > 1).sum(), 1)
    assert 300 * 0.85 < arl < 300 * 1.6


def test_baseline_threshold_from_arl0():
    rng = np.random.default_rng(4)
    P = rng.standard_normal((60_000, 3))
    s, _, _ = MeanDisagreement(1.0, 2.0, 300).block(P, V6, 3)
    arl = len(P) / max((s > 1).sum(), 1)
    assert 300 * 0.8 < arl < 300 * 1.6


def test_kalman_filterpy_step_equals_block_and_false_alarms():
    rng = np.random.default_rng(5)
    P = rng.standard_normal((300, 3))
    P[150:] += 4 * V6[:, 2]
    kf = ParityKalman(20, 1e-2)
    kf.configure(V6, 3)
    step = np.array([kf.update(p)[0] for p in P])
    block, thr, _iso = kf.block(P, V6, 3)
    np.testing.assert_allclose(step, block, rtol=1e-9)
    assert kf.isolate(P[-1])[0] == 2
    fast = ParityKalman(20, 1e-2, engine="steady")
    fast.configure(V6, 3)
    np.testing.assert_allclose([fast.update(p)[0] for p in P], step, rtol=1e-9)
    assert fast.innovation_statistic == pytest.approx(kf.innovation_statistic, rel=1e-9)
    # marginal false-alarm rate: the statistic at one instant of many independent streams
    Q = rng.standard_normal((400, 20_000, 3))
    from scipy.signal import lfilter

    B = lfilter([kf.K], [1, -(1 - kf.K)], Q, axis=0)[-1]
    T = (B * B).sum(1) * (2 - kf.K) / kf.K
    lo, hi = clopper_pearson(int((T > thr).sum()), len(T))
    assert lo <= 1e-2 <= hi
    # the innovation test: white without a fault, chi-square per sample
    inn = ParityKalman(20, 1e-2, test="innovation")
    s_i, thr_i, _ = inn.block(Q[:, :, :].reshape(-1, 3)[:200_000], V6, 3)
    lo, hi = clopper_pearson(int((s_i[100:] > thr_i).sum()), len(s_i) - 100)
    assert lo <= 1e-2 <= hi
    inn.configure(V6, 3)
    np.testing.assert_allclose([inn.update(p)[0] for p in Q[:50, 0]], inn.block(Q[:50, 0], V6, 3)[0], rtol=1e-9)


def test_unequal_noise_estimated_online_restores_false_alarm_rate():
    """Sensor 3 is three times noisier than stated: the equal-weight GLT over-alarms; the noise estimated from
    the parity and used as weights brings the false-alarm rate back to its design value."""
    from rimu.fusion import ProjectionTable

    g = dodecahedron6()
    true = np.ones(6)
    true[3] = 3.0
    rng = np.random.default_rng(6)
    Z = rng.standard_normal((100_000, 6)) * true
    tab = ProjectionTable(g.H, 1.0)
    Pn = Z @ tab.Vz[0].T
    thr = glt_threshold(1e-3, 3)
    assert np.mean((Pn**2).sum(1) > thr) > 0.02
    est = NoiseEstimator(tab.Vz[0])
    est.add(Pn[:50_000])
    s = est.sigma()
    np.testing.assert_allclose(s, true, rtol=0.05)
    tab_w = ProjectionTable(g.H, s)
    Pw = Z[50_000:] @ tab_w.Vz[0].T
    k = int(((Pw**2).sum(1) > thr).sum())
    lo, hi = clopper_pearson(k, len(Pw))
    assert lo <= 1e-3 <= hi


def test_noise_estimator_refuses_what_parity_cannot_separate():
    from rimu.errors import IdentifiabilityError

    est = NoiseEstimator(cone6().parity_matrix())
    est.add(np.random.default_rng(0).standard_normal((100, 3)))
    with pytest.raises(IdentifiabilityError):
        est.sigma()


def test_block_isolate_is_isolate_argmax_row_by_row():
    """The block isolation (sensors along rows, a running maximum) picks, on every row, the sensor
    ``isolate_argmax`` picks for that row alone: on a row of zeros the first column of non-zero norm, never a
    column of zero norm; -1 with one parity dimension. (Columns equal to the last bit are not a case: the block
    product may round them apart.)"""
    from rimu.fdi.glt import block_isolate, isolate_argmax

    rng = np.random.default_rng(3)
    for n, d, zero in ((6, 3, None), (9, 6, 4), (24, 21, 0), (6, 1, None)):
        V = np.linalg.qr(rng.standard_normal((n, n)))[0][:, :d].T.copy()
        if zero is not None:
            V[:, zero] = 0.0
        P = rng.standard_normal((2000, d))
        P[:5] = 0.0                              # every ratio zero: the first usable column
        want = [isolate_argmax(p, V)[0] for p in P]
        got = block_isolate(P, V)
        assert np.array_equal(got, want), (n, d)
        assert (d < 2) == bool(np.all(got == -1))
