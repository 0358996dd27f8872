"""MATLAB ``.mat`` files (level 5, through ``scipy.io.loadmat``) holding IMU structs in NaveGo's convention:
``t`` [s], ``wb`` [rad/s] (N x 3), ``fb`` [m/s^2] (N x 3), optional ``temp`` [degC]; a magnetometer ``mb`` is
ignored. NaveGo (R. Gonzalez et al., the MATLAB INS toolbox) and the projects built on it store an IMU so.

A file or a folder of files is read: every struct variable with these fields is one IMU, named by its variable
(``imu1_raw`` -> ``imu1_raw``), in the order of the file names and, within a file, of the variables; each keeps
its own time stamps (:class:`rimu.io.multiimu.ImuStream`). The axes are each IMU's own (``meta["frame"]``): a unit
set up from the log fits the rotations between them. Records whose stamp does not increase are dropped and
counted (``meta["rejected"]``). MATLAB v7.3 files (HDF5) are refused with what to do.

>>> sniff("imu1_raw.mat", b"MATLAB 5.0 MAT-file, Platform: GLNXA64")
True
>>> sniff("notes.txt", b"MATLAB 5.0 MAT-file")
False
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..multiimu import ImuStream, MultiImuRecording

__all__ = ["EXTRA", "FRAME", "NAME", "read", "sniff"]

NAME = "navego-mat"
EXTRA = None
MAGIC = b"MATLAB 5.0 MAT-file"
#: the axes of every IMU read
FRAME = "each IMU's own axes (NaveGo imu.wb / imu.fb: body frame of that IMU)"


def _files(p: Path) -> list[Path]:
    if p.is_dir():
        return sorted(f for f in p.iterdir() if f.suffix.lower() == ".mat" and f.is_file())
    return [p]


def sniff(name: str, head: bytes) -> bool:
    """A ``.mat`` file starting with MATLAB's level-5 header, or a folder of such files."""
    p = Path(name)
    if p.is_dir():
        for f in _files(p):
            with open(f, "rb") as fh:
                if fh.read(len(MAGIC)) == MAGIC:
                    return True
        return False
    return p.suffix.lower() == ".mat" and head.startswith(MAGIC)


def _field(s: Any, key: str) -> np.ndarray | None:
    return np.asarray(s[key], dtype=float) if key in (s.dtype.names or ()) else None


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Every IMU struct of the file or folder (see the module docstring)."""
    import scipy.io as sio

    p = Path(path)
    units: list[ImuStream] = []
    rejected: dict[str, dict[str, int]] = {}
    files = _files(p)
    for f in files:
        with open(f, "rb") as fh:
            head = fh.read(128)
        if b"MATLAB 7.3 MAT-file" in head:
            raise SessionFormatError(f"{f}: a MATLAB v7.3 (HDF5) file; save it as level 5 (save(..., '-v7')) to read it")
        if not head.startswith(MAGIC):
            continue
        try:
            data = sio.loadmat(f, squeeze_me=False, struct_as_record=True)
        except Exception as exc:  # scipy's MatReadError and what a damaged file raises: one line naming it
            raise SessionFormatError(f"{f}: not a readable MATLAB level-5 file ({type(exc).__name__}: "
                                     f"{str(exc)[:120]}); check that it is complete") from None
        for var, val in data.items():
            if var.startswith("__") or not isinstance(val, np.ndarray) or val.dtype.names is None or val.size != 1:
                continue
            s = val.reshape(-1)[0]
            t, wb, fb = _field(s, "t"), _field(s, "wb"), _field(s, "fb")
            if t is None or (wb is None and fb is None):
                continue
            t = t.reshape(-1)
            n = len(t)
            for nm, a in (("wb", wb), ("fb", fb)):
                if a is not None and a.shape != (n, 3):
                    raise SessionFormatError(f"{f}: {var}.{nm} has shape {a.shape}; NaveGo stores N x 3 for {n} stamps")
            temp = _field(s, "temp")
            temp = None if temp is None or temp.size != n else temp.reshape(-1)
            prev = np.fmax.accumulate(np.concatenate([[-np.inf], t[:-1]]))  # the latest stamp before each
            keep = np.isfinite(t) & (t > prev)                                # a stamp back in time: dropped
            bad = int((~keep).sum())
            if bad:
                rejected[var] = {"time_not_increasing": bad}
            units.append(ImuStream(var, t[keep], None if wb is None else wb[keep], None if fb is None else fb[keep],
                                   None if temp is None else temp[keep]))
    if not units:
        raise SessionFormatError(f"{p}: no struct with the fields t, wb and fb (NaveGo's IMU) in "
                                 f"{len(files)} .mat file(s); give --format for another layout")
    names = [u.name for u in units]
    if len(set(names)) != len(names):
        raise SessionFormatError(f"{p}: IMU variable names repeat across the files ({names}); rename them")
    return MultiImuRecording(units, {"source": str(p), "frame": FRAME, "rejected": rejected,
                                     "units_from": {"gyro": "NaveGo wb (rad/s)", "accel": "NaveGo fb (m/s^2)"}})
