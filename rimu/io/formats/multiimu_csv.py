"""Any CSV of several IMUs, described by a column mapping (``--mapping FILE``; the JSON shape of
:mod:`rimu.io.multiimu`): units are declared per IMU in the mapping, never guessed. Never sniffed: a CSV is read
this way when a mapping is given.
"""

from __future__ import annotations

import os
from typing import Any

from ...errors import SessionFormatError
from ..multiimu import MultiImuRecording, read_multi_imu_csv

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "multiimu-csv"
EXTRA = None


def sniff(name: str, head: bytes) -> bool:
    """Never by content: give ``--mapping``."""
    return False


def read(path: str | os.PathLike[str], mapping: Any = None, **options: Any) -> MultiImuRecording:
    """The IMUs the mapping names, in SI."""
    if mapping is None:
        raise SessionFormatError(f"{path}: a generic multi-IMU CSV needs a column mapping: give --mapping FILE "
                                 "(see docs/io.md, 'multi-IMU CSV')")
    rec = read_multi_imu_csv(mapping, path)
    rec.meta["units_from"] = {"gyro": "the mapping", "accel": "the mapping"}
    return rec
