"""Declarative CAN frame layouts and their vectorised codec.

A layout file (JSON, format ``rimu.can_layout`` version 1, documented in ``docs/io.md``) says which frames a
device sends per sample, where each value sits in the 8 data bytes, and how to check the frame::

    {"format": "rimu.can_layout", "version": 1, "name": "cone6-rimu",
     "instruments": {"gyro": 6, "accel": 6}, "geometry": {"gyro": "cone6", "accel": "cone6"},
     "raw_unit": {"gyro": "count", "accel": "count"}, "sample_rate_hz": 100,
     "messages": [
       {"name": "GYRO_1", "id": "0x101", "length": 8,
        "checksum": {"algorithm": "crc8_sae_j1850", "byte": 7, "data_id": 1},
        "signals": [
          {"name": "G_X1", "role": "sample", "instrument": "gyro", "index": 0,
           "start_bit": 0, "length": 16, "byte_order": "little_endian", "signed": true,
           "scale": 0.03125, "offset": 0.0},
          {"name": "CNT", "role": "counter", "start_bit": 48, "length": 8}]}]}

Signal roles: ``sample`` (raw output of sensor ``index`` of ``instrument``), ``flag`` (sensor status: the
sensor is valid when ``raw & ok_mask == 0``; ``sensors`` lists ``[instrument, index]`` pairs it covers),
``time`` (device time, s after scaling; wraps at ``2**length * scale``), ``temperature`` (degC), ``counter``
(rolling sample counter, the same in every frame of one sample), ``other`` (decoded into ``Epoch.counters``).
Bit numbering follows DBC files: ``little_endian`` (Intel) signals give their least significant bit,
``big_endian`` (Motorola) ones their most significant bit, bit ``8*k + b`` being bit b of data byte k.
Checksums are whole bytes, computed over the other data bytes in order, preceded by ``data_id`` if given.

:class:`CanCodec` decodes many frames at once with numpy (8 data bytes as one 64-bit word, shifts and
masks per signal); :meth:`CanCodec.encode` is the inverse, used by the simulated device.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..epoch import INSTRUMENTS
from ..errors import FrameError, ShapeError
from .checksum import CHECKSUMS, crc8_columns

__all__ = ["Signal", "Message", "Layout", "CanCodec", "DecodedFrames", "load_layout", "linear_checksum", "LAYOUT_FORMAT",
           "STATUS_OK", "STATUS_UNKNOWN_ID", "STATUS_BAD_LENGTH", "STATUS_CHECKSUM", "STATUS_REASONS"]

LAYOUT_FORMAT = "rimu.can_layout"
ROLES = ("sample", "flag", "time", "temperature", "counter", "other")

STATUS_OK = 0
STATUS_UNKNOWN_ID = 1
STATUS_BAD_LENGTH = 2
STATUS_CHECKSUM = 3
#: status code -> rejection reason counted by the sources
STATUS_REASONS = {STATUS_UNKNOWN_ID: "unknown_id", STATUS_BAD_LENGTH: "bad_length", STATUS_CHECKSUM: "checksum"}


@dataclass
class Signal:
    """One field of a frame (see the module docstring for the meaning of each attribute)."""

    name: str
    start_bit: int
    length: int
    role: str = "other"
    byte_order: str = "little_endian"
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0
    instrument: str | None = None
    index: int | None = None
    ok_mask: int = 0
    sensors: list[tuple[str, int]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise FrameError(f"signal {self.name!r}: role must be one of {ROLES}, got {self.role!r}")
        if self.byte_order not in ("little_endian", "big_endian"):
            raise FrameError(f"signal {self.name!r}: byte_order must be little_endian or big_endian")
        if not 1 <= self.length <= 64:
            raise FrameError(f"signal {self.name!r}: length must be 1..64 bits, got {self.length}")
        if not (self.scale != 0 and np.isfinite(self.scale) and np.isfinite(self.offset)):
            raise FrameError(f"signal {self.name!r}: scale must be finite and non-zero, offset finite")
        lo = self.lsb_shift
        if lo < 0 or lo + self.length > 64:
            raise FrameError(f"signal {self.name!r}: bits {self.start_bit}+{self.length} ({self.byte_order}) do "
                             "not fit in 8 data bytes")
        if self.role == "sample" and (self.instrument not in INSTRUMENTS or self.index is None):
            raise FrameError(f"sample signal {self.name!r} needs instrument in {INSTRUMENTS} and an index")
        self.sensors = [(str(a), int(b)) for a, b in self.sensors]

    @property
    def lsb_shift(self) -> int:
        """Position of the least significant bit in the 64-bit word of the frame's byte order."""
        if self.byte_order == "little_endian":
            return self.start_bit
        msb = 8 * (7 - self.start_bit // 8) + self.start_bit % 8
        return msb - self.length + 1

    @property
    def resolution(self) -> float:
        return abs(self.scale)

    def raw_range(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "role": self.role, "start_bit": self.start_bit, "length": self.length,
                             "byte_order": self.byte_order, "signed": self.signed, "scale": self.scale,
                             "offset": self.offset}
        if self.instrument is not None:
            d["instrument"], d["index"] = self.instrument, self.index
        if self.role == "flag":
            d["ok_mask"], d["sensors"] = self.ok_mask, [list(s) for s in self.sensors]
        return d


@dataclass
class Message:
    """One frame of a sample: its identifier, length, signals and checksum."""

    name: str
    id: int
    signals: list[Signal]
    length: int = 8
    extended: bool = False
    checksum: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.length <= 8:
            raise FrameError(f"message {self.name!r}: length must be 1..8 bytes (classical CAN), got {self.length}")
        if self.checksum is not None:
            alg = self.checksum.get("algorithm", "crc8_sae_j1850")
            if alg not in CHECKSUMS:
                raise FrameError(f"message {self.name!r}: unknown checksum {alg!r}; known: {sorted(CHECKSUMS)}")
            b = int(self.checksum.get("byte", self.length - 1))
            if not 0 <= b < self.length:
                raise FrameError(f"message {self.name!r}: checksum byte {b} outside the frame")
            self.checksum = {"algorithm": alg, "byte": b, "data_id": self.checksum.get("data_id")}
        for s in self.signals:
            if s.lsb_shift + s.length > 64 or (s.byte_order == "little_endian" and s.start_bit + s.length > 8 * self.length):
                raise FrameError(f"signal {s.name!r} lies outside the {self.length} bytes of {self.name!r}")
        if sum(s.role == "counter" for s in self.signals) > 1:
            raise FrameError(f"message {self.name!r} has more than one counter signal")

    @property
    def counter(self) -> Signal | None:
        return next((s for s in self.signals if s.role == "counter"), None)

    def data_id_bytes(self) -> bytes:
        d = self.checksum.get("data_id") if self.checksum else None
        if d is None:
            return b""
        d = int(d, 0) if isinstance(d, str) else int(d)
        return d.to_bytes(2, "little") if d > 0xFF else bytes([d])

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "id": hex(self.id), "length": self.length,
                             "signals": [s.to_dict() for s in self.signals]}
        if self.extended:
            d["extended"] = True
        if self.checksum:
            d["checksum"] = {k: v for k, v in self.checksum.items() if v is not None}
        return d


@dataclass
class Layout:
    """What one device sends per sample: its messages, instruments and nominal rate."""

    name: str
    messages: list[Message]
    instruments: dict[str, int]
    sample_rate_hz: float | None = None
    geometry: dict[str, str] = field(default_factory=dict)
    raw_unit: dict[str, str] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        if not self.messages:
            raise FrameError(f"layout {self.name!r} has no messages")
        ids = [(m.id, m.extended) for m in self.messages]
        if len(set(ids)) != len(ids):
            raise FrameError(f"layout {self.name!r}: two messages share an identifier")
        for k in self.instruments:
            if k not in INSTRUMENTS:
                raise FrameError(f"layout {self.name!r}: unknown instrument {k!r}; use {INSTRUMENTS}")
        seen: set[tuple[str, int]] = set()
        for m in self.messages:
            for s in m.signals:
                if s.role == "sample":
                    key = (s.instrument, int(s.index))
                    if s.instrument not in self.instruments or not 0 <= s.index < self.instruments[s.instrument]:
                        raise FrameError(f"signal {s.name!r}: sensor {key} is not among {self.instruments}")
                    if key in seen:
                        raise FrameError(f"sensor {key} is sent by two signals; each sensor is in one frame")
                    seen.add(key)
        missing = [(k, i) for k, n in self.instruments.items() for i in range(n) if (k, i) not in seen]
        if missing:
            raise FrameError(f"layout {self.name!r}: no signal carries sensors {missing}")
        counters = [m.counter for m in self.messages]
        if any(c is None for c in counters) and len(self.messages) > 1:
            raise FrameError(f"layout {self.name!r}: a sample spread over several frames needs a counter in each")
        if len({(c.length if c else 0) for c in counters}) > 1:
            raise FrameError(f"layout {self.name!r}: all counters must have the same length")
        if sum(s.role == "time" for m in self.messages for s in m.signals) > 1:
            raise FrameError(f"layout {self.name!r}: at most one time signal")

    @property
    def counter_modulus(self) -> int | None:
        c = self.messages[0].counter
        return None if c is None else 1 << c.length

    @property
    def period(self) -> float | None:
        return None if not self.sample_rate_hz else 1.0 / float(self.sample_rate_hz)

    def to_dict(self) -> dict[str, Any]:
        return {"format": LAYOUT_FORMAT, "version": 1, "name": self.name, "description": self.description,
                "instruments": dict(self.instruments), "geometry": dict(self.geometry),
                "raw_unit": dict(self.raw_unit), "sample_rate_hz": self.sample_rate_hz,
                "messages": [m.to_dict() for m in self.messages]}

    def to_cantools(self) -> Any:
        """The layout as a cantools ``Database`` (needs cantools, extra ``dbc``); checksum bytes become 8-bit
        signals named ``<message>_CHECKSUM``. ``db.as_dbc_string()`` writes it as a DBC file."""
        try:
            import cantools
            from cantools.database.can import Message as CtMessage
            from cantools.database.can import Signal as CtSignal
            from cantools.database.conversion import BaseConversion
        except ImportError as exc:  # pragma: no cover
            raise FrameError("exporting to DBC needs cantools: pip install 'rimu[dbc]'") from exc
        msgs = []
        for m in self.messages:
            sigs = [CtSignal(s.name if s.role != "counter" else f"{m.name}_{s.name}", s.start_bit, s.length,
                             s.byte_order, s.signed, conversion=BaseConversion.factory(s.scale, s.offset))
                    for s in m.signals]
            if m.checksum is not None:
                b = m.checksum["byte"]
                sigs.append(CtSignal(f"{m.name}_CHECKSUM", 8 * b, 8, "little_endian", False))
            msgs.append(CtMessage(m.id, m.name, m.length, sigs, is_extended_frame=m.extended, strict=False))
        return cantools.database.Database(msgs)

    def save(self, path: str | os.PathLike[str]) -> Path:
        from ..atomic import write_text

        return write_text(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<layout>") -> Layout:
        if d.get("format") != LAYOUT_FORMAT:
            raise FrameError(f"{source}: not a rimu CAN layout (format must be {LAYOUT_FORMAT!r})")
        if d.get("version") != 1:
            raise FrameError(f"{source}: layout version {d.get('version')!r} unknown; this rimu reads version 1")
        try:
            msgs = []
            for m in d["messages"]:
                sigs = [Signal(**{k: v for k, v in s.items()}) for s in m["signals"]]
                mid = m["id"]
                msgs.append(Message(m["name"], int(mid, 0) if isinstance(mid, str) else int(mid), sigs,
                                    int(m.get("length", 8)), bool(m.get("extended", False)), m.get("checksum")))
            return cls(d.get("name", source), msgs, {k: int(v) for k, v in d["instruments"].items()},
                       d.get("sample_rate_hz"), dict(d.get("geometry", {})), dict(d.get("raw_unit", {})),
                       d.get("description", ""))
        except (KeyError, TypeError) as exc:
            raise FrameError(f"{source}: malformed layout ({exc!r}); see docs/io.md for the format") from exc

    @classmethod
    def from_dbc(cls, path: str | os.PathLike[str], roles: dict[str, dict[str, Any]], name: str | None = None,
                 sample_rate_hz: float | None = None, checksums: dict[str, dict[str, Any]] | None = None) -> Layout:
        """Build a layout from a DBC file (needs cantools, extra ``dbc``).

        Parameters
        ----------
        roles : dict
            Signal name -> ``{"role": ..., "instrument": ..., "index": ...}`` for the signals rimu uses; the
            signals of those messages not named here become ``other``.
        checksums : dict, optional
            Message name -> checksum spec (DBC files do not say how a CRC is computed).
        """
        try:
            import cantools
        except ImportError as exc:  # pragma: no cover
            raise FrameError("reading DBC files needs cantools: pip install 'rimu[dbc]'") from exc
        db = cantools.database.load_file(str(path))
        msgs = []
        used = {s for s in roles}
        for m in db.messages:
            if not any(s.name in used for s in m.signals):
                continue
            sigs = []
            for s in m.signals:
                r = roles.get(s.name, {})
                sigs.append(Signal(s.name, s.start, s.length, r.get("role", "other"), s.byte_order, s.is_signed,
                                   float(s.scale), float(s.offset), r.get("instrument"), r.get("index"),
                                   int(r.get("ok_mask", 0)), r.get("sensors", [])))
            msgs.append(Message(m.name, m.frame_id, sigs, m.length, m.is_extended_frame,
                                (checksums or {}).get(m.name)))
        n: dict[str, int] = {}
        for r in roles.values():
            if r.get("role") == "sample":
                n[r["instrument"]] = max(n.get(r["instrument"], 0), int(r["index"]) + 1)
        return cls(name or Path(path).stem, msgs, n, sample_rate_hz)


def load_layout(layout: str | os.PathLike[str] | dict | Layout) -> Layout:
    """A layout from a file path, a dict, or the name of a shipped example (``cone6_rimu``, ``mm7_automotive``).

    >>> load_layout("cone6_rimu").instruments
    {'gyro': 6, 'accel': 6}
    """
    if isinstance(layout, Layout):
        return layout
    if isinstance(layout, dict):
        return Layout.from_dict(layout)
    p = Path(layout)
    if not p.exists():
        shipped = resources.files("rimu.io") / "layouts" / f"{layout}.json"
        if shipped.is_file():
            return Layout.from_dict(json.loads(shipped.read_text()), str(layout))
        raise FrameError(f"layout {str(layout)!r} is neither a file nor a shipped layout (cone6_rimu, mm7_automotive)")
    try:
        d = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise FrameError(f"{p}: not valid JSON ({exc})") from exc
    return Layout.from_dict(d, str(p))


def linear_checksum(m: Message) -> tuple[np.ndarray, int] | None:
    """A message's checksum check as a sum over its bytes: ``(T, c)`` with (8, 256) uint8 tables ``T`` such that
    a frame of the right length passes its check exactly when ``T[0][b0] ^ ... ^ T[7][b7] ^ c == 0`` (``b`` its
    data bytes, zero-padded). CRC-8 (table-driven, ``c <- tab[c ^ b]``) and XOR are linear over GF(2): a byte
    ``b`` entering ``k`` steps before the end contributes ``tab^k(b)``, the initial value and the data id a
    constant, the checksum byte itself ``b``. None for a non-linear checksum (``sum8``) or none.

    >>> m = load_layout("cone6_rimu").messages[1]
    >>> T, c = linear_checksum(m)
    >>> from .checksum import crc8
    >>> body = bytes([1, 2, 3, 4, 5, 6, 7])
    >>> data = body + bytes([crc8(m.data_id_bytes() + body)])
    >>> int(np.bitwise_xor.reduce([T[p][data[p]] for p in range(8)]) ^ c)
    0
    """
    if m.checksum is None or m.checksum["algorithm"] not in ("xor8", "crc8_sae_j1850", "crc8_autosar"):
        return None
    alg = m.checksum["algorithm"]
    tab, init, xorout = CHECKSUMS[alg]
    cb = m.checksum["byte"]
    did = m.data_id_bytes()
    body = [j for j in range(m.length) if j != cb]
    T = np.zeros((8, 256), np.uint8)
    ident = np.arange(256, dtype=np.uint8)
    T[cb] = ident
    if alg == "xor8":
        c = 0
        for b in did:
            c ^= b
        for p in body:
            T[p] = ident
        return T, c ^ xorout
    n = len(did) + len(body)
    powers = [ident]                          # powers[k] = tab applied k times
    for _ in range(n):
        powers.append(tab[powers[-1]])
    c = int(powers[n][init]) ^ xorout
    for k, b in enumerate(did):
        c ^= int(powers[n - k][b])
    for i, p in enumerate(body):
        T[p] = powers[n - len(did) - i]
    return T, c


class _Extraction:
    """Many signals of the messages of a layout extracted at once from a (E, K) array of 64-bit words (one
    column per message): every signal a column of one (E, S) result, shifts, masks and signs broadcast."""

    def __init__(self, entries: list[tuple[int, Signal]]) -> None:
        self.n = len(entries)
        self.msg = np.array([mi for mi, _ in entries], dtype=np.intp)
        self.shift = np.array([s.lsb_shift for _, s in entries], dtype=np.uint64)
        self.mask = np.array([(1 << s.length) - 1 for _, s in entries], dtype=np.uint64)
        self.sbit = np.array([(1 << (s.length - 1)) if s.signed else 0 for _, s in entries], dtype=np.uint64)
        self.any_shift = bool(self.shift.any())
        self.any_signed = bool(self.sbit.any())

    def raw(self, words: np.ndarray) -> np.ndarray:
        """(E, S) int64 raw values (sign-extended where signed) of (E, K) uint64 words."""
        w = np.take(words, self.msg, axis=1)
        if self.any_shift:
            w >>= self.shift
        w &= self.mask
        if self.any_signed:
            s = w & self.sbit
            s <<= np.uint64(1)
            w -= s          # raw - 2**length where the sign bit is set (modulo 2**64: two's complement)
        return w.view(np.int64)


class _ByteFields:
    """Unsigned fields of 1..7 bits within one data byte (status nibbles, short counters) of the messages of a
    layout, extracted at once from the (E, 8 K) data bytes: one uint8 column per field (narrower than words)."""

    def __init__(self, entries: list[tuple[int, Signal]]) -> None:
        self.n = len(entries)
        # byte k of a little-endian word is data byte k; of a big-endian one, data byte 7 - k
        self.col = np.array([8 * mi + (s.lsb_shift // 8 if s.byte_order == "little_endian" else 7 - s.lsb_shift // 8)
                             for mi, s in entries], dtype=np.intp)
        self.shift = np.array([s.lsb_shift % 8 for _, s in entries], dtype=np.uint8)
        self.mask = np.array([(1 << s.length) - 1 for _, s in entries], dtype=np.uint8)

    def raw(self, data: np.ndarray, E: int) -> np.ndarray:
        """(E, S) uint8 raw values of E samples of K frames in layout order ((E K, 8) uint8 data)."""
        b = np.take(data.reshape(E, -1), self.col, axis=1)
        b >>= self.shift
        b &= self.mask
        return b


@dataclass
class DecodedFrames:
    """Result of :meth:`CanCodec.decode` for N frames.

    Attributes
    ----------
    status : ndarray (N,) int8
        ``STATUS_OK`` or the reason a frame is rejected (``STATUS_REASONS``).
    message : ndarray (N,) int
        Index of the frame's message in the layout (-1 for unknown identifiers).
    counter : ndarray (N,) int64
        Rolling counter (0 where the message has none).
    values : ndarray (N, k) float
        Decoded physical values of the message's value slots (see :attr:`CanCodec.slots`); 0 where unused.
    flags_ok : ndarray (N, f) bool
        Status flags of the message: True where the flag says the sensors it covers are valid.
    """

    status: np.ndarray
    message: np.ndarray
    counter: np.ndarray
    values: np.ndarray
    flags_ok: np.ndarray


class CanCodec:
    """Vectorised decoding and encoding of the frames of a :class:`Layout`.

    Slots: every message's non-counter signals get a column in :attr:`DecodedFrames.values`, in signal order;
    :attr:`slots` maps each message's columns to a place in the epoch vector (``instrument`` sensors first,
    then ``time``, ``temperature``, then ``other`` signals by name).

    Examples
    --------
    >>> codec = CanCodec(load_layout("mm7_automotive"))
    >>> msgs = codec.encode({"gyro": np.array([[1.0, -2.0, 3.5]]), "accel": np.array([[0.1, 0.2, -1.0]])},
    ...                     counters=np.array([5]))
    >>> ids, data, dlc = codec.pack(codec.to_messages(msgs, np.array([0.0])))
    >>> dec = codec.decode(ids, data, dlc)
    >>> dec.status.tolist(), dec.counter.tolist()
    ([0, 0, 0], [5, 5, 5])
    """

    def __init__(self, layout: Layout) -> None:
        self.layout = layout
        self.n_messages = len(layout.messages)
        offs, o = {}, 0
        for k in INSTRUMENTS:
            if k in layout.instruments:
                offs[k] = o
                o += layout.instruments[k]
        self.instrument_offsets = offs
        self.n_sensors = o
        self.time_slot = o
        self.temp_slot = o + 1
        others = sorted({s.name for m in layout.messages for s in m.signals if s.role == "other"})
        self.other_names = others
        self.n_slots = o + 2 + len(others)
        self._by_key = {(m.id, m.extended): i for i, m in enumerate(layout.messages)}
        self._id_lookup = {m.id: i for i, m in enumerate(layout.messages)}
        self.value_signals: list[list[Signal]] = []
        self.slots: list[np.ndarray] = []
        self.flag_signals: list[list[Signal]] = []
        self.message_sensors = np.zeros((self.n_messages, self.n_sensors), dtype=bool)
        self.flag_sensors: list[np.ndarray] = []   # per message: (f, n_sensors) bool
        for mi, m in enumerate(layout.messages):
            vs = [s for s in m.signals if s.role in ("sample", "time", "temperature", "other")]
            self.value_signals.append(vs)
            sl = []
            for s in vs:
                if s.role == "sample":
                    sl.append(offs[s.instrument] + int(s.index))
                    self.message_sensors[mi, sl[-1]] = True
                elif s.role == "time":
                    sl.append(self.time_slot)
                elif s.role == "temperature":
                    sl.append(self.temp_slot)
                else:
                    sl.append(o + 2 + others.index(s.name))
            self.slots.append(np.array(sl, dtype=np.int64))
            fs = [s for s in m.signals if s.role == "flag"]
            self.flag_signals.append(fs)
            fm = np.zeros((len(fs), self.n_sensors), dtype=bool)
            for j, s in enumerate(fs):
                for inst, idx in s.sensors:
                    fm[j, offs[inst] + idx] = True
            self.flag_sensors.append(fm)
        self.max_values = max(len(v) for v in self.value_signals)
        self.max_flags = max([len(f) for f in self.flag_signals] + [0])
        self.message_has_time = np.array([any(s.role == "time" for s in vs) for vs in self.value_signals])
        self.message_has_temp = np.array([any(s.role == "temperature" for s in vs) for vs in self.value_signals])
        ts = next((s for m in layout.messages for s in m.signals if s.role == "time"), None)
        self.time_modulus = None if ts is None else float((1 << ts.length) * ts.scale) if not ts.signed else None
        self.sensor_names = [f"{k}[{i}]" for k in offs for i in range(layout.instruments[k])]
        self.message_index = {m.name: i for i, m in enumerate(layout.messages)}
        self._lengths = np.array([m.length for m in layout.messages], dtype=np.int64)
        #: identifiers and extended flags of the messages, in layout order
        self.layout_ids = np.array([m.id for m in layout.messages], dtype=np.int64)
        self.layout_ext = np.array([m.extended for m in layout.messages], dtype=bool)
        self._vector_plan()
        # scalar plans for decoding frames one at a time (live buses): pure Python integer arithmetic
        def plan(sg: Signal) -> tuple:
            return (sg.byte_order == "little_endian", sg.lsb_shift, (1 << sg.length) - 1,
                    (1 << (sg.length - 1)) if sg.signed else 0, 1 << sg.length, sg.scale, sg.offset)
        self._plans = {}
        for mi, m in enumerate(layout.messages):
            ck = None
            if m.checksum is not None:
                tab, init, xorout = CHECKSUMS[m.checksum["algorithm"]]
                ck = (m.checksum["byte"], m.checksum["algorithm"], None if tab is None else tab.tolist(), init,
                      xorout, m.data_id_bytes())
            self._plans[(m.id, m.extended)] = (mi, m.length, ck, plan(m.counter) if m.counter else None,
                                               [plan(sg) for sg in self.value_signals[mi]],
                                               [(plan(sg), sg.ok_mask) for sg in self.flag_signals[mi]])

    def _vector_plan(self) -> None:
        """What :meth:`_decode_regular` does, worked out once: the signals of all messages in a few
        :class:`_Extraction` groups (one per byte order: values, then counters, then flags) and the checksums as
        pair tables (:func:`linear_checksum`) shared by the messages whose checks differ only by a constant."""
        msgs = self.layout.messages
        V, F = self.max_values, self.max_flags
        i64 = np.iinfo(np.int64)
        self._rest: list[tuple[int, str, int, Signal]] = []   # signals decoded one by one (unsigned 64-bit)
        self._groups: list[tuple] = []
        aligned: dict[str, list[tuple[int, int, Signal]]] = {}
        aligned_cnt: dict[str, list[tuple[int, int]]] = {}
        def in_a_byte(sg: Signal) -> bool:      # an unsigned field of 1..7 bits within one data byte
            return not sg.signed and sg.length < 8 and sg.lsb_shift % 8 + sg.length <= 8

        for little in ("bytes", True, False):
            ent: list[tuple[int, Signal]] = []
            vdst: list[int] = []
            scale: list[float] = []
            offset: list[float] = []
            cdst: list[int] = []
            fdst: list[int] = []
            okm: list[int] = []

            def mine(sg: Signal, little: bool | str = little) -> bool:
                if little == "bytes":
                    return in_a_byte(sg)
                return not in_a_byte(sg) and (sg.byte_order == "little_endian") == little

            for mi in range(len(msgs)):
                for j, sg in enumerate(self.value_signals[mi]):
                    if not mine(sg):
                        continue
                    if sg.length in (8, 16, 32) and sg.lsb_shift % sg.length == 0:
                        # a whole aligned integer: read through a view of the data as that type
                        size = sg.length // 8
                        col = (sg.lsb_shift if little else 64 - sg.lsb_shift - sg.length) // sg.length
                        dt = ("<" if little else ">") + ("i" if sg.signed else "u") + str(size)
                        aligned.setdefault(dt, []).append((mi * (8 // size) + col, mi * V + j, sg))
                        continue
                    if sg.length == 64 and not sg.signed:
                        self._rest.append((mi, "value", j, sg))
                        continue
                    ent.append((mi, sg))
                    vdst.append(mi * V + j)
                    scale.append(sg.scale)
                    offset.append(sg.offset)
            nv = len(ent)
            for mi, m in enumerate(msgs):
                c = m.counter
                if c is None or not mine(c):
                    continue
                if c.length in (8, 16, 32) and c.lsb_shift % c.length == 0:
                    size = c.length // 8
                    col = (c.lsb_shift if little else 64 - c.lsb_shift - c.length) // c.length
                    dt = ("<" if little else ">") + ("i" if c.signed else "u") + str(size)
                    aligned_cnt.setdefault(dt, []).append((mi * (8 // size) + col, mi))
                    continue
                if c.length == 64 and not c.signed:
                    self._rest.append((mi, "counter", 0, c))
                    continue
                ent.append((mi, c))
                cdst.append(mi)
            nc = len(ent) - nv
            for mi in range(len(msgs)):
                for j, sg in enumerate(self.flag_signals[mi]):
                    if not mine(sg):
                        continue
                    if (sg.length == 64 and not sg.signed) or not i64.min <= int(sg.ok_mask) <= i64.max:
                        self._rest.append((mi, "flag", j, sg))
                        continue
                    ent.append((mi, sg))
                    fdst.append(mi * F + j)
                    okm.append(int(sg.ok_mask))
            if not ent:
                continue
            sc, of = np.array(scale, dtype=float), np.array(offset, dtype=float)
            self._groups.append((little, (_ByteFields if little == "bytes" else _Extraction)(ent), nv, nc, np.array(vdst, dtype=np.intp), sc, of,
                                 bool((sc != 1.0).any() or (of != 0.0).any()), np.array(cdst, dtype=np.intp),
                                 np.array(fdst, dtype=np.intp), np.array(okm, dtype=np.int64)))
        # straight into epoch slots (decode_slots): where each value goes, which sensors each flag covers
        self._slot_of = np.full(len(msgs) * V, -1, dtype=np.intp)
        for mi, sl in enumerate(self.slots):
            self._slot_of[mi * V: mi * V + len(sl)] = sl
        self._aligned_counters = [(np.dtype(dt), np.array([c for c, _ in it], dtype=np.intp),
                                   np.array([m for _, m in it], dtype=np.intp)) for dt, it in aligned_cnt.items()]
        self._aligned = []
        for dt, items in aligned.items():
            sc = np.array([sg.scale for _, _, sg in items], dtype=float)
            of = np.array([sg.offset for _, _, sg in items], dtype=float)
            vd = np.array([d for _, d, _ in items], dtype=np.intp)
            self._aligned.append((np.dtype(dt), np.array([c for c, _, _ in items], dtype=np.intp), vd,
                                  self._slot_of[vd], sc, of, bool((sc != 1.0).any()), bool((of != 0.0).any())))
        # a slot written by several signals (a temperature in two frames): the last in layout order wins, as in
        # the assembler; the others are not written at all
        self._last_writer = np.zeros(len(msgs) * V, dtype=bool)
        seen: set[int] = set()
        for f in range(len(msgs) * V - 1, -1, -1):
            if self._slot_of[f] >= 0 and int(self._slot_of[f]) not in seen:
                seen.add(int(self._slot_of[f]))
                self._last_writer[f] = True
        self._groups = [(*g, self._last_writer[g[4]]) for g in self._groups]
        self._flag_cover = np.zeros((len(msgs) * F, self.n_sensors), dtype=bool)
        for mi, fm in enumerate(self.flag_sensors):
            self._flag_cover[mi * F: mi * F + len(fm)] = fm
        # checksums: messages with equal tables share them (pair tables: two bytes, one look-up)
        by_tables: dict[bytes, tuple[np.ndarray, list[int], list[int]]] = {}
        self._ck_other: list[int] = []          # non-linear checksums (sum8): checked message by message
        for mi, m in enumerate(msgs):
            if m.checksum is None:
                continue
            lin = linear_checksum(m)
            if lin is None:
                self._ck_other.append(mi)
                continue
            T, c = lin
            key = T.tobytes()
            if key not in by_tables:
                by_tables[key] = (T, [], [])
            by_tables[key][1].append(mi)
            by_tables[key][2].append(c)
        self._ck_groups = []
        for T, mis, cs in by_tables.values():
            pairs = np.stack([(T[2 * q + 1][:, None] ^ T[2 * q][None, :]).reshape(-1) for q in range(4)])
            self._ck_groups.append((np.array(mis, dtype=np.intp), pairs, np.array(cs, dtype=np.uint8)))

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def pack(messages: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Identifiers, (N, 8) zero-padded data and DLC of python-can messages."""
        return CanCodec.pack_all(messages)[:3]

    @staticmethod
    def pack_all(messages: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Identifiers, (N, 8) data, DLC, extended flags and timestamps of python-can messages, in one pass."""
        return CanCodec.pack_frames(messages)[:5]

    @staticmethod
    def pack_frames(messages: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
        """:meth:`pack_all` and whether any message is an error or remote frame, reading each message once (the
        attribute reads of python-can messages, scattered in memory, cost more than everything done with the
        arrays: one loop over them, then arrays)."""
        n = len(messages)
        ids: list[int] = []
        datas: list = []
        tss: list[float] = []
        exts: list[bool] = []
        add_id, add_data, add_t, add_ext = ids.append, datas.append, tss.append, exts.append
        special = False
        for m in messages:
            add_id(m.arbitration_id)
            add_data(m.data)
            add_t(m.timestamp)
            add_ext(m.is_extended_id)
            if m.is_error_frame or m.is_remote_frame:
                special = True
        dlc = np.fromiter(map(len, datas), dtype=np.int64, count=n)
        parts = datas if n and dlc.min() == 8 == dlc.max() else [bytes(d[:8]).ljust(8, b"\0") for d in datas]
        data = np.frombuffer(b"".join(parts), dtype=np.uint8).reshape(n, 8) if n else np.zeros((0, 8), np.uint8)
        return (np.fromiter(ids, dtype=np.int64, count=n), data, dlc, np.fromiter(exts, dtype=bool, count=n),
                np.fromiter(tss, dtype=float, count=n), special)

    @staticmethod
    def _extract(words_le: np.ndarray, words_be: np.ndarray, s: Signal) -> np.ndarray:
        w = words_le if s.byte_order == "little_endian" else words_be
        sh = np.uint64(s.lsb_shift)
        raw = w >> sh
        if s.length < 64:
            raw = raw & np.uint64((1 << s.length) - 1)
        if s.signed:
            v = raw.astype(np.int64)
            if s.length < 64:
                v = v - ((v >> (s.length - 1)) & 1) * (1 << s.length)
            return v
        return raw

    def to_messages(self, encoded: list[tuple[int, np.ndarray]], timestamps: np.ndarray,
                    spacing: float = 1e-5) -> list:
        """python-can messages of :meth:`encode`'s output, sample by sample in layout order; message j of
        sample k is stamped ``timestamps[k] + j * spacing``."""
        import can

        ts = np.asarray(timestamps, dtype=float).tolist()
        msgs = self.layout.messages
        rows = [(msgs[mi], d.tobytes(), d.shape[1]) for mi, d in encoded]
        out = []
        for k, t in enumerate(ts):
            for j, (m, b, L) in enumerate(rows):
                out.append(can.Message(timestamp=t + j * spacing, arbitration_id=m.id, is_extended_id=m.extended,
                                       data=b[k * L:(k + 1) * L], dlc=L))
        return out

    # ------------------------------------------------------------------ decode
    def decode(self, ids: np.ndarray, data: np.ndarray, dlc: np.ndarray,
               extended: np.ndarray | None = None) -> DecodedFrames:
        """Decode N frames at once: status, message index, counter, values, flags.

        Where the frames come in the layout's order, sample after sample (the common case of a clean log), the
        leading whole samples are decoded on strided views without gathering frames per identifier; the rest
        (or everything, for any other order) per identifier. Both give identical results.
        """
        N = len(ids)
        K = self.n_messages
        ids = np.asarray(ids)
        exp_ids = np.array([m.id for m in self.layout.messages], dtype=np.int64)
        # where the layout's order starts (a batch may begin part-way through a sample)
        o = next((j for j in range(min(K, N)) if N - j >= K and np.array_equal(ids[j:j + K], exp_ids)), -1)
        E = (N - o) // K if o >= 0 else 0
        if E >= 2:
            reg = (ids[o:o + E * K].reshape(E, K) == exp_ids).all(axis=1)
            if extended is not None:
                exp_ext = np.array([m.extended for m in self.layout.messages])
                reg &= (np.asarray(extended[o:o + E * K], dtype=bool).reshape(E, K) == exp_ext).all(axis=1)
            bad = np.flatnonzero(~reg)
            E = int(E if not len(bad) else bad[0])
        if E < 2:
            return self._decode_general(ids, data, dlc, extended)
        lo, hi = o, o + E * K
        parts = []
        if lo:
            parts.append(self._decode_general(ids[:lo], data[:lo], dlc[:lo], None if extended is None else extended[:lo]))
        parts.append(self._decode_regular(np.ascontiguousarray(data[lo:hi], dtype=np.uint8), np.asarray(dlc[lo:hi]), E))
        if hi < N:
            parts.append(self._decode_general(ids[hi:], data[hi:], dlc[hi:], None if extended is None else extended[hi:]))
        if len(parts) == 1:
            return parts[0]
        return DecodedFrames(*(np.concatenate([getattr(p, f) for p in parts])
                               for f in ("status", "message", "counter", "values", "flags_ok")))

    def _status_counters(self, data: np.ndarray, dlc: np.ndarray, E: int) -> tuple[np.ndarray, np.ndarray]:
        """Status (E, K) from the lengths and the checksums, and the counters (E, K) with the aligned ones read
        (the start shared by :meth:`_decode_regular` and :meth:`decode_slots`)."""
        K = self.n_messages
        status = np.where(dlc.reshape(E, K) == self._lengths, STATUS_OK, STATUS_BAD_LENGTH).astype(np.int8)
        bad = self._checksum_regular(data, E)
        if bad is not None:
            status[bad & (status == STATUS_OK)] = STATUS_CHECKSUM
        counter = np.zeros((E, K), dtype=np.int64)
        for dt, cols, cdst in self._aligned_counters:
            counter[:, cdst] = np.take(data.view(dt).reshape(E, -1), cols, axis=1)
        return status, counter

    class _Words:
        """The (E, K) 64-bit words of E samples of K frames, little-endian, and big-endian made on first use."""

        def __init__(self, data: np.ndarray, E: int, K: int) -> None:
            self.data, self.E = data, E
            self.le = data.view("<u8").reshape(E, K)
            self._be: np.ndarray | None = None

        def be(self) -> np.ndarray:
            if self._be is None:
                self._be = self.le.byteswap()
            return self._be

    @staticmethod
    def _physical(r: np.ndarray, nv: int, scale: Any, offset: Any, scaled: bool) -> np.ndarray:
        """The first ``nv`` raw fields of a group as physical values (``raw * scale + offset`` where scaled)."""
        v = r[:, :nv].astype(float)
        if scaled:
            v *= scale
            v += offset
        return v

    def _group_raws(self, words: _Words):
        """Each extraction group of :meth:`_vector_plan` with its raw fields (E, fields)."""
        for g in self._groups:
            little, ext = g[0], g[1]
            if little == "bytes":
                yield g, ext.raw(words.data, words.E)
            else:
                yield g, ext.raw(words.le if little else words.be())

    def _decode_regular(self, data: np.ndarray, dlc: np.ndarray, E: int) -> DecodedFrames:
        """E samples of K frames in layout order: the (E, K) words of every message at once, each signal a column
        of one array per byte order (:meth:`_vector_plan`), checksums by pair tables over all frames."""
        K = self.n_messages
        N = E * K
        V, F = self.max_values, self.max_flags
        status, counter = self._status_counters(data, dlc, E)
        values = np.zeros((E, K * V))
        flags_ok = np.ones((E, K * F), dtype=bool)
        for v, vdst, _ in self._aligned_values(data, E):
            values[:, vdst] = v
        words = self._Words(data, E, K)
        for (_, _, nv, nc, vdst, scale, offset, scaled, cdst, fdst, okm, _), r in self._group_raws(words):
            if nv:
                v = self._physical(r, nv, scale, offset, scaled)
                values[:, vdst] = v
            if nc:
                counter[:, cdst] = r[:, nv:nv + nc]
            if len(fdst):
                flags_ok[:, fdst] = (r[:, nv + nc:] & okm) == 0
        if self._rest:
            wle, wbe = words.le, words.be()
            for mi, kind, j, sg in self._rest:
                raw = self._extract(wle[:, mi], wbe[:, mi], sg)
                if kind == "value":
                    values[:, mi * V + j] = raw * sg.scale + sg.offset
                elif kind == "counter":
                    counter[:, mi] = raw
                else:
                    flags_ok[:, mi * F + j] = (raw.astype(np.int64) & int(sg.ok_mask)) == 0
        msg = np.tile(np.arange(K, dtype=np.int64), E)
        return DecodedFrames(status.reshape(N), msg, counter.reshape(N), values.reshape(N, V), flags_ok.reshape(N, F))

    def decode_slots(self, data: np.ndarray, dlc: np.ndarray, E: int) -> tuple[np.ndarray, np.ndarray,
                                                                           np.ndarray, np.ndarray]:
        """E samples of K frames in layout order decoded straight into epoch vectors (what the assembler makes
        of clean samples): ``(status (E, K), counter (E, K), slots (E, n_slots), sensor_ok (E, n_sensors))``;
        ``sensor_ok`` is False where a flag of the sample says a sensor is not valid. Values and flags equal those
        of :meth:`decode` (the same extraction; where two signals share a slot, a temperature sent in two frames,
        the last in layout order is kept, as the assembler does)."""
        K = self.n_messages
        V, F = self.max_values, self.max_flags
        status, counter = self._status_counters(data, dlc, E)
        slots = np.zeros((E, self.n_slots))
        sensor_bad = None          # (E, n_sensors): a flag of the sample says the sensor is not valid
        for v, vdst, sdst in self._aligned_values(data, E):
            last = self._last_writer[vdst]
            if last.all():
                slots[:, sdst] = v
            else:
                slots[:, sdst[last]] = v[:, last]
        words = self._Words(data, E, K)
        for (_, _, nv, nc, vdst, scale, offset, scaled, cdst, fdst, okm, last), r in self._group_raws(words):
            if nv:
                v = self._physical(r, nv, scale, offset, scaled)
                if last.all():
                    slots[:, self._slot_of[vdst]] = v
                else:
                    slots[:, self._slot_of[vdst[last]]] = v[:, last]
            if nc:
                counter[:, cdst] = r[:, nv:nv + nc]
            if len(fdst):
                fb = (r[:, nv + nc:] & okm) != 0
                if fb.any():
                    b = fb @ self._flag_cover[fdst]
                    sensor_bad = b if sensor_bad is None else sensor_bad | b
        if self._rest:
            wle, wbe = words.le, words.be()
            for mi, kind, j, sg in self._rest:
                raw = self._extract(wle[:, mi], wbe[:, mi], sg)
                if kind == "value":
                    if self._last_writer[mi * V + j]:
                        slots[:, self._slot_of[mi * V + j]] = raw * sg.scale + sg.offset
                elif kind == "counter":
                    counter[:, mi] = raw
                else:
                    fb = (raw.astype(np.int64) & int(sg.ok_mask)) != 0
                    b = fb[:, None] & self._flag_cover[mi * F + j]
                    sensor_bad = b if sensor_bad is None else sensor_bad | b
        if sensor_bad is None:
            return status, counter, slots, np.ones((E, self.n_sensors), dtype=bool)
        return status, counter, slots, ~sensor_bad

    def _aligned_values(self, data: np.ndarray, E: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Values of the whole aligned 8/16/32-bit signals of E samples in layout order, read through views of
        the data as those integer types: ``(values (E, s), places in DecodedFrames.values, epoch slots)`` per
        type (the same numbers as the word-wide extraction: the integer, times scale, plus offset)."""
        out = []
        for dt, cols, vdst, sdst, scale, offset, scaled, offs in self._aligned:
            raw = np.take(data.view(dt).reshape(E, -1), cols, axis=1)
            v = raw * scale if scaled else raw.astype(float)
            if offs:
                v += offset
            out.append((v, vdst, sdst))
        return out

    def _checksum_regular(self, data: np.ndarray, E: int) -> np.ndarray | None:
        """(E, K) bool: frames whose checksum fails (frames in layout order), None if no message has one."""
        K = self.n_messages
        if not self._ck_groups and not self._ck_other:
            return None
        bad = np.zeros((E, K), dtype=bool)
        u = data.view("<u2").reshape(E, K, 4)
        for mis, pairs, consts in self._ck_groups:
            uu = u if len(mis) == K else u[:, mis]
            r = np.take(pairs[0], uu[:, :, 0])      # (np.take: cheaper than indexing with an array here)
            for q in range(1, 4):
                r ^= np.take(pairs[q], uu[:, :, q])
            r ^= consts
            if len(mis) == K:
                bad = r != 0
            else:
                bad[:, mis] = r != 0
        d3 = data.reshape(E, K, 8)
        for mi in self._ck_other:
            m = self.layout.messages[mi]
            cb = m.checksum["byte"]
            cols = [j for j in range(m.length) if j != cb]
            did = m.data_id_bytes()
            d = d3[:, mi, cols]
            if did:
                d = np.concatenate([np.broadcast_to(np.frombuffer(did, np.uint8), (E, len(did))), d], axis=1)
            bad[:, mi] = crc8_columns(d, m.checksum["algorithm"]) != d3[:, mi, cb]
        return bad

    def _decode_general(self, ids: np.ndarray, data: np.ndarray, dlc: np.ndarray,
                        extended: np.ndarray | None = None) -> DecodedFrames:
        """Any frames in any order: frames gathered per message identifier."""
        N = len(ids)
        status = np.full(N, STATUS_UNKNOWN_ID, dtype=np.int8)
        msg = np.full(N, -1, dtype=np.int64)
        counter = np.zeros(N, dtype=np.int64)
        values = np.zeros((N, self.max_values))
        flags_ok = np.ones((N, self.max_flags), dtype=bool)
        if N == 0:
            return DecodedFrames(status, msg, counter, values, flags_ok)
        data = np.ascontiguousarray(data, dtype=np.uint8)
        wle = data.view("<u8").reshape(N)
        wbe = data.view(">u8").reshape(N)
        for mi, m in enumerate(self.layout.messages):
            sel = ids == m.id
            if extended is not None:
                sel &= np.asarray(extended, dtype=bool) == m.extended
            if not sel.any():
                continue
            rows = np.flatnonzero(sel)
            msg[rows] = mi
            ok_len = dlc[rows] == m.length
            st = np.where(ok_len, STATUS_OK, STATUS_BAD_LENGTH).astype(np.int8)
            if m.checksum is not None:
                cb = m.checksum["byte"]
                cols = [j for j in range(m.length) if j != cb]
                d = data[rows][:, cols]
                did = m.data_id_bytes()
                if did:
                    d = np.concatenate([np.broadcast_to(np.frombuffer(did, np.uint8), (len(rows), len(did))), d], axis=1)
                crc = crc8_columns(d, m.checksum["algorithm"])
                st[(st == STATUS_OK) & (crc != data[rows, cb])] = STATUS_CHECKSUM
            status[rows] = st
            lw, bw = wle[rows], wbe[rows]
            c = m.counter
            if c is not None:
                counter[rows] = self._extract(lw, bw, c)
            for j, s in enumerate(self.value_signals[mi]):
                values[rows, j] = self._extract(lw, bw, s) * s.scale + s.offset
            for j, s in enumerate(self.flag_signals[mi]):
                flags_ok[rows, j] = (self._extract(lw, bw, s).astype(np.int64) & int(s.ok_mask)) == 0
        return DecodedFrames(status, msg, counter, values, flags_ok)

    @staticmethod
    def _scalar(wle: int, wbe: int, p: tuple) -> int:
        little, shift, mask, sign, span, _, _ = p
        v = ((wle if little else wbe) >> shift) & mask
        return v - span if sign and v & sign else v

    def decode_one(self, arbitration_id: int, extended: bool, data: bytes) -> tuple:
        """One frame in pure Python (cheaper than numpy for a single frame): ``(status, message, counter,
        values, flags_ok)`` as :meth:`decode` gives them for one row."""
        pl = self._plans.get((arbitration_id, bool(extended)))
        if pl is None:
            return STATUS_UNKNOWN_ID, -1, 0, [], []
        mi, length, ck, cplan, vplans, fplans = pl
        if len(data) != length:
            return STATUS_BAD_LENGTH, mi, 0, [], []
        d8 = bytes(data).ljust(8, b"\0")
        wle = int.from_bytes(d8, "little")
        wbe = int.from_bytes(d8, "big")
        sc = self._scalar
        status = STATUS_OK
        if ck is not None:
            cb, alg, tab, init, xorout, did = ck
            body = did + data[:cb] + data[cb + 1:]
            if alg == "xor8":
                c = 0
                for b in body:
                    c ^= b
            elif alg == "sum8":
                c = sum(body) & 0xFF
            else:
                c = init
                for b in body:
                    c = tab[c ^ b]
                c ^= xorout
            if c != data[cb]:
                status = STATUS_CHECKSUM
        counter = sc(wle, wbe, cplan) if cplan else 0
        values = [sc(wle, wbe, p) * p[5] + p[6] for p in vplans]
        flags = [(sc(wle, wbe, p) & okm) == 0 for p, okm in fplans]
        return status, mi, counter, values, flags

    def decode_messages(self, messages: list) -> DecodedFrames:
        """:meth:`decode` of python-can messages."""
        ids, data, dlc, ext, _ = self.pack_all(messages)
        return self.decode(ids, data, dlc, ext)

    # ------------------------------------------------------------------ encode
    def quantize(self, instrument: str, values: np.ndarray) -> np.ndarray:
        """What the layout can carry: ``values`` (N, n) rounded to each signal's resolution and saturated."""
        out = np.array(values, dtype=float, copy=True)
        for m in self.layout.messages:
            for s in m.signals:
                if s.role == "sample" and s.instrument == instrument:
                    lo, hi = s.raw_range()
                    r = np.clip(np.round((out[:, s.index] - s.offset) / s.scale), lo, hi)
                    out[:, s.index] = r * s.scale + s.offset
        return out

    def encode(self, raw: dict[str, np.ndarray], counters: np.ndarray, t: np.ndarray | None = None,
               temperature: np.ndarray | None = None, valid: dict[str, np.ndarray] | None = None,
               other: dict[str, np.ndarray] | None = None) -> list[tuple[int, np.ndarray]]:
        """Frames for N samples: a list, per message, of ``(message index, (N, length) uint8 data)``.

        Values are rounded to the signal's resolution and saturated to its range. A sensor marked invalid
        in ``valid`` gets its flag signals (if any) set to ``ok_mask`` (not ok).
        """
        counters = np.asarray(counters, dtype=np.int64)
        N = len(counters)
        for k, y in raw.items():
            if np.shape(y)[0] != N:
                raise ShapeError(f"raw[{k!r}] has {np.shape(y)[0]} samples, counters has {N}")
        out = []
        for mi, m in enumerate(self.layout.messages):
            word = np.zeros(N, dtype=np.uint64)
            for s in m.signals:
                if s.role == "sample":
                    v = np.asarray(raw[s.instrument], dtype=float)[:, s.index]
                elif s.role == "time":
                    v = np.zeros(N) if t is None else np.asarray(t, dtype=float)
                    if not s.signed:
                        v = np.mod(v, (1 << s.length) * s.scale)
                elif s.role == "temperature":
                    v = np.zeros(N) if temperature is None else np.asarray(temperature, dtype=float)
                elif s.role == "counter":
                    v = counters % (1 << s.length)
                elif s.role == "flag":
                    bad = np.zeros(N, dtype=bool)
                    for inst, idx in s.sensors:
                        if valid is not None and inst in valid:
                            bad |= ~np.asarray(valid[inst], dtype=bool)[:, idx]
                    v = np.where(bad, s.ok_mask, 0)
                else:
                    v = np.zeros(N) if not other or s.name not in other else np.asarray(other[s.name], float)
                if s.role in ("counter", "flag"):
                    r = np.asarray(v, dtype=np.int64)
                else:
                    lo, hi = s.raw_range()
                    r = np.clip(np.round((np.asarray(v, dtype=float) - s.offset) / s.scale), lo, hi).astype(np.int64)
                u = r.astype(np.uint64) if s.length == 64 else (r & ((1 << s.length) - 1)).astype(np.uint64)
                word |= u << np.uint64(s.lsb_shift)
            if all(s.byte_order == "little_endian" for s in m.signals):
                data = word.astype("<u8").view(np.uint8).reshape(N, 8).copy()
            else:
                le = [s for s in m.signals if s.byte_order == "little_endian"]
                if le:
                    raise FrameError(f"message {m.name!r} mixes byte orders; encode supports one per message")
                data = word.astype(">u8").view(np.uint8).reshape(N, 8).copy()
            data = data[:, : m.length]
            if m.checksum is not None:
                cb = m.checksum["byte"]
                cols = [j for j in range(m.length) if j != cb]
                d = data[:, cols]
                did = m.data_id_bytes()
                if did:
                    d = np.concatenate([np.broadcast_to(np.frombuffer(did, np.uint8), (N, len(did))), d], axis=1)
                data[:, cb] = crc8_columns(d, m.checksum["algorithm"])
            out.append((mi, data))
        return out
