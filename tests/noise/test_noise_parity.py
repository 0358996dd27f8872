"""Parity-space check: white and independent sensors pass; per-sensor flicker is not white but independent;
a bias drift common to every sensor is not independent."""

from __future__ import annotations

import math

import numpy as np

from rimu.geometry import cone6
from rimu.noise import InstrumentNoise, parity_allan
from rimu.noise.parity import normalised_parity_matrix
from rimu.sim.noise import FlickerSource

FS, SIG, N = 100.0, 0.01, 60_000


def _model(b: float = 0.0) -> InstrumentNoise:
    return InstrumentNoise.from_terms("gyro", cone6().names, FS, white=SIG / math.sqrt(FS), bias_instability=b)


def test_parity_matrix_is_normalised() -> None:
    sig = np.array([1.0, 2.0, 0.5, 1.0, 3.0, 1.0])
    Vn = normalised_parity_matrix(cone6().H, sig)
    assert np.allclose(Vn @ np.diag(sig ** 2) @ Vn.T, np.eye(3))
    assert np.allclose(Vn @ cone6().H, 0.0, atol=1e-12)


def test_white_independent_sensors_pass_both() -> None:
    rng = np.random.default_rng(0)
    z = SIG * rng.standard_normal((N, 6)) + np.array([0.1, 0.2, -0.3]) @ cone6().H.T   # a constant input
    pw = parity_allan(z, cone6().H, FS, _model())
    assert pw.white and pw.independent, pw.verdict()
    assert np.allclose(pw.normalised[:, :5], 1.0, atol=0.05)


def test_per_sensor_flicker_is_not_white_but_independent() -> None:
    rng = np.random.default_rng(1)
    b = SIG / 5
    # band from 2 ms: the flicker is flat over every tau of the curve (the check is sharp at short tau)
    z = SIG * rng.standard_normal((N, 6)) + FlickerSource(6, FS, b, band_s=(0.002, 1e5), rng=rng).draw(N)
    pw = parity_allan(z, cone6().H, FS, _model(b))
    assert not pw.white and pw.independent, pw.verdict()


def test_equal_common_bias_is_invisible_in_cone6() -> None:
    """cone6's two triads have R1^T 1 = R2^T 1: an equal bias on all six sensors is a rotation rate, V 1 = 0."""
    assert np.allclose(cone6().parity_matrix() @ np.ones(6), 0.0, atol=1e-12)


def test_common_drift_is_not_independent() -> None:
    """One slow signal (a temperature) acting on every sensor with its own coefficient: the parity sees it
    (the coefficients are not in the range of H), and the independent-sensor prediction misses it."""
    rng = np.random.default_rng(2)
    b = SIG / 5
    coeff = np.array([1.0, -0.5, 0.8, 0.2, 1.0, -1.0])
    common = FlickerSource(1, FS, b, rng=rng).draw(N) * coeff
    z = SIG * rng.standard_normal((N, 6)) + common
    model = _model(0.0)
    pw = parity_allan(z, cone6().H, FS, model)
    assert not pw.independent, pw.verdict()
    assert "NOT independent" in pw.verdict()


def test_common_motion_cancels() -> None:
    """A random rotation rate common to the unit (vibration) lies in the range of H: the parity stays white."""
    rng = np.random.default_rng(3)
    motion = np.cumsum(rng.standard_normal((N, 3)), axis=0) * 0.01
    z = SIG * rng.standard_normal((N, 6)) + motion @ cone6().H.T
    pw = parity_allan(z, cone6().H, FS, _model())
    assert pw.white and pw.independent, pw.verdict()
