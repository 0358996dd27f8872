"""Epoch assembly: frames of one sample, spread over several CAN frames, put back together.

Every frame of a sample carries the same rolling counter (modulus M = 2**bits). The assembler unwraps the
counter into a sequence number and keeps a few epochs open; the documented behaviour, case by case:

* **complete**: all the layout's frames of a sequence number arrived -> the epoch is emitted (in sequence
  order: a complete epoch waits only for older open ones).
* **missing frame**: an epoch is closed incomplete when a frame ``max_lag`` or more sequence numbers newer
  arrives, when its first frame is older than ``timeout`` s (frame time), or at the end of the stream. The
  sensors of the missing frame are invalid for that epoch (raw 0.0); event ``missing_frame``. The stream is
  neither stalled nor shifted: later epochs keep their own counter.
* **counter gap**: sequence numbers with no frame at all produce no epoch; event ``counter_gap`` (once per
  gap) and ``missing_epochs`` (their number). Epoch times stay those sent by the device.
* **duplicate**: a frame of a (sequence, message) already accepted is rejected, reason ``duplicate``.
* **out of order**: a frame older than the newest but whose epoch is still open is accepted in its place;
  if its epoch was already emitted it is rejected, reason ``late``.
* **counter jump** (device reset, corrupted stream): a frame more than M/4 behind the last emitted epoch is
  rejected, reason ``counter_jump``; after ``resync_after`` such frames in a row the assembler emits what
  it holds and restarts from the new counter (event ``resync``).

Forward jumps are read as gaps up to M/2; with a layout rate and frame times, a time step longer than M/2
sample periods also restarts the count (event ``resync``), so gaps longer than the counter's range are not
mistaken for short ones.

Epoch time: the layout's ``time`` signal if the frame carrying it arrived (unwrapped past its modulus),
otherwise the previous epoch's time plus the sequence step times the period (event ``time_extrapolated``;
not across a restart), otherwise (and always for a layout without a ``time`` signal) the receive time of the
epoch's first frame.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

from ..epoch import Epoch
from .accounting import Accounting
from .layout import CanCodec

__all__ = ["EpochAssembler"]


class _Open:
    """An epoch being assembled: slot values, bit masks of the messages received and of sensors flagged bad."""

    __slots__ = ("bad", "counter", "first_ts", "have", "vals")

    def __init__(self, n_slots: int, ts: float, counter: int) -> None:
        self.vals = [0.0] * n_slots
        self.have = 0
        self.bad = 0
        self.first_ts = ts
        self.counter = counter


class EpochAssembler:
    """Turns decoded frames into :class:`~rimu.epoch.Epoch` objects (see the module docstring).

    Parameters
    ----------
    codec : CanCodec
    accounting : Accounting
        Frames are counted accepted or rejected here (the caller counts them received).
    max_lag : int
        An incomplete epoch is closed when a frame this many sequence numbers newer arrives.
    timeout : float, optional
        ... or when its first frame is older than this (s, frame time). Default: 3 sample periods.
    resync_after : int
        Consecutive far-behind frames that make the assembler restart (default: frames per sample).
    """

    def __init__(self, codec: CanCodec, accounting: Accounting, max_lag: int = 2, timeout: float | None = None,
                 resync_after: int | None = None) -> None:
        self.codec = codec
        self.acc = accounting
        L = codec.layout
        self.M = L.counter_modulus or 0
        self.period = L.period
        self.max_lag = max(1, int(max_lag))
        self.timeout = timeout if timeout is not None else (3 * self.period if self.period else None)
        self.resync_after = resync_after or codec.n_messages
        self.open: OrderedDict[int, _Open] = OrderedDict()
        self.newest: int | None = None
        self.newest_ts: float | None = None
        self.last_emitted: int | None = None
        self.recent: OrderedDict[int, np.ndarray] = OrderedDict()  # emitted seq -> have mask
        self._far = 0
        self._seq_base = 0
        self._last_t: float | None = None
        self._last_t_seq: int | None = None
        self._t_wraps = 0
        self._last_raw_t: float | None = None
        offs = codec.instrument_offsets
        self._inst = [(k, o, codec.layout.instruments[k]) for k, o in offs.items()]
        self._full = (1 << codec.n_messages) - 1
        self._slots = [sl.tolist() for sl in codec.slots]
        self._msg_sensor_bits = [int(np.dot(r.astype(np.int64), 1 << np.arange(codec.n_sensors, dtype=np.int64)))
                                 for r in codec.message_sensors]
        self._flag_bits = [[int(np.dot(f.astype(np.int64), 1 << np.arange(codec.n_sensors, dtype=np.int64)))
                            for f in fs] for fs in codec.flag_sensors]
        self._time_msgs = int(np.dot(codec.message_has_time.astype(np.int64), 1 << np.arange(codec.n_messages)))
        self._temp_msgs = int(np.dot(codec.message_has_temp.astype(np.int64), 1 << np.arange(codec.n_messages)))
        self._bitpos = np.arange(codec.n_sensors, dtype=np.int64)

    # ------------------------------------------------------------------ sequence numbers
    def _unwrap(self, counter: int, ts: float) -> int:
        if self.newest is None:
            return self._seq_base + counter
        if self.M == 0:  # single-frame samples without a counter: every frame is a new epoch
            return self.newest + 1
        d = (counter - self.newest) % self.M
        if self.period and self.newest_ts is not None and ts - self.newest_ts > (self.M // 2) * self.period:
            return -1  # a gap longer than the counter can tell: restart
        return self.newest + d if d <= self.M // 2 else self.newest - (self.M - d)

    def _restart(self, out: list[Epoch], counter: int) -> None:
        out.extend(self.flush())
        base = (self.last_emitted + 1) if self.last_emitted is not None else 0
        # new numbering that continues after everything emitted and is congruent to the counter
        self._seq_base = base + ((counter - base) % self.M if self.M else 0) - counter
        self.newest = None
        self.newest_ts = None
        self.last_emitted = None   # no gap is counted across a restart: its length is unknown
        self._last_t = None        # nor is time extrapolated across it
        self.recent.clear()
        self.acc.event("resync")

    # ------------------------------------------------------------------ frames in
    def add(self, message: int, counter: int, ts: float, values: list[float], flags_ok: list[bool],
            data: bytes | None = None) -> list[Epoch]:
        """Add one decoded, checksum-valid frame (its value and flag rows of
        :class:`~rimu.io.layout.DecodedFrames`); returns the epochs it completes or closes."""
        out: list[Epoch] = []
        seq = self._unwrap(counter, ts)
        if seq == -1:
            self._restart(out, counter)
            seq = self._unwrap(counter, ts)
        if self.last_emitted is not None and seq <= self.last_emitted:
            behind = self.last_emitted - seq
            if self.M and behind > self.M // 4:
                self._far += 1
                if self._far >= self.resync_after:
                    self._far = 0
                    self._restart(out, counter)
                    seq = self._unwrap(counter, ts)
                else:
                    self.acc.reject("counter_jump", 1, data, ts, message=message, counter=counter)
                    return out
            else:
                self._far = 0
                h = self.recent.get(seq)
                reason = "duplicate" if (h is not None and (h >> message) & 1) else "late"
                self.acc.reject(reason, 1, data, ts, message=message, counter=counter)
                return out
        self._far = 0
        ep = self.open.get(seq)
        bit = 1 << message
        if ep is None:
            ep = _Open(self.codec.n_slots, ts, counter)
            out_of_order = bool(self.open) and seq < next(reversed(self.open))
            self.open[seq] = ep
            if out_of_order:
                self.open = OrderedDict(sorted(self.open.items()))
        elif ep.have & bit:
            self.acc.reject("duplicate", 1, data, ts, message=message, counter=counter)
            return out
        ep.have |= bit
        vals = ep.vals
        for j, sl in enumerate(self._slots[message]):
            vals[sl] = values[j]
        for j, fb in enumerate(self._flag_bits[message]):
            if not flags_ok[j]:
                ep.bad |= fb
        self.acc.accepted += 1
        if self.newest is None or seq > self.newest:
            self.newest = seq
            self.newest_ts = ts
        self._emit_ready(out, ts)
        return out

    def _emit_ready(self, out: list[Epoch], ts: float) -> None:
        while self.open:
            seq, ep = next(iter(self.open.items()))
            if (ep.have == self._full or self.newest - seq >= self.max_lag
                    or (self.timeout is not None and ts - ep.first_ts > self.timeout)):
                del self.open[seq]
                out.append(self._emit(seq, ep))
            else:
                break

    def expire(self, now: float) -> list[Epoch]:
        """Close epochs whose first frame is older than the timeout at frame time ``now`` (live sources call
        this when the bus is quiet)."""
        out: list[Epoch] = []
        if self.timeout is None:
            return out
        while self.open:
            seq, ep = next(iter(self.open.items()))
            if now - ep.first_ts > self.timeout:
                del self.open[seq]
                out.append(self._emit(seq, ep))
            else:
                break
        return out

    def flush(self) -> list[Epoch]:
        """Emit every open epoch (end of stream)."""
        out = [self._emit(seq, ep) for seq, ep in self.open.items()]
        self.open.clear()
        return out

    # ------------------------------------------------------------------ epochs out
    def _emit(self, seq: int, ep: _Open) -> Epoch:
        acc = self.acc
        c = self.codec
        if self.last_emitted is not None and seq > self.last_emitted + 1:
            acc.event("counter_gap")
            acc.event("missing_epochs", seq - self.last_emitted - 1)
        missing = self._full & ~ep.have
        bad = ep.bad
        if missing:
            acc.event("missing_frame", bin(missing).count("1"))
            for m, sb in enumerate(self._msg_sensor_bits):
                if (missing >> m) & 1:
                    bad |= sb
        valid = ((bad >> self._bitpos) & 1) == 0
        vals = ep.vals
        # time
        if ep.have & self._time_msgs:
            raw_t = float(vals[c.time_slot])
            if c.time_modulus and self._last_raw_t is not None and raw_t < self._last_raw_t - c.time_modulus / 2:
                self._t_wraps += 1
            self._last_raw_t = raw_t
            t = raw_t + self._t_wraps * (c.time_modulus or 0.0)
        elif self._time_msgs and self._last_t is not None and self.period:   # the time frame is missing
            t = self._last_t + (seq - self._last_t_seq) * self.period
            acc.event("time_extrapolated")
        else:
            t = float(ep.first_ts)
        self._last_t, self._last_t_seq = t, seq
        temp = float(vals[c.temp_slot]) if ep.have & self._temp_msgs else None
        raw: dict[str, np.ndarray] = {}
        vd: dict[str, np.ndarray] = {}
        for k, o, n in self._inst:
            y = np.array(vals[o:o + n])
            v = valid[o:o + n]
            if bad:
                y[~v] = 0.0
            raw[k] = y
            vd[k] = v
        counters: dict[str, Any] = {"counter": ep.counter, "seq": seq, "frames": bin(ep.have).count("1")}
        for j, name in enumerate(c.other_names):
            counters[name] = int(vals[c.n_sensors + 2 + j])
        self.last_emitted = seq
        self.recent[seq] = ep.have
        while len(self.recent) > max(self.M // 2, 4):
            self.recent.popitem(last=False)
        acc.epochs += 1
        return Epoch(t, raw, vd, temp, counters)
