"""Replayed python-can logs through the CAN source: each stream defect gives the documented result.

The documented behaviour is in :mod:`rimu.io.assembly` and docs/io.md: a missing frame makes its sensors
invalid for that epoch (raw 0.0) and is counted; a counter gap produces no epoch and is counted; duplicates and
late frames are rejected and counted; out-of-order frames within the window are put in their place.
"""

from __future__ import annotations

import can
import numpy as np
import pytest

from rimu.io.accounting import SideLog
from rimu.io.can import CanReplaySource, decode_log
from rimu.io.device import CanDevice

N = 30


@pytest.fixture()
def setup(cone6_block):
    block = _head(cone6_block, N)
    dev = CanDevice("cone6_rimu")
    return block, dev, dev.frames(block), dev.expected(block)


def _head(block, n):
    from rimu.epoch import EpochBlock

    return EpochBlock(block.t[:n].copy(), {k: y[:n].copy() for k, y in block.raw.items()},
                      temperature=block.temperature[:n].copy())


def _replay(msgs, tmp_path, fmt="asc", layout="cone6_rimu", **kw):
    path = tmp_path / f"log.{fmt}"
    with can.Logger(str(path)) as log:
        for m in msgs:
            log.on_message_received(m)
    src = CanReplaySource(path, layout, **kw)
    eps = list(src)
    src.accounting.check()
    return eps, src.accounting


def _frames_of(msgs, k, per=5):
    return msgs[k * per:(k + 1) * per]


def _assert_epoch_equals(ep, block, exp, k, gyro_valid=None, accel_valid=None):
    for inst, vmask in (("gyro", gyro_valid), ("accel", accel_valid)):
        v = np.ones(6, bool) if vmask is None else np.asarray(vmask, bool)
        assert ep.valid[inst].tolist() == v.tolist()
        np.testing.assert_array_equal(ep.raw[inst][v], exp[inst][k][v])
        assert np.all(ep.raw[inst][~v] == 0.0)


@pytest.mark.parametrize("fmt", ["asc", "blf", "csv", "log"])
def test_roundtrip_every_log_format(setup, tmp_path, fmt):
    block, _dev, msgs, exp = setup
    eps, acc = _replay(msgs, tmp_path, fmt)
    assert len(eps) == N
    for k, ep in enumerate(eps):
        _assert_epoch_equals(ep, block, exp, k)
        assert ep.t == pytest.approx(block.t[k], abs=5e-6)   # device time, 10 us resolution
        assert ep.temperature == pytest.approx(block.temperature[k], abs=0.005)
    assert acc.received == acc.accepted == 5 * N and acc.rejected_total == 0 and acc.epochs == N
    assert not acc.events


def test_missing_frame_marks_its_sensors_invalid(setup, tmp_path):
    block, _dev, msgs, exp = setup
    drop = 10 * 5 + 2  # GYRO_2 of sample 10 (gyros x2, y2, z2)
    eps, acc = _replay(msgs[:drop] + msgs[drop + 1:], tmp_path)
    assert len(eps) == N
    _assert_epoch_equals(eps[10], block, exp, 10, gyro_valid=[1, 1, 1, 0, 0, 0])
    for k in (9, 11, 29):
        _assert_epoch_equals(eps[k], block, exp, k)
    assert [e.counters["seq"] for e in eps] == list(range(N))     # not shifted
    assert eps[10].counters["frames"] == 4
    assert acc.events["missing_frame"] == 1 and acc.accepted == 5 * N - 1 and acc.rejected_total == 0


def test_missing_status_frame_extrapolates_time(setup, tmp_path):
    block, _dev, msgs, exp = setup
    drop = 7 * 5  # STATUS of sample 7: time and temperature
    eps, acc = _replay(msgs[:drop] + msgs[drop + 1:], tmp_path)
    assert eps[7].t == pytest.approx(block.t[7], abs=1e-9)
    assert eps[7].temperature is None
    _assert_epoch_equals(eps[7], block, exp, 7)
    assert acc.events["time_extrapolated"] == 1 and acc.events["missing_frame"] == 1


def test_counter_gap_gives_no_epoch_and_is_counted(setup, tmp_path):
    block, _dev, msgs, exp = setup
    eps, acc = _replay(msgs[:50] + msgs[65:], tmp_path)  # samples 10, 11, 12 lost entirely
    assert len(eps) == N - 3
    seqs = [e.counters["seq"] for e in eps]
    assert seqs == list(range(10)) + list(range(13, N))
    assert eps[10].t == pytest.approx(block.t[13], abs=5e-6)
    _assert_epoch_equals(eps[10], block, exp, 13)
    assert acc.events["counter_gap"] == 1 and acc.events["missing_epochs"] == 3
    assert "missing_frame" not in acc.events


def test_duplicates_are_rejected_and_counted(setup, tmp_path):
    block, _dev, msgs, exp = setup
    m = list(msgs)
    m.insert(21, msgs[20])      # STATUS of sample 4 twice in a row
    m.insert(40, msgs[34])      # last frame of sample 6 again, after its epoch was emitted
    eps, acc = _replay(m, tmp_path)
    assert len(eps) == N
    for k, ep in enumerate(eps):
        _assert_epoch_equals(ep, block, exp, k)
    assert acc.rejected == {"duplicate": 2} and acc.accepted == 5 * N


def test_out_of_order_within_window_is_reassembled(setup, tmp_path):
    block, _dev, msgs, exp = setup
    m = list(msgs)
    # sample 10's last frame after two frames of sample 11; sample 20's first frame after its own second
    m[54], m[55], m[56] = msgs[55], msgs[56], msgs[54]
    m[100], m[101] = msgs[101], msgs[100]
    eps, acc = _replay(m, tmp_path)
    assert len(eps) == N
    for k, ep in enumerate(eps):
        _assert_epoch_equals(ep, block, exp, k)
        assert ep.t == pytest.approx(block.t[k], abs=5e-6)
    assert acc.rejected_total == 0 and not acc.events


def test_frame_later_than_the_window_is_rejected_late(setup, tmp_path):
    block, _dev, msgs, exp = setup
    late = msgs[10 * 5 + 3]                       # ACCEL_1 of sample 10 ...
    m = msgs[:53] + msgs[54:75] + [late] + msgs[75:]  # ... arrives after sample 14's frames
    eps, acc = _replay(m, tmp_path)
    assert len(eps) == N
    _assert_epoch_equals(eps[10], block, exp, 10, accel_valid=[0, 0, 0, 1, 1, 1])
    assert acc.rejected == {"late": 1} and acc.events["missing_frame"] == 1


def test_counter_reset_resynchronises(cone6_block, tmp_path):
    block = _head(cone6_block, N)
    first = CanDevice("cone6_rimu", counter0=100).frames(_head(block, 15))
    from rimu.epoch import EpochBlock

    rest_block = EpochBlock(block.t[15:], {k: y[15:] for k, y in block.raw.items()},
                            temperature=block.temperature[15:])
    rest = CanDevice("cone6_rimu", counter0=0).frames(rest_block)   # device restarted its counter
    exp = CanDevice("cone6_rimu").expected(block)
    eps, acc = _replay(first + rest, tmp_path)
    # documented: resync_after (= 5 frames per sample) far frames in a row -> the first 4 are rejected
    assert acc.rejected == {"counter_jump": 4} and acc.events["resync"] == 1
    assert len(eps) == N
    _assert_epoch_equals(eps[15], block, exp, 15, gyro_valid=[0] * 6, accel_valid=[0, 0, 0, 1, 1, 1])
    # no time extrapolation across a restart: receive time of its first accepted frame (ACCEL_2, +40 us)
    assert eps[15].t == pytest.approx(block.t[15] + 4e-5, abs=1e-6)
    for k in range(16, N):
        _assert_epoch_equals(eps[k], block, exp, k)
        assert eps[k].t == pytest.approx(block.t[k], abs=5e-6)
    assert [e.counters["seq"] for e in eps] == sorted({e.counters["seq"] for e in eps})


def test_forward_counter_jump_reads_as_gap(cone6_block, tmp_path):
    block = _head(cone6_block, N)
    from rimu.epoch import EpochBlock

    a = CanDevice("cone6_rimu", counter0=0).frames(_head(block, 10))
    rest = EpochBlock(block.t[10:], {k: y[10:] for k, y in block.raw.items()}, temperature=block.temperature[10:])
    b = CanDevice("cone6_rimu", counter0=50).frames(rest)   # counter jumps 10 -> 50
    eps, acc = _replay(a + b, tmp_path)
    assert len(eps) == N and acc.rejected_total == 0
    assert acc.events["counter_gap"] == 1 and acc.events["missing_epochs"] == 40
    assert eps[10].t == pytest.approx(block.t[10], abs=5e-6)


def test_long_silence_longer_than_counter_range_restarts(mm7_block, tmp_path):
    """MM7 counters have 4 bits (16 values); a 25-sample gap would alias to 9; frame time tells."""
    dev = CanDevice("mm7_automotive")
    msgs = dev.frames(mm7_block)
    exp = dev.expected(mm7_block)
    m = msgs[:3 * 10] + msgs[3 * 35:]
    eps, acc = _replay(m, tmp_path, layout="mm7_automotive")
    assert len(eps) == 100 - 25 and acc.events["resync"] == 1 and acc.rejected_total == 0
    for e, k in zip(eps, list(range(10)) + list(range(35, 100))):
        np.testing.assert_array_equal(e.raw["gyro"], exp["gyro"][k])
        np.testing.assert_array_equal(e.raw["accel"], exp["accel"][k])
        assert e.t == pytest.approx(mm7_block.t[k], abs=1e-6)      # receive time of the first frame
        assert e.temperature == 31.0


def test_mm7_status_flags_invalidate_sensors(mm7_block, tmp_path):
    valid = {"gyro": np.ones((100, 3), bool), "accel": np.ones((100, 3), bool)}
    valid["gyro"][5, 2] = False
    valid["accel"][7, 0] = False
    from rimu.epoch import EpochBlock

    b = EpochBlock(mm7_block.t, mm7_block.raw, valid, mm7_block.temperature)
    eps, _acc = _replay(CanDevice("mm7_automotive").frames(b), tmp_path, layout="mm7_automotive")
    assert eps[5].valid["gyro"].tolist() == [True, True, False] and eps[5].raw["gyro"][2] == 0.0
    assert eps[7].valid["accel"].tolist() == [False, True, True]
    assert all(e.valid["gyro"].all() and e.valid["accel"].all() for i, e in enumerate(eps) if i not in (5, 7))


def test_bad_frames_are_rejected_by_reason_and_side_logged(setup, tmp_path):
    _block, _dev, msgs, _exp = setup
    m = list(msgs)
    bad_crc = can.Message(timestamp=m[12].timestamp, arbitration_id=m[12].arbitration_id, is_extended_id=False,
                          data=bytes([m[12].data[0] ^ 0x10]) + bytes(m[12].data[1:]))
    short = can.Message(timestamp=m[18].timestamp, arbitration_id=m[18].arbitration_id, is_extended_id=False, data=bytes(m[18].data[:6]))
    m[12], m[18] = bad_crc, short
    m.insert(30, can.Message(timestamp=m[30].timestamp, arbitration_id=0x555, data=b"\x01\x02"))
    m.insert(40, can.Message(timestamp=m[40].timestamp, is_error_frame=True, arbitration_id=0x0, data=b""))
    m.insert(45, can.Message(timestamp=m[45].timestamp, arbitration_id=0x101, is_extended_id=False, is_remote_frame=True, dlc=8))
    side = SideLog()
    block_, acc = decode_log(_write(m, tmp_path), "cone6_rimu", side_log=side)
    assert acc.rejected == {"checksum": 1, "bad_length": 1, "unknown_id": 1, "error_frame": 1, "remote_frame": 1}
    assert acc.received == len(m) and acc.accepted == len(m) - 5
    assert len(block_) == N
    assert block_.valid["gyro"][2].tolist() == [1, 1, 1, 0, 0, 0]     # sample 2 lost GYRO_2 (frame 12)
    assert block_.valid["accel"][3].tolist() == [0, 0, 0, 1, 1, 1]    # sample 3 lost ACCEL_1 (frame 18)
    assert sorted(r["reason"] for r in side.items) == sorted(acc.rejected)
    assert next(r for r in side.items if r["reason"] == "checksum")["data"] == bytes(bad_crc.data).hex()


def _write(msgs, tmp_path, fmt="asc"):
    path = tmp_path / f"log2.{fmt}"
    with can.Logger(str(path)) as log:
        for m in msgs:
            log.on_message_received(m)
    return path


def test_realtime_replay_paces_by_timestamps(setup, tmp_path):
    import time

    _block, _dev, msgs, _exp = setup
    path = _write(msgs[:50], tmp_path)     # 10 samples over 0.09 s of log time
    t0 = time.monotonic()
    eps = list(CanReplaySource(path, "cone6_rimu", realtime=True, speed=0.5))
    elapsed = time.monotonic() - t0
    assert len(eps) == 10
    assert elapsed >= 0.09 / 0.5 * 0.95   # pacing honoured (lower bound only: no timing upper bound in tests)


def test_fast_path_equals_per_frame_path(cone6_block):
    """The vectorised assembly of clean batches gives the same epochs and state as frame-by-frame."""
    from rimu.io.accounting import Accounting
    from rimu.io.can import CanFrameProcessor

    msgs = CanDevice("cone6_rimu", counter0=250).frames(cone6_block)   # counter wraps at 256
    a, b = CanFrameProcessor("cone6_rimu", Accounting()), CanFrameProcessor("cone6_rimu", Accounting())
    ea = a.process(msgs[:500]) + a.process(msgs[500:]) + a.flush()
    eb = [e for m in msgs for e in b.process([m])] + b.flush()
    assert len(ea) == len(eb) == len(cone6_block)
    for x, y in zip(ea, eb):
        assert x.t == y.t and x.temperature == y.temperature and x.counters == y.counters
        for k in ("gyro", "accel"):
            assert np.array_equal(x.raw[k], y.raw[k]) and np.array_equal(x.valid[k], y.valid[k])
    assert a.acc.as_dict() == b.acc.as_dict()


def test_block_replay_equals_epoch_replay(cone6_block, tmp_path):
    """read_block (vectorised, EpochChunk arrays) and iteration (Epoch objects) give the same data, also with
    defects in the log."""
    msgs = CanDevice("cone6_rimu").frames(cone6_block)
    m = msgs[:300] + msgs[301:700] + [msgs[700]] + msgs[700:]        # a missing frame and a duplicate
    path = _write(m, tmp_path, "blf")
    a = CanReplaySource(path, "cone6_rimu", chunk=333)
    b = CanReplaySource(path, "cone6_rimu", chunk=333)
    block = a.read_block()
    eps = list(b)
    assert len(block) == len(eps) == len(cone6_block)
    np.testing.assert_array_equal(block.t, [e.t for e in eps])
    for k in ("gyro", "accel"):
        np.testing.assert_array_equal(block.raw[k], [e.raw[k] for e in eps])
        np.testing.assert_array_equal(block.valid[k], [e.valid[k] for e in eps])
    np.testing.assert_array_equal(block.meta["seq"], [e.counters["seq"] for e in eps])
    assert a.accounting.as_dict() == b.accounting.as_dict()
    assert a.accounting.rejected == {"duplicate": 1} and a.accounting.events["missing_frame"] == 1
