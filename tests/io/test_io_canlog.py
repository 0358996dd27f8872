"""candump logs read from their text (rimu.io.canlog): the vectorised pass against python-can's reader line by
line, damaged lines counted (never dropped), and a replay of a .log equal to the python-can route."""

from __future__ import annotations

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rimu.io.accounting import SideLog
from rimu.io.can import CanReplaySource, decode_log
from rimu.io.canlog import KIND_DATA, KIND_ERROR, KIND_REMOTE, _parse_line, iter_candump, parse_candump
from rimu.io.device import CanDevice


def _messages(rng, n):
    out = []
    for i in range(n):
        t = float(rng.choice([0.0, 9.99, 10.5, 123456.0, 1.7e9])) + i * 0.001
        kind = rng.random()
        if kind < 0.05:
            out.append(can.Message(timestamp=t, is_error_frame=True))
        elif kind < 0.1:
            out.append(can.Message(timestamp=t, arbitration_id=int(rng.integers(0x800)), is_remote_frame=True,
                                   dlc=int(rng.integers(9)), is_extended_id=False))
        else:
            ext = bool(rng.random() < 0.3)
            out.append(can.Message(timestamp=t, arbitration_id=int(rng.integers(1 << (29 if ext else 11))),
                                   is_extended_id=ext, data=rng.integers(0, 256, int(rng.integers(9))).astype(
                                       np.uint8).tobytes(), is_rx=bool(rng.random() < 0.5)))
    return out


def test_frames_equal_python_cans_reader(tmp_path):
    """Standard and extended identifiers, 0-8 data bytes, error and remote frames, R/T flags, timestamps of 1 to
    10 integer digits: every field as can.LogReader reads it (timestamps bit for bit)."""
    msgs = _messages(np.random.default_rng(1), 3000)
    path = tmp_path / "a.log"
    with can.Logger(str(path)) as log:
        for m in msgs:
            log.on_message_received(m)
    ref = list(can.LogReader(str(path)))
    text = path.read_bytes()
    fr = parse_candump(text.replace(b"\n", b"\r\n", 50) + b"\n  \n")      # CRLF lines and blank lines too
    assert len(fr) == len(ref) == len(msgs) and not fr.malformed
    assert fr.ts.tolist() == [m.timestamp for m in ref]
    kinds = [KIND_ERROR if m.is_error_frame else KIND_REMOTE if m.is_remote_frame else KIND_DATA for m in ref]
    assert fr.kind.tolist() == kinds
    data = [m for m, k in zip(ref, kinds) if k == KIND_DATA]
    sel = fr.kind == KIND_DATA
    assert fr.ids[sel].tolist() == [m.arbitration_id for m in data]
    assert fr.ext[sel].tolist() == [m.is_extended_id for m in data]
    assert fr.dlc[sel].tolist() == [len(m.data) for m in data]
    assert [bytes(d[:n]) for d, n in zip(fr.data[sel], fr.dlc[sel])] == [bytes(m.data) for m in data]
    assert not fr.data[sel][np.arange(8)[None, :] >= fr.dlc[sel][:, None]].any()   # zero-padded
    rem = [m for m, k in zip(ref, kinds) if k == KIND_REMOTE]
    assert fr.dlc[fr.kind == KIND_REMOTE].tolist() == [m.dlc for m in rem]
    # in chunks of a few hundred bytes: the same frames, line numbers continuing
    parts = list(iter_candump(path, 300))
    assert len(parts) > 100 and np.concatenate([p.ts for p in parts]).tolist() == fr.ts.tolist()[:len(ref)]
    assert np.concatenate([p.line for p in parts]).tolist() == list(range(1, len(ref) + 1))


_LINE = st.builds(lambda t, i, d, f: f"({t}) can0 {i}#{d}{f}", st.sampled_from(["0.000010", "12.5", "1700000000.123456",
                                                                               "3", "-1.0", "1e3", "0.1234567890123456"]),
                  st.sampled_from(["123", "7ff", "1F334455", "12", "123456789", "G23"]),
                  st.sampled_from(["", "00", "0102030405060708", "010203040506070809", "abc", "R", "R3", "#10011"]),
                  st.sampled_from(["", " R", " t", " X", "  R"]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(_LINE, st.text(alphabet="()#0123456789abcdefR .\t", max_size=30)), max_size=40),
       st.lists(st.tuples(st.integers(0, 2000), st.integers(0, 255)), max_size=5))
def test_every_line_is_a_frame_as_the_line_parser_reads_it_or_counted_malformed(lines, flips):
    """Damaged text: each non-blank line is either a frame equal to the per-line parser's (python-can's rules) or
    a malformed line with its number; nothing is lost and nothing raises."""
    text = bytearray("\n".join(lines).encode())
    for pos, byte in flips:
        if pos < len(text):
            text[pos] = byte
    text = bytes(text)
    fr = parse_candump(text, first_line=7)
    body = text.split(b"\n")
    want = {}
    for k, raw in enumerate(body):
        line = raw.rstrip(b"\r").decode("utf-8", "replace")
        if line.strip():
            want[k + 7] = _parse_line(line)
    assert sorted(fr.line.tolist() + [ln for ln, _ in fr.malformed]) == sorted(want)
    assert [ln for ln, _ in fr.malformed] == [ln for ln, f in want.items() if f is None]
    for i, ln in enumerate(fr.line.tolist()):
        t, cid, ext, dlc, payload, kind = want[ln]
        assert (fr.ts[i], fr.ids[i], fr.ext[i], fr.dlc[i], fr.kind[i]) == (t, cid, ext, dlc, kind), (ln, body[ln - 7])
        assert bytes(fr.data[i, :len(payload)]) == payload


def test_a_log_replays_like_the_python_can_route(cone6_block, tmp_path):
    """The same frames as .log (native) and .asc (can.LogReader): the same block and accounting; malformed lines
    in the .log are counted as rejected frames with their line numbers in the side log."""
    msgs = CanDevice("cone6_rimu").frames(cone6_block)
    m = msgs[:300] + msgs[301:700] + [msgs[700]] + msgs[700:]          # a missing frame and a duplicate
    for fmt in ("log", "asc"):
        with can.Logger(str(tmp_path / f"x.{fmt}")) as log:
            for x in m:
                log.on_message_received(x)
    a, acc_a = decode_log(tmp_path / "x.log", "cone6_rimu")
    b, acc_b = decode_log(tmp_path / "x.asc", "cone6_rimu")
    assert CanReplaySource(tmp_path / "x.log", "cone6_rimu").native
    for k in ("gyro", "accel"):
        np.testing.assert_array_equal(a.raw[k], b.raw[k])
        np.testing.assert_array_equal(a.valid[k], b.valid[k])
    np.testing.assert_array_equal(a.t, b.t)
    assert acc_a.as_dict() == acc_b.as_dict() and acc_a.rejected == {"duplicate": 1}
    lines = (tmp_path / "x.log").read_text().splitlines(keepends=True)
    lines[10] = lines[10][:17] + "\x00garbage\n"
    lines.insert(500, "this is not a frame\n")
    (tmp_path / "bad.log").write_text("".join(lines))
    side = SideLog()
    c, acc = decode_log(tmp_path / "bad.log", "cone6_rimu", side_log=side)
    acc.check()
    assert acc.rejected["malformed_line"] == 2 and acc.received == len(m) + 1
    assert sorted(r["line"] for r in side.items if r["reason"] == "malformed_line") == [11, 501]
    assert len(c) == len(b) and acc.events["missing_frame"] == 2      # line 11's frame: a sample with a gap


@pytest.mark.parametrize("chunk", [16, 333])
def test_iteration_equals_read_block_on_a_log(cone6_block, tmp_path, chunk):
    msgs = CanDevice("cone6_rimu").frames(cone6_block)
    path = tmp_path / "y.log"
    with can.Logger(str(path)) as log:
        for x in msgs[:250] + msgs[251:]:
            log.on_message_received(x)
    block = CanReplaySource(path, "cone6_rimu", chunk=chunk).read_block()
    eps = list(CanReplaySource(path, "cone6_rimu", chunk=chunk))
    assert len(block) == len(eps) == len(cone6_block)
    np.testing.assert_array_equal(block.raw["gyro"], [e.raw["gyro"] for e in eps])
    np.testing.assert_array_equal(block.valid["gyro"], [e.valid["gyro"] for e in eps])


@pytest.mark.parametrize("layout", ["cone6_rimu", "mm7_automotive"])
def test_a_damaged_stream_through_a_log_file_meets_the_oracle(layout, tmp_path):
    """The fuzzing oracle of rimu.io.fuzz (every intact frame recovered with its exact values, counts per
    reason) on 20 000 mutated frames written to a candump .log and replayed from its text."""
    from rimu.io.fuzz import CAN_ACTIONS, check_can, draw_actions, layout_stream, mutate_can

    _block, msgs, exp, K = layout_stream(layout, 20_000 // (5 if layout == "cone6_rimu" else 3), seed=1)
    rng = np.random.default_rng(7)
    bad, oracle = mutate_can(msgs, K, draw_actions(rng, len(msgs), CAN_ACTIONS), rng)
    path = tmp_path / "fuzz.log"
    with can.Logger(str(path)) as log:
        for m in bad:
            log.on_message_received(m)
    src = CanReplaySource(path, layout)
    rep = check_can(list(src), src.accounting, oracle, exp, layout)
    assert rep["rejected"] > 0.15 * len(msgs)
