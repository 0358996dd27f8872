"""Calibration.apply against its definition and against imucal's own calibrate() after conversion both ways."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration.result import Calibration, InstrumentCalibration
from rimu.geometry import triad3, triads
from rimu.units import DEG_TO_RAD


def _cal(rng: np.random.Generator, geo, raw_unit: str = "count") -> Calibration:
    n = geo.n
    out = {}
    for k, s in (("gyro", 1e-3), ("accel", 5e-3)):
        m = geo.nominal_rows() + 0.01 * rng.standard_normal((n, 3))
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        out[k] = InstrumentCalibration(k, geo, s * (1 + 0.02 * rng.standard_normal(n)), m, 0.1 * rng.standard_normal(n))
    return Calibration(out, raw_unit=raw_unit)


def test_apply_inverts_the_raw_output_model_per_triad():
    rng = np.random.default_rng(3)
    geo = triads(2)
    cal = _cal(rng, geo)
    u = rng.standard_normal((50, 3))
    raw = {k: cal[k].raw_output(u) for k in ("gyro", "accel")}  # what each sensor outputs for input u (Eq. 1)
    out = cal.apply(raw)
    for k in raw:
        assert out[k].shape == (50, 6)
        np.testing.assert_allclose(out[k][:, :3], u, atol=1e-12)
        np.testing.assert_allclose(out[k][:, 3:], u, atol=1e-12)


def test_imucal_round_trip_and_same_calibrated_data():
    imucal = pytest.importorskip("imucal")
    from rimu.calibration.imucal_interop import from_imucal, to_imucal

    rng = np.random.default_rng(5)
    cal = _cal(rng, triad3())
    info = to_imucal(cal)
    assert isinstance(info, imucal.FerrarisCalibrationInfo)
    acc = rng.standard_normal((40, 3)) * 300
    gyr = rng.standard_normal((40, 3)) * 300
    a_i, g_i = info.calibrate(acc, gyr, acc_unit=cal.raw_unit, gyr_unit=cal.raw_unit)
    mine = cal.apply(accel=acc, gyro=gyr)
    np.testing.assert_allclose(a_i, mine["accel"], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(g_i * DEG_TO_RAD, mine["gyro"], rtol=1e-10, atol=1e-12)  # imucal gives deg/s
    back = from_imucal(info)
    for k in ("gyro", "accel"):
        np.testing.assert_allclose(back[k].scale, cal[k].scale, rtol=1e-12)
        np.testing.assert_allclose(back[k].misalignment, cal[k].misalignment, atol=1e-12)
        np.testing.assert_allclose(back[k].bias, cal[k].bias, atol=1e-12)
