"""Importer of the Ferraris calibration recordings used by imucal (one file of a third-party format)."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from ...errors import SessionFormatError
from ...geometry import triad3
from ...units import G0
from ..model import Segment, Session

__all__ = ["FERRARIS_SECTIONS", "load_ferraris"]

#: section name -> (kind, known input in the sensor frame): static sections give the direction of the
#: specific force (the named axis points up, p, or down, a); rotation sections the axis of a full turn.
FERRARIS_SECTIONS = {
    "x_p": ("static", (1, 0, 0)),
    "x_a": ("static", (-1, 0, 0)),
    "y_p": ("static", (0, 1, 0)),
    "y_a": ("static", (0, -1, 0)),
    "z_p": ("static", (0, 0, 1)),
    "z_a": ("static", (0, 0, -1)),
    "x_rot": ("angle", (1, 0, 0)),
    "y_rot": ("angle", (0, 1, 0)),
    "z_rot": ("angle", (0, 0, 1)),
}
_COLUMNS = ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")


def load_ferraris(
    folder: str | Path,
    sample_rate: float = 102.4,
    gravity: float = G0,
    turn_angle_deg: float = -360.0,
    csv_name: str = "example_ferraris_session.csv",
    sections_name: str = "example_ferraris_session_list.json",
) -> Session:
    """Load a Ferraris-style hand calibration recording (the format of imucal's example data) as a Session.

    The unit is a triad (gyro and accelerometer, geometry ``triad3``, MB = the sensor's axes). Static sections
    ``x_p, x_a, ...`` become ``static`` segments with the specific force ``+-g`` along the named axis; rotation
    sections ``x_rot, ...`` become ``angle`` segments, one full turn about the named axis. The turns of imucal's
    recording are made in the negative sense (the gyro integrates to about -360 deg), which is imucal's
    default (``expected_angle=-360``); pass ``turn_angle_deg`` for recordings made the other way.

    Raw units are those of the file: gyro deg/s, accelerometer m/s^2 (roughly scaled already), so the scale
    factors estimated from it are near ``DEG_TO_RAD`` and 1.

    Raises
    ------
    SessionFormatError
        Missing files, missing or non-numeric columns (row and column named), sections out of range.
    """
    folder = Path(folder)
    path, spath = folder / csv_name, folder / sections_name
    for p in (path, spath):
        if not p.exists():
            raise SessionFormatError(f"{p} does not exist; expected the recording CSV and its section list JSON")
    from ...io.rawtext import csv_header, is_number  # rimu.io only when a recording is read

    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = csv_header(reader, _COLUMNS, f"{path} is empty",
                            lambda missing, header: f"{path}: columns {missing} are missing; the header is {header}")
        cols = [header.index(c) for c in _COLUMNS]
    data = _parse_fast(path)  # pandas' C parser where pandas is loaded already (or the file is large)
    if data is None:
        try:  # numpy's parser (one pass in C); a malformed file is read again below, to name the row and column
            data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=cols, dtype=float, ndmin=2)
        except ValueError:
            data = None
    if data is None or (data.size == 0 and data.shape[1] != len(cols)):
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            next(reader)
            rows = []
            for r, line in enumerate(reader, start=2):
                try:
                    rows.append([float(line[c]) for c in cols])
                except (ValueError, IndexError):
                    bad = next((_COLUMNS[k] for k, c in enumerate(cols) if c >= len(line) or not is_number(line[c])),
                               "?")
                    raise SessionFormatError(f"{path}: row {r}, column {bad!r} is missing or not a number") from None
        data = np.array(rows, dtype=float).reshape(-1, len(cols))
    if not np.all(np.isfinite(data)):
        r, c = np.argwhere(~np.isfinite(data))[0]
        raise SessionFormatError(f"{path}: row {r + 2}, column {_COLUMNS[c]!r} is not finite")
    try:
        sections = json.loads(spath.read_text())
    except json.JSONDecodeError as exc:
        raise SessionFormatError(f"{spath} is not valid JSON: {exc}") from exc
    geo = triad3()
    # each instrument's samples contiguous (one copy of each, the segments are views of it): the statistics of a
    # fit then run on contiguous rows, not on every sixth number
    gyro, accel = np.ascontiguousarray(data[:, 0:3]), np.ascontiguousarray(data[:, 3:6])
    segments = []
    for name, (kind, axis) in FERRARIS_SECTIONS.items():
        if name not in sections:
            raise SessionFormatError(f"{spath}: section {name!r} is missing; a Ferraris session needs {list(FERRARIS_SECTIONS)}")
        s, e = int(sections[name]["start"]), int(sections[name]["end"])
        if not 0 <= s < e <= len(data):
            raise SessionFormatError(f"{spath}: section {name!r} spans samples {s}..{e}, outside 0..{len(data)}")
        t = np.arange(s, e) / sample_rate
        raw = {"gyro": gyro[s:e], "accel": accel[s:e]}
        ax = np.array(axis, dtype=float)
        if kind == "static":
            seg = Segment(name, "static", t, raw, specific_force_mb=ax * gravity, meta={"source": "ferraris"})
        else:
            seg = Segment(name, "angle", t, raw, angle_mb=ax * math.radians(turn_angle_deg), meta={"source": "ferraris"})
        segments.append(seg)
    return Session(segments, {"gyro": geo, "accel": geo}, sample_rate, None, gravity, "gyro: deg/s; accel: m/s^2",
                   {"raw_units": {"gyro": "deg/s", "accel": "m/s^2"}, "source": str(path)})


#: a file at least this large is parsed by pandas even where it is not loaded yet (importing pandas takes about 1 s;
#: its parser saves about 1 ms per 1000 rows against numpy's)
PANDAS_MIN_BYTES = 64 << 20


def _parse_fast(path: Path) -> np.ndarray | None:
    """The recording's six columns (``_COLUMNS`` order, float64) parsed by pandas' C reader, 3x faster than
    ``np.loadtxt`` (the same numbers, tested), where pandas is imported already or the file is large enough to
    repay importing it (:data:`PANDAS_MIN_BYTES`); None otherwise, or where the file is not a clean table of finite
    numbers (then numpy's reader and the row-by-row check name the first bad cell)."""
    if "pandas" not in sys.modules and not (path.stat().st_size >= PANDAS_MIN_BYTES and _has_pandas()):
        return None
    try:
        import pandas as pd

        data = pd.read_csv(path, usecols=list(_COLUMNS))[list(_COLUMNS)].to_numpy(dtype=float)
    except Exception:
        return None
    return data if data.ndim == 2 and bool(np.isfinite(data).all()) else None


def _has_pandas() -> bool:
    import importlib.util

    return importlib.util.find_spec("pandas") is not None

