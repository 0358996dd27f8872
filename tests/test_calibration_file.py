"""The versioned calibration file: exact round trip, and refusal of damaged, foreign or unknown files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.calibration.result import FORMAT_VERSION, document_text
from rimu.errors import (
    CalibrationFileError,
    ChecksumError,
    GeometryMismatchError,
    ShapeError,
    UnsupportedVersionError,
)
from rimu.geometry import cone6, dodecahedron6, tetrad4
from rimu.sim import cho_park_table3


def _cal() -> Calibration:
    cal = cho_park_table3(gyro_sigma=0.008, accel_sigma=0.02)
    g = cal["gyro"]
    names = [f"{n}.{p}" for n in g.geometry.names for p in ("scale", "mis_a", "mis_b", "bias")]
    rng = np.random.default_rng(3)
    A = rng.standard_normal((24, 24)) * 1e-4
    g.covariance, g.param_names = A @ A.T, names
    g.effects = {"g_sensitivity": {"x1.gsens_x": 1.25e-4}}
    return cal


def test_round_trip_is_exact(tmp_path):
    cal = _cal()
    p = cal.save(tmp_path / "cal.json")
    back = Calibration.load(p, geometries={"gyro": cone6(), "accel": cone6()})
    for k in ("gyro", "accel"):
        a, b = cal[k], back[k]
        for attr in ("scale", "misalignment", "bias", "noise_sigma"):
            assert np.array_equal(getattr(a, attr), getattr(b, attr)), attr
        assert a.geometry == b.geometry
    assert np.array_equal(cal["gyro"].covariance, back["gyro"].covariance)
    assert back["gyro"].param_names == cal["gyro"].param_names
    assert back["gyro"].effects == cal["gyro"].effects
    assert back.method == cal.method and back.created == cal.created
    assert list(tmp_path.iterdir()) == [p]  # atomic write leaves no temporary file


def test_every_flipped_byte_is_refused(tmp_path):
    cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", tetrad4(), scale=0.01, bias=0.1)})
    p = cal.save(tmp_path / "cal.json")
    data = bytearray(p.read_bytes())
    bad = tmp_path / "bad.json"
    for pos in range(len(data)):
        flipped = bytearray(data)
        flipped[pos] ^= 0x01
        bad.write_bytes(bytes(flipped))
        with pytest.raises(CalibrationFileError):
            Calibration.load(bad)


def test_checksum_error_is_specific(tmp_path):
    p = _cal().save(tmp_path / "cal.json")
    doc = json.loads(p.read_text())
    doc["payload"]["instruments"]["gyro"]["bias"][2] += 1e-9
    p.write_text(json.dumps(doc))
    with pytest.raises(ChecksumError, match="altered or damaged"):
        Calibration.load(p)


def test_wrong_geometry_is_refused(tmp_path):
    p = _cal().save(tmp_path / "cal.json")
    with pytest.raises(GeometryMismatchError, match="belongs to geometry 'cone6'"):
        Calibration.load(p, geometries={"gyro": dodecahedron6()})


def test_unknown_version_is_refused(tmp_path):
    p = _cal().save(tmp_path / "cal.json")
    doc = json.loads(p.read_text())
    p.write_text(document_text(doc["payload"], version=FORMAT_VERSION + 1))
    with pytest.raises(UnsupportedVersionError, match="upgrade rimu"):
        Calibration.load(p)


def test_not_a_calibration_and_edited_geometry(tmp_path):
    p = tmp_path / "x.json"
    p.write_text('{"hello": 1}')
    with pytest.raises(CalibrationFileError, match="not a rimu calibration"):
        Calibration.load(p)
    q = _cal().save(tmp_path / "cal.json")
    doc = json.loads(q.read_text())
    doc["payload"]["instruments"]["gyro"]["geometry"]["H"][0][0] = -doc["payload"]["instruments"]["gyro"]["geometry"]["H"][0][0]
    q.write_text(document_text(doc["payload"]))
    with pytest.raises(CalibrationFileError, match="fingerprint"):
        Calibration.load(q)


def test_coefficient_validation():
    g = cone6()
    with pytest.raises(ShapeError, match="Eq. 10"):
        InstrumentCalibration("gyro", g, np.ones(6), 1.01 * g.nominal_rows(), np.zeros(6))
    with pytest.raises(ShapeError, match="non-finite"):
        InstrumentCalibration("gyro", g, [1, 1, 1, 1, np.inf, 1], g.nominal_rows(), np.zeros(6))
    with pytest.raises(ShapeError, match="shape"):
        InstrumentCalibration("gyro", g, np.ones(6), np.eye(3), np.zeros(6))


def test_calibrated_axes_are_rows_of_MH():
    cal = cho_park_table3()["gyro"]
    g = cal.geometry
    # Cho & Park Eq. 1: M block-diagonal (rows m_i in sub-unit axes), H = [C_SB1; C_SB2]
    M = np.zeros((6, 6))
    M[:3, :3] = cal.misalignment[:3]
    M[3:, 3:] = cal.misalignment[3:]
    Hblk = np.zeros((6, 3))
    Hblk[:3], Hblk[3:] = g.subunits[0].mat_sb_mb, g.subunits[1].mat_sb_mb
    # (M H) row i = m_i^T C_j: with H stacked from the sub-unit DCMs, M H is block-row wise M_j C_j
    MH = np.vstack([cal.misalignment[:3] @ g.subunits[0].mat_sb_mb, cal.misalignment[3:] @ g.subunits[1].mat_sb_mb])
    assert np.allclose(cal.axes_mb(), MH, atol=1e-15)
    assert np.allclose(np.linalg.norm(cal.axes_mb(), axis=1), 1.0)
