"""Recordings of several IMUs (triads): a generic CSV reader driven by a small column mapping.

A multi-IMU recording is k triads, each with gyro and/or accelerometer columns in declared units, one time
column shared by all of them (an autopilot log) or one file and clock per IMU (IMUs strapped to a vehicle).
The mapping says which columns are which (a dict, or a JSON file of the same shape)::

    {"file": "flight.csv.xz",              # relative to the mapping file; .xz, .gz, .bz2 are read as such
     "time": "t_s", "time_unit": "s",      # or "sample_rate_hz": 100 when there is no time column
     "skip_rows": 0,                       # lines before the header line
     "imus": [
        {"name": "imu0", "gyro": ["g0x", "g0y", "g0z"], "gyro_unit": "deg/s",
         "accel": ["a0x", "a0y", "a0z"], "accel_unit": "g", "temperature": "temp0"},
        {"name": "imu1", "file": "imu1.csv", "time": "time", ...}     # an IMU with its own file and clock
     ]}

Units: ``rad/s``, ``deg/s``, ``mrad/s``, ``m/s^2``, ``g``, ``mg``, ``s``, ``ms``, ``us``, ``ns``, or a number
(SI per raw unit, e.g. ``1/131 * DEG_TO_RAD`` for an MPU-6050 gyro at +-250 deg/s). Everything is converted to
SI on reading, so the epochs carry rad/s and m/s^2 and a nominal calibration has scale 1.

Each IMU keeps its own time stamps (:class:`ImuStream`); :meth:`MultiImuRecording.to_block` puts them on one
time base (the reference IMU's), after removing per-IMU clock offsets where they are known (for instance from
:func:`rimu.calibration.timing.estimate_offsets`): each channel is interpolated linearly at the base times, and a
base time outside an IMU's data or inside a gap of its samples (more than ``gap_factor`` times its median
period) leaves that IMU invalid for the epoch, never extrapolated. Empty or non-finite cells make that IMU's
triad invalid at that sample.

Why rimu.io and not a session loader: these recordings are flights and handling with no known input per
segment; they feed the runtime pipeline and FDI as epochs, as any live source does. (A calibration recording
with known poses is a :class:`rimu.session.Session`, read by ``rimu.session.loaders``.)
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from ..errors import SessionFormatError, ShapeError, TransportError
from ..units import DEG_TO_RAD, G0, MG_TO_MS2
from .base import Source
from .guard import reading
from .rawtext import csv_header

__all__ = [
    "GYRO_RANGE_RAD_S",
    "check_units",
    "UNIT_FACTORS",
    "ImuColumns",
    "ImuStream",
    "MultiImuCsvSource",
    "MultiImuMapping",
    "MultiImuRecording",
    "open_text",
    "read_multi_imu_csv",
    "resample_stream",
]

log = logging.getLogger(__name__)

#: declared unit -> factor to SI
UNIT_FACTORS: dict[str, float] = {
    "rad/s": 1.0, "deg/s": DEG_TO_RAD, "mrad/s": 1e-3,
    "m/s^2": 1.0, "m/s2": 1.0, "g": G0, "mg": MG_TO_MS2,
    "s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9,
}
_QUANTITY_UNITS = {"gyro": ("rad/s", "deg/s", "mrad/s"), "accel": ("m/s^2", "m/s2", "g", "mg"),
                   "time": ("s", "ms", "us", "ns")}


def _factor(unit: str | float, quantity: str) -> float:
    if isinstance(unit, (int, float)) and not isinstance(unit, bool):
        if not (math.isfinite(unit) and unit > 0):
            raise SessionFormatError(f"{quantity} unit factor must be a positive number (SI per raw unit), got {unit}")
        return float(unit)
    if unit not in _QUANTITY_UNITS[quantity]:
        raise SessionFormatError(f"unknown {quantity} unit {unit!r}; use one of {list(_QUANTITY_UNITS[quantity])} "
                                 "or a number (SI per raw unit)")
    return UNIT_FACTORS[str(unit)]


def open_text(path: str | os.PathLike[str]) -> io.TextIOBase:
    """Open a text file, decompressing ``.xz``, ``.gz``, ``.bz2`` and ``.zst`` on the fly
    (:func:`rimu.io.formats._open.open_text`, by content)."""
    from .formats._open import open_text as _open

    p = Path(path)
    if not p.exists():
        raise TransportError(f"no file at {p}")
    return _open(p)


@dataclass
class ImuColumns:
    """Where one IMU's data are: column names (x, y, z), units, and optionally its own file and clock."""

    name: str
    gyro: Sequence[str] | None = None
    accel: Sequence[str] | None = None
    gyro_unit: str | float = "rad/s"
    accel_unit: str | float = "m/s^2"
    temperature: str | None = None
    file: str | None = None
    time: str | None = None

    def __post_init__(self) -> None:
        for q in ("gyro", "accel"):
            cols = getattr(self, q)
            if cols is not None and len(cols) != 3:
                raise SessionFormatError(f"IMU {self.name!r}: {q} needs three columns (x, y, z), got {list(cols)}")
        if self.gyro is None and self.accel is None:
            raise SessionFormatError(f"IMU {self.name!r} has neither gyro nor accel columns")
        _factor(self.gyro_unit, "gyro")
        _factor(self.accel_unit, "accel")


@dataclass
class MultiImuMapping:
    """Which columns of which file hold which IMU (see the module docstring for the JSON shape)."""

    imus: list[ImuColumns]
    file: str | None = None
    time: str | None = "t"
    time_unit: str | float = "s"
    sample_rate_hz: float | None = None
    skip_rows: int = 0
    delimiter: str = ","

    def __post_init__(self) -> None:
        if not self.imus:
            raise SessionFormatError("a multi-IMU mapping needs at least one IMU in 'imus'")
        names = [m.name for m in self.imus]
        if len(set(names)) != len(names):
            raise SessionFormatError(f"IMU names must be unique, got {names}")
        _factor(self.time_unit, "time")
        if self.sample_rate_hz is not None and not (self.sample_rate_hz > 0 and math.isfinite(self.sample_rate_hz)):
            raise SessionFormatError(f"sample_rate_hz must be a positive number, got {self.sample_rate_hz}")

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MultiImuMapping:
        """Build from the JSON shape of the module docstring; unknown keys are refused (typos would be lost)."""
        known = {"imus", "file", "time", "time_unit", "sample_rate_hz", "skip_rows", "delimiter"}
        bad = sorted(set(d) - known)
        if bad:
            raise SessionFormatError(f"unknown mapping keys {bad}; known: {sorted(known)}")
        if "imus" not in d or not isinstance(d["imus"], list):
            raise SessionFormatError("a multi-IMU mapping needs a list 'imus' of {name, gyro, accel, ...}")
        imus = []
        for k, m in enumerate(d["imus"]):
            try:
                imus.append(ImuColumns(**m))
            except TypeError as exc:
                raise SessionFormatError(f"mapping imus[{k}]: {exc}; keys are name, gyro, accel, gyro_unit, "
                                         "accel_unit, temperature, file, time") from None
        rest = {k: v for k, v in d.items() if k != "imus"}
        return cls(imus, **rest)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> MultiImuMapping:
        """Read a mapping JSON file."""
        try:
            with reading(path, "JSON text"):
                doc = json.loads(Path(path).read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise SessionFormatError(f"{path}: not valid JSON ({exc})") from exc
        if not isinstance(doc, dict):
            raise SessionFormatError(f"{path}: a mapping must be a JSON object with 'imus', got {type(doc).__name__}")
        return cls.from_dict(doc)


@dataclass
class ImuStream:
    """One IMU's samples on its own clock, SI units.

    Attributes
    ----------
    name : str
    t : ndarray (N,)
        Time stamps, s, increasing.
    gyro, accel : ndarray (N, 3) or None
        rad/s and m/s^2 in the IMU's own axes; NaN where a cell was empty or non-finite.
    temperature : ndarray (N,) or None
        degC.
    """

    name: str
    t: np.ndarray
    gyro: np.ndarray | None = None
    accel: np.ndarray | None = None
    temperature: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def period_s(self) -> float:
        """Median sample period, s."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else float("nan")


@dataclass
class MultiImuRecording:
    """k IMUs of one recording, each on its own time stamps (see the module docstring)."""

    units: list[ImuStream]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [u.name for u in self.units]

    def __getitem__(self, name: str) -> ImuStream:
        for u in self.units:
            if u.name == name:
                return u
        raise KeyError(f"no IMU {name!r}; IMUs are {self.names}")

    def instruments(self) -> list[str]:
        """Instruments every IMU has (``gyro``, ``accel``)."""
        return [k for k in ("gyro", "accel") if all(getattr(u, k) is not None for u in self.units)]

    def geometry(self, rotations: Sequence[Any] | None = None, positions_mb_m: Sequence[Any] | None = None) -> Any:
        """The unit as :func:`rimu.geometry.triads` (identity rotations unless given, sub-units named after the
        IMUs)."""
        from ..geometry import triads

        return triads(len(self.units) if rotations is None else rotations, positions_mb_m, self.names)

    def to_block(self, offsets_s: Sequence[float] | dict[str, float] | None = None, reference: int | str = 0,
                 t: np.ndarray | None = None, gap_factor: float = 2.5) -> EpochBlock:
        """All IMUs on one time base as an :class:`EpochBlock` (raw = SI values, ``3k`` columns per instrument).

        Parameters
        ----------
        offsets_s : sequence or dict of float, optional
            Clock offset of each IMU, s: the sample an IMU stamps ``t_k`` was taken at ``t_k - offset``.
        reference : int or str
            The IMU whose (corrected) time stamps are the time base, unless ``t`` is given.
        t : ndarray, optional
            The time base, s.
        gap_factor : float
            A base time between two samples further apart than ``gap_factor`` median periods is invalid.
        """
        k = len(self.units)
        off = np.zeros(k)
        if isinstance(offsets_s, dict):
            for name, v in offsets_s.items():
                off[self.names.index(self[name].name)] = float(v)
        elif offsets_s is not None:
            off = np.asarray(offsets_s, dtype=float)
            if off.shape != (k,):
                raise ShapeError(f"{off.shape[0] if off.ndim else 1} offsets for {k} IMUs; give one per IMU")
        if not np.all(np.isfinite(off)):
            raise ShapeError(f"clock offsets must be finite, got {off.tolist()}")
        ref = self.names.index(reference) if isinstance(reference, str) else int(reference)
        base = (self.units[ref].t - off[ref]) if t is None else np.asarray(t, dtype=float)
        raw: dict[str, np.ndarray] = {}
        valid: dict[str, np.ndarray] = {}
        temperature = None
        for inst in self.instruments():
            Y = np.zeros((len(base), 3 * k))
            V = np.zeros((len(base), 3 * k), bool)
            for j, u in enumerate(self.units):
                y, ok = resample_stream(u.t - off[j], getattr(u, inst), base, gap_factor)
                Y[:, 3 * j:3 * j + 3] = np.where(ok[:, None], y, 0.0)
                V[:, 3 * j:3 * j + 3] = ok[:, None]
            raw[inst], valid[inst] = Y, V
        u0 = self.units[ref]
        if u0.temperature is not None:
            tt, ok = resample_stream(u0.t - off[ref], u0.temperature[:, None], base, gap_factor)
            if ok.all() and np.all(np.isfinite(tt)):
                temperature = tt[:, 0].copy()
        meta = dict(self.meta)
        meta.update({"imus": self.names, "offsets_s": off.tolist(), "reference": self.names[ref]})
        return EpochBlock(base.copy(), raw, valid, temperature, meta)

    def delivering(self, block: EpochBlock | None = None, min_fraction: float = 0.5) -> list[str]:
        """IMUs that deliver valid data in at least ``min_fraction`` of the epochs of ``block`` (default: of
        :meth:`to_block`)."""
        b = self.to_block() if block is None else block
        inst = self.instruments()[0]
        v = b.valid[inst]
        return [nm for j, nm in enumerate(self.names) if v[:, 3 * j].mean() >= min_fraction]


def resample_stream(t: np.ndarray, y: np.ndarray, base: np.ndarray, gap_factor: float = 2.5
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of the rows of ``y`` (N, m) sampled at ``t`` onto ``base``, with validity.

    A base time is valid where it lies within the samples, the two samples around it are finite and no
    further apart than ``gap_factor`` median periods. Exact at the sample times themselves.

    >>> y, ok = resample_stream(np.array([0.0, 1.0, 2.0]), np.array([[0.0], [1.0], [4.0]]), np.array([0.5, 2.0, 3.0]))
    >>> y[:, 0].tolist(), ok.tolist()
    ([0.5, 4.0, 0.0], [True, True, False])
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    base = np.asarray(base, dtype=float)
    out = np.zeros((len(base), y.shape[1]))
    ok = np.zeros(len(base), bool)
    if len(t) < 2:
        if len(t) == 1:
            hit = base == t[0]
            ok[hit] = np.all(np.isfinite(y[0]))
            out[hit] = np.where(ok[hit, None], y[0], 0.0)
        return out, ok
    j = np.searchsorted(t, base, side="right")
    inside = (base >= t[0]) & (base <= t[-1])
    j = np.clip(j, 1, len(t) - 1)
    a, b = j - 1, j
    dt = t[b] - t[a]
    period = float(np.median(np.diff(t)))
    w = np.where(dt > 0, (base - t[a]) / np.where(dt > 0, dt, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    ya, yb = y[a], y[b]
    exact_a = w == 0.0
    exact_b = w == 1.0
    fin = np.isfinite(ya).all(1) & np.isfinite(yb).all(1)
    fin |= exact_a & np.isfinite(ya).all(1)
    fin |= exact_b & np.isfinite(yb).all(1)
    ok = inside & fin & (dt <= gap_factor * period)
    with np.errstate(invalid="ignore"):
        val = np.where(exact_a[:, None], ya, np.where(exact_b[:, None], yb, ya + w[:, None] * (yb - ya)))
    out[ok] = val[ok]
    return out, ok


# ---------------------------------------------------------------------- reading
def _read_table(path: Path, columns: list[str], skip_rows: int, delimiter: str) -> dict[str, np.ndarray]:
    """The named columns of a CSV file as float arrays (empty or non-finite cells -> NaN)."""
    with reading(path, "CSV text"), open_text(path) as fh:
        for _ in range(skip_rows):
            fh.readline()
        rd = csv.reader(fh, delimiter=delimiter)
        header = csv_header(rd, columns, f"{path}: no header line after {skip_rows} skipped line(s)",
                            lambda missing, header: f"{path}: columns {missing} are not in the header {header}; "
                            "fix the mapping")
        idx = [header.index(c) for c in columns]
        need = max(idx) + 1
        rows = []
        for lineno, row in enumerate(rd, start=skip_rows + 2):
            if not row or (len(row) == 1 and not row[0].strip()):
                continue
            if len(row) < need:
                raise SessionFormatError(f"{path}: line {lineno} has {len(row)} cells, the mapped columns need {need}")
            vals = []
            for c, j in zip(columns, idx):
                s = row[j].strip()
                if not s:
                    vals.append(math.nan)
                    continue
                try:
                    vals.append(float(s))
                except ValueError:
                    raise SessionFormatError(f"{path}: line {lineno}, column {c!r}: {s!r} is not a number") from None
            rows.append(vals)
    if not rows:
        raise SessionFormatError(f"{path}: no data rows")
    data = np.array(rows, dtype=float)
    data[~np.isfinite(data)] = np.nan
    return {c: data[:, k] for k, c in enumerate(columns)}


def _time(values: np.ndarray | None, n: int, unit: str | float, rate: float | None, path: Path, col: str | None,
          on_bad_time: str = "raise", repairs: list[int] | None = None) -> np.ndarray:
    if values is None:
        if rate is None:
            raise SessionFormatError(f"{path}: no time column and no sample_rate_hz; the mapping needs one of them")
        return np.arange(n) / float(rate)
    t = values * _factor(unit, "time")
    if not np.all(np.isfinite(t)):
        raise SessionFormatError(f"{path}: column {col!r} has {int((~np.isfinite(t)).sum())} empty or non-finite "
                                 f"time stamps (first at data row {int(np.argmax(~np.isfinite(t))) + 1})")
    d = np.diff(t)
    if np.any(d <= 0) and on_bad_time == "grid" and n > 2:
        period = float(np.median(d))
        grid = t[0] + period * np.arange(n)
        off = np.abs(t - grid) > 0.5 * period
        if off.sum() <= max(1, n // 1000) and np.all(np.abs(t - grid) < 2 * period):
            if repairs is not None:
                repairs.extend(int(k) for k in np.flatnonzero(np.abs(t - grid) > 1e-3 * period))
            return grid
    if np.any(d <= 0):
        k = int(np.argmax(d <= 0))
        raise SessionFormatError(f"{path}: time column {col!r} does not increase at data row {k + 2} "
                                 f"({t[k]!r} -> {t[k + 1]!r}); sort the file or fix the clock")
    return t


#: no MEMS gyro measures beyond +-4000 deg/s
GYRO_RANGE_RAD_S = 4000.0 * DEG_TO_RAD


def check_units(streams: Sequence[ImuStream], source: Any, declared: dict[str, dict[str, Any]] | None = None,
                checks: str = "strict") -> list[str]:
    """Per-IMU unit plausibility: each accelerometer's median specific force near 1 g (any vehicle averages
    about 1 g over a record), each gyro within the range of a MEMS gyro and, when the vehicle turns, of the
    same size as the other IMUs' (a factor near 57.3: deg/s under a rad/s label). Returns the findings;
    ``checks="strict"`` raises :class:`~rimu.errors.PlausibilityError` naming the IMU, the file and the likely
    unit, ``"warn"`` only returns them.

    >>> t = np.arange(100) / 100.0
    >>> ok = ImuStream("a", t, np.full((100, 3), 0.1), np.tile([0.0, 0.0, 9.81], (100, 1)))
    >>> g = ImuStream("b", t, np.full((100, 3), 0.1), np.tile([0.0, 0.0, 1.0], (100, 1)))
    >>> check_units([ok, g], "f.csv", checks="warn")
    ["f.csv: IMU 'b' accel: median specific force 1 m/s^2, not about 1 g (9.807 m/s^2): the values look like g declared as m/s^2; fix accel_unit of 'b' (--accel-unit, or the mapping)"]
    """
    from ..errors import PlausibilityError

    declared = declared or {}
    found = []
    for u in streams:
        if u.accel is not None and np.isfinite(u.accel).any():
            norm = float(np.nanmedian(np.linalg.norm(u.accel, axis=1)))
            if not (0.3 * G0 <= norm <= 3.0 * G0):
                unit = declared.get(u.name, {}).get("accel", "m/s^2")
                have = _factor(unit, "accel") if not isinstance(unit, (int, float)) else float(unit)
                likely = [v for v in _QUANTITY_UNITS["accel"] if 0.5 * G0 <= norm / have * UNIT_FACTORS[v] <= 2 * G0]
                cause = f"the values look like {likely[0]} declared as {unit}" if likely else "check the unit"
                found.append(f"{source}: IMU {u.name!r} accel: median specific force {norm:.4g} m/s^2, not about 1 g "
                             f"({G0:.4g} m/s^2): {cause}; fix accel_unit of {u.name!r} (--accel-unit, or the mapping)")
    gy = [u for u in streams if u.gyro is not None and np.isfinite(u.gyro).any()]
    for u in gy:
        peak = float(np.nanmax(np.abs(u.gyro)))
        if peak > GYRO_RANGE_RAD_S:
            found.append(f"{source}: IMU {u.name!r} gyro reaches {peak:.4g} rad/s, beyond any MEMS gyro's range "
                         f"({GYRO_RANGE_RAD_S:.4g} rad/s = 4000 deg/s): the values look like deg/s declared as rad/s; "
                         f"fix gyro_unit of {u.name!r} (--gyro-unit, or the mapping)")
    if len(gy) >= 2:
        rms = np.array([float(np.sqrt(np.nanmean(u.gyro ** 2))) for u in gy])
        for j, u in enumerate(gy):
            others = float(np.median(np.delete(rms, j)))
            if others < 0.05 or rms[j] > GYRO_RANGE_RAD_S:  # a still vehicle tells nothing; range found above
                continue
            r = rms[j] / others
            if 1 / DEG_TO_RAD / 1.5 <= r <= 1.5 / DEG_TO_RAD or DEG_TO_RAD / 1.5 <= r <= 1.5 * DEG_TO_RAD:
                likely = "deg/s declared as rad/s" if r > 1 else "rad/s declared as deg/s"
                found.append(f"{source}: IMU {u.name!r} gyro: rms rate {rms[j]:.4g} rad/s against {others:.4g} "
                             f"rad/s of the other IMUs on the same vehicle ({r:.3g} times): the values look like "
                             f"{likely}; fix gyro_unit of {u.name!r} (--gyro-unit, or the mapping)")
    if found and checks == "strict":
        raise PlausibilityError("; ".join(found) + " (or read with checks='warn')")
    return found


def read_multi_imu_csv(mapping: MultiImuMapping | dict[str, Any] | str | os.PathLike[str],
                       path: str | os.PathLike[str] | None = None, on_bad_time: str = "raise",
                       checks: str = "strict") -> MultiImuRecording:
    """Read a multi-IMU recording as described by ``mapping`` (object, dict or JSON file).

    Parameters
    ----------
    mapping : MultiImuMapping, dict, or path of a JSON file
    path : path, optional
        The data file (overrides the mapping's ``file``); per-IMU ``file`` entries are relative to its folder
        (or to the mapping file's folder).
    on_bad_time : {"raise", "grid"}
        What to do with time stamps that do not increase. ``"raise"`` (default): refuse the file. ``"grid"``:
        where the stamps are a regular grid ``t0 + k T`` (T the median period) except for at most one in a
        thousand isolated stamps (a repeated or slipped stamp, as in one quadrotor run), use the grid; the
        repaired rows are listed in ``meta["time_repairs"]`` per IMU. Anything worse is still refused.
    checks : {"strict", "warn"}
        The per-IMU unit checks (:func:`check_units`): refuse, or list the findings in ``meta["unit_findings"]``
        with a warning.

    Raises
    ------
    SessionFormatError
        Unknown units or keys, missing columns (named), non-numeric cells (line and column), a time column that
        does not increase.
    TransportError
        A file does not exist.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "two.csv").write_text("t,g0x,g0y,g0z,g1x,g1y,g1z\\n0,1,0,0,1,0,0\\n0.01,2,0,0,2,0,0\\n")
    >>> m = {"file": "two.csv", "imus": [{"name": "a", "gyro": ["g0x", "g0y", "g0z"], "gyro_unit": "deg/s"},
    ...                                  {"name": "b", "gyro": ["g1x", "g1y", "g1z"], "gyro_unit": "deg/s"}]}
    >>> rec = read_multi_imu_csv(m, d / "two.csv")
    >>> rec.names, round(float(rec["b"].gyro[1, 0]), 6)
    (['a', 'b'], 0.034907)
    """
    base_dir = Path(".")
    if isinstance(mapping, (str, os.PathLike)):
        base_dir = Path(mapping).parent
        mapping = MultiImuMapping.load(mapping)
    elif isinstance(mapping, dict):
        mapping = MultiImuMapping.from_dict(mapping)
    if path is not None:
        main = Path(path)
        base_dir = main.parent
    elif mapping.file is not None:
        main = base_dir / mapping.file
    else:
        main = None
    # group the IMUs by file
    by_file: dict[Path, list[ImuColumns]] = {}
    for m in mapping.imus:
        f = (base_dir / m.file) if m.file is not None else main
        if f is None:
            raise SessionFormatError(f"IMU {m.name!r}: no file; give the data file or a 'file' in the mapping")
        by_file.setdefault(f, []).append(m)
    if on_bad_time not in ("raise", "grid"):
        raise ValueError(f"on_bad_time must be 'raise' or 'grid', got {on_bad_time!r}")
    streams: dict[str, ImuStream] = {}
    repaired: dict[str, list[int]] = {}
    for f, ms in by_file.items():
        tcols = {m.time or mapping.time for m in ms}
        cols: list[str] = [c for c in tcols if c is not None]
        for m in ms:
            for q in ("gyro", "accel"):
                cols += list(getattr(m, q) or [])
            if m.temperature:
                cols.append(m.temperature)
        cols = list(dict.fromkeys(cols))
        data = _read_table(f, cols, mapping.skip_rows, mapping.delimiter)
        n = len(next(iter(data.values())))
        for m in ms:
            tc = m.time or mapping.time
            rep: list[int] = []
            t = _time(data.get(tc) if tc else None, n, mapping.time_unit, mapping.sample_rate_hz, f, tc,
                      on_bad_time, rep)
            if rep:
                repaired[m.name] = rep
            g = None if m.gyro is None else np.column_stack([data[c] for c in m.gyro]) * _factor(m.gyro_unit, "gyro")
            a = None if m.accel is None else np.column_stack([data[c] for c in m.accel]) * _factor(m.accel_unit,
                                                                                                   "accel")
            temp = data[m.temperature] if m.temperature else None
            streams[m.name] = ImuStream(m.name, t, g, a, temp)
    units = [streams[m.name] for m in mapping.imus]
    if checks not in ("strict", "warn"):
        raise ValueError(f"checks must be 'strict' or 'warn', got {checks!r}")
    files = sorted({str(f) for f in by_file})
    findings = check_units(units, files[0] if len(files) == 1 else ", ".join(files),
                           {m.name: {"gyro": m.gyro_unit, "accel": m.accel_unit} for m in mapping.imus}, checks)
    for f in findings:
        log.warning(f)
    meta: dict[str, Any] = {"source": str(main) if main else None, "format": "multi-imu-csv"}
    if findings:
        meta["unit_findings"] = findings
    if repaired:
        meta["time_repairs"] = repaired
    return MultiImuRecording(units, meta)


class MultiImuCsvSource(Source):
    """Epochs of a multi-IMU CSV recording on one time base (see the module docstring).

    Parameters
    ----------
    mapping : MultiImuMapping, dict or path of a JSON mapping
    path : path, optional
        The data file, if the mapping does not name it.
    offsets_s : sequence of float, optional
        Per-IMU clock offsets removed before resampling (:meth:`MultiImuRecording.to_block`).
    """

    unit = "epoch"

    def __init__(self, mapping: Any = None, path: str | os.PathLike[str] | None = None,
                 offsets_s: Sequence[float] | None = None) -> None:
        super().__init__()
        self.recording = self._read(mapping, path)
        self.offsets_s = offsets_s

    def _read(self, mapping: Any, path: Any) -> MultiImuRecording:
        if mapping is None:
            raise SessionFormatError("a multi-IMU CSV source needs a mapping (dict or JSON file)")
        return read_multi_imu_csv(mapping, path)

    def geometry(self, instrument: str = "gyro") -> Any:
        """Stacked triads named after the IMUs (identity rotations: each IMU as logged)."""
        return self.recording.geometry()

    def _epochs(self) -> Iterator[Epoch]:
        block = self.recording.to_block(self.offsets_s)
        for k, ep in enumerate(block.epochs()):
            if self.stop_event.is_set():
                break
            self.accounting.received += 1
            yield self._accepted(ep, "index", k)
