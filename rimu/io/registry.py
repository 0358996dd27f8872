"""Sources by name, imported lazily: adding a transport is one new file plus one line in :data:`SOURCES`."""

from __future__ import annotations

import importlib
from typing import Any

from ..errors import TransportError
from .base import Source

__all__ = ["SOURCES", "open_source", "source_class", "register_source"]

#: name -> "module:Class" (imported on first use)
SOURCES: dict[str, str] = {
    "can": "rimu.io.can:CanSource",
    "can-replay": "rimu.io.can:CanReplaySource",
    "serial": "rimu.io.serial:SerialSource",
    "serial-replay": "rimu.io.serial:SerialFileSource",
    "csv": "rimu.io.recorded:CsvSource",
    "npz": "rimu.io.recorded:NpzSource",
    "ulog": "rimu.io.ulog:ULogSource",
    "block": "rimu.io.device:BlockSource",
    "multi-imu-csv": "rimu.io.multiimu:MultiImuCsvSource",
    "pixhawk-dual": "rimu.io.pixhawk_dual:PixhawkDualSource",
    "xsens-dot": "rimu.io.xsens_dot:XsensDotSource",
    "mpu6050-csv": "rimu.io.mpu6050_csv:Mpu6050CsvSource",
    "mimu4444": "rimu.io.formats.mimu4444:Mimu4444SerialSource",
    "mimu4444-file": "rimu.io.formats.mimu4444:Mimu4444FileSource",
}


def register_source(name: str, target: str) -> None:
    """Add a source ``"module:Class"`` under ``name`` (plugins)."""
    SOURCES[name] = target


def source_class(name: str) -> type[Source]:
    """The class registered under ``name``.

    >>> source_class("can").__name__
    'CanSource'
    """
    try:
        target = SOURCES[name]
    except KeyError:
        raise TransportError(f"no source named {name!r}; known: {sorted(SOURCES)}") from None
    mod, _, cls = target.partition(":")
    return getattr(importlib.import_module(mod), cls)


def open_source(name: str, **kwargs: Any) -> Source:
    """Create the source registered under ``name`` with ``kwargs``."""
    return source_class(name)(**kwargs)
