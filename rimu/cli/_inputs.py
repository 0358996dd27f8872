"""The one way every command opens what it is given: a rimu session file, a rimu recording, imucal's Ferraris
folder, or any recorded log that :mod:`rimu.io.formats` knows (found from the content and the name, compressed or
not).

:func:`open_session` returns a :class:`rimu.session.Session` (a log becomes one segment of every IMU on the
first IMU's time base, SI, its geometry k parallel triads named after the IMUs); :func:`session_file` a path of a
session file that streaming commands read in chunks (the log imported once into a scratch ``.npz``);
:func:`open_recording` the log's IMUs each on its own stamps. Logs are checked at the door
(:func:`check_recording`): the specific force of every IMU at rest must be one gravity (rimu.session.checks)
and the gyros' rates plausible for rad/s, so counts are never taken as SI nor deg/s as rad/s.
"""

from __future__ import annotations

import argparse
import atexit
import logging
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["add_log_options", "check_recording", "is_session_file", "log_options", "open_array", "open_raw",
           "open_recording", "open_session", "recording_session", "session_file"]

log = logging.getLogger("rimu.cli")

#: fastest plausible rotation of a vehicle or a hand, rad/s (MEMS gyros saturate at 2000-4000 deg/s = 35-70 rad/s)
MAX_RATE_RAD_S = 70.0


def add_log_options(p: argparse.ArgumentParser) -> None:
    """``--format NAME`` and ``--mapping FILE`` (and declared units) for commands that accept logs."""
    g = p.add_argument_group("recorded logs (read directly; rimu import --help lists the formats)")
    g.add_argument("--format", default=None, metavar="NAME", help="log format (default: found from content and name)")
    g.add_argument("--mapping", default=None, metavar="FILE", help="column mapping of a multi-IMU CSV (JSON)")
    g.add_argument("--gyro-unit", default=None, help="gyro unit of a text log that does not state it (rad/s, deg/s, "
                   "or SI per count)")
    g.add_argument("--accel-unit", default=None, help="accelerometer unit of a text log (m/s^2, g, mg, or SI per "
                   "count)")


def _unit(text: str | None) -> Any:
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        return text


def log_options(args: argparse.Namespace | None) -> dict[str, Any]:
    """The reader options of the parsed ``--format``/``--mapping``/``--*-unit`` (absent ones left out)."""
    if args is None:
        return {}
    out: dict[str, Any] = {}
    if getattr(args, "format", None):
        out["format"] = args.format
    if getattr(args, "mapping", None):
        out["mapping"] = args.mapping
        out.setdefault("format", "multiimu-csv")
    for k in ("gyro_unit", "accel_unit"):
        if getattr(args, k, None) is not None:
            out[k] = _unit(getattr(args, k))
    return out


def is_session_file(path: str | os.PathLike[str]) -> bool:
    """Is ``path`` a session in rimu's format (``.npz`` of a session, ``.csv`` with its ``.json`` sidecar, the
    sidecar itself)?"""
    p = Path(path)
    if not p.is_file():
        return False
    if p.suffix == ".json":
        return True
    if p.suffix == ".csv":
        return p.with_suffix(".json").exists()
    if p.suffix == ".npz":
        from ..io.formats._open import head

        return head(p, 64)[30:48] != b"rimu_recording.npy"
    return False


def _not_a_log(p: Path) -> bool:
    """No log format but the catch-all text claims ``p``."""
    from ..io.formats import find_format

    return find_format(p) in (None, "text")


def _is_ferraris(p: Path) -> bool:
    from ..io.formats import format_module

    return p.is_dir() and bool(format_module("ferraris").sniff(str(p), b""))


def open_recording(path: str | os.PathLike[str], args: argparse.Namespace | None = None, checks: str = "strict",
                   **options: Any) -> Any:
    """Every IMU of a log (:func:`rimu.io.formats.read_log`), checked at the door (:func:`check_recording`)."""
    from ..io.formats import read_log

    opts = {**log_options(args), **options}
    rec = read_log(path, **opts)
    if checks != "off":
        from ..session.checks import enforce

        enforce(check_recording(rec, str(path)), checks)
    return rec


def check_recording(rec: Any, source: str = "") -> list[Any]:
    """Plausibility of a recording in SI: every IMU's still spans (gyro and accelerometer quiet over 1 s) must
    measure one gravity (:func:`rimu.session.checks.check_session` on them, declared m/s^2), and no gyro may turn
    faster than :data:`MAX_RATE_RAD_S` over a tenth of its samples (deg/s taken as rad/s would)."""
    from ..geometry import triads
    from ..session import Segment, Session
    from ..session.checks import Finding, check_session

    found = []
    for u in rec.units:
        if u.gyro is not None and len(u) > 10:
            w = np.linalg.norm(u.gyro, axis=1)
            w = w[np.isfinite(w)]
            if len(w) and float(np.quantile(w, 0.9)) > MAX_RATE_RAD_S:
                found.append(Finding("units", "error", f"{source}: {u.name}: gyro rates of "
                                     f"{np.quantile(w, 0.9):.3g} rad/s in a tenth of the samples; the values look "
                                     "like deg/s or counts: declare the unit (--gyro-unit, or the mapping)", "gyro"))
        if u.accel is None or len(u) < 20 or not np.isfinite(u.period_s) or u.period_s <= 0:
            continue
        n = max(5, int(round(1.0 / u.period_s)))
        m = len(u) // n
        if m < 1:
            continue
        a = u.accel[: m * n].reshape(m, n, 3)
        sd = np.nanstd(a, axis=1).max(axis=1)
        if u.gyro is not None:
            sd_g = np.nanstd(u.gyro[: m * n].reshape(m, n, 3), axis=1).max(axis=1)
        else:
            sd_g = np.zeros(m)
        mean = np.nanmean(a, axis=1)
        ok = np.isfinite(sd) & np.isfinite(mean).all(1)
        if not ok.any():
            continue
        # still: the quietest windows, and quiet in absolute terms against their own magnitude
        quiet = ok & (sd <= max(np.nanquantile(sd[ok], 0.2), 1e-12) * 1.5) & \
            (sd < 0.05 * np.linalg.norm(mean, axis=1) + 1e-9)
        if u.gyro is not None:
            quiet &= sd_g <= np.nanquantile(sd_g[ok], 0.5) * 2 + 1e-12
        if not quiet.any():
            continue
        segs = []
        for j in np.flatnonzero(quiet)[:50]:
            t_j, a_j = u.t[j * n:(j + 1) * n], u.accel[j * n:(j + 1) * n]
            fin = np.isfinite(a_j).all(axis=1)  # a NaN row is an invalid sample, not a measurement
            if fin.sum() >= 2:
                segs.append(Segment(f"{u.name}_rest{j}", "static_unknown", t_j[fin], {"accel": a_j[fin]}))
        if not segs:
            continue
        s = Session(segs, {"accel": triads(1)}, 1.0 / u.period_s, raw_unit={"accel": "m/s^2"})
        for f in check_session(s, source):
            if f.check == "units":
                found.append(Finding(f.check, f.level, f.message.replace("accel:", f"{u.name}: accel:", 1)
                                     + " (or give --accel-unit / the mapping's accel_unit)", f.where))
    return found


def recording_session(rec: Any, kind: str = "motion", label: str | None = None, keep_invalid: bool = False) -> Any:
    """A recording as a one-segment :class:`rimu.session.Session`: the IMUs on the first one's time base
    (:meth:`MultiImuRecording.to_block`), the epochs where every IMU is valid (``keep_invalid``: every epoch, an
    invalid sample as NaN, for a replay that decides on it), raw values in SI (``raw_unit`` rad/s and m/s^2), k
    parallel triads named after the IMUs."""
    from ..errors import SessionFormatError
    from ..session import Segment, Session

    block = rec.to_block()
    insts = rec.instruments()
    if not insts:
        raise SessionFormatError(f"{rec.meta.get('source')}: the IMUs share no instrument (gyro, accel)")
    ok = np.ones(len(block.t), bool)
    for k in insts:
        ok &= block.valid[k].all(axis=1)
    if keep_invalid and ok.sum() >= 2:
        ok = np.zeros(len(block.t), bool)
        for k in insts:
            ok |= block.valid[k].any(axis=1)   # an epoch with any valid sample; the invalid ones as NaN
        raw = {k: np.where(block.valid[k], block.raw[k], np.nan) for k in insts}
        block = type(block)(block.t, raw, block.valid, block.temperature)
    dropped = int(len(ok) - ok.sum())
    if dropped and ok.sum() >= 2:   # a counted, reported rejection: never lost without a word
        log.warning("%s: %d of %d epochs left out: %s", rec.meta.get("source"), dropped, len(ok),
                    "no IMU has a valid sample there" if keep_invalid
                    else "not every IMU has a valid sample there (rimu replay decides on them instead)")
    if ok.sum() < 2:
        raise SessionFormatError(f"{rec.meta.get('source')}: fewer than 2 epochs where every IMU ({rec.names}) has a "
                                 "valid sample; the IMUs do not overlap in time")
    t = block.t[ok]
    seg = Segment(label or "log", kind, t, {k: block.raw[k][ok] for k in insts},
                  None if block.temperature is None else block.temperature[ok],
                  meta={"imus": rec.names})
    geo = rec.geometry()
    rate = 1.0 / float(np.median(np.diff(t)))
    meta = {k: v for k, v in rec.meta.items() if isinstance(v, (str, int, float, bool, list, dict))}
    return Session([seg], {k: geo for k in insts}, rate, raw_unit="SI",
                   meta={"recording": meta, "raw_units": {"gyro": "rad/s", "accel": "m/s^2"},
                         "epochs_left_out": dropped})


def open_session(path: str | os.PathLike[str], checks: str = "strict", kind: str = "motion",
                 args: argparse.Namespace | None = None, keep_invalid: bool = False) -> Any:
    """A Session of whatever ``path`` is: a session file (:func:`rimu.session.load_session`), imucal's Ferraris
    folder (:func:`rimu.session.load_ferraris`), or a log (:func:`open_recording` + :func:`recording_session`;
    its one segment is of ``kind``)."""
    from ..errors import SessionFormatError
    from ..session import load_ferraris, load_session

    p = Path(path)
    if not p.exists():
        raise SessionFormatError(f"{p} does not exist; give a session file, a log (rimu import --help lists the "
                                 "formats) or a Ferraris recording folder")
    if is_session_file(p):
        return load_session(p, checks=checks)
    if _is_ferraris(p):
        return load_ferraris(p)
    if p.suffix in (".npz", ".csv", ".json") and not log_options(args) and _not_a_log(p):
        return load_session(p, checks=checks)  # meant as a session: its reader says what is wrong with it
    rec = open_recording(p, args, checks)
    return recording_session(rec, kind, keep_invalid=keep_invalid)


_SCRATCH: list[str] = []


def _cleanup() -> None:
    for d in _SCRATCH:
        shutil.rmtree(d, ignore_errors=True)


def session_file(path: str | os.PathLike[str], checks: str = "strict", kind: str = "motion",
                 args: argparse.Namespace | None = None) -> Path:
    """``path`` itself if it is a session file, else the session of the log or folder written once to a scratch
    ``.npz`` (removed at exit), for commands that stream a session file."""
    from ..session import save_session

    p = Path(path)
    if is_session_file(p):
        return p
    s = open_session(p, checks, kind, args, keep_invalid=True)   # replayed: an invalid sample is decided on, not dropped
    if not _SCRATCH:
        _SCRATCH.append(tempfile.mkdtemp(prefix="rimu-in-"))
        atexit.register(_cleanup)
    out = Path(_SCRATCH[0]) / (p.name.replace(".", "_") + ".npz")
    written = Path(save_session(s, out))
    # the command's output group holds atomic writes back until it ends; this scratch file is read now
    from ..atomic import flush_outputs

    flush_outputs()
    return written


def open_raw(path: str | os.PathLike[str], rate: float | None, accel: Any, gyro: Any, time: Any,
             args: argparse.Namespace | None = None, imu: str | None = None) -> Any:
    """A :class:`rimu.io.rawtext.RawLog` of one IMU for ``rimu detect``: a text log as it is (counts or any
    unit, :func:`rimu.io.rawtext.read_raw_text`), or one IMU (``imu``, default the first) of any other log in SI."""
    from ..io.formats import find_format
    from ..io.rawtext import RawLog, read_raw_text

    opts = log_options(args)
    fmt = opts.get("format") or (find_format(path) if Path(path).exists() else None)
    if fmt in (None, "text", "mpu6050") and "mapping" not in opts:
        return read_raw_text(path, rate, accel, gyro, time)
    rec = open_recording(path, args)
    u = rec[imu] if imu else rec.units[0]
    raw = {k: getattr(u, k) for k in ("accel", "gyro") if getattr(u, k) is not None}
    ok = np.all([np.isfinite(v).all(axis=1) for v in raw.values()], axis=0)
    fs = rate or 1.0 / u.period_s
    return RawLog(u.t[ok] - u.t[ok][0], {k: v[ok] for k, v in raw.items()}, fs,
                  {k: [f"{u.name}_{k}_{a}" for a in "xyz"] for k in raw}, {"imu": u.name, **rec.meta})


def open_array(path: str | os.PathLike[str], args: argparse.Namespace | None = None) -> Any:
    """``(ArrayLayout, t, gyro (N, k, 3), accel (N, k, 3) or None)`` of a log for ``rimu array`` (its IMUs on
    the first one's time base, where every IMU is valid; identity rotations, unknown positions), or None when
    ``path`` is an array ``.npz`` of ``rimu array``'s own shape."""
    from ..array import ArrayLayout

    p = Path(path)
    if p.suffix == ".npz" and p.is_file() and not log_options(args):
        try:
            with np.load(p, allow_pickle=False) as z:
                if "gyro" in z.files and "t" in z.files:
                    return None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            return None  # not an archive: rimu array's own reader names what is wrong
        if _not_a_log(p):
            return None
    rec = open_recording(p, args)
    block = rec.to_block()
    k = len(rec.units)
    ok = np.all([block.valid[i].all(axis=1) for i in rec.instruments()], axis=0)
    gyro = block.raw["gyro"][ok].reshape(-1, k, 3)
    accel = block.raw["accel"][ok].reshape(-1, k, 3) if "accel" in block.raw else None
    rot, pos = np.repeat(np.eye(3)[None], k, axis=0), np.zeros((k, 3))
    geo = _format_geometry(rec, k)
    if geo is not None:  # a device format that knows its board (mimu4444): rotations and nominal positions
        rot = np.stack([su.mat_sb_mb.T for su in geo.subunits])
        pos = np.stack([np.zeros(3) if su.position_mb_m is None else su.position_mb_m for su in geo.subunits])
    layout = ArrayLayout(rot, pos, tuple(rec.names))
    return layout, block.t[ok], gyro, accel


def _format_geometry(rec: Any, k: int) -> Any:
    """The geometry a log format gives for its device (``geometry()`` of its module), when it has k triads."""
    from ..io.formats import FORMATS, format_module

    name = rec.meta.get("format")
    if name not in FORMATS:
        return None
    mod = format_module(name)
    geo = mod.geometry() if hasattr(mod, "geometry") else None
    return geo if geo is not None and len(geo.subunits) == k else None


class _LogSource:
    """Factory of the epoch source of a log (a :class:`rimu.io.multiimu.MultiImuCsvSource` over the recording)."""

    @staticmethod
    def make(rec: Any) -> Any:
        from ..io.multiimu import MultiImuCsvSource

        class LogSource(MultiImuCsvSource):
            def _read(self, mapping: Any, path: Any) -> Any:
                return rec

        return LogSource(mapping=rec)


def log_source(path: str | os.PathLike[str], args: argparse.Namespace | None = None) -> Any:
    """The epoch source of an IMU log for ``rimu monitor --replay`` (every IMU on the first one's time base, SI),
    or None when ``path`` is no IMU log rimu's formats know (then it is a python-can log)."""
    from ..io.formats import find_format

    p = Path(path)
    if not p.exists():
        return None
    opts = log_options(args)
    if "format" not in opts and find_format(p) in (None, "text"):
        return None
    return _LogSource.make(open_recording(p, args))
