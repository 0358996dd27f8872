"""Runs of several Xsens DOT IMUs strapped to one vehicle (the quadrotor recordings of the shared data).

A run folder holds one file per unit, ``IMU_1.csv[.xz]``, ``IMU_2.csv[.xz]``, ... with ``time`` [s, the unit's
own time column, starting at 0], ``Euler_X/Y/Z`` [deg, the unit's filter, not read], ``Acc_X/Y/Z`` [m/s^2,
specific force] and ``Gyr_X/Y/Z`` [deg/s]. Files named otherwise (``IMU_avg``, ``GT``) are not units. Each
unit keeps its own clock: the files of a run are skewed by several samples against each other, so put them on
one time base after estimating the offsets (:func:`rimu.calibration.timing.estimate_offsets`) with
:meth:`MultiImuRecording.to_block`. The units are nominally parallel but misaligned by up to several degrees:
estimate their rotations with :func:`rimu.calibration.alignment.align_triads`. A run may hold fewer units
than the vehicle carried (units lost in flight): the recording then has only the files present. The time
columns are a regular grid (k / 120 s); a repeated stamp (one in ``Horizontal/path_11``) is put back on the
grid and listed in ``meta["time_repairs"]``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from ..errors import SessionFormatError
from .multiimu import MultiImuCsvSource, MultiImuRecording, read_multi_imu_csv

__all__ = ["XsensDotSource", "read_xsens_dot_run"]

_UNIT_FILE = re.compile(r"^IMU_(\d+)\.csv(\.xz|\.gz|\.bz2)?$")


def read_xsens_dot_run(folder: str | os.PathLike[str]) -> MultiImuRecording:
    """Read every ``IMU_<k>.csv[.xz]`` of a run folder (units ``imu<k>``, sorted by k).

    Raises
    ------
    SessionFormatError
        No unit file in the folder, or a file without the expected columns.
    """
    d = Path(folder)
    files = sorted(((int(m.group(1)), f) for f in d.iterdir() if (m := _UNIT_FILE.match(f.name))),
                   key=lambda x: x[0]) if d.is_dir() else []
    if not files:
        raise SessionFormatError(f"{d}: no IMU_<k>.csv[.xz] files; point at a run folder such as Horizontal/path_10")
    imus = [{"name": f"imu{k}", "file": f.name, "time": "time",
             "gyro": ["Gyr_X", "Gyr_Y", "Gyr_Z"], "gyro_unit": "deg/s",
             "accel": ["Acc_X", "Acc_Y", "Acc_Z"], "accel_unit": "m/s^2"} for k, f in files]
    rec = read_multi_imu_csv({"imus": imus}, d / files[0][1], on_bad_time="grid")
    rec.meta.update({"format": "xsens-dot", "run": d.name, "folder": str(d), "own_clocks": True})
    return rec


class XsensDotSource(MultiImuCsvSource):
    """Epochs of one run folder (``offsets_s``: per-unit clock offsets to remove, default none)."""

    def __init__(self, folder: str | os.PathLike[str], offsets_s: Any = None) -> None:
        super().__init__(mapping=folder, offsets_s=offsets_s)

    def _read(self, mapping: Any, path: Any) -> MultiImuRecording:
        return read_xsens_dot_run(mapping)
