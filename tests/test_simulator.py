"""The truth simulator: the papers' procedures, noise levels, Earth rate, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from rimu.calibration.result import InstrumentCalibration
from rimu.geometry import tetrad4, triad3
from rimu.session import earth_rate_ln
from rimu.sim import (
    REFERENCE_ATTITUDE,
    Simulator,
    cho_park_table1,
    cho_park_table2,
    cho_park_table3,
    oliveira_table1,
    rotation,
    static,
    zhang_scheme,
)
from rimu.sim.procedures import CHO_PARK_TABLE1, CHO_PARK_TABLE2
from rimu.units import ARW_DSQH_TO_RSQS, DEG_TO_RAD, DS_TO_RS, EARTH_RATE, G0, UG_TO_MS2


def test_table3_values_in_si():
    cal = cho_park_table3()
    assert cal["gyro"].scale[4] == pytest.approx(3.9207e-1 * DS_TO_RS)
    assert cal["gyro"].bias[2] == pytest.approx(1.9168e2 * DS_TO_RS)
    assert cal["accel"].scale[1] == pytest.approx(2.1681e-4 * G0)
    assert cal["accel"].bias[5] == pytest.approx(3.5403 * G0)
    assert cal["gyro"].misalignment[3, 1] == pytest.approx(-2.7609e-2, rel=1e-4)
    # a raw gyro output at rest is near 500 counts, as for the paper's ADXRS150 (190 deg/s / 0.38)
    y0 = cal["gyro"].raw_output(np.zeros(3))
    assert np.all((470 < y0) & (y0 < 530))


def test_procedures_match_the_papers_tables():
    t1 = cho_park_table1(duration=1.0)
    assert len(t1) == 10
    for spec, row in zip(t1, CHO_PARK_TABLE1):
        assert np.allclose(spec.specific_force_mb(G0), np.array(row) * G0, atol=1e-9)
    t2 = cho_park_table2(rate=0.5, duration=1.0)
    assert len(t2) == 14
    assert np.allclose([s.rate_mb for s in t2], np.array(CHO_PARK_TABLE2) * 0.5)
    # the rotation axis of each rate step is vertical (the table axis)
    for s in t2:
        up_mb = s.mat_ln_mb.T @ [0, 0, 1]
        assert abs(abs(up_mb @ s.rate_mb) / np.linalg.norm(s.rate_mb) - 1) < 1e-12
    ol = oliveira_table1()
    assert len(ol) == 16
    w = 10 * DEG_TO_RAD
    assert np.allclose(ol[12].rate_mb, [0, w * math.cos(math.radians(30)), w * math.sin(math.radians(30))])
    assert all(abs(s.duration * w / (2 * math.pi) - round(s.duration * w / (2 * math.pi))) < 1e-9 for s in ol)
    z = zhang_scheme()
    assert sum(s.is_static for s in z) == 9 and sum(not s.is_static for s in z) == 12
    assert np.allclose(REFERENCE_ATTITUDE @ [0, 0, -1], [0, 0, 1])


def test_deterministic_for_a_seed():
    proc = cho_park_table1(duration=2.0)[:3]
    a = Simulator(seed=5).run(proc).block.raw["gyro"]
    b = Simulator(seed=5).run(proc).block.raw["gyro"]
    c = Simulator(seed=6).run(proc).block.raw["gyro"]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_noise_level_and_earth_rate_on_a_static_position():
    """A static position: compensated outputs average to a.(Earth rate) with the ARW-given spread."""
    sim = Simulator(arw_deg_sqrt_h=3.0, sample_rate=200.0, seed=11, latitude_deg=45.0)
    run = sim.run([static("P", [0, 0, -1], duration=60.0)])
    truth = run.truth["gyro"]
    z = truth.compensate(run.block.raw["gyro"])
    sigma = 3.0 * ARW_DSQH_TO_RSQS * math.sqrt(200.0)
    assert truth.noise_sigma[0] == pytest.approx(sigma)
    N = z.shape[0]
    s2 = z.var(axis=0, ddof=1) / sigma**2 * (N - 1)
    lo, hi = chi2.ppf([0.0005, 0.9995], N - 1)
    assert np.all((lo < s2) & (s2 < hi))
    # Earth rate in MB for the reference attitude (x North, y East, z Down) at 45 deg
    we_mb = REFERENCE_ATTITUDE.T @ earth_rate_ln(math.radians(45.0))
    assert we_mb == pytest.approx([EARTH_RATE * math.cos(math.radians(45)), 0, -EARTH_RATE * math.sin(math.radians(45))])
    expect = truth.axes_mb() @ we_mb
    assert np.all(np.abs(z.mean(axis=0) - expect) < 4 * sigma / math.sqrt(N))


def test_accelerometer_noise_and_gravity():
    sim = Simulator(vrw_ug_sqrt_hz=200.0, seed=2)
    run = sim.run([static("P", [1, 0, 0], duration=30.0)])
    truth = run.truth["accel"]
    z = truth.compensate(run.block.raw["accel"])
    expect = truth.axes_mb() @ np.array([G0, 0, 0])
    sigma = 200 * UG_TO_MS2 * 10
    assert np.all(np.abs(z.mean(axis=0) - expect) < 4 * sigma / math.sqrt(len(z)))


def test_rotation_inputs_and_reported_knowledge():
    sim = Simulator(seed=1, table_angle_error_arcsec=20.0, table_rate_error_ppm=100.0)
    spec = rotation("R", [0, 0, 30 * DS_TO_RS], duration=12.0)
    run = sim.run([spec])
    seg = run.session.segments[0]
    assert seg.kind == "rate" and np.array_equal(seg.rate_mb, spec.rate_mb)  # the commanded rate is reported
    true_rate = run.truth_segments[0].rate_mb
    assert 0 < abs(true_rate[2] / spec.rate_mb[2] - 1) < 1e-3  # the table's rate error is in the truth only
    # the accelerometers see a constant gravity: the rotation axis is vertical
    f = run.truth_inputs["accel"]
    assert np.allclose(np.linalg.norm(f, axis=1), G0)
    assert np.ptp(f, axis=0).max() < 3e-3  # only the 20 arcsec tilt of the table moves gravity
    f0 = Simulator(seed=1).run([spec]).truth_inputs["accel"]
    assert np.ptp(f0, axis=0).max() < 1e-9


def test_other_geometries_and_bias_random_walk():
    sim = Simulator({"gyro": tetrad4(), "accel": triad3()}, gyro_bias_rw_deg_h_sqrt_h=50.0, seed=3)
    run = sim.run([static("P", [1, 0, 0], duration=10.0)])
    assert run.block.raw["gyro"].shape == (1000, 4) and run.block.raw["accel"].shape == (1000, 3)
    assert isinstance(run.truth["gyro"], InstrumentCalibration)
    with pytest.raises(ValueError, match="procedure has no segments"):
        sim.run([])
