"""The log-format registry and its readers: every IMU instance, at its rate, in SI, checked against the format's
own library (pymavlink, rosbags, pyulog) on logs written by that library or laid out as the format's
documentation says; compressed files read identically; a one-hour 1 kHz 3-IMU log imports in constant memory."""

from __future__ import annotations

import bz2
import gzip
import lzma
import struct
import tracemalloc

import numpy as np
import pytest

from rimu.errors import SessionFormatError
from rimu.io.formats import FORMATS, find_format, format_module, iter_log, read_log
from rimu.io.formats._synth import write_dataflash
from rimu.io.formats.rimu_recording import RecordingWriter, save_recording
from tests.conftest import shared_data

pymavlink = pytest.importorskip("pymavlink.DFReader")


def _motion(t: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray]:
    w = np.column_stack([np.sin(2 * np.pi * 0.7 * t), 0.5 * np.cos(2 * np.pi * 1.3 * t), 0.1 * t]) + 0.01 * i
    a = np.column_stack([0.3 * np.sin(t), 0.2 * np.cos(t), 9.80665 + 0.0 * t]) + 0.02 * i
    return w, a


def _pymavlink_imus(path) -> dict:
    """Every IMU record as pymavlink reads it, one message object at a time: (type, instance) -> rows."""
    r = pymavlink.DFReader_binary(str(path))
    out: dict = {}
    while True:
        m = r.recv_msg()
        if m is None:
            break
        if m.get_type() in ("IMU", "IMU2", "IMU3"):
            key = (m.get_type(), getattr(m, "I", 0))
            t = m.TimeUS * 1e-6 if "TimeUS" in m._fieldnames else m.TimeMS * 1e-3
            temp = m.T if "T" in m._fieldnames else np.nan
            out.setdefault(key, []).append([t, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY, m.AccZ, temp])
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("old_names", [False, True])
def test_dataflash_every_instance_as_pymavlink_reads_it(tmp_path, old_names):
    p = tmp_path / "flight.bin"
    write_dataflash(p, 3, 400.0, 2.0, _motion, old_names=old_names)
    assert find_format(p) == "dataflash"
    rec = read_log(p)
    ref = _pymavlink_imus(p)
    assert rec.names == ["imu0", "imu1", "imu2"] and len(ref) == 3
    keys = sorted(ref, key=lambda k: (k[0], k[1]))
    for u, key in zip(rec.units, keys):
        m = ref[key]
        assert len(u) == len(m) == 800
        np.testing.assert_array_equal(u.t, m[:, 0])
        np.testing.assert_array_equal(u.gyro, m[:, 1:4])
        np.testing.assert_array_equal(u.accel, m[:, 4:7])
        np.testing.assert_array_equal(u.temperature, m[:, 7])
        assert 1.0 / u.period_s == pytest.approx(400.0, rel=1e-9)
    assert rec.meta["units_from"] == {"gyro": "log (FMTU)", "accel": "log (FMTU)"}
    assert rec.meta["garbage_bytes"] == 0 and rec.meta["truncated"] == 0


@pytest.mark.parametrize("layout", ["multiplier", "time_ms"])
def test_dataflash_multipliers_and_the_pre_3_3_time_field(tmp_path, layout):
    """``multiplier``: FMTU states the gyro fields in rad/s times multiplier ``C``, and the log's MULT message gives
    C = 1e-3: pymavlink shows the stored numbers in 'mrad/s' and rimu scales them to rad/s. ``time_ms``: ArduPilot
    before 3.3 (IMU/IMU2/IMU3 stamped TimeMS, no units): every instance read, ms to s, at its rate."""
    p = tmp_path / "flight.bin"
    write_dataflash(p, 3, 200.0, 2.0, _motion, **({"gyro_mult": "C"} if layout == "multiplier" else {"time_ms": True}))
    rec = read_log(p)
    ref = _pymavlink_imus(p)
    assert rec.names == ["imu0", "imu1", "imu2"] and len(ref) == 3
    for i, (u, key) in enumerate(zip(rec.units, sorted(ref))):
        m = ref[key]
        assert len(u) == len(m) == 400 and 1.0 / u.period_s == pytest.approx(200.0, rel=1e-9)
        np.testing.assert_array_equal(u.t, m[:, 0])
        np.testing.assert_array_equal(u.accel, m[:, 4:7])
        gyro_si = m[:, 1:4] * (1e-3 if layout == "multiplier" else 1.0)
        np.testing.assert_allclose(u.gyro, gyro_si, rtol=1e-12)
        # and it is the signal written, in rad/s (to float32 of the log)
        np.testing.assert_allclose(u.gyro, _motion(u.t, i)[0], rtol=1e-6, atol=1e-7)
    if layout == "multiplier":
        fmt = next(f for f in pymavlink.DFReader_binary(str(p)).formats.values() if f.name == "IMU")
        assert fmt.units[fmt.columns.index("GyrX")] == "mrad/s"
        assert rec.meta["units_from"]["gyro"] == "log (FMTU: rad/s x 0.001)"
    else:
        assert rec.meta["units_from"]["gyro"] == "ArduPilot convention (SI)"


def test_dataflash_raw_gyr_acc_messages_at_their_rate(tmp_path):
    """ArduPilot's raw IMU messages (INS_RAW_LOG_OPT): GYR at 1 kHz and ACC at 500 Hz per instance, beside IMU at
    200 Hz. Each instance is read again as raw<I> on the GYR stamps: the gyro as pymavlink reads it, the
    accelerometer as numpy's interp of pymavlink's ACC values at those stamps; the same for any block size (the join
    carries waiting samples across blocks); a gyro sample after the last ACC one keeps its gyro and is counted."""
    from pymavlink import mavutil

    p = tmp_path / "raw.bin"
    write_dataflash(p, 3, 200.0, 2.0, _motion, raw_rate_hz=1000.0)
    rec = read_log(p)
    assert rec.names == ["imu0", "imu1", "imu2", "raw0", "raw1", "raw2"]
    ref: dict = {}
    conn = mavutil.mavlink_connection(str(p))
    while (m := conn.recv_match(type=["GYR", "ACC"])) is not None:
        x = (m.GyrX, m.GyrY, m.GyrZ) if m.get_type() == "GYR" else (m.AccX, m.AccY, m.AccZ)
        ref.setdefault((m.get_type(), m.I), []).append([m.SampleUS * 1e-6, *x])
    small = read_log(p, block=4096)
    for i in range(3):
        u, g, a = rec[f"raw{i}"], np.array(ref[("GYR", i)]), np.array(ref[("ACC", i)])
        assert len(u) == len(g) == 2000 and 1.0 / u.period_s == pytest.approx(1000.0, rel=1e-9)
        np.testing.assert_array_equal(u.t, g[:, 0])
        np.testing.assert_array_equal(u.gyro, g[:, 1:])
        inside = u.t <= a[-1, 0]
        want = np.column_stack([np.interp(u.t[inside], a[:, 0], a[:, j]) for j in (1, 2, 3)])
        np.testing.assert_allclose(u.accel[inside], want, rtol=0, atol=1e-9)
        assert np.isnan(u.accel[~inside]).all()
        assert rec.meta["rejected"][f"raw{i}"]["accel_unmatched"] == int((~inside).sum()) == 1
        v = small[f"raw{i}"]
        np.testing.assert_array_equal(u.t, v.t)
        np.testing.assert_array_equal(u.accel[inside], v.accel[inside])


def test_dataflash_garbage_and_truncation_counted_never_guessed(tmp_path):
    p = tmp_path / "flight.bin"
    write_dataflash(p, 2, 200.0, 1.0)
    data = p.read_bytes()
    clean = read_log(p)
    cut = len(data) // 2
    junk = b"\x00\x01\xa3\x02" * 10
    (tmp_path / "bad.bin").write_bytes(data[:cut] + junk + data[cut:-7])
    rec = read_log(tmp_path / "bad.bin")
    assert rec.meta["garbage_bytes"] >= len(junk) and rec.meta["truncated"] == 1
    for u, c in zip(rec.units, clean.units):
        # every sample read is one of the clean file's, unchanged; at most the two records around each damage lost
        idx = np.searchsorted(c.t, u.t)
        np.testing.assert_array_equal(c.gyro[idx], u.gyro)
        assert len(c) - 2 <= len(u) <= len(c)


def test_dataflash_units_other_than_si_refused(tmp_path):
    p = tmp_path / "flight.bin"
    write_dataflash(p, 1, 100.0, 0.5)
    data = p.read_bytes().replace(b"rad/s", b"deg/s")
    (tmp_path / "deg.bin").write_bytes(data)
    with pytest.raises(SessionFormatError, match="deg/s"):
        read_log(tmp_path / "deg.bin")


def test_px4log_real_flight_matches_its_csv_extraction():
    d = shared_data("pixhawk1_dual_imu_flight", "01_07_59.px4log.xz")
    rec = read_log(d / "01_07_59.px4log.xz")
    csv = read_log(d / "01_07_59_imu01.csv.xz")
    assert rec.names == csv.names == ["imu0", "imu1"]
    for u, c in zip(rec.units, csv.units):
        n = min(len(u), len(c))
        # the CSV was taken out of this log: same values (float32 of the log), time base shifted by its start
        np.testing.assert_allclose(u.gyro[:n], c.gyro[:n], atol=1e-6)
        np.testing.assert_allclose(np.diff(u.t[:n]), np.diff(c.t[:n]), atol=2e-6)
        g = np.linalg.norm(u.accel[:500], axis=1)
        assert abs(np.median(g) - 9.81) < 0.2  # SI: one gravity on the ground


@pytest.mark.parametrize("compress", ["xz", "gz", "bz2", "zst"])
def test_compressed_logs_read_identically(tmp_path, compress):
    p = tmp_path / "flight.bin"
    write_dataflash(p, 2, 100.0, 1.0, _motion)
    raw = p.read_bytes()
    if compress == "zst":
        zstandard = pytest.importorskip("zstandard")
        packed = zstandard.ZstdCompressor().compress(raw)
    else:
        packed = {"xz": lzma.compress, "gz": gzip.compress, "bz2": bz2.compress}[compress](raw)
    q = tmp_path / f"flight.bin.{compress}"
    q.write_bytes(packed)
    assert find_format(q) == "dataflash"
    a, b = read_log(p), read_log(q)
    for u, v in zip(a.units, b.units):
        np.testing.assert_array_equal(u.t, v.t)
        np.testing.assert_array_equal(u.gyro, v.gyro)


def _ros_msg(store, t: float, w: float):
    T = store.types
    return T["sensor_msgs/msg/Imu"](
        header=T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round(
            (t % 1) * 1e9))), frame_id="imu") if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__ else
        T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round((t % 1) * 1e9))),
                                 frame_id="imu"),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
        angular_velocity=T["geometry_msgs/msg/Vector3"](x=w, y=-w, z=0.5 * w), angular_velocity_covariance=np.zeros(9),
        linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.1, z=9.81),
        linear_acceleration_covariance=np.zeros(9))


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap", "bare_mcap"])
def test_ros_bags_one_imu_per_topic(tmp_path, kind):
    """Every Imu topic at its own rate, from each container rosbags writes; ``bare_mcap``: the MCAP file taken out
    of its bag folder (no metadata.yaml), its channels and schemas read from the file itself."""
    pytest.importorskip("rosbags")
    from rosbags.typesys import Stores, get_typestore

    rates = {"/imu0/data": 200.0, "/imu1/data": 100.0}
    msgs = sorted((100 + k / r + 1e-4 * i, topic, 0.01 * k + i)
                  for i, (topic, r) in enumerate(rates.items()) for k in range(int(r)))
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        path = tmp_path / "run.bag"
        with Writer(path) as w:
            conns = {t: w.add_connection(t, "sensor_msgs/msg/Imu", typestore=store) for t in rates}
            for t, topic, v in msgs:
                w.write(conns[topic], int(t * 1e9), store.serialize_ros1(_ros_msg(store, t, v), "sensor_msgs/msg/Imu"))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        store = get_typestore(Stores.ROS2_HUMBLE)
        path = tmp_path / "run2"
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        with Writer(path, version=9, storage_plugin=plugin) as w:
            conns = {t: w.add_connection(t, "sensor_msgs/msg/Imu", typestore=store) for t in rates}
            for t, topic, v in msgs:
                w.write(conns[topic], int(t * 1e9), store.serialize_cdr(_ros_msg(store, t, v), "sensor_msgs/msg/Imu"))
        if kind == "bare_mcap":
            (tmp_path / "alone").mkdir()
            path = (path / "run2.mcap").rename(tmp_path / "alone" / "run.mcap")
    assert find_format(path) == "rosbag"
    rec = read_log(path)
    assert rec.names == ["imu0_data", "imu1_data"]
    assert rec.meta["frames"] == {"imu0_data": "header.frame_id 'imu'", "imu1_data": "header.frame_id 'imu'"}
    for i, (u, r) in enumerate(zip(rec.units, rates.values())):
        assert len(u) == int(r) and 1.0 / u.period_s == pytest.approx(r, rel=1e-6)
        np.testing.assert_allclose(u.gyro[:, 0], 0.01 * np.arange(int(r)) + i)
        np.testing.assert_allclose(u.accel[:, 2], 9.81)
    if kind == "bare_mcap":  # compressed as well: decompressed to a temporary file, read alike
        xz = path.with_name("run.mcap.xz")
        xz.write_bytes(lzma.compress(path.read_bytes()))
        for u, v in zip(rec.units, read_log(xz).units):
            np.testing.assert_array_equal(u.t, v.t)
            np.testing.assert_array_equal(u.gyro, v.gyro)


def _ulog(*sections: tuple[str, bytes]) -> bytes:
    """A ULog file as its documentation lays it out: header (version 1, timestamp 0), the flag-bits message, then
    ``(kind, payload)`` messages in order (``F`` format, ``A`` subscription, ``D`` data)."""
    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0))
    for kind, payload in (("B", bytes(40)), *sections):
        out.extend(struct.pack("<HB", len(payload), ord(kind)) + payload)
    return bytes(out)


def _ulog_bytes(instances: int, n: int, rate: float) -> bytes:
    """``instances`` sensor_gyro / sensor_accel pairs, ``n`` samples each at ``rate``."""
    msgs = [("F", f"{topic}:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;"
                  "float temperature;".encode()) for topic in ("sensor_gyro", "sensor_accel")]
    ids = {}
    for i in range(instances):
        for j, topic in enumerate(("sensor_gyro", "sensor_accel")):
            ids[(topic, i)] = mid = 2 * i + j
            msgs.append(("A", struct.pack("<BH", i, mid) + topic.encode()))
    for k in range(n):
        for i in range(instances):
            ts = int(round(1e6 * k / rate)) + 50 * i
            msgs.append(("D", struct.pack("<HQQIffff", ids[("sensor_gyro", i)], ts + 100, ts, 7 + i, 0.1 * i, 0.01 * k,
                                          -0.2, 30.0 + i)))
            msgs.append(("D", struct.pack("<HQQIffff", ids[("sensor_accel", i)], ts + 100, ts, 9 + i, 0.0, 0.1 * i,
                                          9.8, 31.0)))
    return _ulog(*msgs)


def test_ulog_every_instance(tmp_path, capsys):
    pytest.importorskip("pyulog")
    import json

    from rimu.cli import main
    from rimu.io.formats.px4_ulog import FRAME

    p = tmp_path / "flight.ulg"
    p.write_bytes(_ulog_bytes(3, 250, 250.0))
    assert find_format(p) == "ulog"
    rec = read_log(p)
    assert rec.names == ["imu0", "imu1", "imu2"]
    for i, u in enumerate(rec.units):
        assert len(u) == 250 and 1.0 / u.period_s == pytest.approx(250.0, rel=1e-6)
        np.testing.assert_allclose(u.gyro[:, 0], 0.1 * i, rtol=1e-6)
        np.testing.assert_allclose(u.gyro[:, 1], 0.01 * np.arange(250), rtol=1e-6)
        np.testing.assert_allclose(u.accel[:, 2], 9.8, rtol=1e-6)
    # the axes as PX4's message definitions state them, in the recording and in rimu import's summary
    assert rec.meta["frame"] == FRAME and FRAME.startswith("FRD board frame") and rec.meta["body_frame"] is True
    assert main(["import", str(p), "-o", str(tmp_path / "rec.npz"), "--json", str(tmp_path / "s.json"),
                 "--accept-implausible"]) == 0
    assert f"axes: {FRAME}" in capsys.readouterr().out
    doc = json.loads((tmp_path / "s.json").read_text())
    assert [imu["frame"] for imu in doc["imus"]] == [FRAME] * 3
    assert read_log(tmp_path / "rec.npz").meta["frame"] == FRAME


def _ulog_combined_bytes(stamps: list[int], invalid: tuple[int, ...] = ()) -> bytes:
    """A ULog holding only ``sensor_combined`` at ``stamps`` [us] (gyro x = 0.001 k rad/s, accel z = 9.8 m/s^2;
    the records ``invalid`` mark their accelerometer sample invalid, as PX4 does)."""
    from rimu.io.formats.px4_ulog import RELATIVE_TIMESTAMP_INVALID

    msgs = [("F", b"sensor_combined:uint64_t timestamp;float[3] gyro_rad;uint32_t gyro_integral_dt;"
                  b"int32_t accelerometer_timestamp_relative;float[3] accelerometer_m_s2;"
                  b"uint32_t accelerometer_integral_dt;"),
            ("A", struct.pack("<BH", 0, 0) + b"sensor_combined")]
    for k, ts in enumerate(stamps):
        rel = RELATIVE_TIMESTAMP_INVALID if k in invalid else 0
        msgs.append(("D", struct.pack("<HQfffIifffI", 0, ts, 0.001 * k, 0.0, -0.01, 4000, rel, 0.1, 0.0, 9.8, 4000)))
    return _ulog(*msgs)


def test_ulog_without_per_sensor_topics_reads_sensor_combined(tmp_path):
    """Older PX4 logs hold only sensor_combined: one IMU ``combined`` in PX4's FRD body frame, the accelerometer at
    ``timestamp + accelerometer_timestamp_relative``; a gap in the log (here 40 ms) costs no sample around it."""
    pytest.importorskip("pyulog")
    from rimu.io.formats.px4_ulog import FRAME_COMBINED

    stamps = [1_000_000 + 4000 * k for k in range(100)] + [1_440_000 + 4000 * k for k in range(100)]
    p = tmp_path / "old.ulg"
    p.write_bytes(_ulog_combined_bytes(stamps, invalid=(150,)))
    rec = read_log(p)
    assert rec.names == ["combined"] and rec.meta["frame"] == FRAME_COMBINED
    u = rec["combined"]
    assert len(u) == 200
    np.testing.assert_allclose(u.t, np.array(stamps) * 1e-6)
    np.testing.assert_allclose(u.gyro[:, 0], 0.001 * np.arange(200), rtol=1e-6)
    valid = np.isfinite(u.accel).all(axis=1)
    # every accelerometer sample kept but the one PX4 marked invalid (interpolated across it: within 2.5 periods)
    assert valid.sum() == 200 and u.accel[150, 2] == pytest.approx(9.8, rel=1e-6)
    np.testing.assert_allclose(u.accel[valid, 2], 9.8, rtol=1e-6)


def test_text_log_without_units_is_refused_with_units_converted(tmp_path):
    p = tmp_path / "log.txt"
    p.write_text("t ax ay az gx gy gz\n" + "".join(f"{k / 100} 0 0 1 0 0 {k}\n" for k in range(50)))
    assert find_format(p) == "text"
    with pytest.raises(SessionFormatError, match="declare gyro_unit and accel_unit"):
        read_log(p)
    rec = read_log(p, gyro_unit="deg/s", accel_unit="g")
    assert rec.units[0].accel[0, 2] == pytest.approx(9.80665)
    assert rec.units[0].gyro[10, 2] == pytest.approx(np.deg2rad(10))


def test_recording_file_round_trip_and_registry_names(tmp_path):
    p = tmp_path / "flight.bin"
    write_dataflash(p, 2, 100.0, 1.0, _motion)
    rec = read_log(p)
    out = save_recording(rec, tmp_path / "rec.npz")
    assert find_format(out) == "rimu"
    back = read_log(out)
    assert back.names == rec.names and back.meta["format"] == "dataflash"
    for u, v in zip(rec.units, back.units):
        np.testing.assert_array_equal(u.accel, v.accel)
    for name in FORMATS:
        assert format_module(name).NAME  # every registered module imports and names itself
    with pytest.raises(SessionFormatError, match="no log format named"):
        format_module("nope")


def test_one_hour_three_imus_at_1khz_imports_in_constant_memory(tmp_path):
    """3 IMUs x 3.6e6 samples (604 MB in SI float64) through the streaming reader and the recording writer."""
    zstandard = pytest.importorskip("zstandard")
    import pymavlink.DFReader  # noqa: F401  (imported before tracing: the import is not the reader's memory)

    p = tmp_path / "hour.bin.zst"
    n = write_dataflash(p, 3, 1000.0, 3600.0, block=100_000,
                        opener=lambda f, m: zstandard.ZstdCompressor(level=1).stream_writer(open(f, m)))
    assert n == 3 * 3_600_000
    w = RecordingWriter(tmp_path / "hour.npz")
    tracemalloc.start()
    try:
        for piece in iter_log(p):
            w.add(piece)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    w.close({})
    assert w.counts == {"imu0": 3_600_000, "imu1": 3_600_000, "imu2": 3_600_000}
    assert peak < 80e6, f"peak {peak / 1e6:.0f} MB while importing"
    z = np.load(tmp_path / "hour.npz", mmap_mode="r")
    assert z["2.t"][-1] == pytest.approx(3599.999 + 74e-6)


def test_ulog_fifo_topics_unpacked_at_their_full_rate(tmp_path):
    """sensor_gyro_fifo / sensor_accel_fifo: ``samples`` int16 values times ``scale``, ``dt`` us apart, the last at
    ``timestamp_sample`` (PX4's message definition)."""
    pytest.importorskip("pyulog")
    msgs = [("F", f"{topic}:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float dt;float scale;"
                  "uint8_t samples;int16_t[32] x;int16_t[32] y;int16_t[32] z;".encode())
            for topic in ("sensor_gyro_fifo", "sensor_accel_fifo")]
    msgs += [("A", struct.pack("<BH", 0, 0) + b"sensor_gyro_fifo"), ("A", struct.pack("<BH", 0, 1) + b"sensor_accel_fifo")]
    per, dt = 4, 250.0
    for k in range(50):
        ts = 1000 + int(k * per * dt)
        for mid, scale in ((0, 0.001), (1, 0.01)):
            body = struct.pack("<HQQIffB", mid, ts + 5, ts + int((per - 1) * dt), 3, dt, scale, per)
            body += struct.pack("<32h", *([k * per + j for j in range(per)] + [0] * (32 - per)))
            body += struct.pack("<32h", *([1] * 32)) + struct.pack("<32h", *([980] * 32))
            msgs.append(("D", body))
    p = tmp_path / "fifo.ulg"
    p.write_bytes(_ulog(*msgs))
    rec = read_log(p)
    u = rec["fifo0"]
    assert len(u) == 200 and 1.0 / u.period_s == pytest.approx(4000.0)
    np.testing.assert_allclose(u.gyro[:, 0], 0.001 * np.arange(200), atol=1e-9)
    np.testing.assert_allclose(u.accel[:, 2], 9.8, rtol=1e-6)
    np.testing.assert_allclose(u.t[:2], [1000e-6, 1250e-6])


def test_text_log_of_several_triads_reads_one_imu_per_triad(tmp_path):
    """A table of two triads side by side (g0x g0y g0z g1x ...) is two IMUs with their own columns, each converted
    from the declared units; columns that do not form whole triads are refused with the way to map them."""
    rng = np.random.default_rng(3)
    t = np.arange(200) / 100.0
    g = rng.normal(0, 5.0, (200, 6))        # deg/s
    a = rng.normal(0, 0.01, (200, 6)) + np.tile([0, 0, 1.0], 2)   # g
    head = "t," + ",".join(f"g{j}{x}" for j in range(2) for x in "xyz") + "," + \
        ",".join(f"a{j}{x}" for j in range(2) for x in "xyz")
    np.savetxt(tmp_path / "two.csv", np.column_stack([t, g, a]), delimiter=",", header=head, comments="", fmt="%.8f")
    rec = read_log(tmp_path / "two.csv", gyro_unit="deg/s", accel_unit="g")
    assert rec.names == ["imu0", "imu1"]
    for j in range(2):
        np.testing.assert_allclose(rec[f"imu{j}"].gyro, np.radians(g[:, 3 * j:3 * j + 3]), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(rec[f"imu{j}"].accel, 9.80665 * a[:, 3 * j:3 * j + 3], rtol=1e-6, atol=1e-7)
    np.savetxt(tmp_path / "odd.csv", np.column_stack([t, g[:, :4], a[:, :3]]), delimiter=",", comments="",
               header="t,g0x,g0y,g0z,g1x,a0x,a0y,a0z", fmt="%.8f")
    with pytest.raises(SessionFormatError, match="mapping"):
        read_log(tmp_path / "odd.csv", gyro_unit="deg/s", accel_unit="g")


def test_plausibility_check_skips_invalid_samples_at_rest():
    """A NaN accelerometer row is an invalid sample: the gravity check at the door measures the rest, not NaN (it
    refused a whole ULog with 'magnitude nan m/s^2'); counts taken as m/s^2 are still refused."""
    from rimu.cli._inputs import check_recording
    from rimu.io.multiimu import ImuStream, MultiImuRecording

    rng = np.random.default_rng(1)
    t = np.arange(2000) / 200.0
    g = 1e-3 * rng.standard_normal((2000, 3))
    a = np.array([0.0, 0.0, 9.81]) + 0.01 * rng.standard_normal((2000, 3))
    a[::37] = np.nan
    assert check_recording(MultiImuRecording([ImuStream("imu0", t, g, a)]), "x") == []
    found = check_recording(MultiImuRecording([ImuStream("imu0", t, g, a * 1000 / 9.81)]), "x")
    assert found and "imu0: accel" in found[0].message
