"""Plausibility checks at the session boundary (rimu.session.checks): the declared unit against gravity and the
commanded table rates, sample_rate_hz against the time column, dead columns; monotonic time in NPZ; atomic,
normal-mode writes."""

from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest

from rimu.errors import PlausibilityError, SessionFormatError
from rimu.session import load_session, save_session
from rimu.session.checks import check_session, raw_unit_of
from rimu.units import G0, RAD_TO_DEG

from .sessions import si_session


def _errors(session):
    return [f for f in check_session(session) if f.level == "error"]


def test_consistent_units_pass():
    assert check_session(si_session(raw_unit="count")) == []           # counts: nothing to compare
    assert check_session(si_session(raw_unit={"accel": "m/s^2", "gyro": "rad/s"})) == []
    s = si_session(accel_factor=1 / G0, gyro_factor=RAD_TO_DEG, raw_unit={"accel": "g", "gyro": "deg/s"})
    assert check_session(s) == []


def test_accelerometer_in_m_s2_declared_in_g_is_named(tmp_path):
    s = si_session(raw_unit={"accel": "g", "gyro": "rad/s"})
    (f,) = _errors(s)
    assert f.check == "units" and f.where == "accel_*"
    assert "declared in 'g'" in f.message and "look like m/s^2" in f.message
    # the magnitude shown is gravity in m/s^2, read as g
    assert "9.81 g" in f.message
    path = save_session(s, tmp_path / "a.csv")
    with pytest.raises(PlausibilityError, match="accel_.*look like m/s\\^2.*--accept-implausible"):
        load_session(path)


def test_gyro_in_deg_s_declared_in_rad_s_is_named():
    s = si_session(gyro_factor=RAD_TO_DEG, raw_unit={"accel": "m/s^2", "gyro": "rad/s"})
    (f,) = _errors(s)
    assert f.where == "gyro_*" and "look like deg/s" in f.message
    # 57.3 = the ratio of the two units, measured on the rate segments
    assert "57.3 times" in f.message


def test_milli_g_declared_as_g():
    s = si_session(accel_factor=1000 / G0, raw_unit={"accel": "g", "gyro": "rad/s"})
    (f,) = _errors(s)
    assert "look like mg" in f.message


def test_a_modest_mismatch_warns_without_refusing(caplog):
    # a 30% scale on the declared unit: implausible but possible (a gross calibration error); a warning
    s = si_session(accel_factor=1.3, raw_unit={"accel": "m/s^2", "gyro": "rad/s"})
    found = check_session(s)
    assert [f.level for f in found] == ["warning"]


def test_sample_rate_against_time_column(tmp_path, caplog):
    assert check_session(si_session(fs=100.0, dt=1 / 100.4)) == []      # 0.4%: clock tolerance
    (w,) = check_session(si_session(fs=100.0, dt=1 / 102.0))            # 2%: warning
    assert w.level == "warning" and w.where == "sample_rate_hz"
    (e,) = check_session(si_session(fs=200.0, dt=1 / 100.0))            # a factor 2: refused
    assert e.level == "error" and "100 Hz" in e.message and "-50.0%" in e.message
    (ms,) = check_session(si_session(fs=100.0, dt=10.0))                # time column in milliseconds
    assert "milliseconds" in ms.message
    path = save_session(si_session(fs=200.0, dt=1 / 100.0), tmp_path / "r.npz")
    with pytest.raises(PlausibilityError, match="sample_rate_hz is 200 Hz"):
        load_session(path)
    with caplog.at_level(logging.WARNING, logger="rimu"):
        s = load_session(path, checks="warn")                          # the explicit override
    assert s.sample_rate == 200.0 and "sample_rate_hz is 200 Hz" in caplog.text
    assert load_session(path, checks="off").sample_rate == 200.0


def test_dead_column_is_named(tmp_path):
    s = si_session()
    for seg in s.segments:
        seg.raw["gyro"][:, 2] = 0.0
    (f,) = _errors(s)
    assert f.check == "constant" and "gyro_z1" in f.message
    s = si_session()
    for seg in s.segments:  # an axis the session never excites (no rate along z): noise-free data may be constant
        seg.raw["gyro"][:, 2] = 0.25
        if seg.kind == "rate" and abs(seg.rate_mb @ s.geometries["gyro"].H[2]) > 0:
            seg.rate_mb = seg.rate_mb - (seg.rate_mb @ s.geometries["gyro"].H[2]) * s.geometries["gyro"].H[2]
    assert [(f.check, f.level) for f in check_session(s) if f.check == "constant"] == [("constant", "warning")]


def test_npz_time_running_backwards_is_refused_whatever_the_mode(tmp_path):
    path = save_session(si_session(), tmp_path / "s.npz")
    z = dict(np.load(path))
    z["t"] = z["t"].copy()
    z["t"][[50, 51]] = z["t"][[51, 50]]
    np.savez(path, **z)
    for mode in ("strict", "warn", "off"):
        with pytest.raises(SessionFormatError, match=r"t\[51\].*does not increase.*segment 'P0'"):
            load_session(path, checks=mode)


def test_npz_nonfinite_time_and_bad_segment_index(tmp_path):
    path = save_session(si_session(), tmp_path / "s.npz")
    z = dict(np.load(path))
    bad = dict(z, t=np.where(np.arange(len(z["t"])) == 7, np.nan, z["t"]))
    np.savez(tmp_path / "nan.npz", **bad)
    with pytest.raises(SessionFormatError, match=r"t\[7\] is not finite"):
        load_session(tmp_path / "nan.npz")
    np.savez(tmp_path / "seg.npz", **dict(z, segment=z["segment"] + 0.5))
    with pytest.raises(SessionFormatError, match="integer indices"):
        load_session(tmp_path / "seg.npz")


def test_raw_unit_per_instrument_round_trips(tmp_path):
    s = si_session(accel_factor=1 / G0, raw_unit={"accel": "g", "gyro": "rad/s"})
    for name in ("u.csv", "u.npz"):
        back = load_session(save_session(s, tmp_path / name))
        assert raw_unit_of(back, "accel") == "g" and raw_unit_of(back, "gyro") == "rad/s"
    side = json.loads((tmp_path / "u.json").read_text())
    assert side["raw_unit"] == {"accel": "g", "gyro": "rad/s"} or side["meta"]["raw_units"] == {"accel": "g",
                                                                                                   "gyro": "rad/s"}


def test_writes_are_atomic_with_normal_modes(tmp_path, monkeypatch):
    from rimu.calibration import Calibration, InstrumentCalibration
    from rimu.geometry import cone6

    old = os.umask(0o022)
    try:
        cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), 0.01)})
        p = cal.save(tmp_path / "cal.json")
        assert (p.stat().st_mode & 0o777) == 0o644          # not mkstemp's 0600
        s = save_session(si_session(), tmp_path / "s.csv")
        assert (s.stat().st_mode & 0o777) == 0o644 and (tmp_path / "s.json").stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(old)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["cal.json", "s.csv", "s.json"]  # no temporary left


def test_interrupted_session_write_leaves_nothing(tmp_path, monkeypatch):
    """Ctrl-C in the middle of writing the CSV: neither the CSV nor its sidecar appear, an older file of that
    name is untouched, no temporary file is left."""
    s = si_session()
    path = tmp_path / "s.csv"
    path.write_text("old content\n")
    calls = {"n": 0}
    real = np.hstack

    def hstack(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:  # after two segments have been written
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(np, "hstack", hstack)
    with pytest.raises(KeyboardInterrupt):
        save_session(s, path)
    assert path.read_text() == "old content\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.csv"]


def test_parallel_triads_mounted_apart_pass_at_rest_and_a_wrong_unit_is_still_named():
    """Three triads declared parallel but mounted 0, 60 and 120 degrees apart about x, still under gravity in m/s^2:
    through the unit's H^+ their mean reads 2/3 g (a units warning on the NaveGo board set up with --parallel); each
    triad on its own reads 1 g, so nothing is found. The same outputs declared in g are still named as m/s^2."""
    from rimu.geometry import triads
    from rimu.session import Segment, Session

    rng = np.random.default_rng(0)
    ys = []
    for ang in np.radians([0.0, 60.0, 120.0]):
        c, s = np.cos(ang), np.sin(ang)
        R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        ys.append(R.T @ np.array([0.0, 0.0, G0]))
    y = np.tile(np.concatenate(ys), (200, 1)) + 0.01 * rng.standard_normal((200, 9))
    geo = triads(3)
    assert abs(np.linalg.norm(np.linalg.pinv(geo.H) @ y.mean(axis=0)) / G0 - 2 / 3) < 0.01   # the old measure
    seg = Segment("rest", "static_unknown", np.arange(200) / 100.0, {"accel": y})
    assert check_session(Session([seg], {"accel": geo}, 100.0, raw_unit="m/s^2"), "board") == []
    found = check_session(Session([seg], {"accel": geo}, 100.0, raw_unit="g"), "board")
    assert [f.check for f in found] == ["units"] and "m/s^2" in found[0].message
