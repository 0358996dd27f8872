"""The two-IMU Pixhawk CSV of the shared data (``t_s, imu0_gx, ..., imu1_tempC``; rad/s, m/s^2, degC), through
:func:`rimu.io.pixhawk_dual.read_pixhawk_dual`. (Its ``.px4log`` original reads with the ``dataflash`` format.)

>>> sniff("x.csv", b"t_s,imu0_gx,imu0_gy,imu0_gz,imu0_ax")
True
"""

from __future__ import annotations

import os
from typing import Any

from ..multiimu import MultiImuRecording
from ..pixhawk_dual import read_pixhawk_dual

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "pixhawk-csv"
EXTRA = None


def sniff(name: str, head: bytes) -> bool:
    """The header starts ``t_s,imu0_gx``."""
    return head.startswith(b"t_s,imu0_gx")


def read(path: str | os.PathLike[str], gyro_unit: Any = None, accel_unit: Any = None,
         **options: Any) -> MultiImuRecording:
    """Both IMUs in SI (see :mod:`rimu.io.pixhawk_dual`; ``gyro_unit`` / ``accel_unit`` declare other units)."""
    rec = read_pixhawk_dual(path, gyro_unit, accel_unit)
    rec.meta["units_from"] = {
        "gyro": "column names (rad/s, PX4 extraction)" if gyro_unit is None else f"declared ({gyro_unit})",
        "accel": "column names (m/s^2)" if accel_unit is None else f"declared ({accel_unit})"}
    return rec
