"""Cho & Park 2005 estimator: honest uncertainties on their Table 1/2 procedure with Table 3 as truth."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration import ChoPark, LeastSquares
from rimu.calibration.montecarlo import MonteCarlo, normalised_errors
from rimu.errors import IdentifiabilityError
from rimu.sim import Simulator, cho_park_procedure, cho_park_table1, cho_park_table2


@pytest.fixture(scope="module")
def run60():
    return Simulator(seed=11).run(cho_park_procedure(duration=60.0))


def test_every_coefficient_within_3_sigma(run60):
    res = ChoPark().fit(run60.session)
    cal = res.to_calibration()
    for inst in ("gyro", "accel"):
        names, z = normalised_errors(cal[inst], run60.truth[inst])
        assert len(names) == 24
        assert np.all(np.abs(z) < 3.0), dict(zip(names, np.round(z, 2)))
        # the residual chi-square per degree of freedom agrees with the noise level
        assert 0.5 < res.chi2_dof[inst] < 1.6
    # standard deviations in the field's units are reported for every parameter
    sf = res.std_field("gyro")
    # Table 3's biases (about 3 deg/s and 4 m/s^2) read in the field unit their magnitude calls for, one per table
    assert sf["x1.bias"][1] == "deg/s" and sf["x1.mis_y"][1] == "arcsec" and sf["x1.scale"][1] == "ppm"
    assert {u for n, (_, u) in res.std_field("accel").items() if n.endswith(".bias")} == {"m/s^2"}


def test_earth_rate_is_subtracted_and_documented(run60):
    with_e = ChoPark().fit(run60.session)
    without = ChoPark(earth_rate=False).fit(run60.session)
    assert any("Earth rate subtracted" in n for n in with_e.notes)
    assert any("NOT subtracted" in n for n in without.notes)
    truth = run60.truth["gyro"]
    _, z_with = normalised_errors(with_e.to_calibration()["gyro"], truth)
    # the mean Earth rate over Table 1 (about 10 deg/h along some axes) biases Eq. 17 as printed
    b_with = with_e.to_calibration()["gyro"].bias
    b_without = without.to_calibration()["gyro"].bias
    assert np.max(np.abs(b_with - b_without)) > 1e-5  # rad/s, ~2 deg/h or more
    assert np.all(np.abs(z_with) < 3.0)


def test_normalised_error_rms_over_seeds():
    """Over 200 seeds rms(error/sigma) is within [0.85, 1.15]: the reported uncertainties are honest."""
    proc = cho_park_procedure(duration=3.0)

    def simulate(seed):
        r = Simulator(seed=1000 + seed).run(proc)
        return r.session, r.truth

    mc = MonteCarlo(simulate, ChoPark().fit, show_progress=False).run(range(200))
    for inst in ("gyro", "accel"):
        z = mc.normalised[inst]
        rms_all = float(np.sqrt(np.mean(z**2)))
        assert 0.85 <= rms_all <= 1.15, (inst, rms_all)
        # per parameter, with 200 runs the rms of a unit normal lies in [0.8, 1.2] with overwhelming probability
        per = mc.rms_normalised(inst)
        assert np.all((per > 0.78) & (per < 1.22)), (inst, per)


def test_lsq_monte_carlo_std_matches_covariance():
    """Cramer-Rao on a linear problem: MC standard deviation within 10% of the covariance-predicted one."""
    proc = cho_park_table1(duration=4.0)

    def simulate(seed):
        r = Simulator(seed=5000 + seed, latitude_deg=None).run(proc)
        return r.session, r.truth

    sig = {"accel": Simulator().noise_sigma("accel") / Simulator().truth_calibration()["accel"].scale}
    mc = MonteCarlo(simulate, LeastSquares(sigma=sig, instruments=["accel"]).fit, ["accel"], False).run(range(150))
    emp = mc.empirical_std("accel")
    pred = mc.predicted_std["accel"]
    ratio = emp / pred
    # each ratio from 150 runs has a relative sampling error of 1/sqrt(300) = 5.8%; pooled over 24 parameters
    # the mean ratio is within 10% with a wide margin, each single one within 20%
    assert abs(np.sqrt(np.mean(ratio**2)) - 1) < 0.10, ratio
    assert np.all(np.abs(ratio - 1) < 0.2), ratio


def test_three_static_positions_are_refused_with_names():
    run = Simulator(seed=3).run(cho_park_table1(duration=2.0, positions=[1, 2, 5]))
    with pytest.raises(IdentifiabilityError) as exc:
        ChoPark(instruments=["accel"]).fit(run.session)
    assert exc.value.parameters, "the error names the parameters"
    assert any(p.endswith(".bias") or p.endswith(".scale") or ".mis_" in p for p in exc.value.parameters)
    assert "cannot identify" in str(exc.value)
    with pytest.raises(IdentifiabilityError) as exc2:
        LeastSquares(instruments=["accel"]).fit(run.session)
    assert "x1.bias" in exc2.value.parameters and "x1.scale" in exc2.value.parameters


def test_gyro_needs_three_rate_axes_and_a_static_position():
    run = Simulator(seed=3).run(cho_park_table1(duration=2.0) + cho_park_table2(duration=2.0, steps=[1, 2, 3, 4]))
    with pytest.raises(IdentifiabilityError) as exc:
        ChoPark(instruments=["gyro"]).fit(run.session)
    assert exc.value.parameters
    run2 = Simulator(seed=3).run(cho_park_table2(duration=2.0))
    with pytest.raises(IdentifiabilityError, match="bias"):
        ChoPark(instruments=["gyro"]).fit(run2.session)


def test_residuals_per_segment_and_calibration_file(tmp_path, run60):
    res = ChoPark().fit(run60.session)
    r = res.residuals("accel")
    assert set(r) >= {f"P{k}" for k in range(1, 11)}
    assert set(r["P1"]) == {"x1", "y1", "z1", "x2", "y2", "z2"}
    # residual rms per segment is the noise level (in raw units)
    sig = Simulator().noise_sigma("accel") / run60.truth["accel"].scale[0]
    assert 0.8 < np.std(r["P1"]["x1"]) / sig < 1.2
    cal = res.to_calibration()
    from rimu.calibration import Calibration

    back = Calibration.load(cal.save(tmp_path / "cal.json"))
    assert back.method == "Cho & Park 2005"
    assert np.allclose(back["gyro"].covariance, cal["gyro"].covariance)
    assert back["gyro"].param_names[:4] == ["x1.scale", "x1.mis_y", "x1.mis_z", "x1.bias"]
    assert "x1.scale" in res.table()


def test_chopark_equals_generic_lsq_for_accelerometers(run60):
    """On static data both are least squares on the same model (Eq. 7): the estimates agree closely."""
    a = ChoPark(instruments=["accel"]).fit(run60.session).to_calibration()["accel"]
    b = LeastSquares(instruments=["accel"], segments=[f"P{k}" for k in range(1, 11)]).fit(run60.session)
    b = b.to_calibration()["accel"]
    assert np.allclose(a.scale, b.scale, rtol=1e-9)
    assert np.allclose(a.bias, b.bias, rtol=1e-9, atol=1e-12)
