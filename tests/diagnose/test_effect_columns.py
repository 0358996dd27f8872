"""Each effect's columns against the physics written out independently, and its report units."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.calibration.effects import (
    BiasDrift,
    BiasTemperature2,
    CrossCoupling,
    EarthRate,
    G2Sensitivity,
    GSensitivity,
    ScaleAsymmetry,
    ScaleCubic,
    ScaleQuadratic,
    ScaleTemperature,
    SizeEffect,
)
from rimu.calibration.model import EFFECTS, ErrorModel, SensorContext
from rimu.geometry import preset
from rimu.session import Segment, rotation_matrix
from rimu.units import DEG_TO_RAD, DH_TO_RS, EARTH_RATE, G0, PPM, UG_TO_MS2

vec = st.lists(st.floats(-3, 3, allow_nan=False), min_size=3, max_size=3).map(np.array)


def _rate_seg(w, n=5, att=None, T=None):
    return Segment("r", "rate", np.arange(n) * 0.1, {}, temperature=T, rate_mb=w,
                   mat_ln_mb=np.eye(3) if att is None else att)


@settings(max_examples=30, deadline=None)
@given(vec, vec, st.integers(0, 5))
def test_size_effect_is_centripetal_acceleration(w, r, i):
    g = preset("cone6")
    ctx = SensorContext("accel", i, g, 0.5)
    cols = SizeEffect().columns(_rate_seg(w), ctx)
    expect = g.H[i] @ np.cross(w, np.cross(w, r))
    np.testing.assert_allclose(cols @ r, expect, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(vec.filter(lambda v: np.linalg.norm(v) > 0.1), st.integers(0, 3))
def test_g2_columns_are_input_times_cross_specific_force(rv, i):
    g = preset("tetrad4")
    ctx = SensorContext("gyro", i, g, 0.5)
    att = rotation_matrix(rv)
    seg = Segment("s", "static", np.arange(3.0), {}, mat_ln_mb=att)
    f = att.T @ np.array([0, 0, G0])
    cols = G2Sensitivity().columns(seg, ctx)
    E, _ = g.off_axis_basis(i)
    C = g.subunit_of(i).mat_sb_mb
    cross = E @ C
    # the cross axes are orthogonal to the sensing axis and to each other (MB)
    np.testing.assert_allclose(cross @ g.H[i], 0, atol=1e-12)
    np.testing.assert_allclose(cross @ cross.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(cols[0], (f @ g.H[i]) * (cross @ f), atol=1e-9)
    np.testing.assert_allclose(GSensitivity().columns(seg, ctx)[0], f)


def test_asymmetry_gives_two_slopes_and_nonlinearity_powers():
    g = preset("triad3")
    ctx = SensorContext("gyro", 0, g, None)
    for w in (0.5, -0.5):
        seg = _rate_seg(np.array([w, 0.3, 0.0]))
        ka = 300 * PPM
        y = w + ScaleAsymmetry().columns(seg, ctx)[0, 0] * ka
        assert y == pytest.approx(w * (1 + np.sign(w) * ka))
        assert ScaleQuadratic().columns(seg, ctx)[0, 0] == pytest.approx(w**2)
        assert ScaleCubic().columns(seg, ctx)[0, 0] == pytest.approx(w**3)
    xc = CrossCoupling().columns(_rate_seg(np.array([0.5, 0.3, -0.2])), ctx)[0]
    np.testing.assert_allclose(xc, [0.5 * 0.3, 0.5 * -0.2])
    assert [p.name for p in CrossCoupling().parameters(ctx)] == ["xc_y", "xc_z"]
    assert not CrossCoupling().applies_to(SensorContext("gyro", 3, preset("tetrad4"), None))


def test_earth_rate_column_north_and_up():
    g = preset("triad3")
    lat = 0.6
    # MB = ENU: x East, y North, z Up
    seg = Segment("s", "static", np.arange(2.0), {}, mat_ln_mb=np.eye(3))
    ctx = [SensorContext("gyro", i, g, lat, include_earth_rate=False) for i in range(3)]
    vals = [EarthRate().columns(seg, c)[0, 0] for c in ctx]
    np.testing.assert_allclose(vals, [0, EARTH_RATE * np.cos(lat), EARTH_RATE * np.sin(lat)], atol=1e-15)
    assert EarthRate().applies_to(ctx[0])
    assert not EarthRate().applies_to(SensorContext("gyro", 0, g, lat))
    # with the Earth rate left out, the gyro input of a static segment is zero
    np.testing.assert_allclose(ctx[0].input(seg), 0)


def test_temperature_and_time_columns():
    g = preset("triad3")
    ctx = SensorContext("gyro", 2, g, None, reference_temperature=20.0)
    T = np.array([20.0, 25.0, 30.0])
    seg = _rate_seg(np.array([0, 0, 0.4]), n=3, T=T)
    np.testing.assert_allclose(ScaleTemperature().columns(seg, ctx)[:, 0], (T - 20) * 0.4)
    np.testing.assert_allclose(BiasTemperature2().columns(seg, ctx)[:, 0], (T - 20) ** 2)
    np.testing.assert_allclose(BiasDrift().columns(seg, ctx)[:, 0], seg.t)
    assert BiasTemperature2().columns(_rate_seg(np.array([0, 0, 1.0])), ctx) is None


def test_report_units():
    g = preset("triad3")
    gy, ac = SensorContext("gyro", 0, g, None), SensorContext("accel", 0, g, None)
    p = GSensitivity().physical_parameters(gy)[0]
    assert (DH_TO_RS / G0) * p.to_report == pytest.approx(1.0) and p.report_unit == "(deg/h)/g"
    p = ScaleQuadratic().parameters(gy)[0]
    assert (PPM / DEG_TO_RAD) * p.to_report == pytest.approx(1.0) and p.report_unit == "ppm/(deg/s)"
    p = ScaleCubic().parameters(ac)[0]
    assert (PPM / G0**2) * p.to_report == pytest.approx(1.0) and p.report_unit == "ppm/(g)^2"
    p = BiasDrift().parameters(ac)[0]
    assert (UG_TO_MS2 / 3600) * p.to_report == pytest.approx(1.0) and p.report_unit == "ug/h"
    assert SizeEffect().parameters(ac)[0].to_report == 1e3


def test_every_registered_effect_documented_and_composable():
    from rimu.calibration import effects as _  # noqa: F401

    m = ErrorModel.base()
    for name, cls in EFFECTS.items():
        assert cls.description and cls.physics, name
        if name == cls.name and cls.name not in m:
            assert getattr(cls, "excited_by", ""), name
            m = m + cls()
    assert len(m) == len({c for c in EFFECTS.values()})
