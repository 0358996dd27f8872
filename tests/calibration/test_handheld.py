"""Hand-held calibration (poses of unknown attitude, hand rotations between them): simulated recordings against
their truth (normalised errors, noise floor, exact and degenerate cases), the Zhang path on many noisy poses,
redundant geometries."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration import Zhang
from rimu.calibration.handheld import HandHeld, ellipsoid_fit, fit_accel, gauge_fixed
from rimu.calibration.lsq import physical_from_beta
from rimu.calibration.model import ErrorModel
from rimu.errors import IdentifiabilityError
from rimu.geometry import cone6, triad3
from rimu.sim.handheld import handheld_run

BASE = ErrorModel.base()


def normalised_errors(res, run, triple=(0, 1, 2)):
    """(estimate - truth) / sigma of every non-gauge parameter, truth expressed in the estimate's gauge frame."""
    out = {}
    for inst, r in res.instruments.items():
        W, c = gauge_fixed(run.truth["accel"], triple, run.truth[inst])
        z = []
        for f in r.sensors:
            i = f.ctx.index
            th, _, _ = physical_from_beta(BASE, f.ctx, np.concatenate([W[i], [c[i]]]))
            sd = np.sqrt(np.clip(np.diag(f.theta_cov), 0, None))
            ok = sd > 0
            z.append((f.theta - th)[ok] / sd[ok])
        out[inst] = np.concatenate(z)
    return out


def truth_norm_rms(run, session):
    """rms of |f| - g of the pose means with the TRUE coefficients: the floor the fit should reach."""
    cal = run.truth["accel"]
    A = cal.axes_mb()
    r = []
    for s in session.segments:
        if s.kind == "static_unknown":
            f = np.linalg.solve(A, cal.compensate(s.raw["accel"].mean(axis=0)))
            r.append(np.linalg.norm(f) - session.gravity)
    return float(np.sqrt(np.mean(np.square(r))))


def test_ellipsoid_start_is_never_trivial_and_exact_for_nine_points():
    rng = np.random.default_rng(5)
    A = np.array([[1.6e-3, 0, 0], [3e-6, 1.7e-3, 0], [-4e-6, 2e-6, 1.5e-3]])
    b = np.array([250.0, -120.0, 900.0])
    for k in (9, 40):
        u = rng.normal(size=(k, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        y = (9.8 * u) @ np.linalg.inv(A).T + b
        c, M = ellipsoid_fit(y)
        assert np.allclose(c, b, atol=1e-6)
        assert np.allclose(M / np.linalg.norm(M), A.T @ A / np.linalg.norm(A.T @ A), atol=1e-9)
        # a noisy cloud of many poses (the case that made Zhang's old step return a scale of 1e9)
        yn = y + rng.normal(0, 3.0, y.shape)
        c, M = ellipsoid_fit(yn)
        assert np.all(np.linalg.eigvalsh(M) > 0) and np.linalg.norm(c - b) < 30


def test_noise_free_and_exact_nine_poses():
    kw = {"arw_deg_sqrt_h": 0.0, "vrw_ug_sqrt_hz": 0.0, "tremor_deg": 0.0, "sway_deg": 0.0, "tremor_ms2": 0.0, "quantize": False}
    run = handheld_run(n_poses=16, static_s=1.0, seed=7, **kw)
    res = HandHeld(sigma={"accel": 1.0, "gyro": 1.0}).fit(run.session)
    for inst in ("accel", "gyro"):
        W, c = gauge_fixed(run.truth["accel"], (0, 1, 2), run.truth[inst])
        cal = res.to_calibration()[inst]
        We = cal.axes_mb() / cal.scale[:, None]
        assert np.allclose(We, W, rtol=0, atol=1e-7 * np.abs(W).max()), inst
        assert np.allclose(cal.bias / cal.scale, c, atol=1e-6 * np.abs(c).max() + 1e-9), inst
    assert res.extra["norm_rms_accel"] < 1e-9 and res.extra["rotation_rms_deg"] < 1e-6
    # exactly nine noisy poses: nine equations for nine parameters, an exact fit, never an error
    r = np.sqrt(0.5)  # Zhang's nine attitudes: each axis up and down, three in-plane diagonals
    nine = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (r, r, 0), (r, 0, r), (0, r, r)]
    run9 = handheld_run(up_mb=nine, seed=8)
    r9 = HandHeld(instruments=["accel"]).fit(run9.session)
    assert r9.extra["norm_rms_accel"] < 1e-6
    z = normalised_errors(r9, run9)["accel"]  # no degrees of freedom left: the covariance is the a-priori one
    assert np.abs(z).max() < 4.0


def test_simulated_handheld_estimates_are_within_their_covariance():
    """20-60 poses of a MEMS triad, tremor and sway, bumps-free: normalised errors rms over seeds in [0.8, 1.25],
    no error beyond 4 sigma; the static-norm residual reaches the floor of the true coefficients."""
    zs = {"accel": [], "gyro": []}
    for seed, poses in enumerate((20, 28, 36, 44, 60)):
        run = handheld_run(n_poses=poses, static_s=2.0, seed=100 + seed)
        res = HandHeld().fit(run.session)
        for k, z in normalised_errors(res, run).items():
            zs[k].append(z)
        floor = truth_norm_rms(run, run.session)
        assert 0.5 * floor < res.extra["norm_rms_accel"] <= 1.02 * floor
        assert res.extra["rotation_rms_deg"] < 0.1
    for k, v in zs.items():
        z = np.concatenate(v)
        assert 0.8 <= np.sqrt(np.mean(z**2)) <= 1.25, (k, np.sqrt(np.mean(z**2)))
        assert np.abs(z).max() < 4.0, k


def test_unidentifiable_poses_are_named():
    """Every pose with gravity in the x-y plane: z is never excited, and the error says so."""
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * np.pi, 20)
    u = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(20)])
    y = 9.8 * u / 6e-4 + [100.0, -40.0, 300.0] + rng.normal(0, 0.5, (20, 3))
    with pytest.raises(IdentifiabilityError, match="do not identify") as exc:
        fit_accel(y, np.full(y.shape, 0.5), np.eye(3), 9.8, ["x", "y", "z"])
    assert any(p.startswith("z.") for p in exc.value.parameters)
    with pytest.raises(IdentifiabilityError, match="at least 9 poses"):
        fit_accel(y[:7], np.full((7, 3), 0.5), np.eye(3), 9.8, ["x", "y", "z"])


def test_zhang_on_many_noisy_poses_and_accelerometers_alone():
    """The Zhang path on 40 noisy hand-held poses: no 'not positive definite', no garbage, and no rotation
    segments needed for the accelerometers."""
    from rimu.calibration.zhang import solve_ma

    run = handheld_run(n_poses=40, static_s=2.0, seed=11)
    statics = run.session.subset([s.label for s in run.session.segments if s.kind == "static_unknown"])
    # the linear step alone (Eq. 12-14) on these poses: the old right-hand side of ones returned a scale
    # 1e-7 of the truth or "not positive definite" on such data
    Y = np.array([s.raw["accel"].mean(axis=0) for s in statics.segments])
    A, _ = solve_ma(Y, statics.gravity)
    assert np.all(np.abs(1 / np.linalg.norm(np.linalg.inv(A), axis=1) / run.truth["accel"].scale - 1) < 0.01)
    res = Zhang().fit(statics)
    assert list(res.instruments) == ["accel"] and "accelerometers only" in res.notes[0]
    sf = res.to_calibration()["accel"].scale
    assert np.all(np.abs(sf / run.truth["accel"].scale - 1) < 2e-3)
    acc_only = statics.subset([s.label for s in statics.segments])
    acc_only.geometries = {"accel": triad3()}
    assert list(Zhang().fit(acc_only).instruments) == ["accel"]


def test_zhang_full_path_with_more_than_nine_noisy_positions():
    """Zhang's scheme plus nine more static positions in random attitudes (18 noisy positions, MEMS noise):
    the accelerometer step no longer fails or returns garbage, and the whole method still runs."""
    from rimu.sim import Simulator, static, zhang_scheme

    rng = np.random.default_rng(4)
    extra = [static(f"E{k}", u / np.linalg.norm(u), 3.0, report="static_unknown")
             for k, u in enumerate(rng.normal(size=(9, 3)), start=1)]
    g = triad3()
    run = Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.3, vrw_ug_sqrt_hz=300, seed=5).run(
        zhang_scheme(static_duration=3.0, rotation_duration=18.0) + extra)
    res = Zhang().fit(run.session)
    cal = res.to_calibration()
    for k in ("accel", "gyro"):
        assert np.all(np.abs(cal[k].scale / run.truth[k].scale - 1) < 1e-3), k


def test_redundant_unit_joint_and_per_subunit():
    """A cone6 unit held by hand: all six accelerometers and gyros at once (skewed set through the least-squares
    specific force and rate, parity residuals), and each sub-unit triad on its own."""
    g = cone6()
    run = handheld_run(n_poses=24, static_s=2.0, geometries={"gyro": g, "accel": g}, seed=21)
    joint = HandHeld().fit(run.session)
    tri = [int(g.names.index(n)) for n in joint.extra["gauge_accel"][0]]
    third = next(i for i in range(6) if i not in tri and abs(np.linalg.det(g.H[tri + [i]])) > 0.5)
    z = normalised_errors(joint, run, tuple(tri + [third]))
    for k, v in z.items():
        assert np.abs(v).max() < 4.5 and 0.5 < np.sqrt(np.mean(v**2)) < 1.6, (k, np.sqrt(np.mean(v**2)))
    assert joint.extra["norm_rms_accel"] <= 1.02 * truth_norm_rms_cone(run)
    sub = HandHeld(mode="subunits").fit(run.session)
    assert len(sub.extra["gauge_accel"]) == 2
    sf_true = run.truth["accel"].scale
    assert np.all(np.abs(sub.to_calibration()["accel"].scale / sf_true - 1) < 3e-3)
    assert np.all(np.abs(sub.to_calibration()["gyro"].scale / run.truth["gyro"].scale - 1) < 3e-3)


def truth_norm_rms_cone(run):
    cal = run.truth["accel"]
    A = cal.axes_mb()
    r = []
    for s in run.session.segments:
        if s.kind == "static_unknown":
            f = np.linalg.lstsq(A, cal.compensate(s.raw["accel"].mean(axis=0)), rcond=None)[0]
            r.append(np.linalg.norm(f) - run.session.gravity)
    return float(np.sqrt(np.mean(np.square(r))))


def test_gyro_rotation_jacobian_matches_central_differences():
    """The analytic Jacobian of the integrated rotations (first order in the small pose motions) against
    central differences of the exact residual, on a tremor-laden recording: the bias columns to 1e-2 (they
    enter through the small pose rotations), the axis columns to 1e-3."""
    from rimu.calibration.handheld import _dirs_with_jacobian, _pose_stats, _statics, fit_gyro, pose_windows
    from rimu.calibration.lsq import central_jacobian as _jac

    run = handheld_run(n_poses=12, static_s=2.0, seed=13)
    s = run.session
    hh = HandHeld()
    sa, sg = hh._sigma(s, "accel"), hh._sigma(s, "gyro")
    ybar, sd = _pose_stats(_statics(s), "accel", [0, 1, 2], sa)
    af = fit_accel(ybar, sd, np.eye(3), s.gravity, list("xyz"))
    dirs, djac, acov, dcov = _dirs_with_jacobian(af, _statics(s), s, sa)
    gf = fit_gyro(s, pose_windows(s), dirs, djac, acov, [0, 1, 2], sg, np.eye(3), dir_cov=dcov)
    pr = gf.problem
    Ja = pr["jac"](gf.theta)
    Jn = _jac(pr["resid"], gf.theta, pr["typ"] * 1e-6)
    m = 2 * len(gf.pairs)
    rel = np.abs(Ja[:m] - Jn[:m]).max(axis=0) / np.abs(Jn[:m]).max(axis=0)
    assert np.all(rel[:9] < 1e-3) and np.all(rel[9:] < 1e-2), rel
