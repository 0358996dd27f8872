"""Raw IMU logs as plain text or CSV: a time (or sample) column and raw columns, no segment labels.

What loggers write varies; this reader accepts

* comma, semicolon, tab or whitespace separated numbers;
* optional metadata rows before the table (``Fs,100``, ``Initialization time,36.5``: a name and one value),
  kept in ``RawLog.meta`` (``Fs`` / ``rate`` / ``sample_rate`` give the sample rate);
* an optional header row of column names (``ax,ay,az,gx,gy,gz``, ``t,acc_x,...``);
* a time column (``t``, ``time``, ``timestamp``, seconds; ``time_ms``/``time_us`` are scaled) or a sample
  index column (``n``, ``n_samples``, ``sample``), or neither (then the sample rate must be known).

Accelerometer and gyro columns are found by name (names starting ``a``/``acc`` and ``g``/``gyr``/``w``), or
given as names or 0-based indices; without a header the default is three accelerometer columns then three gyro
columns after an optional time column.

>>> import io
>>> log = read_raw_text(io.StringIO("Fs,100\\nax,ay,az,gx,gy,gz\\n1,2,3,4,5,6\\n1,2,3,4,5,7\\n"))
>>> log.sample_rate, log.raw["gyro"][:, 2].tolist(), log.t.tolist()
(100.0, [6.0, 7.0], [0.0, 0.01])
"""

from __future__ import annotations

import io as _io
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SessionFormatError

__all__ = ["RawLog", "read_raw_text"]

_TIME = {"t": 1.0, "time": 1.0, "timestamp": 1.0, "time_s": 1.0, "t_s": 1.0, "time_ms": 1e-3, "t_ms": 1e-3,
         "time_us": 1e-6, "t_us": 1e-6}
_INDEX = ("n", "n_samples", "sample", "samples", "index", "idx")
_RATE_KEYS = ("fs", "rate", "sample_rate", "sampling_rate", "frequency", "hz")


@dataclass
class RawLog:
    """A raw recording: times (s), raw columns per instrument, the sample rate, and the file's metadata."""

    t: np.ndarray
    raw: dict[str, np.ndarray]
    sample_rate: float
    columns: dict[str, list[str]]
    meta: dict[str, Any] = field(default_factory=dict)


def _split(line: str) -> list[str]:
    line = line.strip()
    if "," in line:
        parts = line.split(",")
    elif ";" in line:
        parts = line.split(";")
    elif "\t" in line:
        parts = line.split("\t")
    else:
        parts = line.split()
    return [p.strip() for p in parts]


def csv_header(reader: Any, need: Sequence[str], empty: str, lacking: Callable[[list[str], list[str]], str]
               ) -> list[str]:
    """The header row of a CSV reader, stripped, with the columns ``need`` checked present.

    Raises
    ------
    SessionFormatError
        ``empty`` when there is no row; ``lacking(missing, header)`` when a column of ``need`` is absent.
    """
    header = next(reader, None)
    if header is None:
        raise SessionFormatError(empty)
    header = [h.strip() for h in header]
    missing = [c for c in need if c not in header]
    if missing:
        raise SessionFormatError(lacking(missing, header))
    return header


def is_number(s: str) -> bool:
    """Whether a text field reads as a number (what :func:`float` accepts), for the readers that tell a header
    from data."""
    try:
        float(s)
        return True
    except ValueError:
        return False


def read_raw_text(source: str | Path | _io.TextIOBase, sample_rate: float | None = None,
                  accel: Sequence[str | int] | None = None, gyro: Sequence[str | int] | None = None,
                  time_column: str | int | None = None) -> RawLog:
    """Read a raw log (module docstring).

    Raises
    ------
    SessionFormatError
        Unreadable file, rows of different length or non-numeric values (row named), columns not found,
        no way to know the sample times, or times that do not increase.
    """
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.exists():
            raise SessionFormatError(f"{path} does not exist")
        from .formats._open import head, is_text, open_text

        if path.is_dir() or not is_text(head(path, 8192)):
            raise SessionFormatError(f"{path} is not a text log (binary content); give a CSV/text file, or "
                                     "'rimu import' it if it is a flight log (rimu import --help lists the formats)")
        with open_text(path) as fh:
            try:
                text = fh.read()
            except UnicodeDecodeError as exc:
                raise SessionFormatError(f"{path}: byte {exc.start} is not UTF-8 text; give a CSV/text file") from None
        name = str(path)
    else:
        text = source.read()
        name = "<stream>"
    meta: dict[str, Any] = {}
    header: list[str] | None = None
    rows: list[list[float]] = []
    width = None
    for ln, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = _split(line)
        nums = [is_number(p) for p in parts]
        if rows:
            if len(parts) != width or not all(nums):
                raise SessionFormatError(f"{name}: line {ln} has {len(parts)} fields "
                                         f"({'non-numeric' if not all(nums) else 'count differs'}); every row of "
                                         f"the table must have {width} numbers")
            rows.append([float(p) for p in parts])
            continue
        if all(nums) and (header is None or len(parts) == len(header)) and len(parts) >= 3:
            width = len(parts)
            rows.append([float(p) for p in parts])
        elif len(parts) == 2 and not nums[0] and header is None:
            meta[parts[0]] = float(parts[1]) if nums[1] else parts[1]
        elif not any(nums):
            header = [p.lower() for p in parts]
        else:
            raise SessionFormatError(f"{name}: line {ln} is neither metadata ('name,value'), a header, nor a row "
                                     f"of numbers: {line[:80]!r}")
    if not rows:
        raise SessionFormatError(f"{name}: no rows of numbers found")
    data = np.array(rows, dtype=float)
    ncol = data.shape[1]
    names = header if header is not None and len(header) == ncol else [f"c{k}" for k in range(ncol)]
    if sample_rate is None:
        for k, v in meta.items():
            if k.strip().lower() in _RATE_KEYS and isinstance(v, float):
                sample_rate = v

    def col(c: str | int) -> int:
        if isinstance(c, int) or (isinstance(c, str) and c.isdigit()):
            k = int(c)
            if not 0 <= k < ncol:
                raise SessionFormatError(f"{name}: column {k} is out of range (the table has {ncol} columns)")
            return k
        if c.lower() not in names:
            raise SessionFormatError(f"{name}: no column {c!r}; columns: {names}")
        return names.index(c.lower())

    tcol = None
    if time_column is not None:
        tcol = col(time_column)
    elif header is not None:
        for k, nm in enumerate(names):
            if nm in _TIME or nm in _INDEX:
                tcol = k
                break
    used = {tcol} if tcol is not None else set()

    def find(prefixes: tuple[str, ...]) -> list[int]:
        return [k for k, nm in enumerate(names) if k not in used and re.match(r"^(" + "|".join(prefixes) + r")", nm)]

    if accel is not None:
        ia = [col(c) for c in accel]
    elif header is not None:
        ia = find(("acc", "a"))
    else:
        start = 1 if ncol in (4, 7) else 0
        ia = list(range(start, start + 3))
    if gyro is not None:
        ig = [col(c) for c in gyro]
    elif header is not None:
        ig = find(("gyr", "gyro", "g", "w"))
    else:
        start = 1 if ncol in (4, 7) else 0
        ig = list(range(start + 3, start + 6)) if ncol >= start + 6 else []
    if header is None and tcol is None and ncol in (4, 7):
        tcol = 0
    clash = (set(ia) & set(ig)) | ({tcol} & (set(ia) | set(ig)) if tcol is not None else set())
    if clash:
        raise SessionFormatError(f"{name}: column(s) {[names[k] for k in sorted(clash)]} serve as more than one of "
                                 "time, accelerometer and gyro; name each column once (--time, --accel, --gyro)")
    if len(ia) < 3:
        raise SessionFormatError(f"{name}: found accelerometer columns {[names[k] for k in ia]}; give at least three "
                                 f"(--accel NAMES or indices); columns: {names}")
    if tcol is not None:
        tv = data[:, tcol]
        nm = names[tcol]
        if nm in _INDEX or (header is None and np.allclose(np.diff(tv), np.round(np.diff(tv))) and sample_rate):
            if not sample_rate:
                raise SessionFormatError(f"{name}: column {nm!r} counts samples; give the sample rate (--rate HZ)")
            t = (tv - tv[0]) / sample_rate
        else:
            t = (tv - tv[0]) * _TIME.get(nm, 1.0)
    else:
        if not sample_rate:
            raise SessionFormatError(f"{name}: no time column and no sample rate; give --rate HZ (or a 'Fs,<Hz>' "
                                     "row, or a time column)")
        t = np.arange(len(data)) / sample_rate
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise SessionFormatError(f"{name}: the times do not increase at row {k + 2} of the table")
    if not sample_rate:
        sample_rate = float(1.0 / np.median(dt))
    raw = {"accel": data[:, ia]}
    cols = {"accel": [names[k] for k in ia]}
    if ig:
        raw["gyro"] = data[:, ig]
        cols["gyro"] = [names[k] for k in ig]
    if not np.all(np.isfinite(data[:, ia + ig])):
        raise SessionFormatError(f"{name}: non-finite raw values")
    return RawLog(t, raw, float(sample_rate), cols, meta)
