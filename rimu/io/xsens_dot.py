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

import numpy as np

from ..errors import SessionFormatError
from ..units import DEG_TO_RAD
from .multiimu import ImuStream, MultiImuCsvSource, MultiImuRecording, _read_table, read_multi_imu_csv

__all__ = ["XsensDotSource", "read_xsens_dot_raw", "read_xsens_dot_run"]

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
    rec = read_multi_imu_csv({"imus": imus}, files[0][1], on_bad_time="grid")  # (a path of d: not joined twice)
    rec.meta.update({"format": "xsens-dot", "run": d.name, "folder": str(d), "own_clocks": True})
    return rec


_GYR = ("Gyr_X", "Gyr_Y", "Gyr_Z")
_ACC = ("Acc_X", "Acc_Y", "Acc_Z")
_RAW_FILE = re.compile(r"^Xsens_DOT(\d+)_.*\.csv(\.xz|\.gz|\.bz2)?$")


def read_xsens_dot_raw(folder: str | os.PathLike[str]) -> MultiImuRecording:
    """Read the untrimmed exports ``Xsens_DOT<k>_<address>_<date>_<time>.csv[.xz]`` of a folder (units ``dot<k>``).

    Their time is ``SampleTimeFine`` (microseconds of the units' synchronised clock, an unsigned 32-bit counter:
    a wrap is unwrapped); all units share it (``meta["own_clocks"]`` is False) and the times start at the
    earliest sample of any unit. A row whose accelerometer and gyro values are all exactly zero (the export's
    first row before the first measurement) is invalid, not a measurement of zero.
    """
    d = Path(folder)
    files = sorted(((int(m.group(1)), f) for f in d.iterdir() if (m := _RAW_FILE.match(f.name))),
                   key=lambda x: x[0]) if d.is_dir() else []
    if not files:
        raise SessionFormatError(f"{d}: no Xsens_DOT<k>_*.csv[.xz] files")
    units = []
    for k, f in files:
        data = _read_table(f, ["SampleTimeFine", *_GYR, *_ACC], 0, ",")
        t = data["SampleTimeFine"].copy()
        wraps = np.cumsum(np.where(np.diff(t) < -2.0**31, 2.0**32, 0.0))
        t[1:] += wraps
        if np.any(np.diff(t) <= 0):
            bad = int(np.argmax(np.diff(t) <= 0))
            raise SessionFormatError(f"{f}: SampleTimeFine does not increase at data row {bad + 2}")
        g = np.column_stack([data[c] for c in _GYR]) * DEG_TO_RAD
        a = np.column_stack([data[c] for c in _ACC])
        zero = (g == 0).all(axis=1) & (a == 0).all(axis=1)
        g[zero] = np.nan
        a[zero] = np.nan
        units.append(ImuStream(f"dot{k}", t * 1e-6, g, a))
    t0 = min(u.t[0] for u in units)
    for u in units:
        u.t = u.t - t0
    return MultiImuRecording(units, {"source": str(d), "format": "xsens-dot-raw", "folder": str(d),
                                     "own_clocks": False, "t0_s": t0})


class XsensDotSource(MultiImuCsvSource):
    """Epochs of one run folder (``offsets_s``: per-unit clock offsets to remove, default none)."""

    def __init__(self, folder: str | os.PathLike[str], offsets_s: Any = None) -> None:
        super().__init__(mapping=folder, offsets_s=offsets_s)

    def _read(self, mapping: Any, path: Any) -> MultiImuRecording:
        return read_xsens_dot_run(mapping)
