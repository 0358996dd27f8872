"""Raw MPU-6050 logs with a metadata header (``Fs,100`` then ``ax,ay,az,gx,gy,gz`` int16 counts; the hand-held
session of the shared data), through :func:`rimu.io.mpu6050_csv.read_mpu6050_csv`: the sample rate is the file's
``Fs``; counts are converted to SI with the chip's nominal scales for the declared ranges (options
``accel_lsb_per_g``, default 16384: +-2 g; ``gyro_lsb_per_dps``, default 131: +-250 deg/s); clipped samples are
invalid.

>>> sniff("static.csv", b"Fs,100\\nLogging Type,1\\nax,ay,az,gx,gy,gz\\n1,2,3,4,5,6\\n")
True
"""

from __future__ import annotations

import os
from typing import Any

from ..mpu6050_csv import read_mpu6050_csv
from ..multiimu import MultiImuRecording

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "mpu6050"
EXTRA = None


def sniff(name: str, head: bytes) -> bool:
    """A ``Fs,<Hz>`` line first and an ``ax,ay,az,gx,gy,gz`` header."""
    return head.lstrip().startswith(b"Fs,") and b"ax,ay,az,gx,gy,gz" in head


def read(path: str | os.PathLike[str], accel_lsb_per_g: float = 16384.0, gyro_lsb_per_dps: float = 131.0,
         **options: Any) -> MultiImuRecording:
    """The one IMU ``mpu6050`` in SI (see the module docstring)."""
    rec = read_mpu6050_csv(path, accel_lsb_per_g, gyro_lsb_per_dps)
    rec.meta["units_from"] = {"gyro": f"counts at {gyro_lsb_per_dps:g} LSB/(deg/s) (declared range)",
                              "accel": f"counts at {accel_lsb_per_g:g} LSB/g (declared range)",
                              "sample_rate": "the file's Fs line"}
    return rec
