"""The vectorised CAN paths against their references, exactly, on seeded frames with garbage:

* ``CanCodec.decode`` of frames in layout order (all signals at once, checksums as linear tables, aligned integers
  through views) = the per-identifier decoder ``_decode_general`` = the pure-Python ``decode_one``;
* the batch assembly (clean samples decoded straight into epoch vectors) = the per-frame assembler, epochs and
  accounting, on streams damaged by ``fuzz.mutate_can``;
* ``linear_checksum`` = the checksum computed byte by byte;
* candump text read run by run = read line by line (python-can's rules), with damage inside long runs.

Besides the shipped layouts, a layout made to reach every branch: big-endian signals (aligned and not), signed
odd lengths, 4-, 7-, 12-, 24- and 32-bit fields, CRC-8/AUTOSAR with a two-byte data id, XOR and SUM checksums,
a checksum-less 3-byte frame, an extended identifier, a signed status flag covering two sensors, other signals,
a temperature sent in two frames (the last one counts);
and a one-frame layout with an unsigned 64-bit sample (decoded one signal at a time).
"""

from __future__ import annotations

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rimu.io.accounting import Accounting
from rimu.io.can import CanFrameProcessor
from rimu.io.canlog import iter_candump, parse_candump
from rimu.io.checksum import crc8_columns
from rimu.io.fuzz import CAN_ACTIONS, draw_actions, mutate_can
from rimu.io.layout import STATUS_OK, CanCodec, Layout, linear_checksum, load_layout


def _sig(name, role, start, length, order="little_endian", signed=False, scale=1.0, offset=0.0, **kw):
    return {"name": name, "role": role, "start_bit": start, "length": length, "byte_order": order, "signed": signed,
            "scale": scale, "offset": offset, **kw}


MIXED = {
    "format": "rimu.can_layout", "version": 1, "name": "mixed", "instruments": {"gyro": 3, "accel": 2},
    "sample_rate_hz": 100.0,
    "messages": [
        {"name": "A", "id": "0x200", "length": 8,
         "checksum": {"algorithm": "crc8_autosar", "byte": 7, "data_id": "0x1234"},
         "signals": [_sig("G0", "sample", 7, 16, "big_endian", True, 0.01, instrument="gyro", index=0),
                     _sig("G1", "sample", 23, 12, "big_endian", True, 0.02, 1.5, instrument="gyro", index=1),
                     _sig("CNT_A", "counter", 27, 4, "big_endian"),
                     _sig("TIME", "time", 39, 24, "big_endian", False, 1e-3)]},
        {"name": "B", "id": "0x1ABCDE", "extended": True, "length": 6, "checksum": {"algorithm": "xor8", "byte": 0},
         "signals": [_sig("CNT_B", "counter", 8, 4),
                     _sig("FLAG_B", "flag", 12, 4, signed=True, ok_mask=3, sensors=[["gyro", 2], ["accel", 0]]),
                     _sig("G2", "sample", 16, 8, signed=True, scale=0.5, offset=-1.0, instrument="gyro", index=2),
                     _sig("A0", "sample", 24, 16, scale=0.001, offset=-30.0, instrument="accel", index=0),
                     _sig("TEMP", "temperature", 40, 8, signed=True, scale=0.5)]},
        {"name": "C", "id": "0x300", "length": 8, "checksum": {"algorithm": "sum8", "byte": 7},
         "signals": [_sig("CNT_C", "counter", 0, 4), _sig("TEMP2", "temperature", 4, 4, scale=4.0, offset=-10.0),
                     _sig("A1", "sample", 8, 32, signed=True, scale=1e-4, instrument="accel", index=1),
                     _sig("MODE", "other", 40, 8), _sig("EXTRA", "other", 48, 7, signed=True)]},
        {"name": "D", "id": "0x301", "length": 3,
         "signals": [_sig("CNT_D", "counter", 0, 4),
                     _sig("STAT", "flag", 4, 4, ok_mask=15, sensors=[["gyro", 0], ["gyro", 1]]),
                     _sig("HW", "other", 8, 16)]},
    ]}

WIDE64 = {"format": "rimu.can_layout", "version": 1, "name": "wide64", "instruments": {"gyro": 1},
          "messages": [{"name": "W", "id": "0x10", "length": 8,
                        "signals": [_sig("G", "sample", 0, 64, scale=0.5, instrument="gyro", index=0)]}]}

LAYOUTS = {"cone6_rimu": "cone6_rimu", "mm7_automotive": "mm7_automotive", "mixed": MIXED, "wide64": WIDE64}


def _clean_messages(layout, n, rng, counter0=0):
    """n samples of random raw values within each signal's range, random sensor flags, as python-can messages."""
    codec = CanCodec(load_layout(layout))
    L = codec.layout
    raw = {k: rng.uniform(-30, 30, (n, m)) for k, m in L.instruments.items()}
    if L.name == "wide64":
        raw["gyro"] = rng.uniform(0, 2.0 ** 62, (n, 1))   # (the encoder takes int64; garbage frames go beyond)
    valid = {k: rng.random((n, m)) > 0.1 for k, m in L.instruments.items()}
    other = {name: rng.integers(-60, 60, n) for name in codec.other_names}
    t = 1000.0 + np.arange(n) * 0.01
    enc = codec.encode(raw, counter0 + np.arange(n), t=t, temperature=rng.uniform(-20, 60, n), valid=valid,
                       other=other)
    return codec, codec.to_messages(enc, t)


@pytest.mark.parametrize("name", list(LAYOUTS))
@pytest.mark.parametrize("seed", [1, 2])
def test_layout_order_decode_equals_general_and_scalar_decoders(name, seed):
    """Seeded frames in layout order with bytes flipped, lengths changed and some frames replaced by random
    bytes: every field of every frame equal in the three decoders (bit for bit)."""
    rng = np.random.default_rng(seed)
    codec, msgs = _clean_messages(LAYOUTS[name], 300, rng)
    ids, data, dlc, ext, _ = CanCodec.pack_all(msgs)
    data = data.copy()
    flip = rng.random(data.shape) < 0.02
    data[flip] ^= rng.integers(1, 256, flip.sum(), dtype=np.uint8)
    garbage = rng.random(len(ids)) < 0.05
    data[garbage] = rng.integers(0, 256, (garbage.sum(), 8), dtype=np.uint8)
    dlc = np.where(rng.random(len(dlc)) < 0.02, rng.integers(0, 9, len(dlc)), dlc)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0           # zero-padded beyond the length, as read
    a = codec.decode(ids, data, dlc, ext)
    b = codec._decode_general(ids, data, dlc, ext)
    assert len(ids) >= 2 * codec.n_messages                     # (the layout-order path was taken)
    for f in ("status", "message", "counter", "values", "flags_ok"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert 0 < (a.status == STATUS_OK).sum() < len(ids)         # both good and rejected frames were compared
    for i in range(len(ids)):
        st_, mi, cnt, vals, flags = codec.decode_one(int(ids[i]), bool(ext[i]), bytes(data[i, :dlc[i]]))
        assert (st_, mi) == (a.status[i], a.message[i])
        if st_ == STATUS_OK:
            assert cnt == a.counter[i] and vals == a.values[i, :len(vals)].tolist()
            assert flags == a.flags_ok[i, :len(flags)].tolist()


def _epochs_equal(ea, eb):
    assert len(ea) == len(eb)
    for x, y in zip(ea, eb):
        assert x.t == y.t and x.temperature == y.temperature and x.counters == y.counters
        for k in x.raw:
            assert np.array_equal(x.raw[k], y.raw[k]) and np.array_equal(x.valid[k], y.valid[k])


@pytest.mark.parametrize("name", ["cone6_rimu", "mm7_automotive", "mixed"])
@pytest.mark.parametrize("damage", [0.0, 0.02, 0.2])
def test_batch_assembly_equals_per_frame_assembly(name, damage):
    """Batches (clean samples straight into epoch vectors, the rest frame by frame) and one frame per call give
    the same epochs, accounting and events, on clean and damaged streams (counter wrapping, swaps, duplicates,
    truncated, corrupted, unknown, error and remote frames)."""
    rng = np.random.default_rng(7)
    codec, msgs = _clean_messages(LAYOUTS[name], 400, rng, counter0=5)
    K = codec.n_messages
    if damage:
        table = {k: (v if k != "keep" else 0.0) for k, v in CAN_ACTIONS.items()}
        acts = [a if rng.random() < damage else "keep" for a in draw_actions(rng, len(msgs), table)]
        msgs, _ = mutate_can(msgs, K, acts, rng)
    a = CanFrameProcessor(LAYOUTS[name], Accounting())
    b = CanFrameProcessor(LAYOUTS[name], Accounting())
    ea = [e for i in range(0, len(msgs), 257) for e in a.process(msgs[i:i + 257])] + a.flush()
    eb = [e for m in msgs for e in b.process([m])] + b.flush()
    _epochs_equal(ea, eb)
    assert a.acc.as_dict() == b.acc.as_dict()
    if not damage:
        assert len(ea) == 400 and a.acc.accepted == len(msgs)


@pytest.mark.parametrize("name", ["mixed", "cone6_rimu"])
def test_linear_checksum_tables_equal_the_byte_by_byte_checksum(name):
    rng = np.random.default_rng(3)
    for m in load_layout(LAYOUTS[name]).messages:
        lin = linear_checksum(m)
        if m.checksum is None or m.checksum["algorithm"] == "sum8":
            assert lin is None
            continue
        T, c = lin
        d = np.zeros((500, 8), np.uint8)
        d[:, :m.length] = rng.integers(0, 256, (500, m.length), dtype=np.uint8)
        cb = m.checksum["byte"]
        body = d[:, [j for j in range(m.length) if j != cb]]
        did = np.frombuffer(m.data_id_bytes(), np.uint8)
        crc = crc8_columns(np.hstack([np.broadcast_to(did, (500, len(did))), body]), m.checksum["algorithm"])
        d[:250, cb] = crc[:250]                                 # half right, half (almost surely) wrong
        r = np.bitwise_xor.reduce(np.stack([T[p][d[:, p]] for p in range(8)]), axis=0) ^ c
        assert ((r == 0) == (d[:, cb] == crc)).all() and (r[:250] == 0).all() and (r[250:] != 0).any()


def _log_text(rng, n_lines):
    lines = []
    t = 1_700_000_000.0
    for i in range(n_lines):
        lines.append(f"({t + i * 1e-3:.6f}) can0 {0x100 + i % 5:03X}#{rng.integers(0, 1 << 63):016X} R")
    return lines


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**32 - 1), st.lists(st.tuples(st.integers(0, 599), st.sampled_from(
    ["flip", "newline", "crlf", "channel", "tab", "lower", "short", "blank", "drop_flag"])), max_size=6))
def test_runs_of_lines_read_like_line_by_line(seed, damage):
    """Long runs of equally long lines (found by one strided comparison each) with damage inside them, a line
    break hidden in a line, CRLF endings, other channels: the same frames, line numbers and malformed lines as
    the byte-by-byte search, and every frame as python-can's rules read its line."""
    rng = np.random.default_rng(seed)
    lines = _log_text(rng, 600)
    for i, what in damage:
        s = lines[i]
        if len(s) < 3:      # already blanked
            continue
        if what == "flip":
            j = int(rng.integers(0, len(s)))
            s = s[:j] + chr(int(rng.integers(32, 127))) + s[j + 1:]
        elif what == "newline":
            j = int(rng.integers(1, len(s) - 1))
            s = s[:j] + "\n" + s[j + 1:]
        elif what == "crlf":
            s += "\r"
        elif what == "channel":
            s = s.replace("can0", "can1")
        elif what == "tab":
            s = s.replace("can0", "ca\t0")
        elif what == "lower":
            s = s.lower()
        elif what == "short":
            s = s[:-3]
        elif what == "blank":
            s = ""
        else:
            s = s[:-2]
        lines[i] = s
    text = ("\n".join(lines) + "\n").encode()
    a = parse_candump(text, 3)
    b = parse_candump(text, 3, runs=False)
    for f in ("ts", "ids", "ext", "dlc", "data", "kind", "line"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert a.malformed == b.malformed
    if not damage:
        assert len(a) == 600 and not a.malformed
    # and line by line, as can.LogReader's parser would read them
    from rimu.io.canlog import _parse_line

    all_lines = text.decode().split("\n")[:-1]
    k = 0
    for ln, s in enumerate(all_lines, start=3):
        if not s.strip():
            continue
        f = _parse_line(s)
        if f is None:
            assert (ln, s.removesuffix("\r")) in a.malformed       # reported without the line ending
            continue
        t, cid, ext, dlc, payload, _kind = f
        assert (a.line[k], a.ts[k], a.ids[k], a.ext[k], a.dlc[k]) == (ln, t, cid, ext, dlc)
        assert bytes(a.data[k, :dlc]) == payload
        k += 1
    assert k == len(a)


def test_messages_read_once_equal_attribute_reads():
    """pack_frames (one pass over the messages) = the attributes read one by one; error and remote frames
    flagged."""
    rng = np.random.default_rng(4)
    msgs = [can.Message(timestamp=float(i), arbitration_id=int(rng.integers(0, 0x800)),
                        data=rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes(),
                        is_extended_id=bool(i % 3 == 0)) for i in range(100)]
    ids, data, dlc, ext, ts, special = CanCodec.pack_frames(msgs)
    assert ids.tolist() == [m.arbitration_id for m in msgs] and ts.tolist() == [m.timestamp for m in msgs]
    assert dlc.tolist() == [len(m.data) for m in msgs] and ext.tolist() == [m.is_extended_id for m in msgs]
    assert [bytes(d[:n]) for d, n in zip(data, dlc)] == [bytes(m.data) for m in msgs] and not special
    assert CanCodec.pack_frames([*msgs, can.Message(is_remote_frame=True)])[5]
    assert CanCodec.pack_frames([can.Message(is_error_frame=True), *msgs])[5]


def test_layouts_build():
    """The test layouts are valid (and reach the branches the tests are for)."""
    c = CanCodec(Layout.from_dict(MIXED))
    assert c._ck_other == [2] and len(c._ck_groups) == 2          # sum8 one by one; crc8 and xor8 by tables
    assert {dt.str for dt, *_ in c._aligned} == {">i2", "|i1", "|u1"}     # G0; G2, TEMP; MODE
    kinds = {g[0]: g[1].n for g in c._groups}       # fields within a byte (CNT_A big-endian), words per byte order
    assert kinds == {"bytes": 6, True: 5, False: 2}    # 4 counters, TEMP2, STAT | FLAG_B, A0, A1, EXTRA, HW | G1, TIME
    assert c._last_writer.sum() == c._last_writer.size - (c._slot_of < 0).sum() - 1      # TEMP (B) gives way to TEMP2
    assert CanCodec(Layout.from_dict(WIDE64))._rest


def test_a_log_read_in_any_chunks_gives_the_same_frames(tmp_path):
    """iter_candump reads into one reused buffer: chunks smaller than a line (the buffer grows), a few lines, or
    the whole file give the same frames, line numbers and malformed lines as the whole text at once."""
    rng = np.random.default_rng(9)
    lines = _log_text(rng, 300)
    lines[17] = "not a frame"
    lines[200] = ""
    lines[-1] = lines[-1][:-2] + "#"                     # a damaged last line without a line break
    text = "\n".join(lines).encode()
    path = tmp_path / "a.log"
    path.write_bytes(text)
    whole = parse_candump(text)
    for chunk in (7, 50, 1000, 1 << 20):
        parts = list(iter_candump(path, chunk))
        for f in ("ts", "ids", "ext", "dlc", "data", "kind", "line"):
            np.testing.assert_array_equal(np.concatenate([getattr(p, f) for p in parts]), getattr(whole, f))
        assert [m for p in parts for m in p.malformed] == whole.malformed == [(18, "not a frame"), (300, lines[-1])]


def test_a_layout_without_time_signal_stamps_epochs_with_receive_time():
    """mm7 has no time signal: every epoch (also one with a missing frame) gets the receive time of its first
    frame, frame by frame as in batches, and nothing is counted as extrapolated."""
    rng = np.random.default_rng(11)
    _, msgs = _clean_messages("mm7_automotive", 40, rng)
    del msgs[31]                                               # sample 10 loses its second frame
    for batch in (1, 1000):
        p = CanFrameProcessor("mm7_automotive", Accounting())
        eps = [e for i in range(0, len(msgs), batch) for e in p.process(msgs[i:i + batch])] + p.flush()
        assert [e.t for e in eps] == [1000.0 + k * 0.01 for k in range(40)]
        assert "time_extrapolated" not in p.acc.events and p.acc.events["missing_frame"] == 1
