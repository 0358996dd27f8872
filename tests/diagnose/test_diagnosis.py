"""Diagnosis behaviour with numbers fixed by theory: false alarms on clean data, uniform p-values under the
null, two hidden effects in two rounds, confounded and untestable candidates, agreement with fit_lsq."""

import numpy as np
import pytest
from scenarios import _temp, known_sigma, rich_procedure, simulate
from scipy import stats

from rimu.calibration.effects import BiasTemperature, GSensitivity, ScaleQuadratic
from rimu.calibration.lsq import fit_lsq
from rimu.calibration.model import ErrorModel
from rimu.diagnose import diagnose, fit_model, iterate, noise_from_differences
from rimu.diagnose.residuals import autocorrelation, ljung_box
from rimu.errors import IdentifiabilityError, SessionFormatError
from rimu.geometry import preset
from rimu.sim import Simulator, TruthEffect
from rimu.sim.procedures import cho_park_procedure, rotation, static
from rimu.units import DEG_TO_RAD, DH_TO_RS, G0, PPM


def _clean_run(seed, **kw):
    """Cho & Park's procedure (Table 1 + Table 2, 5 s steps at 10 Hz) with a temperature profile."""
    sim = Simulator({"gyro": preset("cone6")}, sample_rate=10.0, arw_deg_sqrt_h=0.15, temperature=_temp, seed=seed, **kw)
    return sim.run(cho_park_procedure(duration=5.0))


def test_clean_data_nothing_missing_in_95_percent_and_null_p_values_uniform():
    """100 seeds of a complete model: 'nothing missing' in >= 95 % (alpha = 0.01 family-wise, Holm), and the
    per-sensor F-test p-values of a candidate are uniform (Kolmogorov-Smirnov)."""
    ok, pvals, chi2 = 0, [], []
    for seed in range(100):
        run = _clean_run(seed)
        d = diagnose(run.session, sigma={"gyro": known_sigma(run, "gyro")})
        ok += d.nothing_missing
        pvals += [s.p for s in d["gyro"].test("sf_quadratic").sensors]
        chi2.append(d["gyro"].fit.chi2_dof)
    assert ok >= 95, ok
    assert stats.kstest(pvals, "uniform").pvalue > 1e-3
    # chi2/dof of a complete model with the known noise: mean 1, spread sqrt(2/dof) per run
    dof = sum(s.dof for s in d["gyro"].fit.sensors)
    assert abs(np.mean(chi2) - 1.0) < 4 * np.sqrt(2.0 / dof / len(chi2))
    assert abs(np.std(chi2) / np.sqrt(2.0 / dof) - 1.0) < 0.3


def test_two_hidden_effects_found_in_two_rounds():
    g = preset("cone6")
    gs = {0: [40 * DH_TO_RS / G0, -25 * DH_TO_RS / G0, 30 * DH_TO_RS / G0]}
    k2 = {3: [1.5 * PPM / DEG_TO_RAD], 4: [-1.0 * PPM / DEG_TO_RAD]}
    sim = Simulator({"gyro": g}, sample_rate=20.0, arw_deg_sqrt_h=0.15, seed=3,
                    effects={"gyro": [TruthEffect(GSensitivity(), gs), TruthEffect(ScaleQuadratic(), k2)]})
    run = sim.run(rich_procedure())
    sig = {"gyro": known_sigma(run, "gyro")}
    it = iterate(run.session, sigma=sig)
    assert len(it.rounds) == 2
    assert sorted(it.added["gyro"]) == ["g_sensitivity", "sf_quadratic"]
    assert it.final.nothing_missing
    # each round's top finding on its own sensors (the second once the first is in the model)
    expected = {"g_sensitivity": {"x1"}, "sf_quadratic": {"x2", "y2"}}
    tops = [d["gyro"].top() for d, _ in it.rounds]
    assert sorted(tops) == sorted(expected)
    assert set(it.rounds[1][0]["gyro"].test(tops[1]).detected_sensors()) == expected[tops[1]]
    assert expected[tops[0]] <= set(it.rounds[0][0]["gyro"].test(tops[0]).detected_sensors())
    final = it.final["gyro"].fit
    assert 0.8 <= final.chi2_dof <= 1.25
    val, sd, _ = final.sensor("x2").parameter("k2")
    assert abs(val - k2[3][0]) < 3 * sd


def test_confounded_temperature_and_drift_reported_as_confounded():
    """A temperature ramp linear in time: bias_temperature and bias_drift have the same column after the
    bias; the diagnosis must say it cannot tell them apart, not rank one of them."""
    sim = Simulator({"gyro": preset("triad3")}, sample_rate=20.0, arw_deg_sqrt_h=0.15, seed=1,
                    temperature=lambda t: 20.0 + 0.05 * t,
                    effects={"gyro": [TruthEffect(BiasTemperature(), {0: [5 * DH_TO_RS], 2: [-4 * DH_TO_RS]})]})
    run = sim.run(rich_procedure())
    d = diagnose(run.session, sigma={"gyro": known_sigma(run, "gyro")})
    f = d["gyro"].findings[0]
    assert f.confounded and set(f.effects) == {"bias_temperature", "bias_drift"}
    assert d["gyro"].top() is None
    text = "\n".join(d["gyro"].lines())
    assert "confounded" in text and "thermal soak" in text
    # iterate stops rather than pick one arbitrarily
    it = iterate(run.session, sigma={"gyro": known_sigma(run, "gyro")})
    assert it.rounds == [] and not it.final.nothing_missing


def test_confounded_nonlinearity_and_asymmetry_with_one_rate():
    """Rotations about the triad axes at a single rate: |s| and s^2 are proportional, quadratic
    nonlinearity and asymmetry cannot be told apart."""
    proc = [static(f"S{k}", v, 3.0) for k, v in enumerate([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])]
    for k, a in enumerate(np.eye(3)):
        for sgn in (1, -1):
            proc.append(rotation(f"R{k}{sgn}", sgn * 100 * DEG_TO_RAD * a, 3.0))
    sim = Simulator({"gyro": preset("triad3")}, sample_rate=20.0, arw_deg_sqrt_h=0.15, seed=2, latitude_deg=None,
                    effects={"gyro": [TruthEffect(ScaleQuadratic(), {1: [3 * PPM / DEG_TO_RAD]})]})
    run = sim.run(proc)
    d = diagnose(run.session, sigma={"gyro": known_sigma(run, "gyro")})
    f = d["gyro"].findings[0]
    assert f.confounded and {"sf_quadratic", "sf_asymmetry"} <= set(f.effects)


def test_not_testable_temperature_constant_says_why_and_what_to_do():
    run = simulate("g_sensitivity", "cone6", seed=0)[0]
    d = diagnose(run.session)
    t = d["gyro"].test("bias_temperature")
    assert not t.testable and "never changed" in t.reason and "thermal soak" in t.advice
    # Earth rate is part of the input by default: not a candidate
    assert not d["gyro"].test("earth_rate").testable
    # drift is testable (time stamps continuous), cross-coupling too
    assert d["gyro"].test("bias_drift").testable and d["gyro"].test("cross_coupling").testable


def test_not_testable_without_excitation():
    """Static positions with gravity along the axes only: accel cross-coupling (products of two axis
    inputs) is never excited on a triad."""
    proc = [static(f"S{k}", v, 3.0) for k, v in enumerate([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])]
    run = Simulator({"accel": preset("triad3")}, sample_rate=20.0, seed=0).run(proc)
    d = diagnose(run.session)
    c = d["accel"].test("cross_coupling")
    assert not c.testable and "does not excite" in c.reason
    assert "45 deg" in c.advice
    assert d["accel"].test("size_effect").testable is False


def test_fit_agrees_with_fit_lsq():
    run, _truth, _sc = simulate("g_sensitivity", "cone6", seed=0)
    model = ErrorModel.base() + "g_sensitivity"
    sig = known_sigma(run, "gyro")
    mine = fit_model(run.session, model, "gyro", sigma=sig)
    ref = fit_lsq(run.session, model, "gyro", sigma=sig)
    for a, b in zip(mine.sensors, ref.sensors):
        np.testing.assert_allclose(a.theta, b.theta, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(a.theta_cov, b.theta_cov, rtol=1e-5, atol=1e-30)
        assert a.rss == pytest.approx(b.rss, rel=1e-9)


def test_noise_from_differences_unbiased_with_theory_spread():
    rng = np.random.default_rng(0)
    n, reps = 2000, 400
    idx = np.repeat(np.arange(10), n // 10)
    est = np.array([noise_from_differences(rng.standard_normal(n) + np.repeat(rng.standard_normal(10), n // 10), idx) ** 2
                    for _ in range(reps)])
    assert abs(est.mean() - 1.0) < 4 * np.sqrt(3.0 / n / reps)
    assert est.std() == pytest.approx(np.sqrt(3.0 / n), rel=0.2)


def test_autocorrelation_pooled_and_ljung_box():
    rng = np.random.default_rng(1)
    # AR(1) with rho = 0.5 in 5 segments
    segs = []
    for _ in range(5):
        e = rng.standard_normal(4000)
        x = np.empty_like(e)
        x[0] = e[0]
        for k in range(1, e.size):
            x[k] = 0.5 * x[k - 1] + e[k]
        segs.append(x)
    r = np.concatenate(segs)
    idx = np.repeat(np.arange(5), 4000)
    rho = autocorrelation(r, idx, 3)
    np.testing.assert_allclose(rho, [0.5, 0.25, 0.125], atol=0.03)
    # pooled equals the sum of within-segment products
    rr = r - r.mean()
    direct = sum(float(s[1:] @ s[:-1]) for s in np.split(rr, 5)) / float(rr @ rr)
    assert rho[0] == pytest.approx(direct, rel=1e-12)
    # white noise: Q ~ chi2(h)
    qs = [ljung_box(autocorrelation(w, np.zeros(1000, int), 5), 1000)[0] for w in rng.standard_normal((300, 1000))]
    assert np.mean(qs) == pytest.approx(5.0, abs=0.5)


def test_bad_inputs_raise_specific_errors():
    run = simulate("g_sensitivity", "triad3", seed=0)[0]
    with pytest.raises(ValueError):
        diagnose(run.session, alpha=1.5)
    with pytest.raises(SessionFormatError, match="pass its .session"):
        diagnose(run)
    with pytest.raises(IdentifiabilityError):
        diagnose(run.session, instruments=["accel"])
    with pytest.raises(ValueError):
        fit_model(run.session, ErrorModel.base(), "gyro", sigma=[-1.0, 1.0, 1.0])
    only_static = run.session.subset([s.label for s in run.session.segments if s.label.startswith("S")][:2])
    with pytest.raises(IdentifiabilityError):
        diagnose(only_static)


def test_epoch_time_stamps_keep_drift_testable():
    """Time stamps of a real logger (seconds since 1970) must not cost the drift test its digits."""
    run, _truth, _sc = simulate("bias_drift", "triad3", seed=0)
    for seg in run.session.segments:
        seg.t = seg.t + 1.7e9
    d = diagnose(run.session, sigma={"gyro": known_sigma(run, "gyro")})
    assert d["gyro"].top() == "bias_drift"
    assert set(d["gyro"].test("bias_drift").detected_sensors()) == {"x", "z"}
