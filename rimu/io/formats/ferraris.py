"""imucal's Ferraris calibration folder (``example_ferraris_session.csv`` and its ``_list.json`` of sections) as a
recording: the one triad's samples, every row of the file at 102.4 Hz (the rate imucal's example states). Its calibration session (the sections with their known inputs) is
:func:`rimu.session.load_ferraris`, which the commands use for this folder.

Units: the file's gyro columns are deg/s, its accelerometer columns m/s^2 (imucal's example; see the loader).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..multiimu import MultiImuRecording, read_multi_imu_csv

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "ferraris"
EXTRA = None
CSV = "example_ferraris_session.csv"
SECTIONS = "example_ferraris_session_list.json"


def sniff(name: str, head: bytes) -> bool:
    """A folder with imucal's two Ferraris files."""
    p = Path(name)
    return p.is_dir() and (p / CSV).exists() and (p / SECTIONS).exists()


def read(path: str | os.PathLike[str], sample_rate_hz: float = 102.4, **options: Any) -> MultiImuRecording:
    """The triad ``imu0`` in SI (gyro deg/s -> rad/s), every row of the file at ``sample_rate_hz``."""
    p = Path(path)
    mapping = {"time": None, "sample_rate_hz": sample_rate_hz,
               "imus": [{"name": "imu0", "gyro": ["gyr_x", "gyr_y", "gyr_z"], "gyro_unit": "deg/s",
                         "accel": ["acc_x", "acc_y", "acc_z"], "accel_unit": "m/s^2"}]}
    rec = read_multi_imu_csv(mapping, p / CSV)
    rec.meta.update({"format": NAME, "source": str(p), "folder": str(p),
                     "units_from": {"gyro": "imucal example (deg/s)", "accel": "imucal example (m/s^2)",
                                    "sample_rate": f"imucal example ({sample_rate_hz:g} Hz)"}})
    return rec
