"""Data in: CAN (python-can) and serial (pyserial) sources, live and recorded, turned into epochs.

Every source yields :class:`~rimu.epoch.Epoch` objects (iterator, callback or ``async for``) and counts every
frame or byte it receives (:class:`~rimu.io.accounting.Accounting`). Sources are registered by name and
imported lazily (:func:`open_source`); transports live one per file.

>>> from rimu.io import SOURCES
>>> sorted(SOURCES)[:3]
['block', 'can', 'can-replay']
"""

from __future__ import annotations

import importlib
from typing import Any

from .accounting import Accounting, AccountingError, SideLog
from .base import ReconnectPolicy, Source
from .layout import CanCodec, Layout, Message, Signal, load_layout
from .registry import SOURCES, open_source, register_source, source_class

__all__ = [
    "Accounting",
    "AccountingError",
    "SideLog",
    "Source",
    "Layout",
    "Message",
    "Signal",
    "CanCodec",
    "load_layout",
    "SOURCES",
    "open_source",
    "register_source",
    "source_class",
    "CanSource",
    "CanReplaySource",
    "SerialSource",
    "SerialFileSource",
    "SerialDecoder",
    "CanDevice",
    "SerialDevice",
    "BlockSource",
    "ReconnectPolicy",
]

_LAZY = {
    "CanSource": "can", "CanReplaySource": "can",
    "SerialSource": "serial", "SerialFileSource": "serial", "SerialDecoder": "serial",
    "CanDevice": "device", "SerialDevice": "device", "BlockSource": "device",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
