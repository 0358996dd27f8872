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

__all__ = ["Accounting", "AccountingError", "Outages", "SideLog"]


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


class Outages:
    """Outages per instrument in a stream of epochs: runs of consecutive epochs in which none of an instrument's
    sensors delivers a valid value (every gyro dropped out). What a live summary reports beside the accounting.

    >>> import numpy as np
    >>> from rimu.epoch import Epoch
    >>> o = Outages()
    >>> for k in range(10):
    ...     o.update(Epoch(k * 0.01, {"gyro": np.zeros(3), "accel": np.zeros(3)},
    ...                    {"gyro": np.full(3, not 3 <= k < 7)}))
    >>> o.as_dict()["gyro"]
    {'outages': 1, 'epochs': 4, 'longest_epochs': 4, 'longest_s': 0.03, 'first_t_s': 0.03}
    >>> o.as_dict()["accel"]["outages"], o.summary()
    (0, 'gyro: 1 outage (4 epochs, longest 4 epochs = 0.03 s, first at t = 0.03 s); accel: no outage')
    """

    def __init__(self) -> None:
        self._stats: dict[str, dict[str, Any]] = {}
        self._open: dict[str, tuple[float, int]] = {}
        self._last_t: float | None = None

    def update(self, ep: Any) -> None:
        """Count one epoch."""
        for k in ep.raw:
            s = self._stats.setdefault(k, {"outages": 0, "epochs": 0, "longest_epochs": 0, "longest_s": 0.0,
                                           "first_t_s": None})
            out = not bool(ep.valid_mask(k).any())
            if out:
                s["epochs"] += 1
                if k not in self._open:
                    self._open[k] = (float(ep.t), 0)
                    s["outages"] += 1
                    if s["first_t_s"] is None:
                        s["first_t_s"] = float(ep.t)
                t0, n = self._open[k]
                self._open[k] = (t0, n + 1)
                if n + 1 > s["longest_epochs"]:
                    s["longest_epochs"], s["longest_s"] = n + 1, round(float(ep.t) - t0, 9)
            else:
                self._open.pop(k, None)

    def as_dict(self) -> dict[str, dict[str, Any]]:
        """Per instrument: ``outages`` (runs), ``epochs`` (in all of them), the longest run in epochs and in s
        (first to last epoch of the run), and the time of the first."""
        return {k: dict(v) for k, v in self._stats.items()}

    def summary(self) -> str:
        parts = []
        for k, s in self._stats.items():
            if not s["outages"]:
                parts.append(f"{k}: no outage")
                continue
            parts.append(f"{k}: {s['outages']} outage{'s' if s['outages'] > 1 else ''} ({s['epochs']} epochs, longest "
                         f"{s['longest_epochs']} epochs = {s['longest_s']:.4g} s, first at t = {s['first_t_s']:.4g} s)")
        return "; ".join(parts)
