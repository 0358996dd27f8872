"""Xsens DOT exports: a run folder of ``IMU_<k>.csv[.xz]`` (one unit per file, own clocks) or a folder of the
untrimmed ``Xsens_DOT<k>_<address>_...csv[.xz]`` exports (one synchronised clock), through
:mod:`rimu.io.xsens_dot`. Gyro deg/s and accelerometer m/s^2 as the export's columns ``Gyr_*``/``Acc_*`` state.

>>> sniff("not/a/folder", b"")
False
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from ..multiimu import MultiImuRecording
from ..xsens_dot import read_xsens_dot_raw, read_xsens_dot_run

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "xsens-dot"
EXTRA = None
_RUN = re.compile(r"^IMU_\d+\.csv(\.xz|\.gz|\.bz2|\.zst)?$")
_RAW = re.compile(r"^Xsens_DOT\d+_.*\.csv(\.xz|\.gz|\.bz2|\.zst)?$")


def _kind(p: Path) -> str | None:
    if not p.is_dir():
        return None
    names = [f.name for f in p.iterdir()]
    if any(_RUN.match(n) for n in names):
        return "run"
    if any(_RAW.match(n) for n in names):
        return "raw"
    return None


def sniff(name: str, head: bytes) -> bool:
    """A folder holding ``IMU_<k>.csv`` or ``Xsens_DOT<k>_*.csv`` files."""
    return _kind(Path(name)) is not None


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Every unit of the folder (``imu<k>`` of a run, ``dot<k>`` of the raw exports)."""
    p = Path(path)
    rec = read_xsens_dot_raw(p) if _kind(p) == "raw" else read_xsens_dot_run(p)
    rec.meta["units_from"] = {"gyro": "export columns Gyr_* (deg/s)", "accel": "export columns Acc_* (m/s^2)"}
    return rec
