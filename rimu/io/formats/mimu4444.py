"""The OpenShoe / MIMU4444 raw-data stream: eight MPU-9150 triads on one board, as logged or live on a serial port.

Format (big-endian; the stream of the MIMU4444 firmware in its raw-data mode)::

    [A0 28 00 C8]                                   acknowledgement of the start command (logs start with it)
    then one packet per sample:
    offset size  field
    0      1     header 0xAA
    1      2     packet number, uint16, wraps
    3      1     payload length L (100 for 8 IMUs: 4 + 8 * 12)
    4      4     time stamp, uint32 ticks of a 64 MHz clock, wraps every 67.1 s
    8      96    8 IMUs x [ax ay az gx gy gz], int16 counts
    4+L    2     checksum, uint16: the sum of bytes 0 .. 3+L of the packet

Scales (the MPU-9150 settings of the board's firmware): accelerometers 2048 LSB/g (+-16 g), gyros 16.4 LSB per
deg/s (+-2000 deg/s). A count at the int16 limit (-32768 or 32767) is a clipped sample, not a measurement: that
triad's instrument is invalid (NaN) at that sample, before any averaging. An accelerometer vector of exactly
zero counts is physically impossible for a unit on Earth (a placeholder record): invalid too.

Frames: IMUs 1, 3, 5, 7 (top side) are in the array frame, IMUs 2, 4, 6, 8 (bottom side) are rotated by
``C = [[0, -1, 0], [-1, 0, 0], [0, 0, -1]]`` (``v_array = C v_raw``). The reader keeps each triad in its own
axes (a calibration file binds raw outputs); :func:`geometry` gives the board's triads with these rotations
and nominal positions (+-9.45 mm in x and y, +-1 mm in z), for ``rimu detect --geometry`` and the array tools.

Decoding (:class:`Mimu4444Decoder`) works on any chunking of the byte stream: the header byte is searched,
the whole packet awaited, the checksum checked, and on a failed check one byte is dropped and the search goes
on (resynchronisation); every byte is counted (accepted, rejected by reason, or pending), as
:class:`rimu.io.serial.SerialDecoder` does for rimu's own framing. Time stamps are unwrapped; a packet number
that jumps is counted as ``missing_epochs``, a repeated one is rejected as ``duplicate``.

Examples
--------
>>> pk = encode_packet(5, 1000, np.zeros((8, 6), int) + [0, 0, 2048, 16, 0, 0])
>>> dec = Mimu4444Decoder()
>>> eps = dec.feed(ACK + b"xx" + pk[:50]) + dec.feed(pk[50:])
>>> len(eps), round(float(eps[0].raw["accel"][2]), 4), round(float(np.degrees(eps[0].raw["gyro"][0])), 4)
(1, 9.8066, 0.9756)
>>> dec.accounting.summary()
'bytes: received 112 = accepted 106 + rejected 6 (ack 4, garbage 2) + pending 0; epochs 1'
"""

from __future__ import annotations

import lzma
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...epoch import Epoch
from ...errors import SessionFormatError, TransportError
from ...geometry.presets.mimu4444 import MAT_ARRAY_RAW_BOTTOM, POSITIONS_M
from ...units import DEG_TO_RAD, G0
from ..accounting import Accounting
from ..multiimu import ImuStream, MultiImuRecording
from ..serial import SerialSource

__all__ = ["NAME", "EXTRA", "ACK", "N_IMU", "ACCEL_LSB_PER_G", "GYRO_LSB_PER_DPS", "MAT_ARRAY_RAW_BOTTOM",
           "POSITIONS_M", "sniff", "read", "geometry", "encode_packet", "Mimu4444Decoder",
           "Mimu4444SerialSource", "Mimu4444FileSource"]

NAME = "mimu4444"
EXTRA: str | None = None

ACK = bytes([0xA0, 0x28, 0x00, 0xC8])
HEADER = 0xAA
N_IMU = 8
PAYLOAD = 4 + N_IMU * 12
PACKET = 4 + PAYLOAD + 2
TICK_HZ = 64e6
ACCEL_LSB_PER_G = 2048.0
GYRO_LSB_PER_DPS = 16.4
INT16_LIMITS = (-32768, 32767)
_ACCEL_SI = G0 / ACCEL_LSB_PER_G
_GYRO_SI = DEG_TO_RAD / GYRO_LSB_PER_DPS


def encode_packet(number: int, ticks: int, counts: np.ndarray) -> bytes:
    """One packet of the stream: ``counts`` (8, 6) int16 ``[ax ay az gx gy gz]`` per IMU (tests, simulators).

    >>> len(encode_packet(0, 0, np.zeros((8, 6), int)))
    106
    """
    c = np.asarray(counts)
    if c.shape != (N_IMU, 6) or np.any(c < INT16_LIMITS[0]) or np.any(c > INT16_LIMITS[1]):
        raise SessionFormatError(f"a MIMU4444 packet carries (8, 6) int16 counts, got shape {c.shape}")
    body = (bytes([HEADER]) + int(number & 0xFFFF).to_bytes(2, "big") + bytes([PAYLOAD])
            + int(ticks & 0xFFFFFFFF).to_bytes(4, "big") + c.astype(">i2").tobytes())
    return body + (sum(body) & 0xFFFF).to_bytes(2, "big")


def _convert(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Counts (N, 8, 6) -> accel, gyro (N, 24) SI in raw triad axes, NaN where clipped or impossible, and the
    per-triad invalid masks (N, 8) of each."""
    c = counts.astype(np.int32)
    acc_c, gyr_c = c[:, :, :3], c[:, :, 3:]
    lim = INT16_LIMITS
    bad_a = ((acc_c <= lim[0]) | (acc_c >= lim[1])).any(axis=2) | (acc_c == 0).all(axis=2)
    bad_g = ((gyr_c <= lim[0]) | (gyr_c >= lim[1])).any(axis=2)
    acc = acc_c * _ACCEL_SI
    gyr = gyr_c * _GYRO_SI
    acc[bad_a] = np.nan
    gyr[bad_g] = np.nan
    n = len(c)
    return acc.reshape(n, 3 * N_IMU), gyr.reshape(n, 3 * N_IMU), bad_a, bad_g


class Mimu4444Decoder:
    """Streaming decoder of the MIMU4444 packet stream: :meth:`feed` bytes in any chunks, get epochs out.

    Epochs carry SI values (``raw["gyro"]`` rad/s, ``raw["accel"]`` m/s^2, 24 sensors each, raw triad axes),
    ``valid`` False for clipped or impossible samples, ``t`` the unwrapped device time, s, from the first
    packet, and the counters ``packet`` (as sent, uint16) and ``ticks``. ``clipped`` counts invalid triad
    samples per instrument.
    """

    def __init__(self, accounting: Accounting | None = None) -> None:
        self.accounting = accounting or Accounting("byte")
        self.accounting.pending_fn = lambda: len(self._buf)
        self._buf = bytearray()
        self._started = False
        self._last_number: int | None = None
        self._last_ticks: int | None = None
        self._t_ticks = 0
        self.clipped = {"accel": 0, "gyro": 0}

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Epoch]:
        """Add bytes; returns the epochs of every packet completed by them."""
        chunk = bytes(chunk)
        self.accounting.received += len(chunk)
        self._buf += chunk
        return self._epochs(*self.decode_arrays(final=False))

    def flush(self) -> list[Epoch]:
        """End of stream: the bytes of an incomplete packet are rejected (``truncated``)."""
        return self._epochs(*self.decode_arrays(final=True))

    def decode_all(self, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A whole stream at once, as arrays (see :meth:`decode_arrays`); the end of ``data`` ends the stream."""
        self.accounting.received += len(data)
        self._buf += data
        return self.decode_arrays(final=True)

    def _rej(self, reason: str, n: int) -> None:
        self.accounting.reject(reason, n)

    def decode_arrays(self, final: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Decode every complete packet in the buffer as arrays: time stamps (s), packet numbers, counts
        (N, 8, 6). Consecutive good packets are checked at once (vectorised); a bad one costs a byte-wise
        search for the next header."""
        buf = self._buf
        pos = 0
        n = len(buf)
        if not self._started and n >= 4 and buf[:4] == ACK:
            self._rej("ack", 4)
            pos = 4
        if n >= 1:
            self._started = True
        rows: list[np.ndarray] = []
        while True:
            i = buf.find(bytes([HEADER]), pos)
            if i < 0:
                self._rej("garbage", n - pos)
                pos = n
                break
            if i > pos:
                self._rej("garbage", i - pos)
                pos = i
            m = (n - pos) // PACKET
            if m == 0:
                if final:
                    self._rej("truncated", n - pos)
                    pos = n
                break
            a = np.frombuffer(bytes(buf[pos:pos + m * PACKET]), np.uint8).reshape(m, PACKET)
            ok = (a[:, 0] == HEADER) & (a[:, 3] == PAYLOAD)
            ok &= (a[:, :PACKET - 2].sum(axis=1, dtype=np.int64) & 0xFFFF) == (a[:, -2].astype(np.int64) << 8
                                                                              | a[:, -1])
            good = int(np.argmin(ok)) if not ok.all() else m
            if good:
                rows.append(a[:good])
                self.accounting.accepted += good * PACKET
                pos += good * PACKET
            if good < m:  # a bad candidate: drop one byte and search again
                self._rej("bad_length" if a[good, 3] != PAYLOAD else "checksum", 1)
                pos += 1
        del buf[:pos]
        if not rows:
            return np.zeros(0), np.zeros(0, np.int64), np.zeros((0, N_IMU, 6), np.int16)
        a = np.concatenate(rows)
        number = (a[:, 1].astype(np.int64) << 8) | a[:, 2]
        ticks = (a[:, 4].astype(np.int64) << 24) | (a[:, 5].astype(np.int64) << 16) | (a[:, 6].astype(np.int64) << 8
                                                                                        ) | a[:, 7]
        counts = a[:, 8:8 + N_IMU * 12].copy().view(">i2").reshape(len(a), N_IMU, 6).astype(np.int16)
        keep = np.ones(len(a), bool)
        last = self._last_number
        for k in range(len(a)):  # duplicates and gaps of the packet counter
            if last is not None:
                step = (int(number[k]) - last) & 0xFFFF
                if step == 0:
                    keep[k] = False
                    self.accounting.accepted -= PACKET
                    self._rej("duplicate", PACKET)
                    continue
                if step > 1:
                    self.accounting.event("missing_epochs", step - 1)
            last = int(number[k])
        self._last_number = last
        number, ticks, counts = number[keep], ticks[keep], counts[keep]
        # unwrap the 32-bit tick counter
        prev = ticks[0] if self._last_ticks is None else self._last_ticks
        d = np.diff(np.concatenate([[prev], ticks])) & 0xFFFFFFFF
        tt = self._t_ticks + np.cumsum(d)
        if len(tt):
            self._t_ticks = int(tt[-1])
            self._last_ticks = int(ticks[-1])
        return tt / TICK_HZ, number, counts

    def _epochs(self, t: np.ndarray, number: np.ndarray, counts: np.ndarray) -> list[Epoch]:
        if not len(t):
            return []
        acc, gyr, bad_a, bad_g = _convert(counts)
        self.clipped["accel"] += int(bad_a.sum())
        self.clipped["gyro"] += int(bad_g.sum())
        out = []
        for k in range(len(t)):
            ga, gg = np.isfinite(acc[k]), np.isfinite(gyr[k])
            out.append(Epoch(float(t[k]), {"gyro": np.where(gg, gyr[k], 0.0), "accel": np.where(ga, acc[k], 0.0)},
                             {"gyro": gg, "accel": ga}, None, {"packet": int(number[k])}))
            self.accounting.epochs += 1
        return out


def _open_bytes(path: str | os.PathLike[str]) -> bytes:
    p = Path(path)
    if not p.exists():
        raise TransportError(f"no file at {p}")
    try:
        if p.suffix.lower() == ".xz":
            with lzma.open(p, "rb") as fh:
                return fh.read()
        return p.read_bytes()
    except (lzma.LZMAError, EOFError) as exc:
        raise SessionFormatError(f"{p}: not a readable .xz file ({exc})") from None


def sniff(name: str, head: bytes) -> bool:
    """A MIMU4444 stream starts with the acknowledgement ``A0 28 00 C8`` and/or a packet header 0xAA with
    payload length 100.

    >>> sniff("exp_5.bin", ACK + encode_packet(0, 0, np.zeros((8, 6), int))), sniff("a.csv", b"t,gx")
    (True, False)
    """
    h = head[4:] if head[:4] == ACK else head
    return len(h) >= 4 and h[0] == HEADER and h[3] == PAYLOAD


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """Read a MIMU4444 log (``.bin`` or ``.bin.xz``): eight triads ``imu1`` .. ``imu8`` on the board's clock.

    Returns
    -------
    MultiImuRecording
        SI values in each triad's own axes (NaN where clipped or impossible); ``meta`` holds ``format``,
        ``packets``, ``rejected_bytes`` by reason, ``missing_packets``, ``clipped_samples`` per instrument
        (triad samples), ``clipped_per_imu`` and ``sample_rate_hz``.

    Raises
    ------
    SessionFormatError
        No packet in the file, or options this reader does not know.
    """
    if options:
        raise SessionFormatError(f"the {NAME} reader takes no options, got {sorted(options)}")
    data = _open_bytes(path)
    dec = Mimu4444Decoder()
    t, _, counts = dec.decode_all(data)
    if not len(t):
        raise SessionFormatError(f"{path}: no MIMU4444 packet (0xAA, length {PAYLOAD}, good checksum) in "
                                 f"{len(data)} bytes; is it a raw-data stream of this board?")
    acc, gyr, bad_a, bad_g = _convert(counts)
    units = [ImuStream(f"imu{j + 1}", t, gyr[:, 3 * j:3 * j + 3], acc[:, 3 * j:3 * j + 3]) for j in range(N_IMU)]
    acct = dec.accounting
    meta: dict[str, Any] = {
        "source": str(path), "format": NAME, "packets": int(len(t)),
        "rejected_bytes": dict(acct.rejected), "missing_packets": int(acct.events.get("missing_epochs", 0)),
        "clipped_samples": {"gyro": int(bad_g.sum()), "accel": int(bad_a.sum())},
        "clipped_per_imu": {"gyro": bad_g.sum(axis=0).tolist(), "accel": bad_a.sum(axis=0).tolist()},
        "sample_rate_hz": float(1.0 / np.median(np.diff(t))) if len(t) > 1 else float("nan"),
        "range": {"gyro": 32767 * _GYRO_SI, "accel": 32767 * _ACCEL_SI},
    }
    return MultiImuRecording(units, meta)


def geometry(positions: bool = True) -> Any:
    """The board as the geometry preset ``mimu4444`` (:func:`rimu.geometry.presets.mimu4444.mimu4444`): eight
    triads ``imu1`` .. ``imu8``, the bottom ones rotated, nominal positions in metres.

    >>> geometry().n
    24
    """
    from ...geometry import preset

    return preset("mimu4444", positions=positions)


class Mimu4444SerialSource(SerialSource):
    """The board live on a serial port (or Bluetooth SPP): any pyserial URL, the MIMU4444 packet stream.

    Same parameters as :class:`rimu.io.serial.SerialSource` (``framing`` is this stream's own). Send the
    board its start command first (the firmware's raw-data mode); the acknowledgement is counted and skipped.
    """

    def __init__(self, port: str = "loop://", baudrate: int = 115200, **kwargs: Any) -> None:
        kwargs.pop("framing", None)
        super().__init__(port, baudrate, **kwargs)
        self.decoder = Mimu4444Decoder(self.accounting)  # type: ignore[assignment]

    def geometry(self, instrument: str = "gyro") -> Any:
        """The board's triads (:func:`geometry`)."""
        return geometry()


class Mimu4444FileSource(Mimu4444SerialSource):
    """A recorded MIMU4444 stream (``.bin`` or ``.bin.xz``) replayed as epochs, in chunks of ``chunk`` bytes."""

    def __init__(self, path: str | os.PathLike[str], chunk: int = 1 << 16) -> None:
        super().__init__("file")
        self.path, self.chunk = os.fspath(path), int(chunk)
        if not os.path.exists(self.path):
            raise TransportError(f"no MIMU4444 capture at {self.path}")

    def _epochs(self) -> Iterator[Epoch]:
        data = _open_bytes(self.path)
        for k in range(0, len(data), self.chunk):
            if self.stop_event.is_set():
                break
            yield from self.decoder.feed(data[k:k + self.chunk])
        yield from self.decoder.flush()

