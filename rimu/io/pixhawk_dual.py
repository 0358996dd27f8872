"""The two-IMU Pixhawk 1 flight of the shared data (``01_07_59_imu01.csv[.xz]``, taken from a PX4 sdlog2 log).

One row per log record: ``t_s``, then per IMU (``imu0_``, ``imu1_``) ``gx, gy, gz`` [rad/s], ``ax, ay, az``
[m/s^2], ``tempC``. Both IMUs are already rotated into the body frame and compensated with PX4's own
calibration, so the unit is two parallel triads (:func:`rimu.geometry.triads` with identity rotations): a
fault is detected but cannot be isolated between the two. One time column for both, sampled irregularly
(10.8-14.1 ms).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .multiimu import MultiImuCsvSource, MultiImuRecording, read_multi_imu_csv

__all__ = ["PIXHAWK_DUAL_MAPPING", "PixhawkDualSource", "read_pixhawk_dual"]

#: the column mapping of the extracted CSV (see :mod:`rimu.io.multiimu`)
PIXHAWK_DUAL_MAPPING: dict[str, Any] = {
    "time": "t_s", "time_unit": "s",
    "imus": [{"name": f"imu{k}", "gyro": [f"imu{k}_g{a}" for a in "xyz"], "gyro_unit": "rad/s",
              "accel": [f"imu{k}_a{a}" for a in "xyz"], "accel_unit": "m/s^2", "temperature": f"imu{k}_tempC"}
             for k in (0, 1)],
}


def read_pixhawk_dual(path: str | os.PathLike[str], gyro_unit: str | float | None = None,
                      accel_unit: str | float | None = None) -> MultiImuRecording:
    """Read the CSV (or a folder holding ``01_07_59_imu01.csv.xz``) as a two-IMU recording: rad/s and m/s^2 as
    PX4's extraction writes them, unless ``gyro_unit`` / ``accel_unit`` declare otherwise (a file of this layout
    written by another tool)."""
    p = Path(path)
    if p.is_dir():
        p = p / "01_07_59_imu01.csv.xz"
    declared = {k: v for k, v in (("gyro_unit", gyro_unit), ("accel_unit", accel_unit)) if v is not None}
    mapping = {**PIXHAWK_DUAL_MAPPING, "imus": [{**imu, **declared} for imu in PIXHAWK_DUAL_MAPPING["imus"]]}
    rec = read_multi_imu_csv(mapping, p)
    rec.meta.update({"format": "pixhawk-dual", "body_frame": True, "devices": {"imu0": "MPU-6000", "imu1": "L3GD20 + LSM303D"}})
    return rec


class PixhawkDualSource(MultiImuCsvSource):
    """Epochs of the Pixhawk two-IMU CSV (``path``: the file or its folder)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self._path = path
        super().__init__(mapping=PIXHAWK_DUAL_MAPPING, path=path)

    def _read(self, mapping: Any, path: Any) -> MultiImuRecording:
        return read_pixhawk_dual(path)
