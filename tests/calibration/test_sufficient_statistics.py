"""Estimators work on per-segment sufficient statistics: the same numbers as a stacked least squares, and a
fitted result whose memory does not grow with the number of samples."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from rimu.calibration import ChoPark, LeastSquares
from rimu.calibration.lsq import LazyResiduals, fit_lsq
from rimu.calibration.model import ErrorModel, contexts
from rimu.sim import Simulator, cho_park_procedure


@pytest.fixture(scope="module")
def run():
    return Simulator(seed=4).run(cho_park_procedure(duration=4.0))


def test_same_estimate_as_stacked_least_squares(run):
    """beta from the accumulated normal equations equals numpy's lstsq on the stacked design (1e-9 relative)."""
    model = ErrorModel.from_names("bias,scale_misalignment,g_sensitivity")
    res = fit_lsq(run.session, model, "gyro")
    for ctx, fit in zip(contexts(run.session, "gyro"), res.sensors):
        Xs = [model.design(s, ctx) for s in run.session.segments]
        X = np.vstack([x for x in Xs if x is not None])
        y = np.concatenate([s.raw["gyro"][:, ctx.index] for s, x in zip(run.session.segments, Xs) if x is not None])
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        assert np.allclose(fit.beta, beta, rtol=1e-9, atol=1e-12 * np.abs(beta).max())
        r = y - X @ beta
        assert fit.rss == pytest.approx(float(r @ r), rel=1e-6)
    # the residual of a segment, computed on demand, is the stacked one
    lab = res.segments[0]
    assert isinstance(res.sensors[0].residuals, LazyResiduals)
    assert res.sensors[0].residuals[lab].shape == (run.session.segment(lab).n_samples,)


def test_base_fast_path_matches_the_generic_path(run):
    a = LeastSquares().fit(run.session)
    b = LeastSquares(model=ErrorModel.from_names("scale_misalignment,bias")).fit(run.session)
    generic = fit_lsq(run.session, ErrorModel.base(), "accel", sigma=a.instruments["accel"].sensors[0].sigma)
    for sa, sg in zip(a.instruments["accel"].sensors, generic.sensors):
        assert np.allclose(sa.beta, sg.beta, rtol=1e-10)
    assert np.allclose(a.instruments["gyro"].sensors[2].theta, b.instruments["gyro"].sensors[2].theta, rtol=1e-12)


def _retained_bytes(fit):
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    result = fit()
    after = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    del result
    return after - before


@pytest.mark.parametrize("estimator", [ChoPark, LeastSquares])
def test_fitted_result_memory_does_not_grow_with_samples(estimator):
    """The result keeps per-segment figures only: 8x the samples retain (almost) the same memory."""
    short = Simulator(seed=5).run(cho_park_procedure(duration=2.0)).session
    long = Simulator(seed=5).run(cho_park_procedure(duration=16.0)).session
    m_short = _retained_bytes(lambda: estimator().fit(short))
    m_long = _retained_bytes(lambda: estimator().fit(long))
    # the 16 s session's data alone is ~8x the 2 s one's; what the fit keeps may differ by the attitude cache
    # of the rate segments (kept on the session, not the result) and small-object noise
    data_long = sum(s.raw["gyro"].nbytes + s.raw["accel"].nbytes for s in long.segments)
    assert m_long < m_short + 0.25 * data_long


def test_ln_vector_in_mb_equals_the_attitude_matrices(run):
    """The closed-form rotation of a fixed local-level vector equals C(t)^T v from one matrix per sample."""
    v = np.array([0.3, -1.2, 9.8])
    for seg in run.session.segments:
        C = seg.attitude()
        if C is None:
            continue
        assert np.allclose(seg.ln_vector_in_mb(v), np.einsum("nji,j->ni", C, v), rtol=0, atol=1e-12)


def _same_fit(a, b, what, session):
    """Two LeastSquares results of the same base model (perhaps its effects in another order): every sensor's
    values, covariances, residual sums and residuals, and the calibrations they make, equal to 1e-12."""
    for inst in a.instruments:
        for sa, sb in zip(a[inst].sensors, b[inst].sensors):
            pa = [sb.theta_names.index(n) for n in sa.theta_names]  # b's physical parameters in a's order
            qa = [sb.beta_names.index(n) for n in sa.beta_names]
            # (absolute: 1e-14 rad of a misalignment angle near zero, 1e-12 of the largest raw coefficient)
            np.testing.assert_allclose(sa.theta, sb.theta[pa], rtol=1e-12, atol=1e-14, err_msg=what)
            np.testing.assert_allclose(sa.beta, sb.beta[qa], rtol=1e-12, atol=1e-12 * np.abs(sb.beta).max(),
                                       err_msg=what)
            for ca, cb in ((sa.theta_cov, sb.theta_cov[np.ix_(pa, pa)]), (sa.beta_cov, sb.beta_cov[np.ix_(qa, qa)])):
                np.testing.assert_allclose(ca, cb, rtol=1e-12, atol=1e-12 * np.abs(cb).max(), err_msg=what)
            # the residual sum from the statistics, q - 2 b.h + b.G.b, cancels: eps q / rss of it is rounding
            assert sa.rss == pytest.approx(sb.rss, rel=1e-6) and sa.sigma == sb.sigma and sa.n_obs == sb.n_obs
            assert sa.theta_names == [sb.theta_names[k] for k in pa] and list(sa.residuals) == list(sb.residuals)
            for lab in sa.residuals:  # to 1e-12 of the raw outputs they are the residuals of
                y = session.segment(lab).raw[inst][:, sa.ctx.index]
                np.testing.assert_allclose(sa.residuals[lab], sb.residuals[lab], rtol=0,
                                           atol=1e-12 * np.abs(y).max() * max(1.0, np.sqrt(len(y))),
                                           err_msg=f"{what} {lab}")
        ca, cb = a[inst].to_calibration(), b[inst].to_calibration()
        for f in ("scale", "misalignment", "bias", "noise_sigma"):
            # (absolute 1e-14: a misalignment component near zero of a unit row, 2e-9 arcsec; the sums of the two
            # paths are taken in another order)
            np.testing.assert_allclose(getattr(ca, f), getattr(cb, f), rtol=1e-12, atol=1e-14, err_msg=f"{what} {f}")
        p = [cb.param_names.index(n) for n in ca.param_names]
        np.testing.assert_allclose(ca.covariance, cb.covariance[np.ix_(p, p)], rtol=1e-12,
                                   atol=1e-12 * np.abs(cb.covariance).max(), err_msg=what)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("data", ["simulated", "ferraris"])
def test_array_base_path_equals_the_general_path(run, data, backend):
    """LeastSquares of the base model takes the array path (every sensor of an instrument at once, from the shared
    statistics; numpy's, or the compiled statistics and solve); the same model with its effects listed the other way
    round takes the general per-sensor design path. Both give the same numbers to 1e-12: on a simulated Cho & Park
    session (static and rate segments) and on imucal's real Ferraris recording (static positions and turns of known
    angle). The array path's chi-square per degree of freedom, read before any per-sensor fit is made, is the one
    its per-sensor fits give."""
    if backend == "numba":
        pytest.importorskip("numba", reason="the compiled path needs numba")
    if data == "ferraris":
        from rimu.session import load_ferraris
        from tests.conftest import shared_data

        session = load_ferraris(shared_data("imucal_ferraris_session", "example_ferraris_session.csv"))
    else:
        session = run.session
    for sigma in (None, {"gyro": 0.01, "accel": 0.002}):
        fast = LeastSquares(sigma=sigma, backend=backend).fit(session)
        # (the general path's noise level from the same backend's sums: the compiled and numpy sums differ in the
        # last bit)
        general = LeastSquares(model=ErrorModel.from_names("bias,scale_misalignment"), sigma=sigma,
                               backend=backend).fit(session)
        chi2 = fast.chi2_dof  # from the arrays: no per-sensor fit made yet
        _same_fit(fast, general, f"{data}, sigma {sigma}, {backend}", session)
        assert fast.chi2_dof == chi2  # from the per-sensor fits, made by _same_fit
        for inst, c in chi2.items():
            assert c == pytest.approx(general.chi2_dof[inst], rel=1e-6)
