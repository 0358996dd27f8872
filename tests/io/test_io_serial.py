"""Serial framing: resynchronisation, chunk-boundary invariance, loop:// and a pseudo-terminal pair."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.epoch import EpochBlock
from rimu.io.device import SerialDevice
from rimu.io.fuzz import SERIAL_ACTIONS, check_serial, decode_pieces, draw_actions, mutate_serial, pieces
from rimu.io.serial import (
    SYNC,
    CobsDecoder,
    SerialDecoder,
    SerialFileSource,
    SerialSource,
    cobs_decode,
    cobs_encode,
    encode_frame,
    encode_sample,
)


def _block(n=20, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    valid = {"gyro": rng.random((n, 6)) > 0.1, "accel": np.ones((n, 6), bool)}
    raw = {"gyro": rng.normal(500, 3, (n, 6)), "accel": rng.normal(16000, 10, (n, 6))}
    return EpochBlock(t, raw, valid, np.full(n, 24.5))


def _decode_all(chunks, decoder=SerialDecoder):
    dec = decoder()
    eps = decode_pieces(dec, chunks)
    dec.accounting.check()
    return eps, dec.accounting


def _key(eps):
    return [(e.t, e.temperature, e.counters["seq"], tuple(e.raw["gyro"]), tuple(e.valid["gyro"]),
             tuple(e.raw["accel"])) for e in eps]


def _stream_with_garbage(block, seed=1):
    rng = np.random.default_rng(seed)
    parts = []
    for f in SerialDevice().frames(block):
        parts.append(rng.integers(0, 256, rng.integers(0, 6), dtype=np.uint8).tobytes())
        parts.append(f)
    parts.append(SYNC + b"\x30")    # a truncated header at the very end
    return b"".join(parts)


def test_values_and_validity_roundtrip():
    block = _block()
    eps, acc = _decode_all([SerialDevice().stream(block)])
    assert len(eps) == len(block)
    for k, e in enumerate(eps):
        v = block.valid["gyro"][k]
        assert e.valid["gyro"].tolist() == v.tolist()
        np.testing.assert_array_equal(e.raw["gyro"][v], block.raw["gyro"][k][v].astype(np.float32))
        assert np.all(e.raw["gyro"][~v] == 0.0)
        assert e.t == block.t[k] and e.temperature == 24.5
    assert acc.rejected_total == 0 and acc.accepted == acc.received


def test_every_cut_position_decodes_the_same():
    """A stream cut at every possible byte boundary (two chunks) gives the same epochs and the same counts."""
    stream = _stream_with_garbage(_block(12))
    ref, acc_ref = _decode_all([stream])
    assert len(ref) == 12
    for k in range(len(stream) + 1):
        eps, acc = _decode_all([stream[:k], stream[k:]])
        assert _key(eps) == _key(ref), k
        assert acc.as_dict() == acc_ref.as_dict()


def test_byte_by_byte_and_random_chunks_decode_the_same():
    stream = _stream_with_garbage(_block(30), seed=4)
    ref, acc_ref = _decode_all([stream])
    eps1, acc1 = _decode_all([stream[i:i + 1] for i in range(len(stream))])
    rng = np.random.default_rng(2)
    cuts = np.sort(rng.integers(0, len(stream), 40))
    eps2, acc2 = _decode_all(np.split(np.frombuffer(stream, np.uint8), cuts))
    assert _key(eps1) == _key(ref) == _key(eps2)
    assert acc1.as_dict() == acc_ref.as_dict() == acc2.as_dict()
    assert acc_ref.rejected["truncated"] == 1   # the 0xA5 of the cut header; 0x5A 0x30 are garbage


def test_resynchronises_inside_a_damaged_frame():
    block = _block(3)
    f = SerialDevice().frames(block)
    damaged = bytearray(f[1])
    damaged[20] ^= 0xFF
    # the damaged frame is cut short and the next frame starts inside its claimed length
    stream = f[0] + bytes(damaged[:30]) + f[2]
    eps, acc = _decode_all([stream])
    assert [e.counters["seq"] for e in eps] == [0, 2]
    assert acc.accepted == len(f[0]) + len(f[2])
    assert acc.rejected["checksum"] == 1 and acc.rejected["garbage"] == 29
    assert acc.events["counter_gap"] == 1 and acc.events["missing_epochs"] == 1


def test_duplicate_and_bad_payloads_are_rejected():
    block = _block(3)
    f = SerialDevice().frames(block)
    unknown = encode_frame(0x7E, 9, b"xyz")
    short = encode_frame(0x01, 9, b"\x00" * 5)
    nan_t = encode_frame(0x01, 9, encode_sample(float("nan"), {"gyro": np.ones(2)}))
    eps, acc = _decode_all([f[0] + f[0] + unknown + short + nan_t + f[1] + f[2]])
    assert len(eps) == 3
    assert acc.rejected == {"duplicate": len(f[0]), "unknown_type": len(unknown), "bad_payload": len(short) + len(nan_t)}


def test_nonfinite_value_marks_sensor_invalid():
    payload = encode_sample(0.1, {"gyro": np.array([1.0, np.inf, 3.0])}, temperature=float("inf"))
    (e,), acc = _decode_all([encode_frame(1, 0, payload)])
    assert e.valid["gyro"].tolist() == [True, False, True] and e.raw["gyro"].tolist() == [1.0, 0.0, 3.0]
    assert e.temperature is None and acc.events["nonfinite_temperature"] == 1


def test_loop_url_source():
    import serial

    block = _block(25)
    port = serial.serial_for_url("loop://", timeout=0.05)
    SerialDevice().write(port, block)
    src = SerialSource("loop://", serial_port=port, idle_timeout=0.3)
    eps = list(src)
    assert len(eps) == 25 and [e.counters["seq"] for e in eps] == list(range(25))
    src.accounting.check()
    assert src.accounting.rejected_total == 0
    src.close()


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a POSIX pseudo-terminal")
def test_pseudo_terminal_pair_realtime():
    import serial

    master, slave = os.openpty()
    name = os.ttyname(slave)
    block = _block(40)
    garbage = b"\x00\xa5\xa5\x5a\xff" * 3
    src = SerialSource(name, baudrate=115200, idle_timeout=10.0).open()   # raw mode set before any byte
    eps = []

    class _Fd:
        def write(self, b):
            os.write(master, garbage[:2] + b)   # noise before every frame

    writer = threading.Thread(target=lambda: SerialDevice().write(_Fd(), block, realtime=True, speed=4.0))
    it = iter(src)
    first = None
    try:
        writer.start()
        for e in it:
            eps.append(e)
            first = first or e
            if len(eps) == len(block):
                break
    finally:
        writer.join(5)
        src.close()
        os.close(master)
        os.close(slave)
    assert len(eps) == 40
    for k, e in enumerate(eps):
        v = block.valid["gyro"][k]
        np.testing.assert_array_equal(e.raw["gyro"][v], block.raw["gyro"][k][v].astype(np.float32))
    acc = src.accounting
    assert acc.rejected["garbage"] == 2 * 40 and acc.identity_holds()
    assert isinstance(serial.__version__, str)


def test_file_source(tmp_path):
    block = _block(10)
    p = tmp_path / "capture.bin"
    p.write_bytes(b"noise" + SerialDevice().stream(block))
    src = SerialFileSource(p, chunk=7)
    got = src.read_block()
    np.testing.assert_array_equal(got.t, block.t)
    assert src.accounting.rejected == {"garbage": 5}


class _FailingPort:
    """Delivers its bytes, then fails like an unplugged USB adapter."""

    def __init__(self, data):
        self.data = data
        self.calls = 0

    @property
    def in_waiting(self):
        return len(self.data)

    def read(self, n):
        import serial

        self.calls += 1
        if self.calls > 1:
            raise serial.SerialException("device reports readiness to read but returned no data")
        d, self.data = self.data[:n], self.data[n:]
        return d

    def close(self):
        pass


def test_serial_port_error_reconnects_then_gives_up():
    from rimu.errors import TransportError
    from rimu.io.can import ReconnectPolicy

    block = _block(5)
    stream = SerialDevice().stream(block)
    # reopening "loop://" works: the source goes on until idle
    src = SerialSource("loop://", serial_port=_FailingPort(stream[:200]), idle_timeout=0.2,
                       reconnect=ReconnectPolicy(max_attempts=2, backoff_s=0.001))
    eps = list(src)
    assert len(eps) == 2                       # 200 bytes = two whole 74-byte frames and part of a third
    acc = src.accounting
    assert acc.events["port_error"] == 1 and acc.events["reconnect"] == 1
    assert acc.rejected == {"truncated": 1, "garbage": 200 - 2 * 74 - 1} and acc.identity_holds()
    # a port that cannot be reopened: TransportError after the attempts
    bad = SerialSource("/nonexistent/tty", serial_port=_FailingPort(stream), idle_timeout=0.2,
                       reconnect=ReconnectPolicy(max_attempts=2, backoff_s=0.001))
    with pytest.raises(TransportError, match="after 2 attempts"):
        list(bad)
    assert bad.accounting.events["reconnect_failed"] == 2


def test_serial_side_log_keeps_rejected_bytes(tmp_path):
    import json

    from rimu.io.accounting import Accounting, SideLog

    f = SerialDevice().frames(_block(2))
    bad = bytearray(f[1])
    bad[30] ^= 0x40
    side = SideLog(tmp_path / "rejected.jsonl")
    dec = SerialDecoder(Accounting("byte", side_log=side))
    eps = dec.feed(b"xyz" + f[0] + bytes(bad)) + dec.flush()
    side.close()
    assert len(eps) == 1
    recs = [json.loads(line) for line in (tmp_path / "rejected.jsonl").read_text().splitlines()]
    kept = b"".join(bytes.fromhex(r["data"]) for r in recs)
    assert len(kept) == dec.accounting.rejected_total == 3 + len(bad)     # every rejected byte is in the log
    assert recs[0] == {"reason": "garbage", "t": None, "data": b"xyz".hex()}


# ---------------------------------------------------------------------------------------------- COBS variant


@given(st.binary(max_size=700))
def test_cobs_roundtrip(data):
    enc = cobs_encode(data)
    assert 0 not in enc and len(enc) <= len(data) + 1 + len(data) // 254
    assert cobs_decode(enc) == data


def test_cobs_every_cut_position_decodes_the_same():
    block = _block(10)
    parts = []
    for k, f in enumerate(SerialDevice(framing="cobs").frames(block)):
        parts.append(b"\x13\x37\x00" if k % 3 == 1 else b"")   # delimited noise before some frames
        parts.append(f)
    stream = b"".join(parts) + b"\x05\x01"                       # an unfinished frame at the end
    ref, acc_ref = _decode_all([stream], CobsDecoder)
    assert len(ref) == 10 and acc_ref.rejected == {"cobs": 3 * 3, "truncated": 2}
    for k in range(len(stream) + 1):
        eps, acc = _decode_all([stream[:k], stream[k:]], CobsDecoder)
        assert _key(eps) == _key(ref) and acc.as_dict() == acc_ref.as_dict()


def test_cobs_seeded_fuzz():
    block = _block(3000, seed=9)
    rng = np.random.default_rng(5)
    frames = SerialDevice(framing="cobs").frames(block)
    stream, oracle = mutate_serial(frames, draw_actions(rng, len(frames), SERIAL_ACTIONS), rng, framing="cobs")
    cuts = np.unique(np.concatenate([[0, len(stream)], rng.integers(0, len(stream), 300)])).tolist()
    dec = CobsDecoder()
    eps = decode_pieces(dec, pieces(stream, cuts))
    check_serial(eps, dec.accounting, oracle, block)
    assert 0.7 * len(frames) < len(eps) < len(frames)


@settings(max_examples=80, deadline=None)
@given(st.lists(st.sampled_from(list(SERIAL_ACTIONS)), min_size=15, max_size=15), st.integers(0, 2**32 - 1),
       st.lists(st.integers(0, 1500), max_size=8))
def test_cobs_mutations_hypothesis(actions, seed, cuts):
    block = _block(15)
    stream, oracle = mutate_serial(SerialDevice(framing="cobs").frames(block), actions,
                                   np.random.default_rng(seed), framing="cobs")
    bounds = sorted({0, len(stream), *[c for c in cuts if c < len(stream)]})
    eps, acc = _decode_all(pieces(stream, bounds), CobsDecoder)
    check_serial(eps, acc, oracle, block)


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=800))
def test_cobs_arbitrary_bytes_never_raise(data):
    _eps, acc = _decode_all([data[: len(data) // 2], data[len(data) // 2:]], CobsDecoder)
    assert acc.pending == 0


def test_cobs_over_loop_url():
    import serial

    block = _block(12)
    port = serial.serial_for_url("loop://", timeout=0.05)
    SerialDevice(framing="cobs").write(port, block)
    src = SerialSource("loop://", serial_port=port, idle_timeout=0.3, framing="cobs")
    assert [e.counters["seq"] for e in src] == list(range(12))
    src.close()


# ---------------------------------------------------------------- block output (feed_block): same as feed()
@pytest.mark.parametrize("chunk", [7, 1000, 1 << 16])
@pytest.mark.parametrize("framing", ["sync", "cobs"])
def test_block_decoding_equals_epoch_decoding_on_damaged_streams(chunk, framing):
    """feed_block gives exactly the frames, values, validity, counters and accounting of feed, on a fuzzed
    stream (garbage, bit flips, cuts, duplicates, gaps, invalid sensors) cut at any chunk size."""
    from rimu.io.device import SerialDevice
    from rimu.io.fuzz import SERIAL_ACTIONS, draw_actions, mutate_serial
    from rimu.io.serial import make_decoder

    rng = np.random.default_rng(11)
    n = 600
    valid = {"gyro": rng.random((n, 6)) > 0.05, "accel": np.ones((n, 6), bool)}
    raw = {"gyro": rng.normal(0, 100, (n, 6)), "accel": rng.normal(0, 1e4, (n, 6))}
    raw["gyro"][rng.random((n, 6)) < 0.01] = np.nan
    block = EpochBlock(np.arange(n) / 100.0, raw, valid, temperature=np.full(n, 21.5))
    frames = SerialDevice(framing=framing).frames(block)
    data, _ = mutate_serial(frames, draw_actions(rng, n, SERIAL_ACTIONS), rng) if framing == "sync" else \
        (b"".join(frames), None)
    if framing == "sync":  # frames of another type and length among the samples (the one-by-one path of a chunk)
        other = encode_frame(0x02, 9, b"abc")
        data = data[:3000] + other + data[3000:20000] + other + other + data[20000:]
    d1, d2 = make_decoder(framing), make_decoder(framing)
    eps, blocks = [], []
    for i in range(0, len(data), chunk):
        eps += d1.feed(data[i:i + chunk])
        b = d2.feed_block(data[i:i + chunk])
        if b is not None:
            blocks.append(b)
    eps += d1.flush()
    b = d2.flush_block()
    if b is not None:
        blocks.append(b)
    ref = EpochBlock.from_epochs(eps)
    t = np.concatenate([x.t for x in blocks])
    assert np.array_equal(t, ref.t)
    for inst in ("gyro", "accel"):
        assert np.array_equal(np.vstack([x.raw[inst] for x in blocks]), ref.raw[inst])
        assert np.array_equal(np.vstack([x.valid[inst] for x in blocks]), ref.valid[inst])
    assert np.concatenate([x.meta["seq"] for x in blocks]).tolist() == [e.counters["seq"] for e in eps]
    a1, a2 = d1.accounting, d2.accounting
    assert (a1.received, a1.accepted, a1.epochs, dict(a1.rejected), dict(a1.events)) == \
        (a2.received, a2.accepted, a2.epochs, dict(a2.rejected), dict(a2.events))
    a2.check()
    assert len(t) > n // 2
