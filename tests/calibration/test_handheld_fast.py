"""The fast paths of the hand-held calibration against the computations they replace: the pre-integrated gyro fit
against the reference that integrates every sample at every evaluation (scipy's trust-region solver), the
pre-integration's Jacobians and prediction against finite differences and exact integration, the analytic
accelerometer Jacobian against finite differences, and the one-pass noise level and clip levels against the
sample-by-sample formulas."""

from __future__ import annotations

from math import comb

import numpy as np
import pytest

from rimu.calibration.handheld import (
    HandHeld,
    _accel_problem,
    _dirs_with_jacobian,
    _pose_stats,
    _statics,
    clip_levels,
    fit_accel,
    fit_gyro,
    pose_windows,
    white_noise_sigma_hf,
)
from rimu.calibration.lsq import central_jacobian
from rimu.geometry import cone6
from rimu.sim.handheld import handheld_run


def _setup(run):
    s = run.session
    g = s.geometries["accel"]
    hh = HandHeld()
    sa, sg = hh._sigma(s, "accel"), hh._sigma(s, "gyro")
    members = list(range(g.n))
    ybar, sd = _pose_stats(_statics(s), "accel", members, sa)
    af = fit_accel(ybar, sd, g.H, s.gravity, list(g.names))
    dirs, djac, acov, dcov = _dirs_with_jacobian(af, _statics(s), s, sa)
    return s, af, (dirs, djac, acov, members, sg, s.geometries["gyro"].H), dcov


@pytest.mark.parametrize("kw", [{"n_poses": 14, "static_s": 2.0, "seed": 31},
                                {"n_poses": 20, "static_s": 1.5, "seed": 32},
                                {"n_poses": 18, "static_s": 2.0, "seed": 33,
                                 "geometries": {"gyro": cone6(), "accel": cone6()}}])
def test_preintegrated_gyro_fit_equals_full_integration(kw):
    """The pre-integrated fit reaches the optimum of the full integration: every parameter within 1e-2 of its
    stated sigma (observed ~3e-4), the same sigma to 1e-2 and the same rotation residuals."""
    s, _, args, dcov = _setup(handheld_run(**kw))
    fast = fit_gyro(s, pose_windows(s), *args, dir_cov=dcov)
    ref = fit_gyro(s, pose_windows(s), *args, dir_cov=dcov, preintegrate=False)
    sd = np.sqrt(np.diag(ref.cov))
    assert np.max(np.abs(fast.theta - ref.theta) / sd) < 1e-2
    assert np.max(np.abs(np.sqrt(np.diag(fast.cov)) / sd - 1)) < 1e-2
    assert abs(fast.rms_rotation_deg() / ref.rms_rotation_deg() - 1) < 1e-3


def test_preintegration_model_jacobian_and_second_order_error():
    """Away from the linearisation point: the model's Jacobian (d Exp, the G-linear rate change, its bias coupling)
    against central differences of the model's own residual (axes to 1e-3, biases to 1e-2, which enter through
    the first-order pose rotations); and the model's rotation against an exact integration, its error second
    order in the correction (a quarter when the correction halves)."""
    s, _, args, dcov = _setup(handheld_run(n_poses=12, static_s=2.0, seed=13))
    gf = fit_gyro(s, pose_windows(s), *args, dir_cov=dcov)
    pr = gf.problem
    theta, typ = gf.theta, pr["typ"]
    pre = pr["integrate"](theta)
    d = np.random.default_rng(1).normal(size=theta.size) * typ * np.r_[np.full(9, 2e-3), np.full(3, 2e-2)]
    f = pr["model_fun"](pre)
    th1 = theta + d
    Ja = f(th1)[1]
    Jn = central_jacobian(lambda t: f(t)[0], th1, typ * 1e-6)
    m = pr["n_rot"]
    rel = np.abs(Ja[:m] - Jn[:m]).max(axis=0) / np.abs(Jn[:m]).max(axis=0)
    assert np.all(rel[:9] < 1e-3) and np.all(rel[9:] < 1e-2), rel

    def model_error(step):
        th = theta + step
        R_model = pre[1] @ _rot(pr["model_x"](th, pre))
        R_exact = pr["integrate"](th, jac=False)
        E = np.einsum("mji,mjk->mik", R_model, R_exact)
        return float(np.max(np.arccos(np.clip((np.trace(E, axis1=1, axis2=2) - 1) / 2, -1, 1)))), \
            float(np.max(np.abs(pr["model_x"](th, pre))))

    e1, x1 = model_error(5 * d)
    e2, _ = model_error(2.5 * d)
    assert 1e-2 < x1 < 0.2 and e1 < x1**2
    assert 0.15 < e2 / e1 < 0.35  # second order


def _rot(x):
    from rimu.session import rotation_matrix

    return rotation_matrix(x)


@pytest.mark.parametrize("geo", [None, cone6()])
def test_accel_analytic_jacobian_matches_central_differences(geo):
    """d r / d theta and d f / d theta of the accelerometer fit (norm and parity residuals, with and without the
    pose variance) against central differences: 1e-6 of the column scale."""
    kw = {"geometries": {"gyro": geo, "accel": geo}} if geo is not None else {}
    s, af, _, _ = _setup(handheld_run(n_poses=16, static_s=2.0, seed=21, **kw))
    n = len(af.members)
    fixed = np.zeros((n, 3))
    th = af.theta * (1 + 1e-3 * np.random.default_rng(0).normal(size=af.theta.size))
    typ = np.abs(th)
    for tau2 in (0.0, 1e-6):
        _, J, df = _accel_problem(th, af.free, fixed, af.ybar, af.sd, s.gravity, tau2)
        Jn = central_jacobian(lambda t, tau2=tau2: _accel_problem(t, af.free, fixed, af.ybar, af.sd, s.gravity, tau2,
                                                       jac=False)[0], th, typ * 1e-4)
        assert np.max(np.abs(J - Jn).max(axis=0) / np.abs(Jn).max(axis=0)) < 1e-6
    from rimu.calibration.handheld import _specific_forces, _unpack

    def forces(t):
        Wp, c = _unpack(t, af.free, fixed, n)
        return _specific_forces(Wp, c, af.ybar, af.sd)[0].ravel()

    dfn = central_jacobian(forces, th, typ * 1e-4)
    assert np.max(np.abs(df.reshape(-1, th.size) - dfn)) < 1e-6 * np.max(np.abs(dfn))


def _direct_sigma(session, inst, order):
    segs = _statics(session) or list(session.segments)
    acc, cnt = 0.0, 0
    for sg in segs:
        y = sg.raw[inst]
        if y.shape[0] <= order + 2:
            continue
        d = np.diff(y, n=order, axis=0)
        acc = acc + np.sum(d**2, axis=0)
        cnt += d.shape[0]
    return np.sqrt(acc / cnt / comb(2 * order, order))


@pytest.mark.parametrize("quantize", [True, False])
def test_one_pass_noise_level_equals_the_differences(quantize):
    """The noise level from lagged products over the whole record, less the differences across segment
    boundaries and in motions, equals the differences formed pose by pose (1e-9), for orders 1 to 3."""
    run = handheld_run(n_poses=10, static_s=1.0, seed=5, quantize=quantize, initial_still_s=0.5)
    for inst in ("accel", "gyro"):
        for order in (1, 2, 3):
            a = white_noise_sigma_hf(run.session, inst, order)
            b = _direct_sigma(run.session, inst, order)
            assert np.allclose(a, b, rtol=1e-9, atol=0), (inst, order)


def test_clip_levels_from_the_one_pass_peaks():
    """A gyro clipped at an ADC's full scale: the level is found from the per-segment peaks, the count of
    samples at it checked on the record (as the sample-by-sample rule)."""
    run = handheld_run(n_poses=10, static_s=1.0, seed=6)
    s = run.session
    top = float(np.max([np.abs(x.raw["gyro"][:, 1]).max() for x in s.segments]))
    full = float(2 ** int(np.floor(np.log2(top))) - 1)
    for x in s.segments:
        x.raw["gyro"][:, 1] = np.clip(x.raw["gyro"][:, 1], -full, full)
    lim = clip_levels(s, "gyro")
    assert lim[1] == full and np.all(np.isinf(lim[[0, 2]]))
