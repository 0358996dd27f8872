"""Multi-IMU recordings: the generic CSV reader, one time base from several clocks, the shared real logs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.errors import SessionFormatError, ShapeError
from rimu.io import open_source
from rimu.io.multiimu import MultiImuMapping, read_multi_imu_csv, resample_stream
from rimu.units import DEG_TO_RAD, G0
from tests.conftest import shared_data


def _write_two_clock_unit(d, offset_s=0.0123):
    """IMU a in one file at 100 Hz, IMU b in another with its own clock running ``offset_s`` ahead."""
    t = np.arange(200) * 0.01
    def rate(tt):
        return np.column_stack([np.sin(tt), np.cos(2 * tt), 0.5 * tt])
    with open(d / "a.csv", "w") as fh:
        fh.write("time_ms,gx,gy,gz,ax,ay,az,T\n")
        fh.writelines(f"{float(tk) * 1e3!r},{float(g[0])!r},{float(g[1])!r},{float(g[2])!r},0,0,1,25.0\n" for tk, g in zip(t, rate(t)))
    tb = t[:150] + 0.004                                  # b samples at other instants, stamps + offset
    with open(d / "b.csv", "w") as fh:
        fh.write("time_ms,gx,gy,gz,ax,ay,az,T\n")
        fh.writelines(f"{float(tk + offset_s) * 1e3!r},{float(g[0])!r},{float(g[1])!r},{float(g[2])!r},0,0,1000,\n" for tk, g in zip(tb, rate(tb)))
    mapping = {"time": "time_ms", "time_unit": "ms", "imus": [
        {"name": "a", "file": "a.csv", "gyro": ["gx", "gy", "gz"], "gyro_unit": "deg/s",
         "accel": ["ax", "ay", "az"], "accel_unit": "g", "temperature": "T"},
        {"name": "b", "file": "b.csv", "gyro": ["gx", "gy", "gz"], "gyro_unit": "deg/s",
         "accel": ["ax", "ay", "az"], "accel_unit": "mg"}]}
    (d / "map.json").write_text(json.dumps(mapping))
    return t, rate


def test_generic_reader_units_clocks_and_one_time_base(tmp_path):
    t, rate = _write_two_clock_unit(tmp_path)
    rec = read_multi_imu_csv(tmp_path / "map.json")
    assert rec.names == ["a", "b"] and rec.instruments() == ["gyro", "accel"]
    assert np.allclose(rec["a"].accel[:, 2], G0) and np.allclose(rec["b"].accel[:, 2], G0)
    assert np.allclose(rec["a"].gyro, rate(t) * DEG_TO_RAD)
    block = rec.to_block(offsets_s=[0.0, 0.0123])
    g = block.raw["gyro"]
    ok = block.valid["gyro"][:, 3]
    # b is linearly interpolated at a's instants after its offset is removed: error of linear interpolation
    # of a slowly varying rate (bounded by dt^2/8 max|g''| = 1.25e-5 * 4 deg/s)
    assert ok.sum() == 149 and not ok[0]   # before b's first sample and after its last: invalid
    err = np.abs(g[ok, 3:6] - rate(t[ok]) * DEG_TO_RAD)
    assert err.max() < 1.25e-5 * 4 * DEG_TO_RAD
    assert np.array_equal(g[:, :3], rec["a"].gyro)            # the reference is its own samples, exactly
    assert block.temperature is not None and np.allclose(block.temperature, 25.0)
    geo = rec.geometry()
    assert geo.names[3] == "b_x" and [s.name for s in geo.subunits] == ["a", "b"]


def test_gaps_and_empty_cells_are_invalid_not_interpolated():
    t = np.array([0.0, 1.0, 2.0, 10.0, 11.0])
    y = np.array([[0.0], [1.0], [np.nan], [10.0], [11.0]])
    v, ok = resample_stream(t, y, np.array([0.5, 1.5, 5.0, 10.5, 11.0, 12.0]))
    assert ok.tolist() == [True, False, False, True, True, False]
    assert v[ok, 0].tolist() == [0.5, 10.5, 11.0]


@pytest.mark.parametrize("mapping, words", [
    ({"imus": []}, "at least one IMU"),
    ({"imus": [{"name": "a", "gyro": ["x", "y"]}]}, "three columns"),
    ({"imus": [{"name": "a", "gyro": ["x", "y", "z"], "gyro_unit": "rpm"}]}, "unknown gyro unit"),
    ({"imus": [{"name": "a", "gyro": ["x", "y", "z"]}], "tme": "t"}, "unknown mapping keys"),
    ({"imus": [{"name": "a"}]}, "neither gyro nor accel"),
])
def test_bad_mappings(mapping, words):
    with pytest.raises(SessionFormatError, match=words):
        MultiImuMapping.from_dict(mapping)


def test_bad_files_say_where(tmp_path):
    p = tmp_path / "x.csv"
    m = {"time": "t", "imus": [{"name": "a", "gyro": ["gx", "gy", "gz"]}]}
    p.write_text("t,gx,gy,gz\n0,1,2,3\n0.01,1,zwei,3\n")
    with pytest.raises(SessionFormatError, match="line 3, column 'gy'"):
        read_multi_imu_csv(m, p)
    p.write_text("t,gx,gy\n0,1,2\n")
    with pytest.raises(SessionFormatError, match=r"columns \['gz'\]"):
        read_multi_imu_csv(m, p)
    p.write_text("t,gx,gy,gz\n0,1,2,3\n0,1,2,3\n")
    with pytest.raises(SessionFormatError, match="does not increase"):
        read_multi_imu_csv(m, p)
    p.write_text("t,gx,gy,gz\n0,1,2,3\n0.01,1,2,3\n")
    with pytest.raises(ShapeError, match="one per IMU"):
        read_multi_imu_csv(m, p).to_block(offsets_s=[0.0, 1.0])


def test_pixhawk_dual_flight():
    d = shared_data("pixhawk1_dual_imu_flight")
    src = open_source("pixhawk-dual", path=d)
    rec = src.recording
    assert rec.names == ["imu0", "imu1"] and len(rec["imu0"]) == 5741        # README: 5741 rows, 70.5 s
    assert rec["imu0"].t[-1] == pytest.approx(70.5, abs=0.1)
    block = src.read_block()
    assert block.raw["gyro"].shape == (5741, 6) and block.valid["gyro"].all()
    acc = np.linalg.norm(block.raw["accel"][:700, :3], axis=1)                # still on the ground at first
    assert np.median(acc) == pytest.approx(9.8, abs=0.05)


def test_xsens_dot_runs():
    d = shared_data("quadrotor_4x_xsens_dot")
    rec = open_source("xsens-dot", folder=d / "Horizontal" / "path_10").recording
    assert rec.names == ["imu1", "imu2", "imu3", "imu4"] and rec.meta["own_clocks"]
    assert rec["imu1"].period_s == pytest.approx(1 / 120, rel=1e-3)
    lone = open_source("xsens-dot", folder=d / "Vertical" / "path_30").recording   # only IMU 1 survived
    assert lone.names == ["imu1"]
    slip = open_source("xsens-dot", folder=d / "Horizontal" / "path_11").recording  # one repeated stamp
    assert 4683 in slip.meta["time_repairs"]["imu2"]
    assert np.all(np.diff(slip["imu2"].t) > 0)


def test_mpu6050_clipped_samples_invalid():
    d = shared_data("mpu6050_handheld_session")
    src = open_source("mpu6050-csv", path=d / "calibration_data" / "example_data_calibration.csv")
    rec = src.recording
    assert len(rec.units[0]) == 10245 and rec.units[0].period_s == pytest.approx(0.01)
    assert rec.meta["clipped_samples"] == {"gyro": 18, "accel": 0}              # "a few samples of the moves"
    block = src.read_block()
    assert (~block.valid["gyro"][:, 0]).sum() == rec.meta["clipped_samples"]["gyro"]
    still = np.linalg.norm(block.raw["accel"][:3000], axis=1)                  # 36.5 s at rest at the start
    assert 8.9 < np.median(still) < 11.2
