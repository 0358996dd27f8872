"""The one interface every data source implements: epochs out, as an iterator, a callback loop or asyncio.

A source implements a single hook, :meth:`Source._epochs`, a generator of :class:`~rimu.epoch.Epoch`; the
rest (block reading, callbacks, ``async for``, context management, accounting) comes from this class, in the
way python-can's ``BusABC`` asks a backend for ``_recv_internal`` only.
"""

from __future__ import annotations

import asyncio
import threading
from abc import ABC, abstractmethod
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass

from ..epoch import Epoch, EpochBlock
from ..errors import ShapeError
from .accounting import Accounting, SideLog

__all__ = ["Source", "ReconnectPolicy"]


class Source(ABC):
    """Base of every rimu data source.

    Attributes
    ----------
    accounting : Accounting
        Received / accepted / rejected counters (``source.accounting.check()`` verifies the identity).
    stop_event : threading.Event
        Set it (or call :meth:`stop`) to end a live source's iteration cleanly.
    """

    unit = "frame"

    def __init__(self, side_log: SideLog | None = None) -> None:
        self.accounting = Accounting(self.unit, side_log=side_log)
        self.stop_event = threading.Event()

    @abstractmethod
    def _epochs(self) -> Iterator[Epoch]:
        """Yield epochs until the data end or :attr:`stop_event` is set."""

    def _accepted(self, ep: Epoch, counter: str, value: int) -> Epoch:
        """``ep`` counted as accepted (one epoch), with ``ep.counters[counter] = value``."""
        self.accounting.accepted += 1
        self.accounting.epochs += 1
        ep.counters[counter] = value
        return ep

    # ------------------------------------------------------------------ styles of use
    def __iter__(self) -> Iterator[Epoch]:
        return self._epochs()

    def read_block(self, max_epochs: int | None = None) -> EpochBlock:
        """Collect epochs into an :class:`EpochBlock` (all of them, or the first ``max_epochs``)."""
        eps = []
        for ep in self._epochs():
            eps.append(ep)
            if max_epochs is not None and len(eps) >= max_epochs:
                break
        if not eps:
            raise ShapeError("the source produced no epochs")
        block = EpochBlock.from_epochs(eps)
        block.meta["counters"] = [e.counters for e in eps]
        block.meta["accounting"] = self.accounting.as_dict()
        return block

    def run(self, callback: Callable[[Epoch], object], max_epochs: int | None = None) -> int:
        """Call ``callback(epoch)`` for every epoch; a callback returning ``False`` stops. Returns the count."""
        n = 0
        for ep in self._epochs():
            n += 1
            if callback(ep) is False or (max_epochs is not None and n >= max_epochs):
                break
        return n

    async def aepochs(self) -> AsyncIterator[Epoch]:
        """``async for epoch in source.aepochs()``: the blocking reads run in a worker thread."""
        it = self._epochs()
        loop = asyncio.get_running_loop()
        end = object()
        while True:
            ep = await loop.run_in_executor(None, next, it, end)
            if ep is end:
                return
            yield ep  # type: ignore[misc]

    def open(self) -> Source:
        """Open the transport now (otherwise the first read opens it); returns the source."""
        opener = getattr(self, "_open", None)
        if opener is not None:
            opener()
        return self

    def stop(self) -> None:
        self.stop_event.set()

    def close(self) -> None:
        """Release the transport (ports, buses, files)."""
        self.stop_event.set()
        if self.accounting.side_log is not None:
            self.accounting.side_log.close()

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class ReconnectPolicy:
    """What a live source does when the bus fails (bus error, bus-off): up to ``max_attempts`` reopenings in
    a row, waiting ``backoff_s * 2**k`` (capped at ``max_backoff_s``) before attempt k; then
    :class:`~rimu.errors.TransportError`. ``max_attempts = 0`` fails at the first error."""

    max_attempts: int = 5
    backoff_s: float = 0.1
    max_backoff_s: float = 5.0

    def delay(self, attempt: int) -> float:
        return min(self.backoff_s * (2 ** attempt), self.max_backoff_s)
