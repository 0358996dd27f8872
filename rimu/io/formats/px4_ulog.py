"""PX4 ULog flight logs (``.ulg``; pyulog, extra ``ulog``): every ``sensor_gyro`` / ``sensor_accel`` instance, and
the high-rate ``sensor_gyro_fifo`` / ``sensor_accel_fifo`` topics when the log holds them.

Instance ``multi_id`` i is IMU ``imu<i>`` (fifo: ``fifo<i>``): gyro x, y, z [rad/s] and accelerometer x, y, z
[m/s^2] as PX4 logs them (SI by uORB's definition; ``meta["units_from"]`` says so), time ``timestamp_sample``
where logged, else ``timestamp`` [us -> s]. A gyro instance and an accelerometer instance of the same
``multi_id`` are sampled on their own stamps: the accelerometer is interpolated at the gyro's stamps (within one
period, else NaN: rejected as ``unmatched``). A fifo message holds ``samples`` values ``x[k] * scale`` spaced
``dt`` us and ending at ``timestamp_sample``.

Logs without any of these topics (older PX4 logs, and the logging profiles that leave the per-sensor topics
out) are read from ``sensor_combined`` as one IMU, ``combined``: gyro at ``timestamp``, accelerometer at
``timestamp + accelerometer_timestamp_relative`` interpolated to it; PX4 states it in the FRD body frame, calibrated
(``meta["frame"]`` says so).

Axes: PX4 states the per-sensor topics in the FRD board frame (uORB ``SensorGyro``, ``SensorAccel`` and their fifo
messages: each sensor's mounting rotation applied by its driver; the board's ``SENS_BOARD_ROT`` and the sensor
calibration are not). Every instance is in that one frame: ``meta["frame"]`` says so and ``meta["body_frame"]``
is set (a unit set up from the log keeps its triads parallel, as for the autopilots' DataFlash logs).

>>> sniff("flight.ulg", b"ULog\\x01\\x12\\x35\\x01")
True
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..multiimu import ImuStream, MultiImuRecording, resample_stream
from ._open import local_file

__all__ = ["EXTRA", "FRAME", "FRAME_COMBINED", "NAME", "read", "sniff"]

NAME = "ulog"
EXTRA = "ulog"
MAGIC = b"ULog\x01\x12\x35"
TOPICS = ("sensor_gyro", "sensor_accel", "sensor_gyro_fifo", "sensor_accel_fifo", "sensor_combined")
#: the axes of every IMU read (PX4's message definitions)
FRAME = ("FRD board frame (PX4 uORB sensor_gyro/sensor_accel: sensor mounting rotation applied, SENS_BOARD_ROT "
         "and calibration not)")
#: the axes of ``sensor_combined`` (read only when the log holds no per-sensor topic)
FRAME_COMBINED = "FRD body frame (PX4 uORB sensor_combined: the selected IMU, calibrated, board rotation applied)"
#: ``sensor_combined.accelerometer_timestamp_relative`` of an invalid accelerometer sample
RELATIVE_TIMESTAMP_INVALID = 2147483647


def sniff(name: str, head: bytes) -> bool:
    """ULog files start with ``ULog`` 0x01 0x12 0x35."""
    return head.startswith(MAGIC)


def _series(d: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    f = d.data
    if d.name.endswith("_fifo"):
        n = f["samples"].astype(int)
        m = int(n.max()) if len(n) else 0
        if m == 0:
            return np.zeros(0), np.zeros((0, 3)), None
        k = np.arange(m)
        ts = f["timestamp_sample"].astype(float)[:, None] - (n[:, None] - 1 - k) * f["dt"].astype(float)[:, None]
        xyz = np.stack([np.column_stack([f[f"{a}[{j}]"] for j in range(m)]) for a in "xyz"], axis=-1).astype(float)
        xyz = xyz * f["scale"].astype(float)[:, None, None]
        use = k[None, :] < n[:, None]
        return ts[use] * 1e-6, xyz[use], None
    ts = f.get("timestamp_sample", f["timestamp"]).astype(np.float64) * 1e-6
    xyz = np.column_stack([f["x"], f["y"], f["z"]]).astype(float)
    return ts, xyz, (f["temperature"].astype(float) if "temperature" in f else None)


def _combined(d: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gyro stamps [s] and values, accelerometer stamps [s] and values of ``sensor_combined``."""
    f = d.data
    t = f["timestamp"].astype(np.float64)
    g = np.column_stack([f[f"gyro_rad[{j}]"] for j in range(3)]).astype(float)
    rel = f["accelerometer_timestamp_relative"].astype(np.int64)
    ok = rel != RELATIVE_TIMESTAMP_INVALID
    a = np.column_stack([f[f"accelerometer_m_s2[{j}]"] for j in range(3)]).astype(float)
    return t * 1e-6, g, (t[ok] + rel[ok]) * 1e-6, a[ok]


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Every IMU instance of the log (see the module docstring).

    Raises
    ------
    SessionFormatError
        Not a readable ULog file, or no ``sensor_gyro`` / ``sensor_gyro_fifo`` data.
    """
    try:
        from pyulog import ULog
    except ImportError:
        raise ImportError("reading ULog files needs pyulog: pip install 'rimu[ulog]'", name="pyulog") from None
    p = Path(path)
    with local_file(p, ".ulg") as f:
        try:
            ulog = ULog(os.fspath(f), list(TOPICS))
        except Exception as exc:  # pyulog raises bare exceptions on damaged files
            raise SessionFormatError(f"{p}: not a readable ULog file ({type(exc).__name__}); check that it is the "
                                     ".ulg as logged, not truncated") from None
    by: dict[tuple[str, int], dict[str, Any]] = {}
    combined = [d for d in ulog.data_list if d.name == "sensor_combined"]
    for d in ulog.data_list:
        if d.name == "sensor_combined":
            continue
        base = "fifo" if d.name.endswith("_fifo") else "imu"
        inst = "gyro" if "gyro" in d.name else "accel"
        by.setdefault((base, int(d.multi_id)), {})[inst] = d
    units, rejected = [], {}
    series = {key: (_series(parts["gyro"]), parts.get("accel")) for key, parts in sorted(by.items()) if "gyro" in parts}
    frame = FRAME
    if not series and combined:
        t, g, ta, ya = _combined(combined[0])
        series = {("combined", -1): ((t, g, None), (ta, ya))}
        frame = FRAME_COMBINED
    for (base, i), ((t, g, temp), acc) in series.items():
        order = np.argsort(t, kind="stable")
        t, g = t[order], g[order]
        temp = None if temp is None else temp[order]
        keep = np.concatenate([[True], np.diff(t) > 0]) & np.isfinite(g).all(1)
        rej = {"time_not_increasing_or_nonfinite": int((~keep).sum()), "unmatched": 0}
        t, g = t[keep], g[keep]
        temp = None if temp is None else temp[keep]
        a = None
        if acc is not None and len(t) > 1:
            ta, ya = acc if isinstance(acc, tuple) else _series(acc)[:2]
            oa = np.argsort(ta, kind="stable")
            ta, ya = ta[oa], ya[oa]
            ka = np.concatenate([[True], np.diff(ta) > 0])
            if ka.sum() > 1:
                a, ok = resample_stream(ta[ka], ya[ka], t)
                # an accelerometer sample on the gyro's own stamp is taken as it is (sensor_combined logs both in
                # one record: a gap in the log is no reason to refuse the samples on either side of it)
                j = np.clip(np.searchsorted(ta[ka], t), 0, ka.sum() - 1)
                same = ta[ka][j] == t
                a[same], ok[same] = ya[ka][j[same]], True
                a[~ok] = np.nan
                rej["unmatched"] = int((~ok).sum())
        name = base if i < 0 else f"{base}{i}"
        rejected[name] = rej
        units.append(ImuStream(name, t, g, a, temp))
    if not units:
        raise SessionFormatError(f"{p}: no sensor_gyro, sensor_gyro_fifo or sensor_combined data in the log; log "
                                 "the IMU topics (SDLOG_PROFILE) to read it")
    meta = {"format": NAME, "source": str(p), "rejected": rejected,
            "units_from": ({"gyro": "uORB sensor_gyro (rad/s)", "accel": "uORB sensor_accel (m/s^2)"}
                           if frame == FRAME else
                           {"gyro": "uORB sensor_combined (rad/s)", "accel": "uORB sensor_combined (m/s^2)"}),
            "frame": frame, "body_frame": True}
    return MultiImuRecording(units, meta)
