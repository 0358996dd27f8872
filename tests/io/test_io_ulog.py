"""PX4 ULog: a file written here byte by byte after the ULog specification (docs.px4.io, "ULog File Format")
is read back through pyulog as a redundant set of IMU instances."""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("pyulog")

from rimu.io.ulog import ULogSource

FIELDS = "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;float temperature"


def _msg(mtype: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(mtype)) + payload   # message header: uint16 size, uint8 type


def write_ulog(path, streams):
    """streams: list of (topic, multi_id, device_id, t_us array, xyz (N, 3), temperature)."""
    out = bytearray(b"ULog" + bytes([0x01, 0x12, 0x35]) + bytes([1]) + struct.pack("<Q", 0))  # file header
    out += _msg("B", bytes(8) + bytes(8) + bytes(24))          # flag bits: no compat/incompat flags, no appendix
    for topic in sorted({s[0] for s in streams}):
        out += _msg("F", f"{topic}:{FIELDS}".encode())
    for msg_id, (topic, multi, *_rest) in enumerate(streams):
        out += _msg("A", struct.pack("<BH", multi, msg_id) + topic.encode())
    rows = []
    for msg_id, (_topic, _multi, dev, t_us, xyz, temp) in enumerate(streams):
        for k in range(len(t_us)):
            payload = struct.pack("<QQIffff", int(t_us[k]) + 50, int(t_us[k]), dev, *xyz[k], temp)
            rows.append((int(t_us[k]), msg_id, payload))
    for _t, msg_id, payload in sorted(rows, key=lambda r: (r[0], r[1])):
        out += _msg("D", struct.pack("<H", msg_id) + payload)
    path.write_bytes(bytes(out))


def test_three_imus_as_one_redundant_set(tmp_path):
    rng = np.random.default_rng(0)
    n = 200
    t_ref = 1_000_000 + np.arange(n) * 4000                       # 250 Hz, us
    streams = []
    truth = {}
    for inst, topic in (("gyro", "sensor_gyro"), ("accel", "sensor_accel")):
        for i in range(3):
            jitter = rng.integers(-300, 300, n) if i else np.zeros(n, int)
            t = t_ref + jitter
            if inst == "accel" and i == 2:
                t = np.delete(t, [50, 51])                       # instance 2 of the accelerometers drops 2 samples
            xyz = rng.normal(0, 1, (len(t), 3)).astype(np.float32)
            streams.append((topic, i, 1000 + 10 * i + (inst == "accel"), t, xyz, 40.0 + i))
            truth[(inst, i)] = (t, xyz)
    p = tmp_path / "flight.ulg"
    write_ulog(p, streams)
    src = ULogSource(p)
    block = src.read_block()
    assert len(block) == n
    np.testing.assert_allclose(block.t, t_ref * 1e-6)
    assert block.raw["gyro"].shape == (n, 9) and block.raw["accel"].shape == (n, 9)
    for (inst, i), (_t, xyz) in truth.items():
        if inst == "accel" and i == 2:
            keep = np.ones(n, bool)
            keep[[50, 51]] = False
            assert not block.valid["accel"][50:52, 6:9].any()
            np.testing.assert_array_equal(block.raw["accel"][keep, 6:9], xyz.astype(float))
            assert np.all(block.raw["accel"][~keep, 6:9] == 0.0)
        else:
            np.testing.assert_array_equal(block.raw[inst][:, 3 * i:3 * i + 3], xyz.astype(float))
            assert block.valid[inst][:, 3 * i:3 * i + 3].all()
    assert block.temperature[0] == 40.0
    acc = src.accounting
    acc.check()
    assert acc.received == 6 * n - 2 and acc.rejected_total == 0
    g = src.geometry("gyro")
    assert g.n == 9 and len(g.subunits) == 3


def test_unmatched_samples_are_counted(tmp_path):
    n = 50
    t_ref = np.arange(n) * 10_000
    xyz = np.zeros((n, 3), np.float32)
    t_fast = np.arange(2 * n) * 5_000                              # a second gyro at twice the rate
    write_ulog(tmp_path / "f.ulg", [("sensor_gyro", 0, 1, t_ref, xyz, 30.0),
                                     ("sensor_gyro", 1, 2, t_fast, np.ones((2 * n, 3), np.float32), 30.0)])
    src = ULogSource(tmp_path / "f.ulg")
    block = src.read_block()
    assert len(block) == n and block.valid["gyro"].all()
    assert src.accounting.rejected == {"unmatched": n}         # every other sample of the fast gyro
    src.accounting.check()


def test_not_a_ulog(tmp_path):
    from rimu.errors import SessionFormatError

    p = tmp_path / "x.ulg"
    p.write_bytes(b"not a ulog at all")
    with pytest.raises(SessionFormatError):
        ULogSource(p)
