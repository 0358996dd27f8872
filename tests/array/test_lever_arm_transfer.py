"""Issue 32: the accelerometers' specific force transferred to the array's reference point with the gyros' rate and
its central difference (:func:`rimu.array.transfer_to_reference`), checked against a rigid body with a known
angular rate: the transfer leaves exactly the derivative's truncation error, which the finite-difference operators'
closed-form response to a sinusoid gives; clipped gyro samples leave the epochs of their stencil invalid; the stated
1-sigma matches the scatter the gyro noise causes."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.array import angular_acceleration, lever_arm_acceleration, transfer_to_reference

H = 0.016                                                        # the MIMU4444's 62.5 Hz
R = np.array([[sx * 9.45e-3, sy * 9.45e-3, sz * 1e-3] for sx in (-1, 1) for sy in (1, -1) for sz in (1, -1)])
AMP = np.array([20.0, 15.0, 25.0])                               # rad/s, hand-spin rates
FRQ = np.array([2.0, 3.3, 4.7])                                  # Hz
PHS = np.array([0.3, 1.1, 2.0])


def _body(n=3000):
    t = np.arange(n) * H
    a = 2 * np.pi * FRQ
    w = AMP * np.sin(a * t[:, None] + PHS)
    wd = AMP * a * np.cos(a * t[:, None] + PHS)
    s = np.stack([3 * np.sin(0.7 * t), 2 * np.cos(1.3 * t), 9.81 + np.sin(2.1 * t)], axis=1)
    return t, w, wd, s, s[:, None] + lever_arm_acceleration(w, wd, R)


@pytest.mark.parametrize("order", [2, 4])
def test_transfer_leaves_exactly_the_truncation_error(order):
    t, w, wd, s, f = _body()
    tr = transfer_to_reference(t, f, w, R, order=order)
    a = 2 * np.pi * FRQ
    # closed form: the central differences map sin(a t + p) to g(a h) a cos(a t + p), g = sin(x)/x (order 2),
    # (8 sin x - sin 2x) / (6 x) (order 4)
    x = a * H
    g = np.sin(x) / x if order == 2 else (8 * np.sin(x) - np.sin(2 * x)) / (6 * x)
    wd_fd = AMP * a * g * np.cos(a * t[:, None] + PHS)
    ok = tr.valid
    assert ok.sum() == len(t) - order and not ok[:order // 2].any() and not ok[-(order // 2):].any()
    predicted = s[:, None] - np.cross((wd_fd - wd)[:, None], R[None])
    assert np.abs(tr.accel_m_s2[ok] - predicted[ok]).max() < 1e-9
    # the leading truncation term: h^2 w'''/6 (order 2), -h^4 w^(5)/30 (order 4), to its next order
    lead = (-(H**2) / 6 * AMP * a**3 if order == 2 else -(H**4) / 30 * AMP * a**5) * np.cos(a * t[:, None] + PHS)
    err = tr.omega_dot[ok] - wd[ok]
    nxt = (H**4 / 120 * AMP * a**5 if order == 2 else H**6 / 252 * AMP * a**7).max()
    assert np.abs(err - lead[ok]).max() <= nxt * 1.01 + 1e-9
    # and the transfer's stated sigma covers it (no noise here: the truncation estimate alone)
    resid = np.abs(tr.accel_m_s2[ok] - s[ok, None]).max(axis=2)
    assert np.all(resid <= 3 * tr.sigma_m_s2[ok] * np.sqrt(3) + 1e-12)
    # order 4 is the better estimate at these frequencies; the raw lever-arm terms are metres per second squared
    assert np.abs(err).max() < (2e-3 if order == 4 else 0.9) * np.abs(wd).max()


@pytest.mark.parametrize("order", [2, 4])
def test_a_clipped_gyro_sample_invalidates_its_stencil_only(order):
    t, w, _wd, _s, f = _body(200)
    w = w.copy()
    w[100] = np.nan                                  # a clipped gyro: the array's rate is unknown there
    tr = transfer_to_reference(t, f, w, R, order=order)
    m = order // 2
    bad = np.zeros(len(t), bool)
    bad[:m] = bad[-m:] = True
    bad[100 - m:100 + m + 1] = True
    assert np.array_equal(~tr.valid, bad)
    assert np.isnan(tr.accel_m_s2[bad]).all() and np.isfinite(tr.accel_m_s2[~bad]).all()
    # a gap in time (epochs left out) is not bridged either
    keep = np.ones(len(t), bool)
    keep[50] = False
    _, ok = angular_acceleration(t[keep], w[keep], order)
    assert not ok[50 - m:50 + m - 1 + 1].any() and ok[60:90].all()


def test_stated_sigma_matches_the_gyro_noise_scatter():
    """At rest with gyro noise sigma_w: the tangential error w_err' x r has per-axis variance 2/3 (s_wd |r|)^2
    averaged over the axes, s_wd = sigma_w * gain / h; the stated per-axis sigma is s_wd |r|: rms ratio sqrt(2/3)."""
    rng = np.random.default_rng(3)
    n, sw = 20000, np.radians(0.3)
    t = np.arange(n) * H
    f = np.zeros((n, 8, 3)) + [0, 0, 9.81]
    for order in (2, 4):
        w = rng.normal(0, sw, (n, 3))
        ratios = []
        for trunc in (False, True):
            tr = transfer_to_reference(t, f, w, R, order=order, gyro_noise_rad_s=sw, truncation=trunc)
            ok = tr.valid
            z = (tr.accel_m_s2[ok] - [0, 0, 9.81]) / tr.sigma_m_s2[ok][:, :, None]
            ratios.append(float(np.sqrt(np.mean(z**2))))
        assert abs(ratios[0] - np.sqrt(2 / 3)) < 0.02, (order, ratios)
        # with the truncation estimate (which sees the noise as curvature) the sigma is conservative, not wild
        assert 0.5 < ratios[1] < ratios[0], (order, ratios)


def test_what_remains_names_the_angular_acceleration_only_with_its_share():
    """angular_acceleration_check: accelerometers that see an angular acceleration the gyro samples do not hold
    (white, 300 rad/s^2 rms per axis) -> it explains the share of what is left that its variance predicts, and no
    filter of the gyro samples recovers it; a plain rigid body with white accelerometer noise -> nothing named; accelerometers sampled 6 ms
    after the gyros -> a filter of the gyro samples does better than the central difference."""
    from rimu.array import angular_acceleration_check
    from rimu.array.report import accel_verdict

    rng = np.random.default_rng(7)
    t, w, _wd, s, f = _body(4000)
    noise = rng.normal(0, 0.05, f.shape)
    hidden = rng.normal(0, 300.0, w.shape)
    seen = f + np.cross(hidden[:, None], R[None]) + noise
    rem = angular_acceleration_check(t, seen, w, R)
    share_expected = 1 - (0.05**2 * (21 / 18) * 18 / 21) / np.mean(
        (np.cross(hidden[:, None], R[None]) - np.cross(hidden[:, None], R[None]).mean(axis=1, keepdims=True))**2
        + 0.05**2 * 7 / 8)
    assert abs(rem["share"] - share_expected) < 0.02, (rem["share"], share_expected)
    assert rem["held_out"]["fir_rad_s2"] > 0.9 * rem["held_out"]["central_difference_rad_s2"]
    assert "limiting is the angular acceleration" in accel_verdict(rem) and "do not hold it" in accel_verdict(rem)
    # a rigid body with white accelerometer noise, the order-4 difference (its truncation, about 1 rad/s^2 here,
    # is far below the noise's 0.2 m/s^2 over 13 mm): nothing to name
    plain = angular_acceleration_check(t, f + 4 * noise, w, R, order=4)
    assert abs(plain["share"]) < 0.05 and "unexplained" in accel_verdict(plain)
    # accelerometers 6 ms late: their angular acceleration is the gyros' 6 ms later, which a filter of the gyro
    # samples predicts (held out) better than the central difference at the sample does
    a = 2 * np.pi * FRQ
    late = s[:, None] + lever_arm_acceleration(AMP * np.sin(a * (t[:, None] + 6e-3) + PHS),
                                               AMP * a * np.cos(a * (t[:, None] + 6e-3) + PHS), R)
    lr = angular_acceleration_check(t, late + noise, w, R)
    assert lr["held_out"]["fir_rad_s2"] < 0.75 * lr["held_out"]["central_difference_rad_s2"], lr
    assert "a better derivative would recover" in accel_verdict(lr)
