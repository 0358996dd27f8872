"""The compiled kernels of the hand-held calibration (numba, issue 15: the noise level's third differences, the
window sums, the pre-integration of the motions and the rotation model the fit iterates on) give the numbers of
the numpy reference, and the backend choice is explicit (``backend=`` / ``RIMU_BACKEND``, a named error when numba
is asked for and missing).

"Equal": the one pass (segment sums, extremes, third differences) to 1e-12 relative of numpy's reductions and
``np.diff`` (integer raw data: exact);
the pre-integration of the motions (a sequential product instead of a prefix tree, another summation order) to
1e-12 of the size of each quantity; the weighted rotation residuals and their Jacobian to 1e-9 of their largest;
the whole calibration (parameters and covariance) to 1e-9 relative, far below any standard deviation (~1e-4
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


@pytest.mark.parametrize("seed", [5, 11])
def test_calibration_equal(seed):
    pytest.importorskip("numba")
    session = handheld_run(n_poses=20, seed=seed).session
    a, b = (hh.HandHeld(backend=x).fit(session) for x in ("numpy", "numba"))
    for inst in ("accel", "gyro"):
        fa, fb = a.fits[inst][0], b.fits[inst][0]
        np.testing.assert_allclose(fb.theta, fa.theta, rtol=1e-9, atol=0)
        np.testing.assert_allclose(fb.cov, fa.cov, rtol=0, atol=1e-9 * np.abs(fa.cov).max())
    ca, cb = a.to_calibration(), b.to_calibration()
    for inst in ("accel", "gyro"):
        np.testing.assert_allclose(cb[inst].scale, ca[inst].scale, rtol=1e-9)
        np.testing.assert_allclose(cb[inst].bias, ca[inst].bias, rtol=1e-9, atol=1e-15)
