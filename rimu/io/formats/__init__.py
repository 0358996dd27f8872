"""Recorded log formats by name: adding a format is one new file plus one line in :data:`FORMATS`.

A format module (``rimu/io/formats/NAME.py``) provides

* ``NAME: str`` and ``EXTRA: str | None``: the pip extra it needs (named in the error when missing);
* ``sniff(name: str, head: bytes) -> bool``: does a file of this name starting with these (decompressed)
  bytes look like this format;
* ``read(path, **options) -> rimu.io.multiimu.MultiImuRecording``: every IMU of the log, each on its own time
  stamps, in SI units (rad/s, m/s^2, s), with ``meta`` saying what was read and rejected;
* optionally ``iter_chunks(path, **options)``: the same data in bounded pieces, for logs that do not fit in memory.

Errors are rimu errors (:mod:`rimu.errors`) that name the file, the line or record, and what to do.

>>> sorted(FORMATS) == sorted(set(FORMATS))
True
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ...errors import SessionFormatError

__all__ = ["FORMATS", "format_module", "register_format"]

#: name -> module path (imported on first use)
FORMATS: dict[str, str] = {
    "mimu4444": "rimu.io.formats.mimu4444",
}


def register_format(name: str, module: str) -> None:
    """Add a log format implemented by ``module`` under ``name`` (plugins)."""
    FORMATS[name] = module


def format_module(name: str) -> ModuleType:
    """The module registered under ``name``."""
    try:
        target = FORMATS[name]
    except KeyError:
        raise SessionFormatError(f"no log format named {name!r}; known: {sorted(FORMATS)}") from None
    return importlib.import_module(target)
