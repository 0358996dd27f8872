"""Zhang et al. 2010, step 4 (the norm refinement) and the rotation axes of Eq. 42-47, checked by numbers someone
else fixed: the analytic Jacobian against finite differences (scipy's and rimu's), the optimum against scipy's
Levenberg-Marquardt run to its own convergence on the same residuals, the two decoupled problems against the
joint one, and the Gram-matrix axis against the SVD null vector it replaces."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from rimu.calibration import Zhang
from rimu.calibration.lsq import central_jacobian
from rimu.calibration.zhang import accel_rotation_axis, norm_problem, norm_residuals, refine_norms, rotation_pairs
from rimu.geometry import triad3
from rimu.sim import Simulator, zhang_scheme

IL = np.tril_indices(3)


def _groups(seed=0):
    rng = np.random.default_rng(seed)
    L = np.tril(rng.normal(0, 0.02, (3, 3))) + np.diag([100.0, 101.0, 99.0])
    b = np.array([3.0, -2.0, 1.0])
    u = rng.normal(size=(12, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    Y = 9.8 * u @ L.T + b + rng.normal(0, 0.05, (12, 3))
    groups = [(Y[:5] - b, np.full(5, 9.79), np.array([1.0, 2.0, 3.0]), rng.uniform(0.5, 2.0, 5), False),
              (Y[5:], 9.8, np.array([0.5, 0.5, 0.7]), rng.uniform(0.5, 2.0, 7), True)]
    return np.concatenate([L[IL], b * 1.01]), groups


def test_norm_jacobian_matches_finite_differences():
    """Every column of the analytic Jacobian (the weights differentiated too) within 1e-6 of scipy's
    approx_derivative and of rimu's central_jacobian, relative to the column's size."""
    q, groups = _groups()
    _, J = norm_residuals(q, groups)
    Js = approx_derivative(lambda x: norm_residuals(x, groups)[0], q, method="3-point")
    h = np.r_[np.full(6, 100.0), np.abs(q[6:])] * 1e-6  # steps by the size of each L row and of b
    Jc = central_jacobian(lambda x: norm_residuals(x, groups)[0], q, h)
    size = np.abs(J).max(axis=0)
    assert np.all(size > 0)
    assert np.all(np.abs(J - Js).max(axis=0) <= 1e-6 * size)
    assert np.all(np.abs(J - Jc).max(axis=0) <= 1e-6 * size)
    assert np.allclose(J[:5, 6:], 0.0)  # the unbiased group does not see b


def test_stacked_evaluation_equals_one_by_one():
    q, groups = _groups(1)
    prob = norm_problem(groups)
    Q = q + np.random.default_rng(2).normal(0, 1e-3, (4, 9)) * np.abs(q)
    R, J = prob(Q)
    for k in range(4):
        r1, J1 = prob(Q[k])
        assert np.allclose(R[k], r1, rtol=1e-13, atol=0) and np.allclose(J[k], J1, rtol=1e-12, atol=1e-300)


@pytest.fixture(scope="module")
def fitted():
    g = triad3()
    run = Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.1 / 60, vrw_ug_sqrt_hz=500.0, seed=7).run(
        zhang_scheme(static_duration=20.0, rotation_duration=36.0))
    return run, Zhang().fit(run.session)


def test_refinement_reaches_the_least_squares_optimum(fitted):
    """Each decoupled problem: the gradient vanishes at the optimum (scaled), and scipy's Levenberg-Marquardt on the
    same residuals, run from the same start to its own convergence, reaches no lower cost and the same parameters
    (within 1e-6 of their standard deviation)."""
    _, res = fitted
    ref = res.refinement
    for prob, p0, p, typ in zip(ref["problems"], ref["p0"], ref["p"], ref["typ"]):
        r, J = prob(p)
        cov = np.linalg.pinv(J.T @ J)
        sd = np.sqrt(np.diag(cov))
        assert np.max(np.abs(J.T @ r) * sd) < 1e-8 * max(float(r @ r), 1.0)
        sol = least_squares(lambda x, prob=prob: prob(x)[0], p0, jac=lambda x, prob=prob: prob(x)[1], x_scale=typ,
                            method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=5000)
        cost = float(r @ r)
        assert cost <= 2 * sol.cost * (1 + 1e-12) + 1e-20
        assert np.all(np.abs(sol.x - p) <= 1e-6 * sd)
    assert all(1 <= k <= 20 for k in ref["steps"])


def test_decoupled_problems_have_the_joint_optimum(fitted):
    """The accelerometer residuals do not depend on the gyro parameters and vice versa: the joint 18-parameter
    Jacobian is block diagonal and the joint gradient vanishes at the two separate optima."""
    _, res = fitted
    ref = res.refinement
    pa, pg = ref["p"]
    pa_prob, pg_prob = ref["problems"]

    def joint(p):
        return np.concatenate([pa_prob(p[:9])[0], pg_prob(p[9:])[0]])

    p = np.concatenate([pa, pg])
    Jn = approx_derivative(joint, p, method="3-point")
    na = len(pa_prob(pa)[0])
    assert np.all(Jn[:na, 9:] == 0) and np.all(Jn[na:, :9] == 0)


def _svd_axis(f):
    """The null vector of [f, -1] by SVD (the implementation the Gram-matrix form replaced), with the same column
    scaling D (the rms norm of f on the last column)."""
    A = np.column_stack([f, -np.ones(len(f))])
    sc = np.array([1.0, 1.0, 1.0, float(np.sqrt(np.mean(np.sum(f * f, axis=1))))])
    _, _, Vt = np.linalg.svd(A * sc, full_matrices=False)
    v = Vt[-1] * sc
    n = float(np.linalg.norm(v[:3]))
    l = v[:3] / n
    r = (A @ v) / n
    s2 = float(r @ r) / max(len(f) - 4, 1)
    F = f - f.mean(axis=0)
    P = np.eye(3) - np.outer(l, l)
    return l, float(s2 * np.trace(np.linalg.pinv(P @ F.T @ F @ P, rcond=1e-10)) / 2.0)


def test_rotation_axis_equals_the_svd_null_vector(fitted):
    """Eq. 42-47 on the CW + CCW accelerometer samples of every rotation pair (even and odd lengths): the axis
    within 1e-12 and its variance within 1e-9 (relative) of the SVD solution."""
    run, _ = fitted
    for k, (a, b, _) in enumerate(rotation_pairs(run.session.segments)):
        fa, fb = a.raw["accel"], b.raw["accel"][k % 2:]
        l0, v0 = _svd_axis(np.vstack([fa, fb]))
        l1, v1 = accel_rotation_axis([fa, fb])
        assert np.max(np.abs(l1 * np.sign(l1 @ l0) - l0)) < 1e-12
        assert abs(v1 / v0 - 1) < 1e-9
        l2, v2 = accel_rotation_axis(np.vstack([fa, fb]))
        assert np.max(np.abs(l2 - l1)) < 1e-13 and abs(v2 / v1 - 1) < 1e-10


def test_refine_reports_whether_it_converged(fitted):
    """From the closed-form start the gyro problem needs several Newton steps: one step is reported as not
    converged, and the full run is; from the optimum, one step confirms it."""
    _, res = fitted
    ref = res.refinement
    prob, p0, p, typ = ref["problems"][1], ref["p0"][1], ref["p"][1], ref["typ"][1]
    *_, steps, ok = refine_norms(prob, p0, typ, max_iter=1)
    assert (steps, ok) == (1, False)
    q, _, _, steps, ok = refine_norms(prob, p0, typ)
    assert ok and steps > 1 and np.allclose(q, p, rtol=0, atol=0)
    *_, steps, ok = refine_norms(prob, p, typ)
    assert ok and steps == 1
