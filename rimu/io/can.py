"""CAN sources: live buses through python-can (any interface) and recorded logs (candump .log read from its text
by :mod:`rimu.io.canlog`; ASC, BLF, CSV through python-can).

Frames -> :class:`CanFrameProcessor` (accounting, error/remote frames, vectorised decoding and checksum check
with :class:`~rimu.io.layout.CanCodec`, epoch assembly with :class:`~rimu.io.assembly.EpochAssembler`)
-> epochs. Rejection reasons counted: ``error_frame``, ``remote_frame``, ``unknown_id``, ``bad_length``,
``checksum``, ``duplicate``, ``late``, ``counter_jump``, ``malformed_line`` (a log line that is no frame).
Events: ``bus_error``, ``bus_off``, ``reconnect``, ``missing_frame``, ``counter_gap``, ``missing_epochs``,
``resync``, ``time_extrapolated``.
"""

from __future__ import annotations

import operator
import os
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from ..errors import ShapeError, TransportError
from .accounting import Accounting, SideLog
from .assembly import EpochAssembler
from .base import ReconnectPolicy, Source
from .canlog import KIND_DATA, KIND_ERROR, NATIVE_LOG_SUFFIXES, LogFrames, iter_candump
from .layout import STATUS_OK, STATUS_REASONS, CanCodec, Layout, load_layout

__all__ = ["CanFrameProcessor", "EpochChunk", "items_to_block", "CanSource", "CanReplaySource", "ReconnectPolicy", "decode_log"]

#: SocketCAN error class bit for bus-off in an error frame's identifier (linux/can/error.h, CAN_ERR_BUSOFF)
CAN_ERR_BUSOFF = 0x040


_IS_ERROR = operator.attrgetter("is_error_frame")
_IS_REMOTE = operator.attrgetter("is_remote_frame")


@dataclass
class EpochChunk:
    """Many consecutive epochs as arrays (what the vectorised path makes; :meth:`epochs` turns them into
    :class:`~rimu.epoch.Epoch` objects)."""

    t: np.ndarray
    raw: dict[str, np.ndarray]
    valid: dict[str, np.ndarray]
    temperature: np.ndarray | None
    counter: np.ndarray
    seq: np.ndarray
    frames: np.ndarray
    other: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.t)

    def epochs(self) -> list[Epoch]:
        out = []
        tl, cl, sl, fl = self.t.tolist(), self.counter.tolist(), self.seq.tolist(), self.frames.tolist()
        temp = self.temperature.tolist() if self.temperature is not None else [None] * len(tl)
        others = {k: v.tolist() for k, v in self.other.items()}
        for e in range(len(tl)):
            counters = {"counter": cl[e], "seq": sl[e], "frames": fl[e]}
            for k, v in others.items():
                counters[k] = v[e]
            out.append(Epoch(tl[e], {k: y[e].copy() for k, y in self.raw.items()},
                             {k: v[e].copy() for k, v in self.valid.items()}, temp[e], counters))
        return out

    @staticmethod
    def from_epochs(eps: list[Epoch], others: list[str]) -> EpochChunk:
        keys = list(eps[0].raw)
        temps = [e.temperature for e in eps]
        return EpochChunk(
            np.array([e.t for e in eps]), {k: np.vstack([e.raw[k] for e in eps]) for k in keys},
            {k: np.vstack([e.valid_mask(k) for e in eps]) for k in keys},
            None if any(x is None for x in temps) else np.array(temps, dtype=float),
            np.array([e.counters["counter"] for e in eps]), np.array([e.counters["seq"] for e in eps]),
            np.array([e.counters["frames"] for e in eps]), {k: np.array([e.counters[k] for e in eps]) for k in others})


class CanFrameProcessor:
    """Accounting, decoding and assembly of python-can messages into epochs.

    A batch is decoded at once with numpy. Where it holds whole, clean samples (every frame valid, in layout
    order, one counter per sample, counters consecutive) and the assembler holds nothing open, those samples
    are assembled vectorised (:meth:`_fast`); everything else goes frame by frame through the
    :class:`~rimu.io.assembly.EpochAssembler`. Both give the same epochs, counts and state (tested).
    """

    def __init__(self, layout: Layout | str | os.PathLike[str], accounting: Accounting, max_lag: int = 2,
                 timeout: float | None = None) -> None:
        self.layout = load_layout(layout)
        self.codec = CanCodec(self.layout)
        self.acc = accounting
        self.assembler = EpochAssembler(self.codec, accounting, max_lag=max_lag, timeout=timeout)

    def process(self, messages: list) -> list[Epoch]:
        """Count, decode and assemble a batch of messages (in arrival order); the epochs completed."""
        out: list[Epoch] = []
        for item in self.process_items(messages):
            if isinstance(item, EpochChunk):
                out.extend(item.epochs())
            else:
                out.append(item)
        return out

    def process_items(self, messages: list) -> list[Epoch | EpochChunk]:
        """As :meth:`process`, but runs of clean epochs come as :class:`EpochChunk` arrays (block replay)."""
        acc = self.acc
        acc.received += len(messages)
        if not messages:
            return []
        packed = None
        if len(messages) >= 16:    # batches: one read of every message; live buses: frame by frame below
            packed = self.codec.pack_frames(messages)
            if not packed[5]:
                return self._process_arrays(*packed[:5])
        if packed is not None or any(map(_IS_ERROR, messages)) or any(map(_IS_REMOTE, messages)):
            keep = []
            for m in messages:
                if m.is_error_frame:
                    acc.reject("error_frame", 1, bytes(m.data), m.timestamp, id=m.arbitration_id)
                    if m.arbitration_id & CAN_ERR_BUSOFF:
                        acc.event("bus_off")
                elif m.is_remote_frame:
                    acc.reject("remote_frame", 1, b"", m.timestamp, id=m.arbitration_id)
                else:
                    keep.append(m)
            if not keep:
                return []
        else:
            keep = messages
        out: list = []
        side = acc.side_log is not None
        add = self.assembler.add
        if len(keep) < 16:  # live buses: a few frames at a time, decoded in pure Python
            one = self.codec.decode_one
            for m in keep:
                st, mi, cnt, vals, flags = one(m.arbitration_id, m.is_extended_id, m.data)
                if st != STATUS_OK:
                    acc.reject(STATUS_REASONS[st], 1, bytes(m.data) if side else None, m.timestamp, id=m.arbitration_id)
                else:
                    out.extend(add(mi, cnt, m.timestamp, vals, flags, bytes(m.data) if side else None))
            return out
        ids, data, dlc, ext, ts = self.codec.pack_all(keep)
        return self._process_arrays(ids, data, dlc, ext, ts)

    def process_frames(self, frames: LogFrames) -> list[Epoch | EpochChunk]:
        """As :meth:`process_items`, for frames read into arrays from a log's text (:mod:`rimu.io.canlog`): no
        python-can message per frame. Malformed lines count as received frames rejected for
        ``malformed_line`` (their text and line number go to the side log)."""
        acc = self.acc
        acc.received += len(frames) + len(frames.malformed)
        side = acc.side_log is not None
        for ln, text in frames.malformed:
            acc.reject("malformed_line", 1, text.encode() if side else None, None, line=ln)
        if not len(frames):
            return []
        if frames.kind.any():
            odd = np.flatnonzero(frames.kind != KIND_DATA)
            for i in odd.tolist():
                ident, t = int(frames.ids[i]), float(frames.ts[i])
                if frames.kind[i] == KIND_ERROR:
                    acc.reject("error_frame", 1, bytes(frames.data[i, :frames.dlc[i]]) if side else None, t, id=ident)
                    if ident & CAN_ERR_BUSOFF:
                        acc.event("bus_off")
                else:
                    acc.reject("remote_frame", 1, b"" if side else None, t, id=ident)
            frames = frames.take(frames.kind == KIND_DATA)
            if not len(frames):
                return []
        return self._process_arrays(frames.ids, frames.data, frames.dlc, frames.ext, frames.ts)

    def _process_arrays(self, ids: np.ndarray, data: np.ndarray, dlc: np.ndarray, ext: np.ndarray,
                        ts: np.ndarray) -> list[Epoch | EpochChunk]:
        """Decode and assemble N data frames given as arrays (already counted as received): runs of clean samples
        in layout order straight into :class:`EpochChunk` arrays (:meth:`_fast`), the other frames one by one
        through the assembler (decoded a window at a time)."""
        acc = self.acc
        side = acc.side_log is not None
        add = self.assembler.add
        out: list = []
        K = self.codec.n_messages
        first_id = int(self.codec.layout_ids[0])
        n = len(ids)
        status = msgi = cnt = vals = flags = tsl = None
        base = 0
        pos = 0
        retry_at = 0
        one = self.codec.decode_one
        few = 4 * K
        while pos < n:
            if pos >= retry_at and not self.assembler.open:
                used = self._fast(ids, data, dlc, ext, ts, pos, out)
                if used:
                    pos += used
                    few = 4 * K
                    continue
                if n - pos >= 4 * K and ids[pos] != first_id:
                    # not at the start of a sample (a batch cut part-way through one): frame by frame up to the
                    # next frame that may start one
                    nxt = np.flatnonzero(ids[pos + 1:pos + 1 + 16 * K] == first_id)
                    retry_at = pos + 1 + int(nxt[0]) if len(nxt) else pos + 16 * K
                else:
                    retry_at = pos + 16 * K   # damaged stretch: frame by frame for a while before trying again
            if vals is None or not base <= pos < base + len(vals):
                if few > 0 and dlc[pos] <= 8:
                    # a few frames (at the edges of batches and clean runs): decoded one by one in pure Python,
                    # cheaper there than a window of numpy (decode_one equals decode, tested)
                    few -= 1
                    d = bytes(data[pos, :dlc[pos]])
                    st, mi, c_, v_, f_ = one(int(ids[pos]), bool(ext[pos]), d)
                    t_ = float(ts[pos])
                    if st != STATUS_OK:
                        acc.reject(STATUS_REASONS[st], 1, d if side else None, t_, id=int(ids[pos]))
                    else:
                        out.extend(add(mi, c_, t_, v_, f_, d if side else None))
                    pos += 1
                    continue
                # decoded a window at a time, as Python lists for the per-frame path
                base, w = pos, min(n, pos + 64 * K)
                dec = self.codec.decode(ids[pos:w], data[pos:w], dlc[pos:w], ext[pos:w])
                status, msgi, cnt = dec.status.tolist(), dec.message.tolist(), dec.counter.tolist()
                vals, flags = dec.values.tolist(), dec.flags_ok.tolist()
                tsl = ts[pos:w].tolist()
            j = pos - base
            st = status[j]
            raw = bytes(data[pos, :dlc[pos]]) if side else None
            if st != STATUS_OK:
                acc.reject(STATUS_REASONS[st], 1, raw, tsl[j], id=int(ids[pos]))
            else:
                out.extend(add(msgi[j], cnt[j], tsl[j], vals[j], flags[j], raw))
            pos += 1
        return out

    def _fast(self, ids: np.ndarray, data: np.ndarray, dlc: np.ndarray, ext: np.ndarray, ts: np.ndarray, pos: int,
              out: list) -> int:
        """Vectorised assembly of the clean samples from frame ``pos`` on (every frame valid, in layout order, one
        counter per sample, counters consecutive, continuing the stream), decoded straight into epoch vectors
        (:meth:`~rimu.io.layout.CanCodec.decode_slots`): one :class:`EpochChunk` appended to ``out``, with the
        same epochs, counts and assembler state as the per-frame path. Returns the frames used: 0 where fewer than
        4 such samples follow, or where that cannot be proven (a jump from the last epoch, a time gap): those
        frames go through the per-frame path."""
        a = self.assembler
        c = self.codec
        K = c.n_messages
        E = (len(ids) - pos) // K
        if E < 4 or not a.M or (ids[pos:pos + K] != c.layout_ids).any():
            return 0
        hi = pos + E * K
        off = ids[pos:hi].reshape(E, K) != c.layout_ids
        if c.layout_ext.any() or ext[pos:hi].any():
            off |= ext[pos:hi].reshape(E, K) != c.layout_ext
        if off.any():
            E = int(np.argmax(off.reshape(-1))) // K
            if E < 4:
                return 0
            hi = pos + E * K
        status, cnt, vals, valid = c.decode_slots(data[pos:hi], dlc[pos:hi], E)
        # clean: every frame valid, one counter per sample, counters consecutive
        bad = (status != STATUS_OK).reshape(-1)
        bad |= (cnt != cnt[:, :1]).reshape(-1)
        cut = int(np.argmax(bad)) // K if bad.any() else E
        c0 = cnt[:, 0]
        step = np.diff(c0[:cut]) % a.M != 1
        if step.any():
            cut = int(np.argmax(step)) + 1
        tss = ts[pos:pos + cut * K].reshape(cut, K)
        per = a.period
        if per and cut > 1:      # a time step longer than the counter can tell: the per-frame path restarts there
            gap = np.diff(tss[:, 0]) > (a.M // 2) * per
            if gap.any():
                cut = int(np.argmax(gap)) + 1
        if a.timeout is not None:   # a sample spread beyond the time window: closed incomplete per frame
            late = (tss - tss[:, :1] > a.timeout).reshape(-1)
            if late.any():
                cut = int(np.argmax(late)) // K
        E = cut
        if E < 4:
            return 0
        if a.newest is not None:
            if int(c0[0]) != (a.newest + 1) % a.M or a.last_emitted != a.newest:
                return 0
            if per and tss[0, 0] - a.newest_ts > (a.M // 2) * per:
                return 0
            seq0 = a.newest + 1
        else:
            if a.last_emitted is not None:
                return 0
            seq0 = a._seq_base + int(c0[0])
        vals, valid, tss, c0 = vals[:E], valid[:E], tss[:E], c0[:E]
        # time, as EpochAssembler._emit does it
        if c.message_has_time.any():
            raw_t = vals[:, c.time_slot]
            mod = c.time_modulus or 0.0
            prev = np.concatenate([[a._last_raw_t if a._last_raw_t is not None else raw_t[0]], raw_t[:-1]])
            wraps = a._t_wraps + np.cumsum(raw_t < prev - mod / 2) if mod else np.zeros(E)
            t = raw_t + wraps * mod
            a._t_wraps = int(wraps[-1]) if mod else 0
            a._last_raw_t = float(raw_t[-1])
        else:
            t = tss[:, 0].copy()
        if not valid.all():
            vals[:, :c.n_sensors][~valid] = 0.0
        seq = np.arange(seq0, seq0 + E)
        out.append(EpochChunk(
            t, {k: vals[:, o:o + n] for k, o, n in a._inst}, {k: valid[:, o:o + n] for k, o, n in a._inst},
            vals[:, c.temp_slot].copy() if c.message_has_temp.any() else None, c0.copy(), seq, np.full(E, K),
            {name: vals[:, c.n_sensors + 2 + j].astype(np.int64) for j, name in enumerate(c.other_names)}))
        last = seq0 + E - 1
        a.newest = a.last_emitted = last
        a.newest_ts = float(tss[-1].max())
        keep_n = max(a.M // 2, 4)
        for s_ in range(max(seq0, last - keep_n + 1), last + 1):
            a.recent[s_] = a._full
        while len(a.recent) > keep_n:
            a.recent.popitem(last=False)
        a._last_t, a._last_t_seq = float(t[-1]), last
        a._far = 0
        self.acc.accepted += E * K
        self.acc.epochs += E
        return E * K

    def expire(self, now: float) -> list[Epoch]:
        return self.assembler.expire(now)

    def flush(self) -> list[Epoch]:
        return self.assembler.flush()


class CanSource(Source):
    """Live CAN through python-can.

    Parameters
    ----------
    layout : Layout, path or shipped layout name
    interface, channel : str
        python-can interface (``"virtual"``, ``"socketcan"``, ``"pcan"``, ...) and channel.
    bus : can.BusABC, optional
        An open bus to read from (then ``bus_factory`` is needed for reconnects).
    bus_factory : callable returning a bus, optional
        How to (re)open the bus; default ``can.Bus(interface=..., channel=..., **bus_kwargs)``.
    reconnect : ReconnectPolicy
    recv_timeout : float
        s per blocking read; on silence, epochs older than the assembler's timeout are closed.
    idle_timeout : float, optional
        End the iteration after this long without any frame (s); None = until :meth:`stop`.
    batch : int
        Frames read without blocking after the first one of a batch.
    """

    def __init__(self, layout: Any, interface: str = "virtual", channel: Any = "rimu", bus: Any = None,
                 bus_factory: Callable[[], Any] | None = None, reconnect: ReconnectPolicy | None = None,
                 recv_timeout: float = 0.05, idle_timeout: float | None = None, batch: int = 256, max_lag: int = 2,
                 timeout: float | None = None, side_log: SideLog | None = None, **bus_kwargs: Any) -> None:
        super().__init__(side_log)
        self.proc = CanFrameProcessor(layout, self.accounting, max_lag, timeout)
        self.layout = self.proc.layout
        self.interface, self.channel, self.bus_kwargs = interface, channel, bus_kwargs
        if bus_factory is None and bus is None:
            def bus_factory() -> Any:
                import can
                return can.Bus(interface=interface, channel=channel, **bus_kwargs)
        self.bus_factory = bus_factory
        self.bus = bus
        self.reconnect = reconnect or ReconnectPolicy()
        self.recv_timeout = recv_timeout
        self.idle_timeout = idle_timeout
        self.batch = batch
        self._bus_offs = 0

    def _open(self) -> None:
        if self.bus is None:
            if self.bus_factory is None:
                raise TransportError("the bus failed and no bus_factory was given to reopen it")
            self.bus = self.bus_factory()

    def _recover(self, exc: BaseException) -> None:
        """Reconnect policy: close, wait, reopen; TransportError when the attempts are used up."""
        for attempt in range(self.reconnect.max_attempts):
            try:
                if self.bus is not None:
                    self.bus.shutdown()
            except Exception:
                pass
            self.bus = None
            if self.stop_event.wait(self.reconnect.delay(attempt)):
                return
            try:
                self._open()
                self.accounting.event("reconnect")
                return
            except Exception as e:
                self.accounting.event("reconnect_failed")
                exc = e
        raise TransportError(f"CAN bus {self.interface}:{self.channel} failed and could not be reopened after "
                             f"{self.reconnect.max_attempts} attempts: {exc}") from exc

    def _epochs(self) -> Iterator[Epoch]:
        import can

        self._open()
        last_frame = time.monotonic()
        while not self.stop_event.is_set():
            batch: list = []
            error: BaseException | None = None
            try:
                msg = self.bus.recv(self.recv_timeout)
                if msg is not None:
                    batch.append(msg)
                    while len(batch) < self.batch:
                        m = self.bus.recv(0.0)
                        if m is None:
                            break
                        batch.append(m)
            except (can.CanError, OSError) as exc:
                error = exc
            if batch:  # frames read before an error are still counted and used
                last_frame = time.monotonic()
                yield from self.proc.process(batch)
            if error is not None:
                self.accounting.event("bus_error")
                self._recover(error)
                continue
            if not batch:
                newest = self.proc.assembler.newest_ts
                if newest is not None:  # frame clock = newest frame time + wall time since it (any bus clock)
                    yield from self.proc.expire(newest + time.monotonic() - last_frame)
                if self.idle_timeout is not None and time.monotonic() - last_frame > self.idle_timeout:
                    break
                continue
            if self.accounting.events.get("bus_off", 0) > self._bus_offs:
                self._bus_offs = self.accounting.events["bus_off"]
                self._recover(TransportError("bus off"))
        yield from self.proc.flush()

    def close(self) -> None:
        super().close()
        if self.bus is not None:
            self.bus.shutdown()
            self.bus = None


class CanReplaySource(Source):
    """Replay of a python-can log file (ASC, BLF, CSV, candump .log, ... anything ``can.LogReader`` reads).

    Parameters
    ----------
    path : path of the log
    layout : Layout, path or shipped layout name
    realtime : bool
        Pace the frames by their timestamps (scaled by ``speed``) instead of as fast as possible.
    chunk : int
        Frames decoded together (vectorised) when not in real time (a candump ``.log``, read natively by
        :mod:`rimu.io.canlog`: chunks of ``48 * chunk`` bytes of text, at least 2 MB).
    """

    def __init__(self, path: str | os.PathLike[str], layout: Any, realtime: bool = False, speed: float = 1.0,
                 chunk: int = 8192, max_lag: int = 2, timeout: float | None = None,
                 side_log: SideLog | None = None) -> None:
        super().__init__(side_log)
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise TransportError(f"no CAN log at {self.path}")
        self.proc = CanFrameProcessor(layout, self.accounting, max_lag, timeout)
        self.layout = self.proc.layout
        self.realtime, self.speed, self.chunk = realtime, float(speed), int(chunk)
        #: candump .log files are read from their text (rimu.io.canlog); other formats through can.LogReader
        self.native = os.path.splitext(self.path)[1].lower() in NATIVE_LOG_SUFFIXES

    def _batches(self, reader: Any) -> Iterator[list]:
        """The log's frames, decoded and assembled a batch at a time (as fast as possible)."""
        if self.native:
            for frames in iter_candump(self.path, max(48 * self.chunk, 1 << 21)):
                yield self.proc.process_frames(frames)
            return
        buf = []
        for m in reader:
            buf.append(m)
            if len(buf) >= self.chunk:
                yield self.proc.process_items(buf)
                buf = []
        yield self.proc.process_items(buf)

    def _epochs(self) -> Iterator[Epoch]:
        from .guard import reading

        with reading(self.path, "CAN log", (ValueError, IndexError, struct.error)):
            yield from self._read_epochs()

    def _read_epochs(self) -> Iterator[Epoch]:
        import can

        reader = None if self.native and not self.realtime else can.LogReader(self.path)
        try:
            if self.realtime:
                t0 = w0 = None
                for m in reader:
                    if self.stop_event.is_set():
                        break
                    if t0 is None:
                        t0, w0 = m.timestamp, time.monotonic()
                    wait = (m.timestamp - t0) / self.speed - (time.monotonic() - w0)
                    if wait > 0 and self.stop_event.wait(wait):
                        break
                    yield from self.proc.process([m])
            else:
                for items in self._batches(reader):
                    for item in items:
                        if isinstance(item, EpochChunk):
                            yield from item.epochs()
                        else:
                            yield item
                    if self.stop_event.is_set():
                        break
            yield from self.proc.flush()
        finally:
            stop = getattr(reader, "stop", None)
            if stop is not None:
                stop()

    def read_block(self, max_epochs: int | None = None) -> EpochBlock:
        """The whole log (or its first ``max_epochs`` epochs) as a block, through the vectorised path."""
        if self.realtime or max_epochs is not None:
            return super().read_block(max_epochs)
        import can

        from .guard import reading

        items: list = []
        with reading(self.path, "CAN log", (ValueError, IndexError, struct.error)):
            reader = None if self.native else can.LogReader(self.path)
            try:
                for batch in self._batches(reader):
                    items.extend(batch)
                items.extend(self.proc.flush())
            finally:
                stop = getattr(reader, "stop", None)
                if stop is not None:
                    stop()
        block = items_to_block(items, self.proc.codec.other_names)
        block.meta["accounting"] = self.accounting.as_dict()
        return block


def items_to_block(items: list[Epoch | EpochChunk], other_names: list[str]) -> EpochBlock:
    """One :class:`EpochBlock` from the output of :meth:`CanFrameProcessor.process_items` (arrays kept as
    they are; loose epochs stacked); ``meta`` holds ``counter``, ``seq``, ``frames`` and other signals."""
    chunks: list[EpochChunk] = []
    loose: list[Epoch] = []
    for it in items:
        if isinstance(it, EpochChunk):
            if loose:
                chunks.append(EpochChunk.from_epochs(loose, other_names))
                loose = []
            chunks.append(it)
        else:
            loose.append(it)
    if loose:
        chunks.append(EpochChunk.from_epochs(loose, other_names))
    if not chunks:
        raise ShapeError("the replay produced no epochs")
    keys = list(chunks[0].raw)
    temp = None if any(c.temperature is None for c in chunks) else np.concatenate([c.temperature for c in chunks])
    block = EpochBlock(np.concatenate([c.t for c in chunks]), {k: np.concatenate([c.raw[k] for c in chunks]) for k in keys},
                       {k: np.concatenate([c.valid[k] for c in chunks]) for k in keys}, temp)
    block.meta.update({"counter": np.concatenate([c.counter for c in chunks]),
                       "seq": np.concatenate([c.seq for c in chunks]),
                       "frames": np.concatenate([c.frames for c in chunks])})
    for k in other_names:
        block.meta[k] = np.concatenate([c.other[k] for c in chunks])
    return block


def decode_log(path: str | os.PathLike[str], layout: Any, **kwargs: Any) -> tuple[EpochBlock, Accounting]:
    """Replay a whole log as fast as possible: its epochs as a block, and the accounting."""
    src = CanReplaySource(path, layout, **kwargs)
    block = src.read_block()
    return block, src.accounting
