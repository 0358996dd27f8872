"""ArduPilot DataFlash ``.bin`` logs and PX4's older sdlog2 ``.px4log`` (the same binary framing), extra ``logs``.

Every message is ``0xA3 0x95 TYPE payload``; ``FMT`` messages (type 128) declare each type's length, name,
field types and names, and may appear anywhere before a type's first use (ArduPilot writes them lazily). The
field types are pymavlink's (``pymavlink.DFReader.FORMAT_TO_STRUCT``, scales of ``c``, ``C``, ``e``, ``E``, ``L``
included), so a log reads here as pymavlink reads it; the messages are cut out of the byte stream in blocks and
decoded with numpy, not one Python object per message (see ``benchmarks/bench_import.py``).

IMUs read:

* ArduPilot, current: ``IMU`` with the instance field ``I`` -> ``imu<I>``;
* ArduPilot, older: ``IMU``, ``IMU2``, ``IMU3`` -> ``imu0``, ``imu1``, ``imu2``;
  fields ``TimeUS`` [us] (``TimeMS`` [ms] in logs before ArduPilot 3.3), ``GyrX/Y/Z`` [rad/s], ``AccX/Y/Z``
  [m/s^2], ``T`` (older: ``Temp``) [degC]. Where the log states units (``FMTU``/``UNIT`` messages) they are read
  and must be rad/s and m/s/s, each times its multiplier (``FMTU.MultIds``, the values of the log's ``MULT``
  messages or ArduPilot's table :data:`MULTIPLIERS`), which is applied; otherwise ArduPilot's convention (SI) is
  taken; ``meta["units_from"]`` says which;
* ArduPilot's raw IMU messages (``INS_RAW_LOG_OPT``): ``GYR`` and ``ACC`` of instance ``I`` -> ``raw<I>`` at the
  gyro's ``SampleUS`` stamps and rate, the accelerometer interpolated to them (within 2.5 of its periods, else NaN:
  counted ``accel_unmatched``), across blocks;
* PX4 sdlog2: ``IMU``, ``IMU1``, ``IMU2`` (``GyroX/Y/Z`` [rad/s], ``AccX/Y/Z`` [m/s^2], ``tG`` [degC]), stamped with
  the ``TIME.StartTime`` [us] record logged before them (one TIME per logging cycle).

Both autopilots log their IMUs rotated into the vehicle's body frame (``meta["body_frame"]``: a unit set up from the
log keeps its triads parallel). Rejected records are counted by reason in ``meta["rejected"]`` per IMU: ``nonfinite`` (a NaN or inf value),
``time_not_increasing`` (a stamp at or before the previous one of the same IMU); bytes that are no message
(``garbage_bytes``) and a cut last message (``truncated``) are counted for the file.

>>> import io
>>> sniff("flight.bin", b"\\xa3\\x95\\x80\\x80Y")
True
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..guard import reading
from ..multiimu import ImuStream, MultiImuRecording
from ._open import open_binary

__all__ = ["EXTRA", "FRAMES", "MULTIPLIERS", "NAME", "iter_chunks", "read", "sniff"]

NAME = "dataflash"
EXTRA = "logs"

HEAD = b"\xa3\x95"
FMT_TYPE = 128
FMT_LEN = 89
#: bytes read per block
BLOCK = 1 << 22

_NP = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "f": "<f4", "d": "<f8", "q": "<i8",
       "Q": "<u8", "M": "u1", "g": "<f2", "c": "<i2", "C": "<u2", "e": "<i4", "E": "<u4", "L": "<i4",
       "n": "S4", "N": "S16", "Z": "S64", "a": "S64"}
_IMU_NAMES = {"IMU": 0, "IMU1": 1, "IMU2": 1, "IMU3": 2}
_UNITS_OK = {"gyro": ("rad/s",), "accel": ("m/s/s", "m/s^2", "m/s2")}
#: ArduPilot's multipliers by id (``AP_Logger/LogStructure.h``, ``log_Multipliers``): a field's value times its
#: multiplier is in the field's unit; ``-`` (0) marks a field without one (a string), ``?`` one not worked out (1).
#: The log restates them in ``MULT`` messages, which take precedence.
MULTIPLIERS = {"-": 0.0, "?": 1.0, "2": 1e2, "1": 1e1, "0": 1e0, "A": 1e-1, "B": 1e-2, "C": 1e-3, "D": 1e-4,
               "E": 1e-5, "F": 1e-6, "G": 1e-7, "I": 1e-9, "!": 3.6, "/": 3600.0}
#: the time fields of ArduPilot's IMU messages and their scale to s (``TimeMS`` before ArduPilot 3.3)
_TIME_FIELDS = {"TimeUS": 1e-6, "TimeMS": 1e-3}
#: ArduPilot's raw IMU messages (``INS_RAW_LOG_OPT``): gyro and accelerometer samples of instance ``I`` apart, each
#: stamped ``SampleUS``, at the sensors' own rates
_RAW = {"GYR": ("GyrX", "GyrY", "GyrZ"), "ACC": ("AccX", "AccY", "AccZ")}
#: the axes of the IMUs read, per flavour (``meta["frame"]``)
FRAMES = {"ardupilot": "vehicle body frame (ArduPilot IMU messages: sensor and board orientation applied)",
          "sdlog2": "vehicle body frame (PX4 sdlog2 IMU messages)"}


def sniff(name: str, head: bytes) -> bool:
    """A DataFlash / sdlog2 log starts with an FMT message (``A3 95 80``)."""
    return head[:3] == HEAD + bytes([FMT_TYPE])


def _scales() -> dict[str, float]:
    """Field scale per type character, from pymavlink's table."""
    try:
        from pymavlink.DFReader import FORMAT_TO_STRUCT
    except ImportError:
        raise ImportError("reading DataFlash/px4log files needs pymavlink: pip install 'rimu[logs]'",
                          name="pymavlink") from None
    return {c: (float(m) if m else 1.0) for c, (_, m, _) in FORMAT_TO_STRUCT.items()}


class _Fmt:
    __slots__ = ("columns", "dtype", "format", "length", "name", "scales", "type")

    def __init__(self, type_: int, length: int, name: str, fmt: str, columns: list[str], scales: dict[str, float]
                 ) -> None:
        self.type, self.length, self.name, self.format, self.columns = type_, length, name, fmt, columns
        if len(fmt) != len(columns) or any(c not in _NP for c in fmt):
            self.dtype = None
        else:
            dt = np.dtype([(f"f{k}", _NP[c]) for k, c in enumerate(fmt)])
            self.dtype = dt if dt.itemsize == length - 3 else None
        self.scales = [scales.get(c, 1.0) for c in fmt]

    def field(self, rec: np.ndarray, name: str) -> np.ndarray:
        k = self.columns.index(name)
        v = rec[f"f{k}"].astype(np.float64)
        return v * self.scales[k] if self.scales[k] != 1.0 else v


def _cstr(b: bytes) -> str:
    return b.split(b"\x00", 1)[0].decode("ascii", "replace")


class _Parser:
    """The byte-stream walk: message starts per wanted type, FMT/FMTU/UNIT decoded as they come."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.scales = _scales()
        self.lengths = [0] * 256
        self.lengths[FMT_TYPE] = FMT_LEN
        self.fmts: dict[int, _Fmt] = {}
        self.units: dict[str, str] = {}
        self.fmtu: dict[int, str] = {}
        self.fmtu_mult: dict[int, str] = {}
        self.mults: dict[str, float] = dict(MULTIPLIERS)
        self.garbage = 0
        self.truncated = 0
        self.offset = 0  # bytes before the current block
        self.records = 0
        self.first_garbage: int | None = None

    def _fmt(self, buf: bytes, p: int) -> None:
        t, ln = buf[p + 3], buf[p + 4]
        name, fmt, cols = _cstr(buf[p + 5:p + 9]), _cstr(buf[p + 9:p + 25]), _cstr(buf[p + 25:p + 89])
        if t == FMT_TYPE or ln < 3:
            return
        self.lengths[t] = ln
        self.fmts[t] = _Fmt(t, ln, name, fmt, [c for c in cols.split(",") if c], self.scales)

    def _chain(self, arr: np.ndarray, p: int, L: np.ndarray) -> np.ndarray:
        """Starts of the messages that follow each other from ``p`` (each the previous start plus its length),
        found for the whole block at once: every ``A3 95`` is a candidate whose successor is the candidate at
        its end; the chain from ``p`` is listed by pointer doubling (log2 of its length numpy steps)."""
        n = len(arr)
        if n - p < 3:
            return np.zeros(0, np.int64)
        cand = np.flatnonzero((arr[p:n - 2] == 0xA3) & (arr[p + 1:n - 1] == 0x95)).astype(np.int64) + p
        ln = L[arr[cand + 2]]
        nxt = cand + ln
        m = len(cand)
        idx = np.searchsorted(cand, nxt)
        fits = (ln > 0) & (nxt <= n)
        succ = fits & (idx < m)
        succ[succ] = cand[idx[succ]] == nxt[succ]
        f = np.append(np.where(succ, idx, m), m)
        path = np.zeros(1, np.int64)
        jump = f
        while path[-1] != m:
            path = np.concatenate([path, jump[path]])
            jump = jump[jump]
        path = path[: int(np.argmax(path == m))]
        if len(path) and not fits[path[-1]]:
            path = path[:-1]
        return cand[path]

    def walk(self, buf: bytes, final: bool) -> tuple[dict[int, np.ndarray], int]:
        """Starts of the messages of ``buf`` by type, and how many bytes were consumed."""
        arr = np.frombuffer(buf, np.uint8)
        n = len(buf)
        parts = []
        p = 0
        while p + 3 <= n:
            L = np.asarray(self.lengths, np.int64)
            if buf[p] != 0xA3 or buf[p + 1] != 0x95 or not L[buf[p + 2]]:
                q = buf.find(HEAD, p + 1)
                while q >= 0 and q + 2 < n and not L[buf[q + 2]]:
                    q = buf.find(HEAD, q + 1)
                if q < 0 or q + 2 >= n:
                    q = n if (final or q < 0) else q
                if self.first_garbage is None:
                    self.first_garbage = self.offset + p
                self.garbage += q - p
                p = q
                continue
            chain = self._chain(arr, p, L)
            if not len(chain):
                break  # the message at p is cut by the end of the block
            for q in chain[arr[chain + 2] == FMT_TYPE].tolist():
                self._fmt(buf, q)
            parts.append(chain)
            last = int(chain[-1])
            p = last + int(L[buf[last + 2]])
        pos = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        types = arr[pos + 2]
        keep = types != FMT_TYPE
        pos, types = pos[keep], types[keep]
        self.records += len(pos)
        starts = {int(t): pos[types == t] for t in np.unique(types)}
        if final and p < n:
            self.truncated += 1
            p = n
        return starts, p

    def decode(self, buf: bytes, t: int | None, pos: Any) -> np.ndarray | None:
        f = self.fmts.get(t) if t is not None else None
        if f is None or f.dtype is None or pos is None or not len(pos):
            return None
        arr = np.frombuffer(buf, np.uint8)
        w = f.length - 3
        rows = np.lib.stride_tricks.as_strided(arr, (len(arr) - w + 1, w), (1, 1), writeable=False)
        return rows[np.asarray(pos, np.int64) + 3].view(f.dtype).ravel()


def _imu_types(fmts: dict[int, _Fmt]) -> dict[int, tuple[str, str]]:
    """type -> (flavour, base name) of the IMU messages: ``ardupilot`` (TimeUS, GyrX) or ``sdlog2`` (GyroX)."""
    out = {}
    for t, f in fmts.items():
        if f.name not in _IMU_NAMES:
            continue
        if {"GyrX", "AccX"} <= set(f.columns) and any(c in f.columns for c in _TIME_FIELDS):
            out[t] = ("ardupilot", f.name)
        elif {"GyroX", "AccX"} <= set(f.columns):
            out[t] = ("sdlog2", f.name)
    return out


def _raw_types(fmts: dict[int, _Fmt]) -> dict[int, str]:
    """type -> ``GYR`` / ``ACC`` of ArduPilot's raw IMU messages."""
    return {t: f.name for t, f in fmts.items()
            if f.name in _RAW and {"I", "SampleUS", *_RAW[f.name]} <= set(f.columns)}


class _RawJoin:
    """Each instance's ``GYR`` samples with its ``ACC`` samples interpolated at their stamps, across blocks: a gyro
    sample waits until an accelerometer sample at or after it has been read (or the log ends: then the ones after
    the last accelerometer sample have none, NaN)."""

    def __init__(self) -> None:
        self.gyro: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.acc: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def add(self, kind: str, i: int, t: np.ndarray, v: np.ndarray) -> None:
        store = self.gyro if kind == "GYR" else self.acc
        t0, v0 = store.get(i, (np.zeros(0), np.zeros((0, 3))))
        store[i] = (np.concatenate([t0, t]), np.concatenate([v0, v]))

    def take(self, final: bool) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        from ..multiimu import resample_stream

        out = {}
        for i, (tg, g) in list(self.gyro.items()):
            ta, a = self.acc.get(i, (np.zeros(0), np.zeros((0, 3))))
            order = np.argsort(ta, kind="stable")
            ta, a = ta[order], a[order]
            keep = np.concatenate([[True], np.diff(ta) > 0]) if len(ta) else np.zeros(0, bool)
            ta, a = ta[keep], a[keep]
            ready = np.ones(len(tg), bool) if final else (tg <= ta[-1] if len(ta) else np.zeros(len(tg), bool))
            if ready.any():
                acc = np.full((int(ready.sum()), 3), np.nan)
                if len(ta) > 1:
                    acc, ok = resample_stream(ta, a, tg[ready])
                    acc[~ok] = np.nan
                out[i] = (tg[ready], g[ready], acc)
            self.gyro[i] = (tg[~ready], g[~ready])
            # the accelerometer samples a waiting gyro sample may need: from the one before the earliest on
            first = tg[~ready].min() if (~ready).any() else (ta[-1] if len(ta) else 0.0)
            j = max(0, int(np.searchsorted(ta, first)) - 1)
            self.acc[i] = (ta[j:], a[j:])
        return out


def _unit_of(parser: _Parser, f: _Fmt, col: str) -> str | None:
    spec = parser.fmtu.get(f.type)
    if spec is None or col not in f.columns:
        return None
    k = f.columns.index(col)
    return parser.units.get(spec[k]) if k < len(spec) else None


def _mult_of(parser: _Parser, f: _Fmt, col: str) -> float:
    """The multiplier ``FMTU`` states for a field (1 where none, or ``-``/``?``)."""
    spec = parser.fmtu_mult.get(f.type)
    k = f.columns.index(col)
    if spec is None or k >= len(spec) or spec[k] in "-?":
        return 1.0
    m = parser.mults.get(spec[k])
    return 1.0 if m is None or m == 0.0 else m


def iter_chunks(path: str | os.PathLike[str], block: int = BLOCK, **options: Any) -> Iterator[MultiImuRecording]:
    """The IMUs of the log in pieces of about ``block`` bytes of log each (constant memory); the last piece's
    ``meta`` holds the file's counts (``records``, ``garbage_bytes``, ``truncated``, ``rejected``)."""
    p = Path(path)
    parser = _Parser(p)
    last_t: dict[str, float] = {}
    rejected: dict[str, dict[str, int]] = {}
    time_us = None  # sdlog2: the current TIME.StartTime
    flavour_seen: set[str] = set()
    units_from: dict[str, str] = {}
    join = _RawJoin()
    raw_seen = False
    rest = b""
    with reading(p, "DataFlash log"), open_binary(p) as fh:  # damaged compression: one line naming the file
        while True:
            try:
                data = fh.read(block)
            except (EOFError, OSError, ValueError) as exc:
                raise SessionFormatError(f"{p}: the compressed stream ends or breaks after byte "
                                         f"{parser.offset + len(rest)} ({type(exc).__name__}); re-copy the file or "
                                         "decompress what is left by hand") from None
            final = not data
            buf = rest + data
            starts, used = parser.walk(buf, final)
            # FMTU / UNIT / MULT (units and multipliers of the fields, ArduPilot), the tables before their uses
            decl = {"UNIT": 0, "MULT": 1, "FMTU": 2}
            for t, pos in sorted(((t, pos) for t, pos in starts.items()
                                  if t in parser.fmts and parser.fmts[t].name in decl),
                                 key=lambda tp: decl[parser.fmts[tp[0]].name]):
                f = parser.fmts[t]
                rec = parser.decode(buf, t, pos)
                if rec is None:
                    continue
                if f.name == "UNIT" and {"Id", "Label"} <= set(f.columns):
                    for i, lab in zip(rec[f"f{f.columns.index('Id')}"], rec[f"f{f.columns.index('Label')}"]):
                        parser.units[chr(int(i))] = _cstr(bytes(lab))
                elif f.name == "MULT" and {"Id", "Mult"} <= set(f.columns):
                    for i, m in zip(rec[f"f{f.columns.index('Id')}"], f.field(rec, "Mult")):
                        parser.mults[chr(int(i))] = float(m)
                elif f.name == "FMTU" and {"FmtType", "UnitIds"} <= set(f.columns):
                    for ft, u in zip(rec[f"f{f.columns.index('FmtType')}"], rec[f"f{f.columns.index('UnitIds')}"]):
                        parser.fmtu[int(ft)] = _cstr(bytes(u))
                    if "MultIds" in f.columns:
                        for ft, m in zip(rec[f"f{f.columns.index('FmtType')}"],
                                         rec[f"f{f.columns.index('MultIds')}"]):
                            parser.fmtu_mult[int(ft)] = _cstr(bytes(m))
            imu_types = _imu_types(parser.fmts)
            time_type = next((t for t, f in parser.fmts.items() if f.name == "TIME" and "StartTime" in f.columns), None)
            pieces: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]] = {}
            tpos = starts.get(time_type, np.zeros(0, np.int64)) if time_type is not None else np.zeros(0, np.int64)
            tval = None
            trec = parser.decode(buf, time_type, tpos)
            if trec is not None:
                tval = parser.fmts[time_type].field(trec, "StartTime")  # type: ignore[index]
            for t, (flavour, base) in imu_types.items():
                pos = starts.get(t)
                if pos is None or not len(pos):
                    continue
                f = parser.fmts[t]
                rec = parser.decode(buf, t, pos)
                if rec is None:
                    continue
                flavour_seen.add(flavour)
                if flavour == "ardupilot":
                    tcol = next(c for c in _TIME_FIELDS if c in f.columns)
                    ts = f.field(rec, tcol) * _TIME_FIELDS[tcol]
                    scale = {}
                    for col, q in (("GyrX", "gyro"), ("AccX", "accel")):
                        u = _unit_of(parser, f, col)
                        if u is not None and u not in _UNITS_OK[q]:
                            raise SessionFormatError(f"{p}: {f.name}.{col} is logged in {u!r}, not "
                                                     f"{_UNITS_OK[q][0]}; this reader knows ArduPilot's SI IMU "
                                                     "messages only")
                        scale[q] = _mult_of(parser, f, col) if u is not None else 1.0
                        units_from[q] = ("ArduPilot convention (SI)" if u is None else "log (FMTU)" if scale[q] == 1.0
                                         else f"log (FMTU: {u} x {scale[q]:g})")
                    g = np.column_stack([f.field(rec, c) for c in ("GyrX", "GyrY", "GyrZ")])
                    a = np.column_stack([f.field(rec, c) for c in ("AccX", "AccY", "AccZ")])
                    if scale["gyro"] != 1.0:
                        g *= scale["gyro"]
                    if scale["accel"] != 1.0:
                        a *= scale["accel"]
                    tc = next((c for c in ("T", "Temp") if c in f.columns), None)
                    temp = f.field(rec, tc) if tc is not None else None
                    inst = (rec[f"f{f.columns.index('I')}"].astype(int) if "I" in f.columns
                            else np.full(len(rec), _IMU_NAMES[base]))
                else:
                    pos_a = np.asarray(pos, np.int64)
                    if tval is not None:
                        k = np.searchsorted(tpos, pos_a) - 1
                        prev = np.where(k >= 0, tval[np.maximum(k, 0)], np.nan)
                    else:
                        prev = np.full(len(pos_a), np.nan)
                    if time_us is not None:
                        prev = np.where(np.isnan(prev), time_us, prev)
                    ts = prev * 1e-6
                    g = np.column_stack([f.field(rec, c) for c in ("GyroX", "GyroY", "GyroZ")])
                    a = np.column_stack([f.field(rec, c) for c in ("AccX", "AccY", "AccZ")])
                    temp = f.field(rec, "tG") if "tG" in f.columns else None
                    inst = np.full(len(rec), _IMU_NAMES[base])
                    units_from.update(gyro="PX4 sdlog2 convention (SI)", accel="PX4 sdlog2 convention (SI)")
                for i in np.unique(inst):
                    sel = inst == i
                    pieces.setdefault(f"imu{int(i)}", []).append(
                        (np.asarray(pos, np.int64)[sel], ts[sel], np.column_stack([g[sel], a[sel]]),
                         None if temp is None else temp[sel]))
            for t, kind in _raw_types(parser.fmts).items():
                pos = starts.get(t)
                rec = parser.decode(buf, t, pos)
                if rec is None:
                    continue
                f = parser.fmts[t]
                cols = _RAW[kind]
                q = "gyro" if kind == "GYR" else "accel"
                u = _unit_of(parser, f, cols[0])
                if u is not None and u not in _UNITS_OK[q]:
                    raise SessionFormatError(f"{p}: {f.name}.{cols[0]} is logged in {u!r}, not {_UNITS_OK[q][0]}; "
                                             "this reader knows ArduPilot's SI IMU messages only")
                scale = _mult_of(parser, f, cols[0]) if u is not None else 1.0
                units_from.setdefault(q, "ArduPilot convention (SI)" if u is None else "log (FMTU)" if scale == 1.0
                                      else f"log (FMTU: {u} x {scale:g})")
                v = np.column_stack([f.field(rec, c) for c in cols]) * scale
                ts = f.field(rec, "SampleUS") * 1e-6
                inst = rec[f"f{f.columns.index('I')}"].astype(int)
                for i in np.unique(inst):
                    join.add(kind, int(i), ts[inst == i], v[inst == i])
                raw_seen = True
                flavour_seen.add("ardupilot")
            for i, (ts, g, a) in join.take(final).items():
                if len(ts):
                    pieces.setdefault(f"raw{i}", []).append((np.arange(len(ts)), ts, np.column_stack([g, a]), None))
            if tval is not None and len(tval):
                time_us = float(tval[-1])
            units = []
            for name in sorted(pieces):
                parts = pieces[name]
                order = np.argsort(np.concatenate([q[0] for q in parts]), kind="stable")
                ts = np.concatenate([q[1] for q in parts])[order]
                ga = np.concatenate([q[2] for q in parts])[order]
                temps = None if any(q[3] is None for q in parts) else np.concatenate([q[3] for q in parts])[order]
                rej = rejected.setdefault(name, {"nonfinite": 0, "time_not_increasing": 0})
                # a raw gyro sample without an accelerometer sample around it keeps its gyro (accel NaN: invalid)
                fin = (np.isfinite(ga[:, :3]).all(axis=1) if name.startswith("raw")
                       else np.isfinite(ga).all(axis=1)) & np.isfinite(ts)
                if name.startswith("raw"):
                    rej.setdefault("accel_unmatched", 0)
                    rej["accel_unmatched"] += int((fin & ~np.isfinite(ga[:, 3:]).all(axis=1)).sum())
                rej["nonfinite"] += int((~fin).sum())
                ts, ga = ts[fin], ga[fin]
                temps = None if temps is None else temps[fin]
                prev = last_t.get(name, -np.inf)
                keep = ts > np.maximum.accumulate(np.concatenate([[prev], ts]))[:-1]
                rej["time_not_increasing"] += int((~keep).sum())
                ts, ga = ts[keep], ga[keep]
                temps = None if temps is None else temps[keep]
                if len(ts):
                    last_t[name] = float(ts[-1])
                units.append(ImuStream(name, ts, ga[:, :3].copy(), ga[:, 3:].copy(), temps))
            parser.offset += used
            rest = buf[used:]
            meta: dict[str, Any] = {"format": NAME, "source": str(p)}
            if final:
                if not parser.fmts:
                    raise SessionFormatError(f"{p}: no FMT message: not a DataFlash/px4log file, or its start is "
                                             "missing; check that this is the .bin/.px4log as logged")
                if not imu_types and not raw_seen:
                    names = sorted({f.name for f in parser.fmts.values()})[:20]
                    raise SessionFormatError(f"{p}: no IMU messages (IMU, IMU2, IMU3, GYR/ACC; sdlog2 IMU, IMU1) in "
                                             f"the log; it declares {names}")
                meta.update({"records": parser.records, "garbage_bytes": parser.garbage,
                             "truncated": parser.truncated, "rejected": rejected,
                             "flavour": sorted(flavour_seen), "units_from": units_from, "body_frame": True,
                             "frame": FRAMES["ardupilot" if "ardupilot" in flavour_seen else "sdlog2"],
                             "first_garbage_byte": parser.first_garbage})
            yield MultiImuRecording(units, meta)
            if final:
                return


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Every IMU of the log in SI (see the module docstring).

    Raises
    ------
    SessionFormatError
        No FMT message, no IMU message, units other than rad/s and m/s/s, a damaged compressed stream.
    """
    from ._join import join_chunks

    return join_chunks(iter_chunks(path, **options))
