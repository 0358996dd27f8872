"""rimu's own session formats: CSV with a JSON sidecar, and NPZ (see ``docs/session-format.md``)."""

from __future__ import annotations

import csv
import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_files, atomic_path
from ..errors import RimuError, SessionFormatError
from ..units import G0
from .model import Segment, Session

__all__ = ["SESSION_FORMAT", "SESSION_FORMAT_VERSION", "load_session", "save_session", "session_from_sidecar",
           "session_sidecar", "sidecar_geometries"]

log = logging.getLogger(__name__)

#: format tag and version of the JSON sidecar (and of the NPZ ``meta`` entry)
SESSION_FORMAT = "rimu.session"
SESSION_FORMAT_VERSION = 1

#: accepted spellings of the known inputs of a segment in the sidecar: key -> (attribute, factor to SI)
_INPUT_KEYS = {
    "specific_force_mb_m_s2": ("specific_force_mb", 1.0),
    "specific_force_mb_g": ("specific_force_mb", None),  # times the session's gravity
    "rate_mb_rad_s": ("rate_mb", 1.0),
    "rate_mb_deg_s": ("rate_mb", math.pi / 180.0),
    "angle_mb_rad": ("angle_mb", 1.0),
    "angle_mb_deg": ("angle_mb", math.pi / 180.0),
}


def session_sidecar(session: Session, data_name: str | None = None) -> dict:
    """The JSON sidecar of a session (everything but the samples): geometry, units, sample rate, latitude,
    gravity, and per segment its label, kind and known inputs (SI, with the unit in the key)."""
    segs = []
    for s in session.segments:
        d: dict = {"label": s.label, "kind": s.kind}
        if s.specific_force_mb is not None:
            d["specific_force_mb_m_s2"] = np.asarray(s.specific_force_mb).reshape(-1, 3).mean(axis=0).tolist()
        if s.rate_mb is not None:
            d["rate_mb_rad_s"] = s.table_rate().tolist()
        if s.angle_mb is not None:
            d["angle_mb_rad"] = np.asarray(s.angle_mb).reshape(-1, 3)[-1].tolist()
        if s.mat_ln_mb is not None:
            d["mat_ln_mb"] = s.mat_ln_mb.tolist()
        if s.meta:
            d["meta"] = _plain(s.meta)
        segs.append(d)
    out = {
        "format": SESSION_FORMAT,
        "version": SESSION_FORMAT_VERSION,
        "sample_rate_hz": session.sample_rate,
        "latitude_deg": None if session.latitude is None else math.degrees(session.latitude),
        "gravity_m_s2": session.gravity,
        "raw_unit": session.raw_unit,
        "frames": "MB: the unit's master-body frame; local level frame ENU (mat_ln_mb maps MB to ENU)",
        "geometries": {k: g.to_dict() for k, g in session.geometries.items()},
        "segments": segs,
        "meta": _plain(session.meta),
    }
    if data_name is not None:
        out["data"] = data_name
    return out


def _readable_json(d: dict) -> str:
    """JSON with one key per line but short lists of numbers kept on one line."""
    import re

    text = json.dumps(d, indent=1)
    pat = re.compile(r"\[\s*((?:-?[\d.eE+-]+|null)(?:,\s*(?:-?[\d.eE+-]+|null))*)\s*\]")
    for _ in range(2):
        text = pat.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)
        text = re.sub(r"\[\s*(\[[^\[\]]*\](?:,\s*\[[^\[\]]*\])*)\s*\]",
                      lambda m: "[" + re.sub(r"\],\s*\[", "], [", m.group(1)) + "]", text)
    return text + "\n"


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    return str(x)


def _columns(session_or_geoms) -> list[str]:
    geoms = session_or_geoms.geometries if isinstance(session_or_geoms, Session) else session_or_geoms
    cols = []
    for k in ("gyro", "accel"):
        if k in geoms:
            cols += [f"{k}_{n}" for n in geoms[k].names]
    return cols


def save_session(session: Session, path: str | Path) -> Path:
    """Write a session in rimu's format: ``.csv`` (plus a ``.json`` sidecar beside it) or ``.npz``.

    CSV: one header row ``t,segment,gyro_<sensor>...,accel_<sensor>...[,temperature]``, one row per sample,
    ``segment`` the label of the segment the sample belongs to. The sidecar ``<name>.json`` holds the rest
    (see :func:`session_sidecar` and docs/session-format.md). NPZ: arrays ``t``, ``segment`` (index into the
    sidecar's segment list), ``raw_gyro``, ``raw_accel``, optional ``temperature``, and ``meta`` (the sidecar as
    a JSON string). Returns the path of the data file.
    """
    path = Path(path)
    cols = _columns(session)
    t = np.concatenate([s.t for s in session.segments])
    has_temp = all(s.temperature is not None for s in session.segments)
    if path.suffix == ".npz":
        side = session_sidecar(session)
        arrays = {"t": t, "segment": np.concatenate([np.full(s.n_samples, k) for k, s in enumerate(session.segments)])}
        for k in session.instruments:
            # C order whatever the segments hold (a session of transposed or column-major data, as `rimu detect`
            # makes from a CSV, stacked Fortran-ordered): the streaming reader reads rows in chunks
            arrays[f"raw_{k}"] = np.ascontiguousarray(np.vstack([s.raw[k] for s in session.segments]))
        if has_temp:
            arrays["temperature"] = np.concatenate([s.temperature for s in session.segments])
        with atomic_path(path) as tmp:  # whole or not at all (Ctrl-C, full disk)
            np.savez_compressed(tmp, meta=np.array(json.dumps(side)), **arrays)
        log.info("wrote %s (%d samples)", path, len(t))
        return path
    if path.suffix != ".csv":
        raise SessionFormatError(f"{path}: use a .csv (with a .json sidecar) or .npz file name")
    for s in session.segments:
        if any(ch in s.label for ch in ',"\n\r') or s.label != s.label.strip():
            raise SessionFormatError(f"segment label {s.label!r} cannot be written to CSV: no commas, quotes, line "
                                     "breaks or surrounding spaces")
    side = session_sidecar(session, path.name)
    header = ["t", "segment"] + cols + (["temperature"] if has_temp else [])
    with atomic_files() as tx, tx.path(path).open("w", newline="") as fh:  # CSV and sidecar appear together
        tx.path(path.with_suffix(".json")).write_text(_readable_json(side))
        fh.write(",".join(header) + "\n")
        for s in session.segments:
            block = [s.raw[k] for k in session.instruments]
            if has_temp:
                block.append(s.temperature[:, None])
            data = np.hstack(block)
            tcol = np.char.mod("%.17g", s.t)
            body = np.char.mod("%.17g", data)
            lab = s.label
            for k in range(s.n_samples):
                fh.write(f"{tcol[k]},{lab}," + ",".join(body[k]) + "\n")
    log.info("wrote %s and its sidecar %s (%d samples)", path, path.with_suffix(".json").name, len(t))
    return path


def load_session(path: str | Path, checks: str = "strict") -> Session:
    """Read a session written by :func:`save_session` or by any tool following docs/session-format.md.

    ``path`` is the ``.csv`` (its sidecar ``.json`` beside it), the ``.json`` sidecar (naming its ``data``
    file), or an ``.npz``.

    Parameters
    ----------
    checks : {"strict", "warn", "off"}
        What to do with the plausibility checks of :mod:`rimu.session.checks` (declared units against gravity and
        commanded rates, ``sample_rate_hz`` against the time column, dead columns): refuse implausible data
        (default), only log them, or skip the checks. Format errors, non-finite values and time running backwards
        are refused whatever this says.

    Raises
    ------
    SessionFormatError
        Missing file, sidecar key, column or segment; a malformed value (the row and column are named).
    PlausibilityError
        The data contradict what the file declares (``checks="strict"``); the message names the column and the
        likely cause.
    """
    from .checks import check_session, enforce

    path = Path(path)
    if not path.exists():
        raise SessionFormatError(f"{path} does not exist")
    if path.is_dir():
        raise SessionFormatError(f"{path} is a folder; give a session file (.csv with its .json sidecar, or .npz)")
    try:
        session = _load_any(path)
    except RimuError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, AttributeError, UnicodeDecodeError) as exc:
        # the specific checks above name row and column; this net catches the malformed content they do not foresee
        raise SessionFormatError(f"{path}: malformed session file ({type(exc).__name__}: {exc}); see "
                                 "docs/session-format.md") from exc
    if checks != "off":
        enforce(check_session(session, str(path)), checks)
    log.info("read %s: %d segments, %d samples at %g Hz, instruments %s", path, len(session),
             sum(s.n_samples for s in session.segments), session.sample_rate, ", ".join(session.instruments))
    return session


def _load_any(path: Path) -> Session:
    if path.suffix == ".npz":
        return _load_npz(path)
    if path.suffix == ".json":
        side = _read_sidecar(path)
        if "data" not in side or not isinstance(side["data"], str) or not side["data"]:
            raise SessionFormatError(f"{path}: the sidecar has no 'data' key naming its CSV file")
        return _load_csv(path.parent / side["data"], side, path)
    if path.suffix == ".csv":
        sp = path.with_suffix(".json")
        if not sp.exists():
            raise SessionFormatError(f"{path}: its sidecar {sp.name} is missing (geometry, sample rate, segments)")
        return _load_csv(path, _read_sidecar(sp), sp)
    raise SessionFormatError(f"{path}: unknown session file type {path.suffix!r}; use .csv/.json or .npz")


def _read_sidecar(path: Path) -> dict:
    try:
        side = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise SessionFormatError(f"{path}: not valid JSON ({exc})") from exc
    _check_sidecar(side, str(path))
    return side


def _check_sidecar(side: object, src: str) -> None:
    if not isinstance(side, dict):
        raise SessionFormatError(f"{src}: the sidecar must be a JSON object")
    if side.get("format") == "rimu.calibration":
        raise SessionFormatError(f"{src} is a calibration file, not a session; give the session it was made from "
                                 "(.csv with its .json sidecar, or .npz)")
    if side.get("format") != SESSION_FORMAT:
        raise SessionFormatError(f"{src}: 'format' must be {SESSION_FORMAT!r}, got {side.get('format')!r}")
    v = side.get("version")
    if v != SESSION_FORMAT_VERSION:
        raise SessionFormatError(f"{src}: session format version {v!r} is not known (this rimu reads "
                                 f"{SESSION_FORMAT_VERSION})")
    missing = [k for k in ("sample_rate_hz", "geometries", "segments") if k not in side]
    if missing:
        raise SessionFormatError(f"{src}: the sidecar lacks the keys {missing}")
    sr = side["sample_rate_hz"]
    if not isinstance(sr, (int, float)) or not sr > 0:
        raise SessionFormatError(f"{src}: sample_rate_hz must be a positive number, got {sr!r}")
    if not isinstance(side["geometries"], dict) or not side["geometries"]:
        raise SessionFormatError(f"{src}: 'geometries' must map 'gyro'/'accel' to a preset name or a geometry")
    if not isinstance(side["segments"], list) or not side["segments"]:
        raise SessionFormatError(f"{src}: 'segments' must be a non-empty list")
    for k, seg in enumerate(side["segments"]):
        if not isinstance(seg, dict) or "label" not in seg or "kind" not in seg:
            raise SessionFormatError(f"{src}: segments[{k}] needs 'label' and 'kind'")


def sidecar_geometries(side: dict, src: str = "sidecar") -> dict:
    """The geometry of each instrument a session sidecar names (a preset name or a geometry dict).

    ``src`` names the file in error messages. Raises :class:`rimu.errors.SessionFormatError` for a geometry it
    cannot build.

    >>> sorted(sidecar_geometries({"geometries": {"gyro": "cone6"}})["gyro"].names)
    ['x1', 'x2', 'y1', 'y2', 'z1', 'z2']
    """
    from ..errors import GeometryError
    from ..geometry import Geometry, preset

    out = {}
    for k, g in side["geometries"].items():
        try:
            out[k] = preset(g) if isinstance(g, str) else Geometry.from_dict(g)
        except GeometryError as exc:
            raise SessionFormatError(f"{src}: geometries[{k!r}]: {exc}") from exc
    return out


def _segment_from_sidecar(d: dict, t: np.ndarray, raw: dict, temp, gravity: float, src: str, k: int) -> Segment:
    kw: dict = {}
    for key, (attr, fac) in _INPUT_KEYS.items():
        if key in d and d[key] is not None:
            try:
                v = np.asarray(d[key], dtype=float)
            except (TypeError, ValueError):
                raise SessionFormatError(f"{src}: segments[{k}] ({d['label']!r}): {key} is not numeric") from None
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise SessionFormatError(f"{src}: segments[{k}] ({d['label']!r}): {key} must be 3 finite numbers")
            kw[attr] = v * (gravity if fac is None else fac)
    if d.get("mat_ln_mb") is not None:
        m = np.asarray(d["mat_ln_mb"], dtype=float)
        if m.shape != (3, 3) or np.abs(m @ m.T - np.eye(3)).max() > 1e-6:
            raise SessionFormatError(f"{src}: segments[{k}] ({d['label']!r}): mat_ln_mb must be a 3x3 rotation")
        kw["mat_ln_mb"] = m
    try:
        return Segment(str(d["label"]), str(d["kind"]), t, raw, temp, meta=dict(d.get("meta") or {}), **kw)
    except (SessionFormatError, ValueError) as exc:
        raise SessionFormatError(f"{src}: segments[{k}]: {exc}") from exc


def session_from_sidecar(side: dict, t: np.ndarray, seg_idx: np.ndarray, raw: dict, temp: np.ndarray | None = None,
                         src: str = "sidecar") -> Session:
    """A :class:`Session` from a sidecar (:func:`session_sidecar`) and its samples: times ``t`` (N,), s, the
    index of each sample's segment in the sidecar's ``segments`` (N,), ``raw`` per instrument (N, n) in raw
    units and the temperature (N,) degC or None. Every sidecar field is checked (gravity, latitude, raw units,
    segment inputs), as :func:`load_session` does; a segment without samples is a
    :class:`rimu.errors.SessionFormatError` naming it. ``src`` names the file in error messages.
    """
    geoms = sidecar_geometries(side, src)
    gravity = side.get("gravity_m_s2") or G0
    if not isinstance(gravity, (int, float)) or not 9.0 < gravity < 10.5:
        raise SessionFormatError(f"{src}: gravity_m_s2 must be the local gravity in m/s^2 (about 9.78 to 9.83), got "
                                 f"{gravity!r}")
    gravity = float(gravity)
    lat = side.get("latitude_deg")
    if lat is not None and (not isinstance(lat, (int, float)) or not -90 <= lat <= 90):
        raise SessionFormatError(f"{src}: latitude_deg must be a number in [-90, 90] or null, got {lat!r}")
    raw_unit = side.get("raw_unit", "count")
    meta = dict(side.get("meta") or {}) if isinstance(side.get("meta") or {}, dict) else {}
    if isinstance(raw_unit, dict):  # one unit per instrument: {"gyro": "deg/s", "accel": "g"}
        if not all(isinstance(v, str) for v in raw_unit.values()) or set(raw_unit) - set(geoms):
            raise SessionFormatError(f"{src}: raw_unit must be a string or map instruments {sorted(geoms)} to unit "
                                     f"strings, got {raw_unit!r}")
        meta["raw_units"] = dict(raw_unit)
        raw_unit = "; ".join(f"{k}: {v}" for k, v in raw_unit.items())
    elif not isinstance(raw_unit, str):
        raise SessionFormatError(f"{src}: raw_unit must be a string such as 'count', 'g' or 'rad/s', got {raw_unit!r}")
    segs = []
    for k, d in enumerate(side["segments"]):
        rows = np.flatnonzero(seg_idx == k)
        if rows.size == 0:
            raise SessionFormatError(f"{src}: segment {d['label']!r} (segments[{k}]) has no samples in the data")
        segs.append(_segment_from_sidecar(d, t[rows], {i: raw[i][rows] for i in geoms}, None if temp is None else
                                          temp[rows], gravity, src, k))
    return Session(segs, geoms, float(side["sample_rate_hz"]), None if lat is None else math.radians(float(lat)),
                   gravity, raw_unit, meta)


def read_header(reader: Any, path: Path, need: list[str]) -> list[str]:
    """The header row of a session CSV (stripped), with the columns ``need`` checked present."""
    from ..io.rawtext import csv_header  # rimu.io only when a CSV is read

    return csv_header(reader, need, f"{path} is empty; the first row must be the header {need}",
                      lambda missing, header: f"{path}: header lacks the columns {missing} (header is {header})")


def npz_layout(side: dict, present: Any, path: Path) -> tuple[dict, list[str]]:
    """The geometries of an NPZ session's sidecar and the arrays it must hold, checked against those ``present``."""
    _check_sidecar(side, str(path))
    geoms = sidecar_geometries(side, str(path))
    need = ["t", "segment"] + [f"raw_{k}" for k in geoms]
    missing = [c for c in need if c not in present]
    if missing:
        raise SessionFormatError(f"{path}: arrays {missing} are missing; present: {present}")
    return geoms, need


def _load_csv(path: Path, side: dict, src: Path) -> Session:
    if not path.exists():
        raise SessionFormatError(f"{src}: its data file {path} does not exist")
    geoms = sidecar_geometries(side, str(src))
    need = ["t", "segment"] + _columns(geoms)
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = read_header(reader, path, need)
        unknown = [c for c in header if c not in need and c != "temperature"]
        if unknown:
            raise SessionFormatError(f"{path}: unknown columns {unknown}; expected {need} and optionally 'temperature'")
        num_cols = [c for c in need if c != "segment"] + (["temperature"] if "temperature" in header else [])
        idx = {c: header.index(c) for c in header}
        labels = {str(d["label"]): k for k, d in enumerate(side["segments"])}
        lines = list(reader)
    if not lines:
        raise SessionFormatError(f"{path}: no data rows")
    nh = len(header)
    for r, line in enumerate(lines, start=2):
        if len(line) != nh:
            raise SessionFormatError(f"{path}: row {r} has {len(line)} fields, the header has {nh}")
    ci = [idx[c] for c in num_cols]
    si = idx["segment"]
    segi = []
    for r, line in enumerate(lines, start=2):
        k = labels.get(line[si].strip())
        if k is None:
            raise SessionFormatError(f"{path}: row {r}, column 'segment': label {line[si].strip()!r} is not a "
                                     f"segment of the sidecar ({sorted(labels)})")
        segi.append(k)
    try:
        vals = np.array([[line[c] for c in ci] for line in lines], dtype=float)
    except ValueError:
        vals = None
    if vals is None or (vals.size and not np.all(np.isfinite(vals))):
        for r, line in enumerate(lines, start=2):  # find the first bad cell for the message
            for c in num_cols:
                try:
                    v = float(line[idx[c]])
                except ValueError:
                    raise SessionFormatError(f"{path}: row {r}, column {c!r}: {line[idx[c]]!r} is not a number") from None
                if not math.isfinite(v):
                    raise SessionFormatError(f"{path}: row {r}, column {c!r} is not finite ({v})")
    data = vals
    t = data[:, 0]
    seg_idx = np.array(segi)
    bad = np.flatnonzero((np.diff(t) <= 0) & (np.diff(seg_idx) == 0))
    if bad.size:
        raise SessionFormatError(f"{path}: row {bad[0] + 3}, column 't': time does not increase within segment "
                                 f"{side['segments'][seg_idx[bad[0]]]['label']!r}")
    raw, c0 = {}, 1
    for k in ("gyro", "accel"):
        if k in geoms:
            raw[k] = data[:, c0:c0 + geoms[k].n]
            c0 += geoms[k].n
    temp = data[:, c0] if "temperature" in header else None
    return session_from_sidecar(side, t, seg_idx, raw, temp, str(src))


def _load_npz(path: Path) -> Session:
    import tokenize
    import zipfile
    import zlib

    try:
        npz = np.load(path, allow_pickle=False)
        if not hasattr(npz, "files"):
            raise ValueError("a single .npy array, not an .npz archive")
        with npz:
            arrays = {name: npz[name] for name in npz.files}  # read every member now: damage shows here
    except (OSError, ValueError, EOFError, KeyError, SyntaxError, tokenize.TokenError, zipfile.BadZipFile,
            zlib.error) as exc:
        # (numpy parses each member's header with ast: a damaged header is a SyntaxError)
        raise SessionFormatError(f"{path}: not a readable NPZ file ({exc or type(exc).__name__}); it may be "
                                 "truncated or not written by rimu: write it again with 'rimu simulate' or "
                                 "rimu.session.save_session") from exc

    z, files = arrays, list(arrays)
    for name, a in arrays.items():
        if name != "meta" and a.dtype.kind not in "iuf":
            raise SessionFormatError(f"{path}: array {name!r} holds {a.dtype} values; rimu's NPZ arrays are real "
                                     "numbers (see docs/session-format.md)")
    if "meta" not in files:
        raise SessionFormatError(f"{path}: no 'meta' entry (the JSON sidecar); arrays present: {files}")
    try:
        if z["meta"].dtype.kind not in "US" or z["meta"].ndim != 0:
            raise json.JSONDecodeError("'meta' must be one string", "", 0)
        side = json.loads(str(z["meta"]))
    except json.JSONDecodeError as exc:
        raise SessionFormatError(f"{path}: 'meta' is not valid JSON ({exc})") from exc
    geoms, _ = npz_layout(side, files, path)
    try:
        t = np.asarray(z["t"], dtype=float)
        seg_idx = np.asarray(z["segment"])
    except (ValueError, TypeError, OSError, EOFError) as exc:
        raise SessionFormatError(f"{path}: arrays 't' and 'segment' cannot be read as numbers ({exc})") from exc
    if t.ndim != 1:
        raise SessionFormatError(f"{path}: 't' must be one-dimensional, got shape {t.shape}")
    N = t.shape[0]
    if N == 0:
        raise SessionFormatError(f"{path}: no samples ('t' is empty)")
    if not np.all(np.isfinite(t)):
        raise SessionFormatError(f"{path}: t[{int(np.argmax(~np.isfinite(t)))}] is not finite")
    n_seg = len(side["segments"])
    if (seg_idx.shape != (N,) or not np.all(np.isfinite(seg_idx)) or not np.all(seg_idx == np.round(seg_idx))
            or seg_idx.min() < 0 or seg_idx.max() >= n_seg):
        raise SessionFormatError(f"{path}: 'segment' must hold N={N} integer indices into the {n_seg} segments "
                                 "of meta")
    seg_idx = seg_idx.astype(int)
    raw = {}
    for k, g in geoms.items():
        y = np.asarray(z[f"raw_{k}"], dtype=float)
        if y.shape != (N, g.n):
            raise SessionFormatError(f"{path}: raw_{k} has shape {y.shape}, expected ({N}, {g.n}) "
                                     f"(columns {list(g.names)})")
        if not np.all(np.isfinite(y)):
            r, c = np.argwhere(~np.isfinite(y))[0]
            raise SessionFormatError(f"{path}: raw_{k} row {r}, column {g.names[c]!r} is not finite")
        raw[k] = y
    if seg_idx.shape != (N,) or seg_idx.min() < 0 or seg_idx.max() >= len(side["segments"]):
        raise SessionFormatError(f"{path}: 'segment' must hold N={N} indices into the {len(side['segments'])} "
                                 "segments of meta")
    bad = np.flatnonzero((np.diff(t) <= 0) & (np.diff(seg_idx) == 0))
    if bad.size:
        raise SessionFormatError(f"{path}: t[{bad[0] + 1}] = {t[bad[0] + 1]:.9g} s does not increase after "
                                 f"t[{bad[0]}] = {t[bad[0]]:.9g} s within segment "
                                 f"{side['segments'][seg_idx[bad[0]]]['label']!r}: time must increase within a "
                                 "segment (sort the samples or fix the clock)")
    temp = None
    if "temperature" in files:
        temp = np.asarray(z["temperature"], dtype=float)
        if temp.shape != (N,) or not np.all(np.isfinite(temp)):
            raise SessionFormatError(f"{path}: 'temperature' must hold N={N} finite values, got shape {temp.shape}")
    return session_from_sidecar(side, t, seg_idx, raw, temp, str(path))
