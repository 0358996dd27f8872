"""Accounting of everything a source receives: nothing is dropped without being counted.

Every unit of input (a CAN frame, or a byte of a serial stream) that reaches a source is counted once as
*received* and, as soon as the source has decided about it, once as *accepted* or as *rejected* with a reason.
Units a source holds but has not decided about yet (bytes of a serial frame whose end has not arrived) are
*pending*. The identity

    received == accepted + sum(rejected.values()) + pending

holds after every call into a source, and :meth:`Accounting.check` verifies it. ``events`` counts things
that happen to the stream but are not units of input (a counter gap, an epoch completed with a missing frame,
a reconnect); they are reported, not part of the identity.

Rejected raw data can be kept for later inspection in a side log (:class:`SideLog`).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from ..errors import RimuError

__all__ = ["Accounting", "AccountingError", "SideLog"]


class AccountingError(RimuError, AssertionError):
    """The accounting identity received = accepted + rejected + pending does not hold (a bug in a source)."""


class SideLog:
    """Keeps rejected raw data: in memory (``max_items`` most recent) and/or as JSON lines in a file.

    Each record is ``{"reason": ..., "t": ..., "data": hex string, ...extra}``.
    """

    def __init__(self, path: str | os.PathLike[str] | None = None, max_items: int | None = 10000) -> None:
        self.path = None if path is None else Path(path)
        self.max_items = max_items
        self.items: list[dict[str, Any]] = []
        self._fh: TextIO | None = None
        if self.path is not None:
            self._fh = open(self.path, "a", encoding="utf-8")

    def add(self, reason: str, data: bytes | bytearray | memoryview, t: float | None = None, **extra: Any) -> None:
        rec = {"reason": reason, "t": t, "data": bytes(data).hex(), **extra}
        if self.max_items is None or self.max_items > 0:
            self.items.append(rec)
            if self.max_items is not None and len(self.items) > self.max_items:
                del self.items[: len(self.items) - self.max_items]
        if self._fh is not None:
            self._fh.write(json.dumps(rec) + "\n")

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


@dataclass
class Accounting:
    """Counters of one source.

    Attributes
    ----------
    unit : str
        What is counted: ``"frame"`` (CAN) or ``"byte"`` (serial).
    received, accepted : int
    rejected : Counter
        Rejected units by reason.
    events : Counter
        Stream events (not units): ``counter_gap``, ``missing_epochs``, ``missing_frame``, ``reconnect``, ...
    pending_fn : callable returning int, optional
        Units held and not yet decided (serial: bytes in the resynchronisation buffer).
    side_log : SideLog, optional
        Where rejected raw data goes.
    """

    unit: str = "frame"
    received: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    events: Counter = field(default_factory=Counter)
    epochs: int = 0
    pending_fn: Callable[[], int] | None = field(default=None, repr=False)
    side_log: SideLog | None = field(default=None, repr=False)

    @property
    def pending(self) -> int:
        return 0 if self.pending_fn is None else int(self.pending_fn())

    @property
    def rejected_total(self) -> int:
        return int(sum(self.rejected.values()))

    def reject(self, reason: str, n: int = 1, data: bytes | None = None, t: float | None = None, **extra: Any) -> None:
        """Count ``n`` units rejected for ``reason`` (and keep ``data`` in the side log)."""
        if n:
            self.rejected[reason] += n
            if self.side_log is not None and data is not None:
                self.side_log.add(reason, data, t, **extra)

    def event(self, name: str, n: int = 1) -> None:
        if n:
            self.events[name] += n

    def identity_holds(self) -> bool:
        return self.received == self.accepted + self.rejected_total + self.pending

    def check(self) -> None:
        """Raise :class:`AccountingError` if received != accepted + rejected + pending."""
        if not self.identity_holds():
            raise AccountingError(
                f"accounting identity broken: received {self.received} != accepted {self.accepted} + "
                f"rejected {self.rejected_total} + pending {self.pending}")

    def as_dict(self) -> dict[str, Any]:
        return {"unit": self.unit, "received": self.received, "accepted": self.accepted,
                "rejected": dict(self.rejected), "rejected_total": self.rejected_total, "pending": self.pending,
                "events": dict(self.events), "epochs": self.epochs, "identity_holds": self.identity_holds()}

    def summary(self) -> str:
        """One readable line, e.g. for a status line or a final report.

        >>> a = Accounting("frame", received=10, accepted=8)
        >>> a.reject("crc", 2)
        >>> a.summary()
        'frames: received 10 = accepted 8 + rejected 2 (crc 2) + pending 0; epochs 0'
        """
        rej = ", ".join(f"{k} {v}" for k, v in sorted(self.rejected.items()))
        ev = ", ".join(f"{k} {v}" for k, v in sorted(self.events.items()))
        s = (f"{self.unit}s: received {self.received} = accepted {self.accepted} + rejected {self.rejected_total}"
             + (f" ({rej})" if rej else "") + f" + pending {self.pending}; epochs {self.epochs}")
        return s + (f"; events: {ev}" if ev else "")
