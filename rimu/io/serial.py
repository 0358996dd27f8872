"""Serial sources (pyserial) and rimu's binary framing for UART / RS-232 / RS-422 links.

Frame (all integers little-endian; documented in ``docs/io.md``)::

    offset  size  field
    0       2     sync 0xA5 0x5A
    2       1     LEN: payload length, 0..255
    3       1     TYPE: 0x01 = sample
    4       2     SEQ: sample counter, uint16, wraps
    6       LEN   payload
    6+LEN   2     CRC-16/CCITT-FALSE over bytes 2 .. 5+LEN (LEN, TYPE, SEQ, payload)

Sample payload (TYPE 0x01)::

    float64 t (s, device time) | float32 temperature (degC, NaN = not sent) | uint8 n_gyro | uint8 n_accel |
    uint16 gyro valid mask | uint16 accel valid mask | float32 gyro[n_gyro] | float32 accel[n_accel]

COBS variant (``framing="cobs"``, :class:`CobsDecoder`): ``COBS(TYPE, SEQ, payload, CRC-16) 0x00``, the CRC
over TYPE, SEQ and payload; no sync word or length: every 0x00 ends a frame.

Decoding (:class:`SerialDecoder`) works on any chunking of the byte stream: it searches the sync word,
waits for the whole frame, checks the CRC, and on a failed check drops one byte and searches again, so a
frame starting inside a damaged one is still found (resynchronisation). Every byte is counted: accepted (part
of a good frame), rejected (``garbage`` between frames, ``checksum`` for the first byte of a candidate whose
CRC fails, ``bad_length``, ``bad_payload``, ``unknown_type``, ``duplicate``, ``truncated`` at the end of a
stream) or pending (held in the buffer, waiting for more bytes). Baud rate does not matter to the decoder.
"""

from __future__ import annotations

import binascii
import math
import os
import struct
import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from ..errors import FrameError, TransportError
from .accounting import Accounting, SideLog
from .base import ReconnectPolicy, Source
from .checksum import crc16_ccitt

__all__ = ["read_available", "SYNC", "TYPE_SAMPLE", "encode_frame", "encode_sample", "encode_block", "SerialDecoder",
           "cobs_encode", "cobs_decode", "encode_frame_cobs", "CobsDecoder", "make_decoder", "FRAMINGS",
           "SerialSource", "SerialFileSource"]

SYNC = b"\xa5\x5a"
TYPE_SAMPLE = 0x01
HEADER = 6
OVERHEAD = 8
_SAMPLE_HEAD = struct.Struct("<dfBBHH")
_HDR = struct.Struct("<BBH")
MAX_SENSORS = 16
FRAMINGS = ("sync", "cobs")
_BLOCK_REASONS = ("", "unknown_type", "bad_payload", "duplicate")


def encode_frame(ftype: int, seq: int, payload: bytes) -> bytes:
    """One frame around ``payload``.

    >>> f = encode_frame(TYPE_SAMPLE, 258, b"ab")
    >>> f[:6].hex(), len(f), int.from_bytes(f[-2:], "little") == crc16_ccitt(f[2:-2])
    ('a55a02010201', 10, True)
    """
    if len(payload) > 255:
        raise FrameError(f"payload of {len(payload)} bytes; the framing carries at most 255")
    body = _HDR.pack(len(payload), ftype, seq & 0xFFFF) + payload
    return SYNC + body + crc16_ccitt(body).to_bytes(2, "little")


def encode_sample(t: float, raw: dict[str, np.ndarray], valid: dict[str, np.ndarray] | None = None,
                  temperature: float | None = None) -> bytes:
    """Payload of one sample (TYPE 0x01). Invalid sensors are sent as 0.0 with their mask bit cleared."""
    g = np.asarray(raw.get("gyro", np.zeros(0)), dtype=np.float32)
    a = np.asarray(raw.get("accel", np.zeros(0)), dtype=np.float32)
    if len(g) > MAX_SENSORS or len(a) > MAX_SENSORS:
        raise FrameError(f"the sample payload carries at most {MAX_SENSORS} sensors per instrument")
    vg = np.ones(len(g), bool) if not valid or "gyro" not in valid else np.asarray(valid["gyro"], bool)
    va = np.ones(len(a), bool) if not valid or "accel" not in valid else np.asarray(valid["accel"], bool)
    g = np.where(vg, g, 0).astype("<f4")
    a = np.where(va, a, 0).astype("<f4")
    mg = int(np.dot(vg.astype(np.int64), 1 << np.arange(len(g)))) if len(g) else 0
    ma = int(np.dot(va.astype(np.int64), 1 << np.arange(len(a)))) if len(a) else 0
    temp = float("nan") if temperature is None else float(temperature)
    return _SAMPLE_HEAD.pack(float(t), temp, len(g), len(a), mg, ma) + g.tobytes() + a.tobytes()


def encode_block(block: EpochBlock, seq0: int = 0, framing: str = "sync") -> list[bytes]:
    """Frames of every sample of a block (sequence numbers from ``seq0``); ``framing`` ``"sync"`` or ``"cobs"``."""
    if framing not in FRAMINGS:
        raise FrameError(f"framing must be one of {sorted(FRAMINGS)}, got {framing!r}")
    enc = encode_frame if framing == "sync" else encode_frame_cobs
    out = []
    for k in range(len(block)):
        raw = {i: y[k] for i, y in block.raw.items()}
        val = {i: v[k] for i, v in block.valid.items()}
        temp = None if block.temperature is None else float(block.temperature[k])
        out.append(enc(TYPE_SAMPLE, seq0 + k, encode_sample(float(block.t[k]), raw, val, temp)))
    return out


class SerialDecoder:
    """Streaming decoder of the framing: :meth:`feed` bytes in any chunks, get epochs out.

    Parameters
    ----------
    accounting : Accounting, optional
        Byte accounting (created if not given); ``pending`` is the buffered byte count.
    max_payload : int
        Longest payload accepted (candidates with a longer LEN are rejected at once, ``bad_length``).

    Examples
    --------
    >>> frame = encode_frame(TYPE_SAMPLE, 7, encode_sample(0.5, {"gyro": np.ones(3), "accel": np.zeros(3)}))
    >>> dec = SerialDecoder()
    >>> eps = dec.feed(b"junk" + frame[:10]) + dec.feed(frame[10:])
    >>> [e.t for e in eps], dec.accounting.summary()
    ([0.5], 'bytes: received 54 = accepted 50 + rejected 4 (garbage 4) + pending 0; epochs 1')
    """

    def __init__(self, accounting: Accounting | None = None, max_payload: int = 255) -> None:
        self.accounting = accounting or Accounting("byte")
        self.accounting.pending_fn = lambda: len(self._buf)
        self.max_payload = int(max_payload)
        self._buf = bytearray()
        self._last_seq: int | None = None
        self._fmts: dict[int, struct.Struct] = {}
        self._masks: dict[tuple[int, int], np.ndarray] = {}

    def _rej(self, reason: str, start: int, stop: int) -> None:
        a = self.accounting
        a.reject(reason, stop - start, bytes(self._buf[start:stop]) if a.side_log is not None else None)

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Epoch]:
        """Add bytes; returns the epochs of every frame completed by them."""
        if not isinstance(chunk, (bytes, bytearray)):
            chunk = memoryview(chunk).tobytes()
        a = self.accounting
        a.received += len(chunk)
        self._buf += chunk
        return self._scan(final=False)

    def flush(self) -> list[Epoch]:
        """End of stream: decide about every pending byte (``truncated`` for incomplete frames)."""
        return self._scan(final=True)

    def _scan(self, final: bool) -> list[Epoch]:
        starts, lengths, pos = self._find_frames(final)
        out: list[Epoch] = []
        for p, L in zip(starts, lengths):
            self._settle(self._frame(self._buf, p, L), p, p + OVERHEAD + L, out)
        del self._buf[:pos]
        return out

    def _find_frames(self, final: bool) -> tuple[list[int], list[int], int]:
        """Positions and payload lengths of the frames with a good CRC in the buffer, and how far the buffer is
        settled; garbage, damaged candidates and (at the end of a stream) truncated bytes are rejected here."""
        buf = self._buf
        n = len(buf)
        pos = 0
        starts: list[int] = []
        lengths: list[int] = []
        crc = crc16_ccitt
        mv = memoryview(buf)
        try:
            while True:
                i = buf.find(SYNC, pos)
                if i < 0:
                    keep = 1 if (n > pos and buf[n - 1] == 0xA5 and not final) else 0
                    if n - keep > pos:
                        self._rej("garbage", pos, n - keep)
                    pos = n - keep
                    break
                if i > pos:
                    self._rej("garbage", pos, i)
                    pos = i
                if n - pos < HEADER:
                    if final:
                        self._rej("truncated", pos, pos + 1)
                        pos += 1
                        continue
                    break
                L = buf[pos + 2]
                if L > self.max_payload:
                    self._rej("bad_length", pos, pos + 1)
                    pos += 1
                    continue
                end = pos + OVERHEAD + L
                if end > n:
                    if final:
                        self._rej("truncated", pos, pos + 1)
                        pos += 1
                        continue
                    break
                if crc(mv[pos + 2:end - 2]) != buf[end - 2] | (buf[end - 1] << 8):
                    self._rej("checksum", pos, pos + 1)
                    pos += 1
                    continue
                starts.append(pos)
                lengths.append(L)
                pos = end
                # a good frame: the frames that follow it back to back with the same length are checked as arrays
                k = self._run_of_frames(buf, pos, L, n)
                if k:
                    F = OVERHEAD + L
                    starts.extend(range(pos, pos + k * F, F))
                    lengths.extend([L] * k)
                    pos += k * F
        finally:
            mv.release()
        return starts, lengths, pos

    @staticmethod
    def _run_of_frames(buf: bytearray, pos: int, L: int, n: int) -> int:
        """How many frames of payload length L follow at ``pos`` back to back, each with its sync word, length
        byte and a good CRC (headers and checksums compared as arrays, the CRCs computed in C; stops at the
        first frame that fails, which the byte-wise search then examines as before)."""
        F = OVERHEAD + L
        K = (n - pos) // F
        if K <= 0:
            return 0
        b = np.frombuffer(buf, dtype=np.uint8, count=n)
        s = pos + F * np.arange(K)
        ok = (b[s] == 0xA5) & (b[s + 1] == 0x5A) & (b[s + 2] == L)
        k = K if ok.all() else int(np.argmin(ok))
        if k == 0:
            return 0
        mv = memoryview(buf)
        try:
            crc = np.fromiter((binascii.crc_hqx(mv[q + 2:q + F - 2], 0xFFFF) for q in range(pos, pos + k * F, F)),
                              dtype=np.int64, count=k)
        finally:
            mv.release()
        ok = crc == (b[s[:k] + F - 2].astype(np.int64) | (b[s[:k] + F - 1].astype(np.int64) << 8))
        return k if ok.all() else int(np.argmin(ok))

    # ------------------------------------------------------------------ block output (no object per frame)
    def feed_block(self, chunk: bytes | bytearray | memoryview) -> EpochBlock | None:
        """Add bytes; returns the samples of every frame completed by them as one :class:`EpochBlock` (None when
        no frame completed). Same frames, values, validity and accounting as :meth:`feed`, decoded as arrays:
        the path for recorded captures and high-rate links (``counters["seq"]`` of the epochs is the block's
        ``meta["seq"]``)."""
        if not isinstance(chunk, (bytes, bytearray)):
            chunk = memoryview(chunk).tobytes()
        self.accounting.received += len(chunk)
        self._buf += chunk
        return self._scan_block(final=False)

    def flush_block(self) -> EpochBlock | None:
        """End of stream for :meth:`feed_block` (``truncated`` for incomplete frames)."""
        return self._scan_block(final=True)

    def _scan_block(self, final: bool) -> EpochBlock | None:
        starts, lengths, pos = self._find_frames(final)
        try:
            return self._decode_block(np.asarray(starts, dtype=np.int64), np.asarray(lengths, dtype=np.int64))
        finally:
            del self._buf[:pos]

    def _decode_block(self, starts: np.ndarray, lengths: np.ndarray) -> EpochBlock | None:
        """The sample frames at ``starts`` (good CRC) decoded together: the checks of :meth:`_frame`, in order,
        as array operations."""
        if starts.size == 0:
            return None
        if np.any(lengths != lengths[0]):  # frames of several lengths: one by one, then stacked
            out: list[Epoch] = []
            for q, L in zip(starts.tolist(), lengths.tolist()):
                self._settle(self._frame(self._buf, q, L), q, q + OVERHEAD + L, out)
            return _stack(out)
        L = int(lengths[0])
        F = OVERHEAD + L
        buf = self._buf
        b = np.frombuffer(buf, dtype=np.uint8, count=int(starts[-1] + F))
        if starts.size == 1 or np.all(np.diff(starts) == F):  # back to back: a (K, F) view, no gather
            frames = np.lib.stride_tricks.as_strided(b[int(starts[0]):], (starts.size, F), (F, 1), writeable=False)
        else:
            frames = b[starts[:, None] + np.arange(F)]
        a = self.accounting
        ends = starts + F
        ftype = frames[:, 3]
        seq = frames[:, 4].astype(np.int64) | (frames[:, 5].astype(np.int64) << 8)
        ok = ftype == TYPE_SAMPLE
        reason = np.where(ok, 0, 1).astype(np.int8)  # index into _BLOCK_REASONS (0: accepted)
        long_enough = ok & (L >= _SAMPLE_HEAD.size)
        reason[ok & ~long_enough] = 2
        head = np.zeros((starts.size, _SAMPLE_HEAD.size), dtype=np.uint8)
        if L >= _SAMPLE_HEAD.size:
            head[:] = frames[:, HEADER:HEADER + _SAMPLE_HEAD.size]
        hv = head.view(np.dtype([("t", "<f8"), ("temp", "<f4"), ("ng", "u1"), ("na", "u1"), ("mg", "<u2"),
                                 ("ma", "<u2")]))[:, 0]
        ng, na = hv["ng"].astype(np.int64), hv["na"].astype(np.int64)
        good = long_enough & (ng <= MAX_SENSORS) & (na <= MAX_SENSORS) & (L == _SAMPLE_HEAD.size + 4 * (ng + na))
        good &= np.isfinite(hv["t"])
        reason[long_enough & ~good] = 2
        # sequence counter against the last accepted frame: a frame rejected as a duplicate carries the same
        # counter as the one before it, so comparing each frame with the previous good one is the sequential rule
        gi = np.flatnonzero(good)
        if gi.size:
            sq = seq[gi]
            prev = np.empty_like(sq)
            prev[0] = -1 if self._last_seq is None else self._last_seq
            prev[1:] = sq[:-1]
            d = (sq - prev) & 0xFFFF
            first_free = self._last_seq is None
            dup = d == 0
            if first_free:
                dup[0] = False
            reason[gi[dup]] = 3
            chk = ~dup
            if first_free:
                chk[0] = False
            gap = chk & (d > 1) & (d <= 0x8000)
            if gap.any():
                a.event("counter_gap", int(gap.sum()))
                a.event("missing_epochs", int(np.sum(d[gap] - 1)))
            jump = chk & (d > 0x8000)
            if jump.any():
                a.event("counter_jump", int(jump.sum()))
            self._last_seq = int(sq[-1])
            good[gi[dup]] = False
        for k in np.flatnonzero(reason):
            self._rej(_BLOCK_REASONS[reason[k]], int(starts[k]), int(ends[k]))
        gi = np.flatnonzero(good)
        a.accepted += int(np.sum(ends[gi] - starts[gi]))
        if gi.size == 0:
            return None
        ngs, nas = ng[gi], na[gi]
        if np.any(ngs != ngs[0]) or np.any(nas != nas[0]):
            raise FrameError("the frames of one chunk carry different sensor counts; a block needs one layout: "
                             "decode this stream with feed() (one Epoch per frame)")
        a.epochs += int(gi.size)
        n_g, n_a = int(ngs[0]), int(nas[0])
        m = n_g + n_a
        vals = np.empty((gi.size, m), dtype=np.float64)
        if m:
            o = HEADER + _SAMPLE_HEAD.size
            vals[:] = np.ascontiguousarray(frames[gi, o:o + 4 * m]).view("<f4")
        finite = np.isfinite(vals)
        raw: dict[str, np.ndarray] = {}
        valid: dict[str, np.ndarray] = {}
        for key, n_i, masks, o in (("gyro", n_g, hv["mg"][gi], 0), ("accel", n_a, hv["ma"][gi], n_g)):
            if n_i:
                y = vals[:, o:o + n_i].copy()
                v = ((masks[:, None].astype(np.int64) >> np.arange(n_i)) & 1).astype(bool) & finite[:, o:o + n_i]
                y[~v] = 0.0
                raw[key], valid[key] = y, v
        temp = hv["temp"][gi].astype(np.float64)
        if np.any(np.isinf(temp)):
            a.event("nonfinite_temperature", int(np.sum(np.isinf(temp))))
        return EpochBlock(hv["t"][gi].astype(np.float64), raw, valid,
                          temp if np.all(np.isfinite(temp)) else None, {"seq": seq[gi]})

    def _settle(self, decoded: tuple[str | None, Epoch | None], pos: int, end: int, out: list[Epoch]) -> None:
        """Account the bytes pos..end of one frame: accepted (with its epoch, if it completed one) or rejected."""
        reason, ep = decoded
        if reason is None:
            self.accounting.accepted += end - pos
            if ep is not None:
                out.append(ep)
        else:
            self._rej(reason, pos, end)

    def _frame(self, buf: bytearray, pos: int, L: int) -> tuple[str | None, Epoch | None]:
        ftype = buf[pos + 3]
        seq = buf[pos + 4] | (buf[pos + 5] << 8)
        if ftype != TYPE_SAMPLE:
            return "unknown_type", None
        p = pos + HEADER
        if L < _SAMPLE_HEAD.size:
            return "bad_payload", None
        t, temp, ng, na, mg, ma = _SAMPLE_HEAD.unpack_from(buf, p)
        if ng > MAX_SENSORS or na > MAX_SENSORS or L != _SAMPLE_HEAD.size + 4 * (ng + na) or not math.isfinite(t):
            return "bad_payload", None
        a = self.accounting
        if self._last_seq is not None:
            d = (seq - self._last_seq) & 0xFFFF
            if d == 0:
                return "duplicate", None
            if d > 1 and d <= 0x8000:
                a.event("counter_gap")
                a.event("missing_epochs", d - 1)
            elif d > 0x8000:
                a.event("counter_jump")
        self._last_seq = seq
        fmt = self._fmts.get(ng + na)
        if fmt is None:
            fmt = self._fmts[ng + na] = struct.Struct(f"<{ng + na}f")
        vals = fmt.unpack_from(buf, p + _SAMPLE_HEAD.size)
        raw: dict[str, np.ndarray] = {}
        valid: dict[str, np.ndarray] = {}
        tot = sum(vals)
        finite = tot - tot == 0.0
        for k, n, m, o in (("gyro", ng, mg, 0), ("accel", na, ma, ng)):
            if n:
                y = np.array(vals[o:o + n])
                v = self._mask(m, n)
                if not finite:
                    v &= np.isfinite(y)
                if not finite or m != (1 << n) - 1:
                    y[~v] = 0.0
                raw[k], valid[k] = y, v
        if math.isinf(temp):
            a.event("nonfinite_temperature")
        a.epochs += 1
        return None, Epoch(float(t), raw, valid, float(temp) if math.isfinite(temp) else None, {"seq": seq})

    def _mask(self, m: int, n: int) -> np.ndarray:
        key = (m, n)
        v = self._masks.get(key)
        if v is None:
            if len(self._masks) > 4096:
                self._masks.clear()
            v = self._masks[key] = ((m >> np.arange(n)) & 1).astype(bool)
        return v.copy()


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire & Baker 1999): ``data`` without zero bytes, one byte longer
    per 254 bytes; the frame is then ended by a single 0x00.

    >>> cobs_encode(b"\\x11\\x00\\x22").hex(), cobs_decode(cobs_encode(b"\\x11\\x00\\x22")).hex()
    ('02110222', '110022')
    """
    out = bytearray()
    block = bytearray()
    for b in data:
        if b == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out.append(255)
                out += block
                block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data: bytes | bytearray | memoryview) -> bytes | None:
    """Inverse of :func:`cobs_encode` (without the delimiter); None if ``data`` is not a valid encoding."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        j = i + code
        if code == 0 or j > n:
            return None
        block = data[i + 1:j]
        if 0 in block:
            return None
        out += block
        i = j
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)


def encode_frame_cobs(ftype: int, seq: int, payload: bytes) -> bytes:
    """The COBS variant of a frame: ``COBS(TYPE, SEQ, payload, CRC-16) 0x00`` (CRC over TYPE, SEQ, payload).

    >>> f = encode_frame_cobs(TYPE_SAMPLE, 1, b"\\x00\\x00")
    >>> f[-1], 0 in f[:-1]
    (0, False)
    """
    body = struct.pack("<BH", ftype, seq & 0xFFFF) + payload
    return cobs_encode(body + crc16_ccitt(body).to_bytes(2, "little")) + b"\x00"


class CobsDecoder(SerialDecoder):
    """Streaming decoder of the COBS variant of the framing (see the module docstring): frames end at every
    0x00 byte, so resynchronisation happens at the next delimiter: bytes damaged or inserted before a frame
    without a delimiter in between make that frame invalid too. Rejections: ``cobs`` (not a valid encoding),
    ``checksum``, ``bad_length`` (longer than any valid frame), ``truncated`` (bytes after the last delimiter
    at the end of a stream), and the payload reasons of :class:`SerialDecoder`. A lone delimiter (an empty
    frame: idle line or a leading delimiter) is accepted as framing.

    >>> dec = CobsDecoder()
    >>> frame = encode_frame_cobs(TYPE_SAMPLE, 3, encode_sample(1.5, {"gyro": np.zeros(3)}))
    >>> eps = dec.feed(b"noise\\x00" + frame[:7]) + dec.feed(frame[7:])
    >>> [e.t for e in eps], dict(dec.accounting.rejected), dec.accounting.identity_holds()
    ([1.5], {'cobs': 6}, True)
    """

    def _scan(self, final: bool) -> list[Epoch]:
        buf = self._buf
        n = len(buf)
        pos = 0
        out: list[Epoch] = []
        max_enc = self.max_payload + 5 + (self.max_payload + 5) // 254 + 1
        while True:
            z = buf.find(b"\x00", pos)
            if z < 0:
                if n - pos > max_enc:        # no delimiter in reach: this cannot be a frame
                    self._rej("bad_length", pos, n)
                    pos = n
                elif final and n > pos:
                    self._rej("truncated", pos, n)
                    pos = n
                break
            end = z + 1
            if z == pos:   # an empty frame: a lone delimiter (idle line, or a sender that also leads with 0x00)
                self.accounting.accepted += 1
            elif z - pos > max_enc:
                self._rej("bad_length", pos, end)
            else:
                body = cobs_decode(memoryview(buf)[pos:z])
                if body is None or len(body) < 5:
                    self._rej("cobs", pos, end)
                elif crc16_ccitt(body[:-2]) != body[-2] | (body[-1] << 8):
                    self._rej("checksum", pos, end)
                else:
                    L = len(body) - 5
                    pseudo = bytearray(SYNC) + bytes([L]) + body[:-2]
                    self._settle(self._frame(pseudo, 0, L), pos, end, out)
            pos = end
        del buf[:pos]
        return out

    def _scan_block(self, final: bool) -> EpochBlock | None:
        # COBS frames are decoded one by one (each needs its own un-stuffing) and stacked
        return _stack(self._scan(final))


def _stack(epochs: list[Epoch]) -> EpochBlock | None:
    if not epochs:
        return None
    blk = EpochBlock.from_epochs(epochs)
    blk.meta["seq"] = np.array([e.counters["seq"] for e in epochs], dtype=np.int64)
    return blk


def make_decoder(framing: str, accounting: Accounting | None = None, max_payload: int = 255) -> SerialDecoder:
    """The decoder of a framing: ``"sync"`` (:class:`SerialDecoder`) or ``"cobs"`` (:class:`CobsDecoder`)."""
    if framing == "sync":
        return SerialDecoder(accounting, max_payload)
    if framing == "cobs":
        return CobsDecoder(accounting, max_payload)
    raise FrameError(f"framing must be one of {FRAMINGS}, got {framing!r}")


def read_available(ser: Any, size: int, timeout: float | None) -> bytes:
    """What a pyserial port has for us, in one block of at most ``size`` bytes: waits up to the port's timeout for
    the first byte, then takes everything that has arrived without waiting.

    ``in_waiting`` is exact for local ports, ``loop://`` and ``rfc2217://`` but only 0 or 1 for ``socket://``
    (a ``select`` poll): where it says at most one byte, the rest is drained with a zero-timeout read, so that
    a socket is read in blocks too instead of one byte per call.

    >>> import serial
    >>> port = serial.serial_for_url("loop://", timeout=0.01)
    >>> port.write(b"abcdef")
    6
    >>> read_available(port, 4, 0.01), read_available(port, 4, 0.01), read_available(port, 4, 0.01)
    (b'abcd', b'ef', b'')
    """
    n = ser.in_waiting
    if n > 1:
        return bytes(ser.read(min(n, size)))
    first = ser.read(1)
    if not first or size <= 1:
        return bytes(first)
    ser.timeout = 0
    try:
        rest = ser.read(size - 1)
    finally:
        ser.timeout = timeout
    return bytes(first) + bytes(rest)


class SerialSource(Source):
    """Live serial port (any pyserial URL: ``/dev/ttyUSB0``, ``COM3``, ``loop://``, ``socket://host:port``).

    Parameters
    ----------
    port : str
    baudrate : int
    serial_port : serial.SerialBase, optional
        An already open port (``port`` is then only a label).
    read_size : int
        Largest read per call.
    idle_timeout : float, optional
        End after this long without bytes (s); None = until :meth:`stop`.
    reconnect : ReconnectPolicy, optional
    """

    unit = "byte"

    def __init__(self, port: str = "loop://", baudrate: int = 921600, serial_port: Any = None,
                 read_size: int = 4096, read_timeout: float = 0.05, idle_timeout: float | None = None,
                 reconnect: Any = None, max_payload: int = 255, framing: str = "sync",
                 side_log: SideLog | None = None) -> None:
        super().__init__(side_log)
        self.port, self.baudrate = port, baudrate
        self.ser = serial_port
        self.read_size, self.read_timeout, self.idle_timeout = read_size, read_timeout, idle_timeout
        self.reconnect = reconnect or ReconnectPolicy()
        self.decoder = make_decoder(framing, self.accounting, max_payload)

    def _open(self) -> None:
        if self.ser is None:
            import serial

            self.ser = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=self.read_timeout)

    def _epochs(self) -> Iterator[Epoch]:
        import serial

        self._open()
        last = time.monotonic()
        attempt = 0
        error: BaseException | None = None
        while not self.stop_event.is_set():
            if self.ser is None:  # reconnect policy: wait, reopen; TransportError when the attempts are used up
                if attempt >= self.reconnect.max_attempts:
                    raise TransportError(f"serial port {self.port} failed and could not be reopened after "
                                         f"{attempt} attempts: {error}") from error
                if self.stop_event.wait(self.reconnect.delay(attempt)):
                    break
                attempt += 1
                try:
                    self._open()
                    self.accounting.event("reconnect")
                except (serial.SerialException, OSError) as exc:
                    self.accounting.event("reconnect_failed")
                    error = exc
                    continue
            try:
                data = read_available(self.ser, self.read_size, self.read_timeout)
                attempt = 0
            except (serial.SerialException, OSError) as exc:
                self.accounting.event("port_error")
                error = exc
                try:
                    self.ser.close()
                except Exception:
                    pass
                self.ser = None
                continue
            if data:
                last = time.monotonic()
                yield from self.decoder.feed(data)
            elif self.idle_timeout is not None and time.monotonic() - last > self.idle_timeout:
                break
        yield from self.decoder.flush()

    def close(self) -> None:
        super().close()
        if self.ser is not None:
            self.ser.close()
            self.ser = None


class SerialFileSource(Source):
    """A recorded serial byte stream (a raw capture file), decoded in chunks of ``chunk`` bytes."""

    unit = "byte"

    def __init__(self, path: str | os.PathLike[str], chunk: int = 1 << 16, max_payload: int = 255,
                 framing: str = "sync", side_log: SideLog | None = None) -> None:
        super().__init__(side_log)
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise TransportError(f"no serial capture at {self.path}")
        self.chunk = chunk
        self.decoder = make_decoder(framing, self.accounting, max_payload)

    def _epochs(self) -> Iterator[Epoch]:
        with open(self.path, "rb") as fh:
            while not self.stop_event.is_set():
                data = fh.read(self.chunk)
                if not data:
                    break
                yield from self.decoder.feed(data)
        yield from self.decoder.flush()
