"""rimu's recording file (``rimu import -o REC.npz``): every IMU of a log on its own time stamps, in SI, with what
was read and rejected.

An ``.npz`` (numpy zip, uncompressed members) whose first member ``rimu_recording`` is a JSON text
(``format: rimu.recording``, ``version``, ``imus`` in order, ``meta`` of the reader: source, format, units read
from, rejected records by reason), then per IMU ``<k>.t`` (N,) [s], ``<k>.gyro`` (N, 3) [rad/s], ``<k>.accel``
(N, 3) [m/s^2], ``<k>.temperature`` (N,) [degC] where present (k the IMU's index in ``imus``).
:class:`RecordingWriter` writes one piece at a time (each array goes to a scratch file, then into the zip in
blocks), so importing a long log never holds it in memory.

>>> import tempfile, pathlib
>>> from rimu.io.multiimu import ImuStream, MultiImuRecording
>>> p = pathlib.Path(tempfile.mkdtemp()) / "rec.npz"
>>> rec = MultiImuRecording([ImuStream("a", np.arange(3.0), np.zeros((3, 3)), np.ones((3, 3)))], {"x": 1})
>>> _ = save_recording(rec, p); r = read(p); r.names, r["a"].accel[2].tolist(), r.meta["x"]
(['a'], [1.0, 1.0, 1.0], 1)
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..multiimu import ImuStream, MultiImuRecording

__all__ = ["EXTRA", "FORMAT", "NAME", "VERSION", "RecordingWriter", "read", "save_recording", "sniff"]

NAME = "rimu"
EXTRA = None
FORMAT = "rimu.recording"
VERSION = 1
_FIELDS = (("t", 1), ("gyro", 3), ("accel", 3), ("temperature", 1))


def sniff(name: str, head: bytes) -> bool:
    """A zip whose first member is ``rimu_recording.npy``."""
    return head[:4] == b"PK\x03\x04" and head[30:48] == b"rimu_recording.npy"


class RecordingWriter:
    """Write a recording piece by piece (:meth:`add`), then :meth:`close` (the file appears whole) or
    :meth:`abort`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._dir = Path(tempfile.mkdtemp(prefix="rimu-rec-", dir=self.path.parent if self.path.parent.exists()
                                          else None))
        self.names: list[str] = []
        self.counts: dict[str, int] = {}
        self._has: dict[str, set[str]] = {}
        self._fh: dict[tuple[str, str], Any] = {}

    def add(self, rec: MultiImuRecording) -> None:
        for u in rec.units:
            if u.name not in self.counts:
                self.names.append(u.name)
                self.counts[u.name] = 0
                self._has[u.name] = {f for f, _ in _FIELDS if getattr(u, f) is not None}
            k = self.names.index(u.name)
            for f, _ in _FIELDS:
                if f not in self._has[u.name]:
                    continue
                v = getattr(u, f)
                if v is None:
                    v = np.full((len(u), 3) if f in ("gyro", "accel") else len(u), np.nan)
                key = (u.name, f)
                if key not in self._fh:
                    self._fh[key] = open(self._dir / f"{k}.{f}", "wb")
                self._fh[key].write(np.ascontiguousarray(v, dtype="<f8").tobytes())
            self.counts[u.name] += len(u)

    def close(self, meta: dict[str, Any]) -> Path:
        from ...atomic import atomic_path

        for fh in self._fh.values():
            fh.close()
        head = {"format": FORMAT, "version": VERSION, "imus": self.names,
                "samples": [self.counts[n] for n in self.names], "meta": meta}
        try:
            with atomic_path(self.path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
                with z.open("rimu_recording.npy", "w") as m:
                    np.lib.format.write_array(m, np.array(json.dumps(head, default=str)))
                for k, name in enumerate(self.names):
                    for f, width in _FIELDS:
                        if f not in self._has[name]:
                            continue
                        n = self.counts[name]
                        shape = (n,) if width == 1 else (n, width)
                        with z.open(f"{k}.{f}.npy", "w", force_zip64=True) as m:
                            np.lib.format.write_array_header_2_0(
                                m, {"descr": "<f8", "fortran_order": False, "shape": shape})
                            with open(self._dir / f"{k}.{f}", "rb") as src:
                                shutil.copyfileobj(src, m, 1 << 20)
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)
        return self.path

    def abort(self) -> None:
        for fh in self._fh.values():
            fh.close()
        shutil.rmtree(self._dir, ignore_errors=True)


def save_recording(rec: MultiImuRecording, path: str | os.PathLike[str]) -> Path:
    """Write a whole recording (see :class:`RecordingWriter` for pieces)."""
    w = RecordingWriter(path)
    try:
        w.add(rec)
    except BaseException:
        w.abort()
        raise
    return w.close(rec.meta)


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Read a recording file (arrays memory-mapped where the zip allows, else loaded)."""
    p = Path(path)
    try:
        z = np.load(p, allow_pickle=False)
        head = json.loads(str(z["rimu_recording"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:  # (EOFError: an empty file)
        raise SessionFormatError(f"{p}: not a readable rimu recording ({type(exc).__name__}); write it with "
                                 "'rimu import LOG -o REC.npz'") from None
    if head.get("format") != FORMAT or head.get("version") != VERSION:
        raise SessionFormatError(f"{p}: format {head.get('format')!r} version {head.get('version')!r} is not "
                                 f"{FORMAT} {VERSION}")
    units = []
    for k, name in enumerate(head["imus"]):
        def get(f: str, k: int = k) -> np.ndarray | None:
            key = f"{k}.{f}"
            return np.asarray(z[key], float) if key in z.files else None
        t = get("t")
        if t is None:
            raise SessionFormatError(f"{p}: IMU {name!r} has no time stamps ({k}.t)")
        units.append(ImuStream(name, t, get("gyro"), get("accel"), get("temperature")))
    return MultiImuRecording(units, dict(head.get("meta") or {}))
