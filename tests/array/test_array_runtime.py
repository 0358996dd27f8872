"""The array as one sensor: lever arms, the ML estimate of Skog et al. 2016 and its Cramer-Rao bound."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.array import (
    ArrayLayout,
    accel_jacobian,
    accel_model,
    crb,
    lever_arm_acceleration,
    ml_motion,
    remove_lever_arms,
)
from rimu.errors import GeometryError, NonFiniteError, ShapeError
from rimu.sim.array import random_array_truth, simulate_array

TRUE = np.array([3.0, -2.0, 4.0, 40.0, -25.0, 60.0, 1.0, -2.0, 9.81])  # w [rad/s], w' [rad/s^2], s [m/s^2]


def test_accel_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    r = rng.normal(0, 0.03, (5, 3))
    theta = rng.normal(0, 3, (4, 9))
    J = accel_jacobian(theta[:, :3], r)
    h = 1e-6
    for i in range(9):
        d = np.zeros(9)
        d[i] = h
        num = (accel_model(theta + d, r) - accel_model(theta - d, r)) / (2 * h)
        np.testing.assert_allclose(J[..., i], num, atol=1e-8)


def test_crb_matches_finite_difference_fisher():
    """The CRB from the analytic Jacobian equals the inverse of a Fisher matrix built from finite differences."""
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.02, two_sided=True)
    sg, sa = 0.02, 0.05
    P = crb(TRUE[None, :3], lay.positions_m, sg, sa)[0]
    h = 1e-6
    J = np.zeros((lay.k * 3, 9))
    for i in range(9):
        d = np.zeros(9)
        d[i] = h
        J[:, i] = ((accel_model((TRUE + d)[None], lay.positions_m) - accel_model((TRUE - d)[None], lay.positions_m))
                   / (2 * h)).ravel()
    info = J.T @ J / sa**2
    info[:3, :3] += lay.k / sg**2 * np.eye(3)
    np.testing.assert_allclose(np.linalg.inv(P), info, rtol=1e-6, atol=1e-6 * np.abs(info).max())
    Pfd = np.linalg.inv(info)
    np.testing.assert_allclose(P, Pfd, atol=1e-4 * np.sqrt(np.outer(np.diag(Pfd), np.diag(Pfd))).max())


@pytest.mark.parametrize(
    "rows, cols, two_sided, sg, sa, pitch",
    [
        (2, 2, True, 2e-3, 0.09, 0.01),     # 8 triads, MEMS noise (MPU-9150 class at 1 kHz)
        (4, 4, True, 2e-3, 0.09, 0.01),     # 32 triads, MEMS noise
        (2, 2, True, 0.2, 0.01, 0.05),      # 8 triads where the accelerometers carry most of the rate information
    ],
)
def test_ml_covariance_at_the_cramer_rao_bound(rows, cols, two_sided, sg, sa, pitch):
    lay = ArrayLayout.planar_grid(rows, cols, pitch_m=pitch, two_sided=two_sided)
    M = 4000
    rng = np.random.default_rng(rows * 10 + cols)
    theta = np.repeat(TRUE[None], M, axis=0)
    fa = accel_model(theta, lay.positions_m) + rng.normal(0, sa, (M, lay.k, 3))
    fg = theta[:, None, :3] + rng.normal(0, sg, (M, lay.k, 3))
    est = ml_motion(lay, fa, fg, sa, sg)
    x = np.column_stack([est.omega, est.omega_dot, est.specific_force])
    C = np.cov(x.T)
    P = crb(TRUE[None, :3], lay.positions_m, sg, sa)[0]
    ratio = np.diag(C) / np.diag(P)
    assert np.all(np.abs(ratio - 1) < 0.10), ratio
    # the rate block as a whole (generalised eigenvalues of the MC covariance against the bound)
    ev = np.linalg.eigvals(np.linalg.solve(P[:3, :3], C[:3, :3])).real
    assert np.all(np.abs(ev - 1) < 0.10), ev
    # unbiased within the Monte Carlo error
    z = (x.mean(axis=0) - TRUE) / np.sqrt(np.diag(P) / M)
    assert np.all(np.abs(z) < 4.5), z
    # the covariance the estimator reports is the bound at its estimate
    np.testing.assert_allclose(est.covariance.mean(axis=0)[np.diag_indices(9)], np.diag(P), rtol=0.02)
    if sg > 0.1:  # accelerometers make the rate better than the gyros alone
        assert P[0, 0] < 0.5 * sg**2 / lay.k


def test_remove_lever_arms_recovers_the_reference_specific_force():
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.02)
    rec = simulate_array(random_array_truth(lay, seed=3, accel_scale_sigma=0, accel_misalignment_sigma_rad=0,
                                            accel_bias_sigma_m_s2=0, sampling_offset_sigma_s=0,
                                            accel_noise_density_ug_sqrt_hz=1e-6), duration_s=0.3, seed=3)
    f = remove_lever_arms(lay.to_body(rec.accel), rec.omega, rec.omega_dot, lay.positions_m)
    np.testing.assert_allclose(f, np.repeat(rec.specific_force[:, None], lay.k, axis=1), atol=1e-6)
    raw_spread = np.std(lay.to_body(rec.accel) - rec.specific_force[:, None], axis=1).max()
    assert raw_spread > 1.0  # the lever-arm terms are metres per second squared in this motion


def test_ml_on_simulated_motion_uses_every_sample():
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.01)
    tr = random_array_truth(lay, seed=5, gyro_scale_sigma=0, gyro_misalignment_sigma_rad=0, gyro_bias_sigma_deg_s=0,
                            accel_scale_sigma=0, accel_misalignment_sigma_rad=0, accel_bias_sigma_m_s2=0,
                            sampling_offset_sigma_s=0)
    rec = simulate_array(tr, duration_s=0.5, seed=5)
    est = ml_motion(lay, lay.to_body(rec.accel), lay.to_body(rec.gyro), tr.accel_noise_m_s2, tr.gyro_noise_rad_s)
    e = est.omega - rec.omega
    sd = np.sqrt(np.einsum("nii->ni", est.covariance[:, :3, :3]))
    assert 0.8 < np.sqrt(np.mean((e / sd) ** 2)) < 1.25
    # the specific force at triad 4's position: the truth there is s + w' x r + w x (w x r)
    f, P = est.specific_force_at(lay.positions_m[3])
    f_true = rec.specific_force + lever_arm_acceleration(rec.omega, rec.omega_dot, lay.positions_m[3:4])[:, 0]
    ef = (f - f_true) / np.sqrt(np.einsum("nii->ni", P))
    assert 0.8 < np.sqrt(np.mean(ef**2)) < 1.25


def test_bad_input_is_named():
    lay = ArrayLayout.planar_grid(1, 2)
    with pytest.raises(ShapeError, match=r"\(N, 2, 3\)"):
        ml_motion(lay, np.zeros((5, 3, 3)), None, 0.1)
    with pytest.raises(ShapeError, match="omega_init"):
        ml_motion(lay, np.zeros((5, 2, 3)), None, 0.1)
    fa = np.zeros((3, 2, 3))
    fa[1] = np.nan
    with pytest.raises(NonFiniteError, match="no finite accelerometer"):
        ml_motion(lay, fa, np.zeros((3, 2, 3)), 0.1, 0.01)
    with pytest.raises(GeometryError, match="orthonormal"):
        ArrayLayout(np.ones((2, 3, 3)), np.zeros((2, 3)))
    with pytest.raises(ShapeError, match="at least two"):
        ArrayLayout(np.eye(3)[None], np.zeros((1, 3)))


def test_one_missing_triad_sample_is_left_out_not_nan():
    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.02)
    rng = np.random.default_rng(1)
    theta = np.repeat(TRUE[None], 10, axis=0)
    fa = accel_model(theta, lay.positions_m) + rng.normal(0, 0.01, (10, 4, 3))
    fg = theta[:, None, :3] + rng.normal(0, 0.01, (10, 4, 3))
    fa[2, 1, 0] = np.nan
    fg[4, 0, 2] = np.inf
    est = ml_motion(lay, fa, fg, 0.01, 0.01)
    assert est.n_missing == 2 and np.all(np.isfinite(est.omega)) and np.all(np.isfinite(est.covariance))


def test_layout_from_geometry_before_and_after_subunit_positions():
    from dataclasses import dataclass

    from rimu.geometry import cone6

    g = cone6()
    lay = ArrayLayout.from_geometry(g, positions_m=[[0.01, 0, 0], [-0.01, 0, 0]])
    for j, su in enumerate(g.subunits):
        np.testing.assert_allclose(lay.rotations[j], g.H[list(su.members)].T)
    # the body-frame vector of a triad projects back onto its own sensing axes
    w = np.array([0.3, -0.2, 0.9])
    yt = lay.to_triad(np.repeat(w[None, None], 2, axis=1))[0]
    np.testing.assert_allclose(yt.ravel(), g.H @ w, atol=1e-12)
    with pytest.raises(GeometryError, match="no position"):
        ArrayLayout.from_geometry(g)

    @dataclass
    class WithPosition:   # what a sub-unit looks like once rimu.geometry carries positions
        name: str
        members: tuple
        mat_sb_mb: np.ndarray
        position_mb_m: tuple

    class G2:
        H = g.H
        subunits = tuple(WithPosition(s.name, s.members, s.mat_sb_mb, (0.0, 0.02 * j, 0.0))
                         for j, s in enumerate(g.subunits))

    np.testing.assert_allclose(ArrayLayout.from_geometry(G2()).positions_m, [[0, 0, 0], [0, 0.02, 0]])
