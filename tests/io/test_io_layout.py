"""CAN layouts and the vectorised codec: checked against cantools' decoder and known CRC check values."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.errors import FrameError
from rimu.io.checksum import crc8, crc8_columns, crc16_ccitt
from rimu.io.layout import (
    STATUS_BAD_LENGTH,
    STATUS_CHECKSUM,
    STATUS_OK,
    STATUS_UNKNOWN_ID,
    CanCodec,
    Layout,
    Message,
    Signal,
    load_layout,
)

cantools = pytest.importorskip("cantools")


def test_crc_check_values():
    # catalogue check values (CRC RevEng): CRC-8/SAE-J1850 0x4B, CRC-8/AUTOSAR 0xDF, CRC-16/IBM-3740 0x29B1
    assert crc8(b"123456789", "crc8_sae_j1850") == 0x4B
    assert crc8(b"123456789", "crc8_autosar") == 0xDF
    assert crc16_ccitt(b"123456789") == 0x29B1
    assert crc8(b"\x01\x02\x04", "xor8") == 7 and crc8(b"\xff\x02", "sum8") == 1


@given(st.binary(min_size=0, max_size=12), st.integers(0, 95), st.integers(1, 8))
def test_crc8_detects_every_burst_up_to_8_bits(data, pos, width):
    """A degree-8 CRC with a non-zero constant term detects every error burst of length <= 8 (bits counted in the
    CRC's order: most significant bit of each byte first)."""
    frame = bytearray(data + bytes([crc8(data)]))
    nbits = 8 * len(frame)
    pos = pos % max(nbits - width + 1, 1)
    if nbits < width:
        return
    pattern = (1 | (1 << (width - 1)))  # first and last bit of the burst flipped
    v = int.from_bytes(frame, "big") ^ (pattern << pos)
    bad = v.to_bytes(len(frame), "big")
    assert crc8(bad[:-1]) != bad[-1]


def _signal_strategy():
    @st.composite
    def sig(draw):
        L = draw(st.integers(1, 32))
        order = draw(st.sampled_from(["little_endian", "big_endian"]))
        if order == "little_endian":
            start = draw(st.integers(0, 64 - L))
        else:
            P = draw(st.integers(L - 1, 63))  # msb position in the big-endian word
            start = 8 * (7 - P // 8) + P % 8
        signed = draw(st.booleans()) if L > 1 else False
        scale = draw(st.sampled_from([1.0, 0.5, 0.005, 0.000127465, 1 / 32, 10.0]))
        offset = draw(st.sampled_from([0.0, -163.84, 3.0]))
        return Signal("S", start, L, "other", order, signed, scale, offset)
    return sig()


@settings(max_examples=150, deadline=None)
@given(_signal_strategy(), st.lists(st.binary(min_size=8, max_size=8), min_size=1, max_size=20))
def test_decode_matches_cantools(sig, datas):
    """rimu's shift-and-mask decoding equals cantools' decode_message for any signal position and byte order."""
    from cantools.database.can import Message as CtMessage
    from cantools.database.can import Signal as CtSignal
    from cantools.database.conversion import BaseConversion

    ct = CtMessage(0x10, "M", 8, [CtSignal("S", sig.start_bit, sig.length, sig.byte_order, sig.signed,
                                           conversion=BaseConversion.factory(sig.scale, sig.offset))], strict=False)
    ids = np.full(len(datas), 0x10)
    data = np.frombuffer(b"".join(datas), np.uint8).reshape(-1, 8)
    words_le, words_be = data.view("<u8").ravel(), data.view(">u8").ravel()
    ours = CanCodec._extract(words_le, words_be, sig) * sig.scale + sig.offset
    theirs = [ct.decode(d, decode_choices=False)["S"] for d in datas]
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9 * max(1.0, abs(sig.scale)) * 2 ** sig.length)
    assert ids.shape == (len(datas),)


@pytest.mark.parametrize("name", ["cone6_rimu", "mm7_automotive"])
def test_shipped_layouts_agree_with_cantools(name, cone6_block, mm7_block):
    """Frames encoded by rimu decode to the same signal values with cantools (layout -> cantools Database)."""
    layout = load_layout(name)
    codec = CanCodec(layout)
    block = cone6_block if name == "cone6_rimu" else mm7_block
    enc = codec.encode(block.raw, np.arange(len(block)), block.t, block.temperature)
    msgs = codec.to_messages(enc, block.t)
    dec = codec.decode_messages(msgs)
    assert (dec.status == STATUS_OK).all()
    db = layout.to_cantools()
    for i, m in enumerate(msgs[:60]):
        got = db.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False)
        mi = dec.message[i]
        for j, s in enumerate(codec.value_signals[mi]):
            assert got[s.name] == pytest.approx(dec.values[i, j], abs=1e-9)
    # values are what the layout can carry: the simulated ones to half a resolution step
    for k, y in block.raw.items():
        for mi, _msg in enumerate(layout.messages):
            for j, s in enumerate(codec.value_signals[mi]):
                if s.role == "sample" and s.instrument == k:
                    rows = dec.message == mi
                    err = np.abs(dec.values[rows, j] - y[:, s.index])
                    assert err.max() <= s.resolution / 2 + 1e-9


def test_dbc_roundtrip(tmp_path):
    """A layout exported as DBC and read back through Layout.from_dbc decodes the same frames."""
    layout = load_layout("mm7_automotive")
    path = tmp_path / "mm7.dbc"
    path.write_text(layout.to_cantools().as_dbc_string())
    roles = {}
    for m in layout.messages:
        for s in m.signals:
            if s.role in ("sample", "temperature", "flag"):
                roles[s.name] = {"role": s.role, "instrument": s.instrument, "index": s.index,
                                 "ok_mask": s.ok_mask, "sensors": s.sensors}
            elif s.role == "counter":
                roles[f"{m.name}_{s.name}"] = {"role": "counter"}
    checks = {m.name: m.checksum for m in layout.messages}
    back = Layout.from_dbc(path, roles, sample_rate_hz=100.0, checksums=checks)
    assert back.instruments == layout.instruments
    a, b = CanCodec(layout), CanCodec(back)
    rng = np.random.default_rng(0)
    raw = {"gyro": rng.uniform(-100, 100, (50, 3)), "accel": rng.uniform(-3, 3, (50, 3))}
    msgs = a.to_messages(a.encode(raw, np.arange(50)), np.arange(50) * 0.01)
    da, db_ = a.decode_messages(msgs), b.decode_messages(msgs)
    assert (db_.status == STATUS_OK).all()
    assert np.array_equal(da.counter, db_.counter)
    for mi in range(3):
        rows = da.message == mi
        sa = {s.name: da.values[rows, j] for j, s in enumerate(a.value_signals[mi])}
        sb = {s.name: db_.values[rows, j] for j, s in enumerate(b.value_signals[db_.message[rows][0]])}
        for k, v in sa.items():
            np.testing.assert_allclose(sb[k], v, atol=1e-12)


def test_status_codes(cone6_block):
    codec = CanCodec(load_layout("cone6_rimu"))
    b = cone6_block
    msgs = codec.to_messages(codec.encode({k: y[:3] for k, y in b.raw.items()}, np.arange(3), b.t[:3],
                                         b.temperature[:3]), b.t[:3])[:5]
    ids, data, dlc = codec.pack(msgs)
    data = data.copy()
    ids = ids.copy()
    dlc = dlc.copy()
    data[1, 0] ^= 0x01        # value bit flipped -> checksum
    dlc[2] = 6                # short frame -> bad_length
    ids[3] = 0x7FF            # not in the layout -> unknown_id
    dec = codec.decode(ids, data, dlc)
    assert dec.status.tolist() == [STATUS_OK, STATUS_CHECKSUM, STATUS_BAD_LENGTH, STATUS_UNKNOWN_ID, STATUS_OK]


def test_bad_layouts_raise(tmp_path):
    with pytest.raises(FrameError, match="do not fit"):
        Signal("S", 60, 16)
    with pytest.raises(FrameError, match="outside"):
        Message("M", 1, [Signal("S", 40, 16)], 6)
    with pytest.raises(FrameError, match="role"):
        Signal("S", 0, 8, role="bogus")
    with pytest.raises(FrameError, match="no signal carries"):
        Layout("x", [Message("M", 1, [Signal("S", 0, 16, "sample", instrument="gyro", index=0)])], {"gyro": 2})
    with pytest.raises(FrameError, match="two signals"):
        Layout("x", [Message("M", 1, [Signal("S", 0, 16, "sample", instrument="gyro", index=0),
                                      Signal("T", 16, 16, "sample", instrument="gyro", index=0)])], {"gyro": 1})
    with pytest.raises(FrameError, match="counter"):
        Layout("x", [Message("M", 1, [Signal("S", 0, 16, "sample", instrument="gyro", index=0)]),
                     Message("N", 2, [Signal("S", 0, 16, "sample", instrument="gyro", index=1)])], {"gyro": 2})
    p = tmp_path / "l.json"
    p.write_text(json.dumps({"format": "rimu.can_layout", "version": 9}))
    with pytest.raises(FrameError, match="version"):
        load_layout(p)
    with pytest.raises(FrameError, match="neither a file"):
        load_layout("no_such_layout")


def test_layout_save_load_roundtrip(tmp_path):
    lay = load_layout("cone6_rimu")
    back = load_layout(lay.save(tmp_path / "c.json"))
    assert back.to_dict() == lay.to_dict()
    assert back.counter_modulus == 256 and back.period == pytest.approx(0.01)


def test_crc8_columns_vectorised_equals_scalar():
    rng = np.random.default_rng(1)
    d = rng.integers(0, 256, (100, 7), dtype=np.uint8)
    v = crc8_columns(d)
    assert all(v[i] == crc8(d[i].tobytes()) for i in range(100))


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(["cone6_rimu", "mm7_automotive"]), st.integers(0, 5),
       st.binary(min_size=0, max_size=8), st.booleans())
def test_scalar_decoder_equals_vectorised(name, which, data, extended):
    """decode_one (pure Python, live path) and decode (numpy, replay path) agree on any frame."""
    codec = CanCodec(load_layout(name))
    ids = [m.id for m in codec.layout.messages] + [0x7FF]
    ident = ids[which % len(ids)]
    st_, mi, cnt, vals, flags = codec.decode_one(ident, extended, data)
    d = np.frombuffer(data.ljust(8, b"\0"), np.uint8)[None, :]
    dec = codec.decode(np.array([ident]), d, np.array([len(data)]), np.array([extended]))
    assert st_ == dec.status[0] and mi == dec.message[0]
    if st_ in (STATUS_OK, STATUS_CHECKSUM):
        assert cnt == dec.counter[0]
        np.testing.assert_allclose(vals, dec.values[0, :len(vals)], rtol=0, atol=0)
        assert flags == dec.flags_ok[0, :len(flags)].tolist()


def test_valid_frames_pass_the_scalar_checksum(cone6_block):
    codec = CanCodec(load_layout("cone6_rimu"))
    b = cone6_block
    msgs = codec.to_messages(codec.encode(b.raw, np.arange(len(b)), b.t, b.temperature), b.t)
    assert all(codec.decode_one(m.arbitration_id, m.is_extended_id, m.data)[0] == STATUS_OK for m in msgs)


@settings(max_examples=100, deadline=None)
@given(st.sampled_from(["cone6_rimu", "mm7_automotive"]), st.integers(2, 12), st.integers(0, 2**32 - 1),
       st.integers(0, 3), st.floats(0, 0.3))
def test_regular_decode_equals_general_decode(name, n_samples, seed, extra, p_damage):
    """The strided decoder of frames in layout order equals the per-identifier decoder, also where the order
    breaks part-way (the rest then goes per identifier) and on damaged data."""
    codec = CanCodec(load_layout(name))
    rng = np.random.default_rng(seed)
    K = codec.n_messages
    raw = {"gyro": rng.normal(0, 50, (n_samples, codec.layout.instruments["gyro"])),
           "accel": rng.normal(0, 1, (n_samples, codec.layout.instruments["accel"]))}
    msgs = codec.to_messages(codec.encode(raw, np.arange(n_samples)), np.arange(n_samples) * 0.01)
    ids, data, dlc, ext, _ = CanCodec.pack_all(msgs)
    data = data.copy()
    flip = rng.random(data.shape) < p_damage / 8
    data[flip] ^= rng.integers(1, 256, flip.sum(), dtype=np.uint8)
    dlc = np.where(rng.random(len(dlc)) < p_damage / 4, 5, dlc)
    if extra:   # break the order part-way: swap two frames
        i = int(rng.integers(0, len(ids) - 1))
        for arr in (ids, data, dlc):
            arr[[i, i + 1]] = arr[[i + 1, i]]
    for start in range(K + 1):     # batches beginning part-way through a sample
        a = codec.decode(ids[start:], data[start:], dlc[start:], ext[start:])
        b = codec._decode_general(ids[start:], data[start:], dlc[start:], ext[start:])
        for f in ("status", "message", "counter", "values", "flags_ok"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert K >= 3
