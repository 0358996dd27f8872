"""Real logs that are not in ../shared/data (ArduPilot DataFlash, ROS 1/2 bags, bare MCAP, PX4 ULog): every IMU
instance each holds, at its rate, in SI, checked against the format's own library reading the same file one message
at a time (pymavlink, rosbags, pyulog) and against one gravity at rest.

The files are public third-party data and are not part of the repository: put them in a folder (any layout; the
logs docs/io.md lists, or others) and point ``RIMU_EXTERNAL_LOGS`` at it. Without it the test skips.

    RIMU_EXTERNAL_LOGS=/tmp/rimu-ext python -m pytest tests/io/test_external_logs.py
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rimu.io.formats import read_log

ENV = "RIMU_EXTERNAL_LOGS"


def _logs() -> list[Path]:
    base = os.environ.get(ENV)
    if not base or not Path(base).is_dir():
        return []
    out = []
    for p in sorted(Path(base).rglob("*")):
        if p.is_dir() and (p / "metadata.yaml").exists():
            out.append(p)  # a ROS 2 bag folder
        elif p.is_file() and (p.parent / "metadata.yaml").exists():
            continue  # a file of such a folder
        elif p.is_file() and p.suffix.lower() in (".bin", ".bag", ".mcap", ".ulg") and p.stat().st_size > 0:
            out.append(p)
    return out


def _reference(p: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Stamps [s] and accelerometer [m/s^2] per IMU, read with the format's library one message at a time."""
    out: dict[str, list[list[float]]] = {}
    if p.suffix.lower() == ".bin":
        from pymavlink import mavutil

        conn = mavutil.mavlink_connection(str(p))
        while (m := conn.recv_match(type=["IMU", "IMU2", "IMU3"])) is not None:
            fields = m.get_fieldnames()
            t = m.TimeUS * 1e-6 if "TimeUS" in fields else m.TimeMS * 1e-3
            key = f"{m.get_type()}[{m.I if 'I' in fields else 0}]"
            out.setdefault(key, []).append([t, m.AccX, m.AccY, m.AccZ])
    elif p.suffix.lower() == ".ulg":
        from pyulog import ULog

        ulog = ULog(str(p), ["sensor_accel", "sensor_combined", "sensor_gyro"])
        gyro = {d.multi_id for d in ulog.data_list if d.name == "sensor_gyro"}
        for d in ulog.data_list:
            f = d.data
            if d.name == "sensor_accel" and d.multi_id in gyro:
                # rimu's samples are the gyro's; the accelerometer's count is the reference for its rate only
                out[f"accel[{d.multi_id}]"] = np.column_stack(
                    [f.get("timestamp_sample", f["timestamp"]) * 1e-6, f["x"], f["y"], f["z"]]).tolist()
            elif d.name == "sensor_combined" and not gyro:
                out["combined"] = np.column_stack([f["timestamp"] * 1e-6] + [
                    f[f"accelerometer_m_s2[{j}]"] for j in range(3)]).tolist()
    else:
        from rosbags.highlevel import AnyReader
        from rosbags.rosbag2.storage_mcap import McapReader
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE)
        if p.suffix == ".mcap":  # a bare MCAP file: rosbags' MCAP storage reader
            r = McapReader(p)
            r.open()
            msgs = ((c, store.deserialize_cdr(raw, c.msgtype)) for c, _, raw in r.messages(
                [c for c in r.connections if c.msgtype == "sensor_msgs/msg/Imu"]))
        else:
            r = AnyReader([p], default_typestore=store)
            r.open()
            msgs = ((c, r.deserialize(raw, c.msgtype)) for c, _, raw in r.messages(
                connections=[c for c in r.connections if c.msgtype in ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")]))
        for c, m in msgs:
            a = m.linear_acceleration
            out.setdefault(c.topic, []).append([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, a.x, a.y, a.z])
        r.close()
    return {k: (np.array(v)[:, 0], np.array(v)[:, 1:]) for k, v in sorted(out.items())}


LOGS = _logs()


@pytest.mark.parametrize("log", LOGS or [None], ids=[p.name for p in LOGS] or ["none"])
def test_external_log_every_instance_at_its_rate_in_si(log):
    if log is None:
        pytest.skip(f"no external logs: set {ENV} to a folder of them (docs/io.md lists the ones checked)")
    pytest.importorskip("pymavlink")
    pytest.importorskip("rosbags")
    from rimu.cli._inputs import check_recording

    rec = read_log(log)
    ref = _reference(log)
    assert len(rec.units) == len(ref), (rec.names, list(ref))
    for u, (key, (t, acc)) in zip(rec.units, ref.items()):
        # the same samples as the library reads (the ULog's gyro-stamped IMUs: at the accelerometer's own rate)
        if not key.startswith("accel["):
            assert len(u) == len(t), (u.name, key)
            np.testing.assert_allclose(u.t, t, rtol=0, atol=1e-6)
            np.testing.assert_allclose(u.accel, acc, rtol=1e-6, atol=1e-6)
        rate = (len(t) - 1) / (t[-1] - t[0])
        assert (len(u) - 1) / (u.t[-1] - u.t[0]) == pytest.approx(rate, rel=0.02), (u.name, key)
        # SI: one gravity (+-5 %, uncalibrated consumer sensors) over the quietest second
        n = max(2, int(round(1.0 / u.period_s)))
        norm = np.linalg.norm(u.accel, axis=1)
        w = np.linalg.norm(np.nan_to_num(u.gyro), axis=1)
        j = int(np.argmin(np.convolve(w, np.ones(n) / n, "valid"))) if len(u) > n else 0
        assert 9.81 * 0.95 < np.nanmean(norm[j:j + n]) < 9.81 * 1.05, (u.name, np.nanmean(norm[j:j + n]))
    assert not [f for f in check_recording(rec, str(log)) if f.level == "error"]
