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

__all__ = ["SYNC", "TYPE_SAMPLE", "encode_frame", "encode_sample", "encode_block", "SerialDecoder",
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
        buf = self._buf
        n = len(buf)
        pos = 0
        out: list[Epoch] = []
        crc = crc16_ccitt
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
            if crc(memoryview(buf)[pos + 2:end - 2]) != buf[end - 2] | (buf[end - 1] << 8):
                self._rej("checksum", pos, pos + 1)
                pos += 1
                continue
            self._settle(self._frame(buf, pos, L), pos, end, out)
            pos = end
        del buf[:pos]
        return out

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


def make_decoder(framing: str, accounting: Accounting | None = None, max_payload: int = 255) -> SerialDecoder:
    """The decoder of a framing: ``"sync"`` (:class:`SerialDecoder`) or ``"cobs"`` (:class:`CobsDecoder`)."""
    if framing == "sync":
        return SerialDecoder(accounting, max_payload)
    if framing == "cobs":
        return CobsDecoder(accounting, max_payload)
    raise FrameError(f"framing must be one of {FRAMINGS}, got {framing!r}")


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
                waiting = self.ser.in_waiting
                data = self.ser.read(min(max(waiting, 1), self.read_size))
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
