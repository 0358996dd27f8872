"""Stream mutators with an exact oracle, to test a decoder: what must come out of a damaged stream.

:func:`mutate_can` and :func:`mutate_serial` apply per-frame actions (keep, drop, duplicate, corrupt, ...)
and return the damaged stream together with what a correct receiver must produce: which frames are intact,
and how many units must be rejected for which reason. :func:`check_can` and :func:`check_serial` run a
decoder on it and compare. Used by rimu's tests (hypothesis and seeded runs) and ``benchmarks/io.py``; handy to
test a new layout the same way.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..epoch import EpochBlock
from .accounting import Accounting
from .layout import CanCodec, load_layout

__all__ = ["layout_stream", "CAN_ACTIONS", "SERIAL_ACTIONS", "CanOracle", "SerialOracle", "draw_actions", "mutate_can",
           "check_can", "mutate_serial", "check_serial", "random_block", "pieces", "decode_pieces", "process_chunks"]

#: action -> probability in the seeded runs
CAN_ACTIONS = {"keep": 0.76, "drop": 0.04, "dup": 0.04, "flip": 0.05, "truncate": 0.03, "bad_id": 0.03,
               "error_before": 0.02, "remote_before": 0.03}
SERIAL_ACTIONS = {"keep": 0.78, "drop": 0.04, "dup": 0.04, "flip": 0.05, "truncate": 0.04, "garbage_before": 0.05}


def draw_actions(rng: np.random.Generator, n: int, table: dict[str, float]) -> list[str]:
    names = list(table)
    p = np.array([table[k] for k in names])
    return [names[i] for i in rng.choice(len(names), size=n, p=p / p.sum())]


@dataclass
class CanOracle:
    intact: set = field(default_factory=set)          # (sample, message) delivered intact
    rejected: Counter = field(default_factory=Counter)
    received: int = 0


def mutate_can(messages: Sequence[Any], n_per_sample: int, actions: Sequence[str], rng: np.random.Generator,
               swap_p: float = 0.03, unknown_ids: Sequence[int] = (0x7F0,)) -> tuple[list, CanOracle]:
    """Damage a clean frame list (``n_per_sample`` frames per sample, in order) by ``actions`` (one per frame).

    Actions: ``keep``; ``drop``; ``dup`` (an identical copy right after); ``flip`` (a burst of 1..8 bits
    flipped, contiguous in transmission order, most significant bit of each byte first: always caught by a
    CRC-8); ``truncate`` (DLC shortened); ``bad_id`` (identifier not in the layout);
    ``error_before`` / ``remote_before`` (an error or remote frame inserted before it, the frame kept). Then
    neighbouring frames of the same or adjacent samples are swapped with probability ``swap_p`` each.
    """
    import can

    out: list[tuple[Any, int]] = []   # (message, sample or -1)
    o = CanOracle()
    for i, (m, act) in enumerate(zip(messages, actions)):
        k, j = divmod(i, n_per_sample)
        if act == "drop":
            continue
        if act in ("keep", "dup", "error_before", "remote_before"):
            if act == "error_before":
                out.append((can.Message(timestamp=m.timestamp, is_error_frame=True, arbitration_id=0x20,
                                        data=b"\x00" * 8), -1))
                o.rejected["error_frame"] += 1
            if act == "remote_before":
                out.append((can.Message(timestamp=m.timestamp, arbitration_id=m.arbitration_id,
                                        is_extended_id=m.is_extended_id, is_remote_frame=True, dlc=8), -1))
                o.rejected["remote_frame"] += 1
            out.append((m, k))
            o.intact.add((k, j))
            if act == "dup":
                out.append((m, k))
                o.rejected["duplicate"] += 1
            continue
        d = bytearray(m.data)
        if act == "flip":
            width = int(rng.integers(1, 9))
            pos = int(rng.integers(0, 8 * len(d) - width + 1))
            pattern = int(rng.integers(0, 1 << width)) | 1 | (1 << (width - 1))
            # bits numbered in transmission order, most significant bit of byte 0 first (the CRC's order)
            v = int.from_bytes(d, "big") ^ (pattern << pos)
            d = bytearray(v.to_bytes(len(d), "big"))
            o.rejected["checksum"] += 1
            ident = m.arbitration_id
        elif act == "truncate":
            d = d[: int(rng.integers(0, len(d)))]
            o.rejected["bad_length"] += 1
            ident = m.arbitration_id
        elif act == "bad_id":
            ident = int(rng.choice(unknown_ids))
            o.rejected["unknown_id"] += 1
        else:
            raise ValueError(f"unknown action {act!r}")
        out.append((can.Message(timestamp=m.timestamp, arbitration_id=ident, is_extended_id=m.is_extended_id,
                                data=bytes(d), dlc=len(d)), -2))
    i = 0
    while i < len(out) - 1:
        a, b = out[i][1], out[i + 1][1]
        if rng.random() < swap_p and (a < 0 or b < 0 or abs(a - b) <= 1):
            out[i], out[i + 1] = out[i + 1], out[i]
            i += 2
        else:
            i += 1
    o.received = len(out)
    return [m for m, _ in out], o


def check_can(epochs: list, accounting: Accounting, oracle: CanOracle, expected: dict[str, np.ndarray],
              layout: Any, seq0: int = 0) -> dict[str, int]:
    """Assert that a receiver did what the oracle says; returns a small report."""
    codec = CanCodec(load_layout(layout))
    accounting.check()
    assert accounting.received == oracle.received, (accounting.received, oracle.received)
    assert accounting.accepted == len(oracle.intact), (accounting.accepted, len(oracle.intact))
    assert dict(accounting.rejected) == {k: v for k, v in oracle.rejected.items() if v}, \
        (dict(accounting.rejected), dict(oracle.rejected))
    samples = sorted({k for k, _ in oracle.intact})
    assert len(epochs) == len(samples), (len(epochs), len(samples))
    offs = codec.instrument_offsets
    ms = codec.message_sensors
    for ep, k in zip(epochs, samples):
        assert ep.counters["seq"] - seq0 == k, (ep.counters["seq"], k)
        have = np.array([(k, j) in oracle.intact for j in range(codec.n_messages)])
        valid = ~ms[~have].any(axis=0)
        for inst, o in offs.items():
            n = codec.layout.instruments[inst]
            v = valid[o:o + n]
            assert ep.valid[inst].tolist() == v.tolist(), (k, inst)
            assert np.array_equal(ep.raw[inst][v], expected[inst][k][v]), (k, inst)
            assert not np.any(ep.raw[inst][~v]), (k, inst)
    return {"frames": oracle.received, "accepted": accounting.accepted, "rejected": accounting.rejected_total,
            "epochs": len(epochs)}


@dataclass
class SerialOracle:
    intact: list = field(default_factory=list)        # sample indices delivered intact, in order
    accepted_bytes: int = 0
    duplicate_bytes: int = 0
    received: int = 0


def mutate_serial(frames: Sequence[bytes], actions: Sequence[str], rng: np.random.Generator,
                  framing: str = "sync") -> tuple[bytes, SerialOracle]:
    """Damage a framed byte stream: ``keep``, ``drop``, ``dup``, ``flip`` (a burst of 1..16 bits: always caught
    by the CRC-16), ``truncate`` (the frame cut short, the next one follows), ``garbage_before`` (1..40 random
    bytes before the frame, kept).

    The oracle: with the sync framing every intact frame is recovered; with COBS an intact frame is recovered
    only if the byte before it is a delimiter (0x00) or it starts the stream (damage before a frame merges
    with it up to the next delimiter). A recovered frame with the same SEQ as the last accepted one is a
    duplicate."""
    parts: list[tuple[bytes, int]] = []   # (bytes, sample index or -1 for damaged / garbage)
    for k, (f, act) in enumerate(zip(frames, actions)):
        if act == "drop":
            continue
        if act == "garbage_before":
            parts.append((rng.integers(0, 256, int(rng.integers(1, 41)), dtype=np.uint8).tobytes(), -1))
        if act in ("keep", "dup", "garbage_before"):
            parts.append((f, k))
            if act == "dup":
                parts.append((f, k))
        elif act == "flip":
            width = int(rng.integers(1, 17))
            pos = int(rng.integers(0, 8 * len(f) - width + 1))
            pattern = int(rng.integers(0, 1 << width)) | 1 | (1 << (width - 1))
            parts.append(((int.from_bytes(f, "big") ^ (pattern << pos)).to_bytes(len(f), "big"), -1))
        elif act == "truncate":
            parts.append((f[: int(rng.integers(1, len(f)))], -1))
        else:
            raise ValueError(f"unknown action {act!r}")
    o = SerialOracle()
    prev: int | None = None
    last_seq: int | None = None
    for b, k in parts:
        recoverable = framing == "sync" or prev is None or prev == 0
        if k >= 0 and recoverable:
            if last_seq == k:
                o.duplicate_bytes += len(b)
            else:
                o.intact.append(k)
                o.accepted_bytes += len(b)
                last_seq = k
        if b:
            prev = b[-1]
    stream = b"".join(b for b, _ in parts)
    if framing == "cobs":   # lone delimiters (a 0x00 right after another, or first) are accepted as framing
        z = np.frombuffer(stream, np.uint8) == 0
        o.accepted_bytes += int((z & np.concatenate([[True], z[:-1]])).sum())
    o.received = len(stream)
    return stream, o


def check_serial(epochs: list, accounting: Accounting, oracle: SerialOracle, block: EpochBlock) -> dict[str, int]:
    accounting.check()
    assert accounting.pending == 0
    assert accounting.received == oracle.received
    assert accounting.accepted == oracle.accepted_bytes, (accounting.accepted, oracle.accepted_bytes)
    assert accounting.rejected.get("duplicate", 0) == oracle.duplicate_bytes
    assert [e.counters["seq"] for e in epochs] == [k & 0xFFFF for k in oracle.intact]
    for e, k in zip(epochs, oracle.intact):
        assert e.t == block.t[k]
        for inst, y in block.raw.items():
            v = block.valid[inst][k] if inst in block.valid else np.ones(y.shape[1], bool)
            assert e.valid[inst].tolist() == v.tolist()
            assert np.array_equal(e.raw[inst][v], y[k][v].astype(np.float32))
    return {"bytes": oracle.received, "accepted": accounting.accepted, "rejected": accounting.rejected_total,
            "epochs": len(epochs)}


def layout_stream(layout: str, n: int, seed: int = 0) -> tuple[EpochBlock, list[Any], Any, int]:
    """A seeded stream of ``n`` epochs for a shipped layout, as frames: what the fuzz tests and the benchmark feed in.

    Raw values are drawn in each layout's range (counts around the cone6 unit's zero-rate outputs, physical
    units for the automotive layout). Returns the block, its frames, the values a receiver must decode (to the
    layout's resolution) and the number of messages per epoch.
    """
    from .device import CanDevice

    rng = np.random.default_rng(seed)
    lay = load_layout(layout)
    ng, na = lay.instruments["gyro"], lay.instruments["accel"]
    if layout == "cone6_rimu":
        raw = {"gyro": rng.normal(500, 50, (n, ng)), "accel": rng.normal(16000, 3000, (n, na))}
    else:
        raw = {"gyro": rng.uniform(-150, 150, (n, ng)), "accel": rng.uniform(-4, 4, (n, na))}
    block = EpochBlock(np.arange(n) / 100.0, raw, temperature=np.full(n, 20.0))
    dev = CanDevice(layout)
    return block, dev.frames(block), dev.expected(block), len(lay.messages)


def random_block(n: int, seed: int = 0) -> EpochBlock:
    """``n`` samples at 200 Hz of six gyros and six accelerometers with random raw values (gyros 5 % invalid),
    21 degC: the block the serial fuzz runs encode."""
    rng = np.random.default_rng(seed)
    return EpochBlock(np.arange(n) / 200.0, {"gyro": rng.normal(0, 100, (n, 6)), "accel": rng.normal(0, 1e4, (n, 6))},
                      {"gyro": rng.random((n, 6)) > 0.05, "accel": np.ones((n, 6), bool)}, np.full(n, 21.0))


def pieces(data: bytes, cuts: Sequence[int]) -> Iterable[bytes]:
    """``data`` between consecutive ``cuts`` (sorted, from 0 to ``len(data)``)."""
    return (data[a:b] for a, b in zip(cuts[:-1], cuts[1:]))


def decode_pieces(decoder: Any, chunks: Iterable[Any]) -> list:
    """The epochs of a serial decoder fed ``chunks`` one by one, then flushed; the accounting identity is checked
    after every chunk (:meth:`Accounting.check` raises when it breaks)."""
    eps: list = []
    for c in chunks:
        eps += decoder.feed(c)
        decoder.accounting.check()
    eps += decoder.flush()
    return eps


def process_chunks(processor: Any, messages: Sequence[Any], chunk: int) -> list:
    """The epochs of a CAN frame processor given ``messages`` ``chunk`` at a time, then flushed; the accounting
    identity is checked after every chunk."""
    eps: list = []
    for i in range(0, len(messages), chunk):
        eps += processor.process(messages[i:i + chunk])
        processor.acc.check()
    eps += processor.flush()
    return eps
