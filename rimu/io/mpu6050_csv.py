"""Raw MPU-6050 recordings with a metadata header (the hand-held session of the shared data).

Format: metadata lines ``key,value`` (``Fs,100`` = sample rate in Hz, ``Logging Type``, ``Initialization
time``, ``Waiting time``), then the header ``ax,ay,az,gx,gy,gz`` and int16 counts. Scales are the chip's nominal
ones for the ranges given (defaults +-2 g: 16384 LSB/g, +-250 deg/s: 131 LSB/(deg/s)); the counts are
converted to SI with them, and a count at the int16 limit (+-32767, -32768) is at the range limit: that
triad's sample is marked invalid (a clipped value is not a measurement). One triad: no redundancy, but the
same stream interface as the multi-IMU recordings (a calibration session of the same file is the business of
``rimu.session.loaders``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SessionFormatError
from ..units import DEG_TO_RAD, G0
from .guard import reading
from .multiimu import MultiImuCsvSource, MultiImuRecording, open_text, read_multi_imu_csv

__all__ = ["INT16_LIMITS", "Mpu6050CsvSource", "read_mpu6050_csv"]

INT16_LIMITS = (-32768.0, 32767.0)


def read_mpu6050_csv(path: str | os.PathLike[str], accel_lsb_per_g: float = 16384.0,
                     gyro_lsb_per_dps: float = 131.0) -> MultiImuRecording:
    """Read one raw MPU-6050 file (unit ``mpu6050``); clipped samples become NaN (invalid)."""
    p = Path(path)
    meta: dict[str, Any] = {}
    skip = 0
    with reading(p, "CSV text"), open_text(p) as fh:
        for line in fh:
            cells = [c.strip() for c in line.strip().split(",")]
            if cells[:3] == ["ax", "ay", "az"]:
                break
            if len(cells) >= 2:
                meta[cells[0]] = cells[1]
            skip += 1
            if skip > 50:
                raise SessionFormatError(f"{p}: no header line 'ax,ay,az,gx,gy,gz' in the first 50 lines")
    try:
        rate = float(meta["Fs"])
    except (KeyError, ValueError):
        raise SessionFormatError(f"{p}: metadata line 'Fs,<Hz>' missing or not a number") from None
    mapping = {"time": None, "sample_rate_hz": rate, "skip_rows": skip,
               "imus": [{"name": "mpu6050", "gyro": ["gx", "gy", "gz"], "gyro_unit": DEG_TO_RAD / gyro_lsb_per_dps,
                         "accel": ["ax", "ay", "az"], "accel_unit": G0 / accel_lsb_per_g}]}
    rec = read_multi_imu_csv(mapping, p)
    u = rec.units[0]
    clipped = {}
    for inst, lsb in (("gyro", DEG_TO_RAD / gyro_lsb_per_dps), ("accel", G0 / accel_lsb_per_g)):
        y = getattr(u, inst)
        counts = np.rint(y / lsb)
        bad = ((counts <= INT16_LIMITS[0]) | (counts >= INT16_LIMITS[1])).any(axis=1)
        y[bad] = np.nan
        clipped[inst] = int(bad.sum())
    rec.meta.update({"format": "mpu6050-csv", "header": meta, "clipped_samples": clipped})
    return rec


class Mpu6050CsvSource(MultiImuCsvSource):
    """Epochs of a raw MPU-6050 file (SI values, clipped samples invalid)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__(mapping=path)

    def _read(self, mapping: Any, path: Any) -> MultiImuRecording:
        return read_mpu6050_csv(mapping)
