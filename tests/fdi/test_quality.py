"""Parity calibration check (de Oliveira et al. 2012, Eq. 21-25) on simulated Table 1 runs of the tetrad."""

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.experiments.quality import parity_quality
from rimu.fdi import stated_covariance
from rimu.geometry import tetrad4
from rimu.sim import Simulator, oliveira_table1
from rimu.units import DEG_TO_RAD, RAD_TO_ARCSEC


@pytest.fixture(scope="module")
def run():
    sim = Simulator({"gyro": tetrad4()}, seed=5, arw_deg_sqrt_h=0.05, sample_rate=50.0)
    return sim.run(oliveira_table1(turns=1))


def _misaligned(cal, i, k, angle):
    m = cal.misalignment.copy()
    E, _ = cal.geometry.off_axis_basis(i)
    m[i] = m[i] + angle * E[k]
    m[i] /= np.linalg.norm(m[i])
    return InstrumentCalibration("gyro", cal.geometry, cal.scale, m, cal.bias, cal.noise_sigma, cal.covariance,
                                 cal.param_names), cal.geometry.subunit_of(i).mat_sb_mb.T @ E[k]


@pytest.mark.parametrize("sensor,k", [(1, 0), (3, 1)])
def test_tells_a_correct_calibration_from_a_half_degree_error_and_names_the_direction(run, sensor, k):
    good = stated_covariance(run.truth["gyro"], 0.01 * DEG_TO_RAD, 50e-6)
    rep = parity_quality(run.session, good)
    assert rep.verdict == "good" and len(rep.pairs) == 8
    bad, err_mb = _misaligned(good, sensor, k, 0.5 * DEG_TO_RAD)
    rep_b = parity_quality(run.session, bad)
    assert rep_b.verdict == "bad"
    # flagged exactly where the error projects on the rate direction; named: the largest projection
    proj = np.array([abs(err_mb @ p.direction) for p in rep_b.pairs])
    flagged = np.array([p.bad for p in rep_b.pairs])
    assert np.all(flagged[proj > 0.3]) and not np.any(flagged[proj < 0.02])
    w = rep_b.worst()
    assert abs(err_mb @ w.direction) == pytest.approx(proj.max(), abs=1e-6)
    # its size: |v_c,i| x 0.5 deg x |cos(error, rate)| (Eq. 22 to first order)
    from rimu.geometry import null_space_rows

    vc = null_space_rows(bad.axes_mb())
    expect = np.linalg.norm(vc[:, sensor]) * 0.5 * DEG_TO_RAD * RAD_TO_ARCSEC * proj.max()
    assert w.misalignment_arcsec == pytest.approx(expect, rel=0.05)
    assert "BAD" in rep_b.summary()


def test_nominal_parity_shows_the_mounting_errors_the_calibrated_one_removes(run):
    rep = parity_quality(run.session, run.truth["gyro"])
    assert np.median([p.nominal_arcsec for p in rep.pairs]) > 20 * np.median([p.misalignment_arcsec for p in rep.pairs])


def test_needs_opposite_rate_pairs():
    from rimu.errors import SessionFormatError
    from rimu.sim import cho_park_table1

    sim = Simulator({"gyro": tetrad4()}, seed=1, sample_rate=10.0)
    r = sim.run(cho_park_table1(duration=2.0))
    with pytest.raises(SessionFormatError, match="opposite"):
        parity_quality(r.session, r.truth["gyro"])


def test_with_the_de_oliveira_estimator_output(run):
    """The calibration the estimator makes from the same Table 1 run (with its own covariance) passes; the same
    calibration with 0.5 deg more on g3 fails."""
    from rimu.calibration.oliveira import Oliveira

    cal = Oliveira().fit(run.session).to_calibration()["gyro"]
    assert cal.covariance is not None
    assert parity_quality(run.session, cal).good
    bad, err_mb = _misaligned(cal, 2, 1, 0.5 * DEG_TO_RAD)
    rep = parity_quality(run.session, bad)
    assert not rep.good
    assert abs(err_mb @ rep.worst().direction) == pytest.approx(max(abs(err_mb @ p.direction) for p in rep.pairs))
