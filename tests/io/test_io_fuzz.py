"""Fuzzing: damaged CAN and serial streams against an exact oracle (rimu.io.fuzz).

No exception escapes, every intact frame is recovered with its exact values, nothing damaged is accepted, and
the accounting identity holds with the expected count per rejection reason. The seeded runs have the sizes of
the issue: 1e5 mutated frames (cone6 layout; 3e4 for the MM7 layout, 1e5 with ``RIMU_FULL_FUZZ=1``) and 1 MB
of mutated serial bytes; ``benchmarks/io.py`` runs them too and reports the counts.
"""

from __future__ import annotations

import os

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rimu.io.accounting import Accounting
from rimu.io.can import CanFrameProcessor
from rimu.io.device import SerialDevice
from rimu.io.fuzz import (
    CAN_ACTIONS,
    SERIAL_ACTIONS,
    check_can,
    check_serial,
    decode_pieces,
    draw_actions,
    layout_stream,
    mutate_can,
    mutate_serial,
    pieces,
    process_chunks,
    random_block,
)
from rimu.io.serial import SerialDecoder

FULL = os.environ.get("RIMU_FULL_FUZZ") == "1"




def _run_can(msgs, layout, chunk):
    proc = CanFrameProcessor(layout, Accounting())
    return process_chunks(proc, msgs, chunk), proc.acc


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(["cone6_rimu", "mm7_automotive"]),
       st.lists(st.sampled_from(list(CAN_ACTIONS)), min_size=40, max_size=40),
       st.integers(0, 2**32 - 1), st.sampled_from([1, 7, 1000]))
def test_can_mutations_hypothesis(layout, actions, seed, chunk):
    _block, msgs, exp, K = layout_stream(layout, 40 // (5 if layout == "cone6_rimu" else 3) + 1)
    msgs = msgs[:40]
    acts = (actions + ["keep"] * len(msgs))[:len(msgs)]
    bad, oracle = mutate_can(msgs, K, acts, np.random.default_rng(seed), swap_p=0.2)
    eps, acc = _run_can(bad, layout, chunk)
    check_can(eps, acc, oracle, exp, layout)


@pytest.mark.parametrize("layout", ["cone6_rimu", "mm7_automotive"])
def test_can_seeded_long_run(layout):
    n_frames = 100_000 if (FULL or layout == "cone6_rimu") else 30_000
    K = 5 if layout == "cone6_rimu" else 3
    _block, msgs, exp, K = layout_stream(layout, n_frames // K, seed=1)
    rng = np.random.default_rng(2024)
    bad, oracle = mutate_can(msgs, K, draw_actions(rng, len(msgs), CAN_ACTIONS), rng)
    eps, acc = _run_can(bad, layout, 4096)
    rep = check_can(eps, acc, oracle, exp, layout)
    assert rep["rejected"] > 0.15 * len(msgs)       # the run did damage a good share of the stream


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0x100, 0x101, 0x112, 0x174, 0x17C, 0x7FF]),
                          st.binary(min_size=0, max_size=8), st.booleans()), max_size=60),
       st.sampled_from(["cone6_rimu", "mm7_automotive"]))
def test_arbitrary_can_frames_never_raise(frames, layout):
    msgs = [can.Message(timestamp=0.001 * i, arbitration_id=a, is_extended_id=False, data=d, is_error_frame=e and i % 7 == 0)
            for i, (a, d, e) in enumerate(frames)]
    eps, acc = _run_can(msgs, layout, 5)
    acc.check()
    for ep in eps:                         # whatever passed its checksum: finite values, invalid ones are 0.0
        for k, y in ep.raw.items():
            assert np.all(np.isfinite(y)) and not np.any(y[~ep.valid[k]])


def _run_serial(stream, chunks):
    dec = SerialDecoder()
    return decode_pieces(dec, pieces(stream, chunks)), dec.accounting


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(list(SERIAL_ACTIONS)), min_size=20, max_size=20), st.integers(0, 2**32 - 1),
       st.lists(st.integers(0, 2000), max_size=10))
def test_serial_mutations_hypothesis(actions, seed, cuts):
    block = random_block(20)
    stream, oracle = mutate_serial(SerialDevice().frames(block), actions, np.random.default_rng(seed))
    bounds = sorted({0, len(stream), *[c for c in cuts if c < len(stream)]})
    eps, acc = _run_serial(stream, bounds)
    check_serial(eps, acc, oracle, block)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(0, 600), max_size=6))
def test_arbitrary_bytes_never_raise(data, cuts):
    _eps, acc = _run_serial(b"\xa5\x5a" + data, sorted({0, len(data) + 2, *[c for c in cuts if c < len(data)]}))
    acc.check()
    assert acc.pending == 0


def test_serial_seeded_long_run():
    n_bytes = 1_000_000
    frame_len = len(SerialDevice().frames(random_block(1))[0])
    n = n_bytes // frame_len
    block = random_block(n, seed=3)
    rng = np.random.default_rng(99)
    stream, oracle = mutate_serial(SerialDevice().frames(block), draw_actions(rng, n, SERIAL_ACTIONS), rng)
    cuts = np.unique(np.concatenate([[0, len(stream)], rng.integers(0, len(stream), len(stream) // 500)]))
    eps, acc = _run_serial(stream, cuts.tolist())
    rep = check_serial(eps, acc, oracle, block)
    assert rep["rejected"] > 0.1 * n_bytes * 0.5
