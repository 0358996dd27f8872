"""The fast candidate tests (one shared design per sensor, appended to the model's by its inner products, every
candidate tested in the small space) against the straightforward refit of the model plus each candidate by
least squares on the samples (``score_candidates(method="refit")``), on sessions with a hidden effect: the same
ranking, F statistics, p-values, BIC changes and coefficients to 1e-9; and the p-value functions against
scipy.stats."""

import numpy as np
import pytest
from scenarios import known_sigma, simulate
from scipy import stats

from rimu.calibration.model import ErrorModel
from rimu.diagnose.api import candidate_effects
from rimu.diagnose.candidates import chi2_logsf, conditional_log10_p, confounding, f_logsf, score_candidates
from rimu.diagnose.fitting import cached, fit_model

CASES = [("g_sensitivity", "cone6"), ("sf_cubic", "cone6"), ("cross_coupling", "cone6"), ("size_effect", "cone6"),
         ("bias_temperature", "tetrad4"), ("earth_rate", "triad3")]


def _both(name, geometry):
    run, _truth, sc = simulate(name, geometry, seed=0)
    s = cached(run.session)
    inst = sc.instrument
    fit = fit_model(s, ErrorModel.base(), inst, known_sigma(run, inst), **sc.diagnose)
    cands = candidate_effects(fit.model)
    return run, sc, s, fit, score_candidates(s, fit, cands), score_candidates(s, fit, cands, method="refit")


@pytest.mark.parametrize("name,geometry", CASES)
def test_fast_tests_equal_the_refit(name, geometry):
    _run, _sc, _s, fit, fast, ref = _both(name, geometry)
    assert [t.name for t in fast] == [t.name for t in ref]
    assert fast[0].name == name and fast[0].significant
    for a, b in zip(fast, ref):
        assert (a.testable, a.significant, a.reason) == (b.testable, b.significant, b.reason)
        assert a.log10_p == pytest.approx(b.log10_p, rel=1e-9, abs=1e-12)
        assert a.log10_p_holm == pytest.approx(b.log10_p_holm, rel=1e-9, abs=1e-12)
        assert a.dbic == pytest.approx(b.dbic, rel=1e-9, abs=1e-9)
        assert [x.sensor for x in a.sensors] == [x.sensor for x in b.sensors]
        for x, y in zip(a.sensors, b.sensors):
            assert (x.k, x.dof1, x.significant) == (y.k, y.dof1, y.significant)
            assert x.drss == pytest.approx(y.drss, rel=1e-9, abs=1e-12 * y.rss0)
            assert x.f == pytest.approx(y.f, rel=1e-9, abs=1e-12)
            assert x.log10_p == pytest.approx(y.log10_p, rel=1e-9, abs=1e-12)
            assert x.dbic == pytest.approx(y.dbic, rel=1e-9, abs=1e-9)
        for i in a.sensor_indices:
            np.testing.assert_allclose(a.coefficients(i), b.coefficients(i), rtol=1e-9,
                                       atol=1e-9 * np.abs(b.coefficients(i)).max())
    # the confounding analysis (encompassing tests in the small space) agrees too
    assert confounding(fit, fast, 0.01) == confounding(fit, ref, 0.01)
    sig = [t for t in fast if t.testable and t.sensors][:3]
    sig_ref = {t.name: t for t in ref}
    for a in sig:
        for b in sig:
            if a is not b:
                assert conditional_log10_p(fit, a, b) == pytest.approx(
                    conditional_log10_p(fit, sig_ref[a.name], sig_ref[b.name]), rel=1e-9, abs=1e-9)


def test_fast_coefficients_are_what_adding_the_effect_estimates():
    """The hidden effect's coefficients and dRSS from the small space equal those of the model refitted from
    scratch with the effect added (``Diagnosis.add``), to 1e-7 of their standard error: the from-scratch fit
    (Cholesky QR on the uncentred design) itself resolves them only to ~1e-8 sigma on these sessions."""
    from rimu.diagnose.api import compare

    run, sc, s, fit, fast, _ref = _both("g_sensitivity", "cone6")
    comp = compare(s, fit, fit.model + "g_sensitivity", known_sigma(run, sc.instrument))
    t = fast[0]
    for i in t.sensor_indices:
        after = comp.after.sensors[i]
        k = len(t.coefficients(i))
        sd = np.sqrt(np.diag(after.beta_cov)[-k:])
        assert np.all(np.abs(after.beta[-k:] - t.coefficients(i)) <= 1e-7 * sd)
        x = next(x for x in t.sensors if x.sensor == after.name)
        assert x.drss == pytest.approx(fit.sensors[i].rss - after.rss, rel=1e-7)


def test_p_value_functions_equal_scipy_stats():
    for x in [1e-3, 0.5, 2.0, 7.5, 40.0, 300.0]:
        for k in [1, 3, 10]:
            assert chi2_logsf(x, k) == pytest.approx(float(stats.chi2.logsf(x, k)), rel=1e-12, abs=1e-15)
            for d2 in [5, 1000]:
                assert f_logsf(x, k, d2) == pytest.approx(float(stats.f.logsf(x, k, d2)), rel=1e-12, abs=1e-15)


def test_unknown_method_is_refused():
    run, _truth, _sc = simulate("g_sensitivity", "triad3", seed=0)
    fit = fit_model(run.session, ErrorModel.base(), "gyro")
    with pytest.raises(ValueError, match="fast"):
        score_candidates(run.session, fit, candidate_effects(fit.model), method="exact")


def test_base_model_fit_is_its_own_first_fit_seen_from_the_calibrated_axes():
    """A model of scale, misalignment and bias only is fitted once (its design does not depend on the axes): the
    result equals the fit on the calibrated axes done from scratch, to the bit."""
    run, _truth, _sc = simulate("g_sensitivity", "cone6", seed=1)
    a = fit_model(run.session, ErrorModel.base(), "gyro")
    b = fit_model(run.session, ErrorModel.base(), "gyro", ctxs=a.contexts)
    for x, y in zip(a.sensors, b.sensors):
        for name in ("beta", "beta_cov", "theta", "theta_cov", "r", "axis_input"):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name))
        assert x.ctx.axis.tolist() == y.ctx.axis.tolist() and x.sigma == y.sigma


def test_adding_an_effect_reuses_only_the_fits_own_calibrated_axes():
    """``compare`` (Diagnosis.add) refits on the calibrated axes of the fit it extends when that fit found them
    itself: the result equals a fit of the extended model from scratch, to the bit; a fit on axes the caller
    gave (here the nominal ones) is not taken as the model's own, and the refit again equals the fit from
    scratch."""
    from rimu.calibration.model import contexts
    from rimu.diagnose.api import compare

    run, _truth, _sc = simulate("g_sensitivity", "cone6", seed=2)
    s = cached(run.session)
    model = ErrorModel.base() + "g_sensitivity"
    scratch = fit_model(s, model, "gyro")
    for before in (fit_model(s, ErrorModel.base(), "gyro"),
                   fit_model(s, ErrorModel.base(), "gyro", ctxs=contexts(s, "gyro"))):
        after = compare(s, before, model).after
        for x, y in zip(after.sensors, scratch.sensors):
            np.testing.assert_array_equal(x.beta, y.beta)
            np.testing.assert_array_equal(x.theta_cov, y.theta_cov)
            assert x.ctx.axis.tolist() == y.ctx.axis.tolist()


def test_a_candidate_whose_inputs_some_segments_lack_is_not_tested_and_says_which():
    """The shared design leaves out, per sensor, the effects that cannot be built on every segment, with the
    segments named; both paths agree, and the other candidates are tested as before."""
    import dataclasses

    from rimu.session import Session

    run, _truth, _sc = simulate("bias_temperature", "cone6", seed=0)
    s0 = run.session
    segs = list(s0.segments)
    segs[3] = dataclasses.replace(segs[3], temperature=None)
    s = Session(segs, dict(s0.geometries), s0.sample_rate, s0.latitude, s0.gravity, s0.raw_unit, dict(s0.meta))
    fit = fit_model(s, ErrorModel.base(), "gyro", known_sigma(run, "gyro"))
    cands = candidate_effects(fit.model)
    fast, ref = score_candidates(s, fit, cands), score_candidates(s, fit, cands, method="refit")
    t = next(x for x in fast if x.name == "bias_temperature")
    assert not t.testable and segs[3].label in t.reason and "lack the inputs it needs" in t.reason
    assert [(x.name, x.testable, x.reason) for x in fast] == [(x.name, x.testable, x.reason) for x in ref]
    assert any(x.testable and x.sensors for x in fast)
