"""Recorded log formats by name: adding a format is one new file plus one line in :data:`FORMATS`.

A format module (``rimu/io/formats/NAME.py``) provides

* ``NAME: str`` and ``EXTRA: str | None``: the pip extra it needs (named in the error when missing);
* ``sniff(name: str, head: bytes) -> bool``: does a file of this name starting with these (decompressed)
  bytes look like this format;
* ``read(path, **options) -> rimu.io.multiimu.MultiImuRecording``: every IMU of the log, each on its own time
  stamps, in SI units (rad/s, m/s^2, s), with ``meta`` saying what was read and rejected;
* optionally ``iter_chunks(path, **options)``: the same data in bounded pieces, for logs that do not fit in memory.

Errors are rimu errors (:mod:`rimu.errors`) that name the file, the line or record, and what to do.

:func:`find_format` picks the format of a file by content and name (the modules are asked in the order of
:data:`FORMATS`, the catch-all ``text`` last); :func:`read_log` and :func:`iter_log` read it. Compressed files
(``.xz``, ``.gz``, ``.bz2``, ``.zst``) are decompressed on the fly (:mod:`rimu.io.formats._open`).

>>> sorted(FORMATS) == sorted(set(FORMATS))
True
"""

from __future__ import annotations

import gzip
import importlib
import lzma
import os
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from ...errors import RimuError, SessionFormatError, TransportError

__all__ = ["FALLBACK", "FORMATS", "find_format", "format_module", "iter_log", "read_log", "register_format"]

#: name -> module path (imported on first use)
FORMATS: dict[str, str] = {
    "rimu": f"{__name__}.rimu_recording",
    "dataflash": f"{__name__}.dataflash",
    "ulog": f"{__name__}.px4_ulog",
    "rosbag": f"{__name__}.rosbag",
    "xsens-dot": f"{__name__}.xsens_dot",
    "ferraris": f"{__name__}.ferraris",
    "pixhawk-csv": f"{__name__}.pixhawk_csv",
    "mpu6050": f"{__name__}.mpu6050",
    "multiimu-csv": f"{__name__}.multiimu_csv",
    "mimu4444": f"{__name__}.mimu4444",
    "navego-mat": f"{__name__}.navego_mat",
}
#: asked last when sniffing (it accepts any numeric text)
FALLBACK = {"text": f"{__name__}.text"}


def register_format(name: str, module: str) -> None:
    """Add a log format implemented by ``module`` under ``name`` (plugins)."""
    FORMATS[name] = module


def format_module(name: str) -> ModuleType:
    """The module registered under ``name``."""
    try:
        target = FORMATS[name] if name in FORMATS else FALLBACK[name]
    except KeyError:
        raise SessionFormatError(f"no log format named {name!r}; known: {sorted(FORMATS) + sorted(FALLBACK)}") from None
    return importlib.import_module(target)


def find_format(path: str | os.PathLike[str]) -> str | None:
    """The name of the format of ``path`` (a file, compressed or not, or a folder) by content and name, or None.

    >>> find_format(Path(__file__).parent)  # this package is no log
    """
    from ._open import head, plain_name

    p = Path(path)
    if not p.exists():
        raise TransportError(f"no file or folder at {p}; check the path")
    data = head(p)
    name = str(p.parent / plain_name(p)) if p.is_file() else str(p)
    for fmt in list(FORMATS) + list(FALLBACK):
        try:
            if format_module(fmt).sniff(name, data):
                return fmt
        except ImportError:
            continue
    return None


def _module_for(path: str | os.PathLike[str], format: str | None) -> ModuleType:
    if format is not None:
        return format_module(format)
    fmt = find_format(path)
    if fmt is None:
        raise SessionFormatError(f"{path}: not a log format rimu knows (by its content and name); give --format "
                                 f"NAME (one of {sorted(FORMATS) + sorted(FALLBACK)}) or a column mapping "
                                 "(--mapping FILE)")
    return format_module(fmt)


def _printable(text: str, limit: int = 160) -> str:
    return "".join(c if c.isprintable() else "?" for c in text)[:limit]


def _malformed(path: Any, name: str, exc: BaseException) -> SessionFormatError:
    """The one error of a reader that met content it does not foresee (never a traceback, never binary text)."""
    if isinstance(exc, UnicodeDecodeError):
        return SessionFormatError(f"{path}: byte {exc.start} of the text is not UTF-8 (binary content in a {name} "
                                  "log); check that the file is the log as written, or give --format")
    return SessionFormatError(f"{path}: malformed {name} log ({type(exc).__name__}: {_printable(str(exc))}); check "
                              "that the file is complete and of this format (--format NAME to force another)")


#: what a reader may raise on content it does not foresee (turned into one SessionFormatError naming the file)
_CONTENT_ERRORS = (ValueError, IndexError, KeyError, TypeError, EOFError, OverflowError, struct.error, lzma.LZMAError,
                   zlib.error, gzip.BadGzipFile)


def read_log(path: str | os.PathLike[str], format: str | None = None, **options: Any) -> Any:
    """Every IMU of a log as a :class:`rimu.io.multiimu.MultiImuRecording` in SI (``format``: found from the
    content and name when None).

    Raises
    ------
    SessionFormatError
        Not a known format, or content the format's reader refuses (the message names the file and the record).
    TransportError
        No such file.
    """
    mod = _module_for(path, format)
    try:
        rec = mod.read(path, **options)
    except (RimuError, ImportError):
        raise
    except _CONTENT_ERRORS as exc:
        raise _malformed(path, mod.NAME, exc) from exc
    rec.meta.setdefault("format", mod.NAME)
    return rec


def iter_log(path: str | os.PathLike[str], format: str | None = None, **options: Any) -> Iterator[Any]:
    """The log in pieces (the format's ``iter_chunks``; one piece for formats without it)."""
    mod = _module_for(path, format)
    if not hasattr(mod, "iter_chunks"):
        yield read_log(path, mod.NAME, **options)
        return
    try:
        yield from mod.iter_chunks(path, **options)
    except (RimuError, ImportError):
        raise
    except _CONTENT_ERRORS as exc:
        raise _malformed(path, mod.NAME, exc) from exc
