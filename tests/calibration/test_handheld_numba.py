"""The compiled kernels of the hand-held calibration (numba, issue 15: the noise level's third differences, the
window sums, the pre-integration of the motions and the rotation model the fit iterates on) give the numbers of
the numpy reference, and the backend choice is explicit (``backend=`` / ``RIMU_BACKEND``, a named error when numba
is asked for and missing).

"Equal": the one pass (segment sums, extremes, third differences) to 1e-12 relative of numpy's reductions and
``np.diff`` (integer raw data: exact);
the pre-integration of the motions (a sequential product instead of a prefix tree, another summation order) to
1e-12 of the size of each quantity; the weighted rotation residuals and their Jacobian to 1e-9 of their largest;
the accelerometers' leave-one-out problems (residuals, Jacobians, normal equations) to 1e-10 of their largest;
the whole calibration (parameters and covariance, the held-out checks' figures and verdicts) to 1e-9 relative, far below any standard deviation (~1e-4
relative) and above the rounding of another order of operations (~1e-15).
"""

from __future__ import annotations

import numpy as np
import pytest

import rimu.calibration.handheld as hh
from rimu.errors import BackendUnavailableError, OptionError
from rimu.sim.handheld import handheld_run


@pytest.fixture(scope="module")
def run():
    return handheld_run(n_poses=20, seed=5)


def test_backend_choice(monkeypatch):
    assert hh.HandHeld(backend="numpy").backend == "numpy"
    with pytest.raises(OptionError, match="auto, numpy, numba.*'fortran'"):
        hh.HandHeld(backend="fortran")
    monkeypatch.setattr(hh, "_KERNELS", [None])
    assert hh.HandHeld(backend="auto").backend == "numpy"
    with pytest.raises(BackendUnavailableError, match=r"pip install rimu\[fast\]"):
        hh.HandHeld(backend="numba")
    monkeypatch.setenv("RIMU_BACKEND", "numba")
    with pytest.raises(BackendUnavailableError, match="RIMU_BACKEND"):
        hh.HandHeld()
    monkeypatch.setenv("RIMU_BACKEND", "numpy")
    assert hh.HandHeld().backend == "numpy"


def test_segment_stats_sample_by_sample():
    """The compiled one pass: per segment the sum, extremes and squared third differences of ``Y - ref``, against
    numpy's reductions and ``np.diff`` (segments of 0 to 101 samples, odd and even lengths)."""
    pytest.importorskip("numba")
    kern = hh._kernels()
    rng = np.random.default_rng(2)
    counts = np.array([0, 1, 3, 4, 5, 6, 7, 50, 101])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    Y = rng.normal(size=(counts.sum(), 3)) * 40.0 + 1000.0
    ref = Y[0].copy()
    out = [np.zeros((len(counts), 3)) for _ in range(4)]
    kern.segment_stats(Y, starts, counts, ref, *out)
    for j, (a, k) in enumerate(zip(starts, counts)):
        x = Y[a:a + k] - ref
        if k == 0:
            assert np.all(out[0][j] == 0) and np.all(out[1][j] == -np.inf) and np.all(out[2][j] == np.inf)
            continue
        np.testing.assert_allclose(out[0][j], x.sum(axis=0), rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(out[1][j], x.max(axis=0))
        np.testing.assert_array_equal(out[2][j], x.min(axis=0))
        want = np.sum(np.diff(x, 3, axis=0) ** 2, axis=0) if k > 3 else np.zeros(3)
        np.testing.assert_allclose(out[3][j], want, rtol=1e-12, atol=0.0)


def test_noise_level_equal(run):
    pytest.importorskip("numba")
    for inst in ("accel", "gyro"):
        ref = hh.white_noise_sigma_hf(run.session, inst, _stats=hh._raw_stats(run.session, inst))
        fast = hh.white_noise_sigma_hf(run.session, inst, _stats=hh._raw_stats(run.session, inst, hh._kernels()))
        assert fast is not None and np.all(fast > 0)
        np.testing.assert_allclose(fast, ref, rtol=1e-12)


def test_preintegration_equal(run):
    """integrate(theta): the motions' rotations, d x / d vec(G) and the bias term, numba against numpy."""
    pytest.importorskip("numba")
    res = {b: hh.HandHeld(backend=b).fit(run.session) for b in ("numpy", "numba")}
    g_np, g_nb = res["numpy"].fits["gyro"][0], res["numba"].fits["gyro"][0]
    theta = g_np.theta * (1 + 1e-3)  # away from the optimum, the same point for both
    a, b = g_np.problem["integrate"](theta), g_nb.problem["integrate"](theta)
    for k in (1, 2, 3):  # R (M, 3, 3), DG (M, 3, 3n), Qc (M, 3, 3)
        np.testing.assert_allclose(b[k], a[k], rtol=0, atol=1e-12 * np.abs(a[k]).max())
    R_exact = g_np.problem["integrate"](theta, jac=False)
    np.testing.assert_allclose(b[1], R_exact, rtol=0, atol=1e-12)
    # the rotation model on it (residuals and Jacobian), near its point and far enough (a correction above
    # 1 mrad) that the right Jacobian of the exponential enters
    for step in (1e-6, 3e-3):
        th = theta * (1 + step)
        ra, Ja = g_np.problem["model_fun"](a)(th)
        rb, Jb = g_nb.problem["model_fun"](b)(th)
        assert np.max(np.abs(g_np.problem["model_x"](th, a))) > (1e-3 if step > 1e-4 else 0.0)
        np.testing.assert_allclose(rb, ra, rtol=0, atol=1e-9 * np.abs(ra).max())
        np.testing.assert_allclose(Jb, Ja, rtol=0, atol=1e-9 * np.abs(Ja).max())


def test_accel_triad_batch_equal():
    """The compiled leave-one-out problems of a triad's accelerometers (residuals, Jacobians, normal equations)
    against the numpy batch, and the batch against the one-problem reference (_accel_problem, whose Jacobian is
    tested against central differences in test_handheld_fast.py)."""
    pytest.importorskip("numba")
    run = handheld_run(n_poses=12, static_s=1.0, seed=1)
    s = run.session
    sa = hh.white_noise_sigma_hf(s, "accel")
    ybar, sd = hh._pose_stats(hh._statics(s), "accel", [0, 1, 2], sa)
    K = len(ybar)
    for model in ("scale_bias", "full"):
        af = hh.fit_accel(ybar, sd, np.eye(3), s.gravity, "xyz", model=model, quick=True)
        rng = np.random.default_rng(0)
        theta = af.theta * (1 + 1e-4 * rng.standard_normal((K, len(af.theta))))  # K different points
        r, J, _ = hh._accel_triad_batch(theta, af.free, ybar, sd, s.gravity)
        # (r = (|f| - g) / sd(|f|): the rounding of |f| ~ g, 1e-15 g, divided by sd(|f|) ~ 1e-3 g: ~1e-12)
        for b in (0, 7):
            r1, J1, _ = hh._accel_problem(theta[b], af.free, np.zeros((3, 3)), ybar, sd, s.gravity, 0.0)
            np.testing.assert_allclose(r[b], r1, rtol=0, atol=1e-10 * np.abs(r1).max())
            np.testing.assert_allclose(J[b], J1, rtol=0, atol=1e-12 * np.abs(J1).max())
        keep = 1.0 - np.eye(K)
        typ = np.abs(af.theta) + 1.0
        fp = np.full(9, -1, dtype=np.int64)
        fp[af.free.ravel()] = np.arange(int(af.free.sum()))
        rc, Jc, A, g = hh._kernels().accel_triad_batch(theta, fp, ybar, sd, float(s.gravity), keep, typ)
        Js = J * (keep[..., None] * typ)
        np.testing.assert_allclose(rc, r * keep, rtol=0, atol=1e-10 * np.abs(r).max())
        np.testing.assert_allclose(Jc, Js, rtol=0, atol=1e-12 * np.abs(Js).max())
        np.testing.assert_allclose(A, np.einsum("bkp,bkq->bpq", Js, Js), rtol=1e-11, atol=0)
        np.testing.assert_allclose(g, np.einsum("bkp,bk->bp", Js, r * keep), rtol=0,
                                   atol=1e-11 * np.abs(g).max())


@pytest.mark.parametrize("seed", [5, 11])
def test_calibration_equal(seed):
    pytest.importorskip("numba")
    session = handheld_run(n_poses=20, seed=seed).session
    a, b = (hh.HandHeld(backend=x).fit(session) for x in ("numpy", "numba"))
    for inst in ("accel", "gyro"):
        fa, fb = a.fits[inst][0], b.fits[inst][0]
        np.testing.assert_allclose(fb.theta, fa.theta, rtol=1e-9, atol=0)
        np.testing.assert_allclose(fb.cov, fa.cov, rtol=0, atol=1e-9 * np.abs(fa.cov).max())
    # the held-out checks (compiled leave-one-out Gauss-Newton of the accelerometers, compiled fold solves of the
    # gyros) give the reference's figures and verdicts
    for key in ("held_out_accel", "held_out_gyro"):
        for part in ("in_sample", "held_out"):
            np.testing.assert_allclose(b.extra[key][0][part], a.extra[key][0][part], rtol=1e-9)
    assert [s["applied"] for s in b.extra["steps"]] == [s["applied"] for s in a.extra["steps"]]
    ca, cb = a.to_calibration(), b.to_calibration()
    for inst in ("accel", "gyro"):
        np.testing.assert_allclose(cb[inst].scale, ca[inst].scale, rtol=1e-9)
        np.testing.assert_allclose(cb[inst].bias, ca[inst].bias, rtol=1e-9, atol=1e-15)
