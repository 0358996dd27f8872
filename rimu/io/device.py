"""A simulated device: an :class:`~rimu.epoch.EpochBlock` (from ``rimu.sim`` in the caller) sent as CAN frames
on a python-can bus or as framed bytes on a serial port, in real time or as fast as possible.

This module does not import ``rimu.sim``: it takes any block. ``fault`` is an optional hook, a callable
``block -> block`` applied before encoding (fault types belong to ``rimu.fdi``/``rimu.sim``).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from .base import Source
from .layout import CanCodec, Layout, load_layout
from .serial import encode_block

__all__ = ["CanDevice", "SerialDevice", "BlockSource"]

FaultHook = Callable[[EpochBlock], EpochBlock]


def _prepare(block: EpochBlock, fault: FaultHook | None) -> EpochBlock:
    return fault(block) if fault is not None else block


def _paced(items: Sequence[Any], times: Sequence[float], put: Callable[[Any], int], realtime: bool, speed: float,
           stop: threading.Event | None) -> int:
    """Hand every item to ``put`` (which returns what it counts), item k at ``times[k] / speed`` s after the
    start when ``realtime``, until ``stop`` is set; the total count."""
    w0 = time.monotonic()
    n = 0
    for item, tk in zip(items, times):
        if stop is not None and stop.is_set():
            break
        if realtime:
            wait = tk / speed - (time.monotonic() - w0)
            if wait > 0:
                time.sleep(wait)
        n += put(item)
    return n


def _start(send: Callable[..., int], *args: Any) -> threading.Thread:
    """``send(*args, stop)`` in a daemon thread; ``thread.stop`` is the Event that ends it early."""
    stop = threading.Event()
    th = threading.Thread(target=send, args=(*args, stop), daemon=True)
    th.stop = stop  # type: ignore[attr-defined]
    th.start()
    return th


class CanDevice:
    """Encodes a block with a CAN layout and sends it.

    Parameters
    ----------
    layout : Layout, path or shipped name
    fault : callable, optional
        ``block -> block`` applied before encoding.
    counter0 : int
        Rolling counter of the first sample.
    """

    def __init__(self, layout: Any, fault: FaultHook | None = None, counter0: int = 0) -> None:
        self.layout: Layout = load_layout(layout)
        self.codec = CanCodec(self.layout)
        self.fault = fault
        self.counter0 = counter0

    def encoded(self, block: EpochBlock) -> list[tuple[int, np.ndarray]]:
        b = _prepare(block, self.fault)
        counters = self.counter0 + np.arange(len(b))
        return self.codec.encode(b.raw, counters, b.t, b.temperature, b.valid or None)

    def frames(self, block: EpochBlock, t0: float = 0.0) -> list:
        """python-can messages of every sample, stamped ``t0 + block.t`` (+10 us per frame within a sample)."""
        return self.codec.to_messages(self.encoded(block), t0 + np.asarray(block.t))

    def expected(self, block: EpochBlock) -> dict[str, np.ndarray]:
        """What a receiver must decode: the (faulted) raw values rounded to the layout's resolution."""
        b = _prepare(block, self.fault)
        return {k: self.codec.quantize(k, y) for k, y in b.raw.items()}

    def write_log(self, path: str | os.PathLike[str], block: EpochBlock, t0: float = 0.0) -> None:
        """Write the frames to a python-can log (format by extension: .asc, .blf, .csv, .log)."""
        import can

        with can.Logger(os.fspath(path)) as log:
            for m in self.frames(block, t0):
                log.on_message_received(m)

    def send(self, bus: Any, block: EpochBlock, realtime: bool = False, speed: float = 1.0,
             stop: threading.Event | None = None) -> int:
        """Send every frame on ``bus``; returns the number sent."""
        msgs = self.frames(block, 0.0)

        def put(m: Any) -> int:
            bus.send(m)
            return 1

        return _paced(msgs, [m.timestamp for m in msgs], put, realtime, speed, stop)

    def start(self, bus: Any, block: EpochBlock, realtime: bool = False, speed: float = 1.0) -> threading.Thread:
        """:meth:`send` in a daemon thread (``thread.stop`` is an Event that ends it early)."""
        return _start(self.send, bus, block, realtime, speed)


class SerialDevice:
    """Encodes a block in rimu's serial framing and writes it to a port (or returns the bytes)."""

    def __init__(self, fault: FaultHook | None = None, seq0: int = 0, framing: str = "sync") -> None:
        self.fault = fault
        self.seq0 = seq0
        self.framing = framing

    def frames(self, block: EpochBlock) -> list[bytes]:
        return encode_block(_prepare(block, self.fault), self.seq0, self.framing)

    def stream(self, block: EpochBlock) -> bytes:
        return b"".join(self.frames(block))

    def expected(self, block: EpochBlock) -> dict[str, np.ndarray]:
        """What a receiver must decode: the raw values as float32."""
        b = _prepare(block, self.fault)
        return {k: y.astype(np.float32).astype(float) for k, y in b.raw.items()}

    def write(self, port: Any, block: EpochBlock, realtime: bool = False, speed: float = 1.0,
              stop: threading.Event | None = None) -> int:
        """Write frame by frame to a pyserial port (or any object with ``write``); returns bytes written."""
        frames = self.frames(block)
        t = np.asarray(block.t, dtype=float)

        def put(f: bytes) -> int:
            port.write(f)
            return len(f)

        n = _paced(frames, t - t[0] if len(t) else t, put, realtime, speed, stop)
        flush = getattr(port, "flush", None)
        if flush is not None:
            flush()
        return n

    def start(self, port: Any, block: EpochBlock, realtime: bool = False, speed: float = 1.0) -> threading.Thread:
        """:meth:`write` in a daemon thread (``thread.stop`` is an Event that ends it early)."""
        return _start(self.write, port, block, realtime, speed)


class BlockSource(Source):
    """Epochs straight from a block, no transport (a simulated device without a wire), optionally paced."""

    unit = "epoch"

    def __init__(self, block: EpochBlock, fault: FaultHook | None = None, realtime: bool = False,
                 speed: float = 1.0) -> None:
        super().__init__()
        self.block = _prepare(block, fault)
        self.realtime, self.speed = realtime, speed

    def _epochs(self) -> Iterator[Epoch]:
        t = self.block.t
        w0 = time.monotonic()
        for k, ep in enumerate(self.block.epochs()):
            if self.stop_event.is_set():
                break
            if self.realtime:
                wait = (t[k] - t[0]) / self.speed - (time.monotonic() - w0)
                if wait > 0 and self.stop_event.wait(wait):
                    break
            self.accounting.received += 1
            yield self._accepted(ep, "seq", k)
