"""Streaming a session file in chunks: the same samples as load_session, in memory that does not grow."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from rimu.errors import SessionFormatError
from rimu.session import load_session, save_session
from rimu.session.stream import iter_blocks
from rimu.sim import Simulator, cho_park_procedure


@pytest.fixture(scope="module")
def run():
    return Simulator(seed=2).run(cho_park_procedure(duration=2.0))


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
@pytest.mark.parametrize("chunk", [1, 777, 10**7])
def test_blocks_equal_the_loaded_session(tmp_path, run, suffix, chunk):
    if chunk == 1 and suffix == ".csv":
        chunk = 50  # tiny blocks are slow in CSV; 50 still cuts segments everywhere
    p = save_session(run.session, tmp_path / f"s{suffix}")
    s = load_session(p)
    blocks = list(iter_blocks(p, chunk=chunk))
    assert all(len(b) <= chunk for b in blocks)
    t = np.concatenate([b.t for b in blocks])
    seg = np.concatenate([b.meta["segment"] for b in blocks])
    assert np.array_equal(t, np.concatenate([x.t for x in s.segments]))
    labels = blocks[0].meta["labels"]
    assert [labels[k] for k in seg[np.r_[0, np.flatnonzero(np.diff(seg)) + 1]]] == [x.label for x in s.segments]
    for inst in ("gyro", "accel"):
        assert np.array_equal(np.vstack([b.raw[inst] for b in blocks]),
                              np.vstack([x.raw[inst] for x in s.segments]))


def _peak(fn) -> int:
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_memory_does_not_grow_with_the_file(tmp_path, suffix):
    """Reading 8x the samples in chunks of 1000 peaks at about the same memory (the chunk, not the file)."""
    peaks = []
    for dur in ((1.0, 8.0) if suffix == ".npz" else (0.5, 4.0)):
        p = save_session(Simulator(seed=3).run(cho_park_procedure(duration=dur)).session, tmp_path / f"d{dur}{suffix}")
        peaks.append(_peak(lambda p=p: sum(len(b) for b in iter_blocks(p, chunk=1000))))
    assert peaks[1] < 1.5 * peaks[0], peaks


def test_errors_name_the_row_and_column(tmp_path, run):
    p = save_session(run.session, tmp_path / "s.csv")
    lines = p.read_text().splitlines()
    lines[1500] = lines[1500].replace(lines[1500].split(",")[2], "oops", 1)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SessionFormatError, match=r"row 1501, column 'gyro|row 1501"):
        list(iter_blocks(p, chunk=700))
    q = save_session(run.session, tmp_path / "t.npz")
    data = q.read_bytes()
    q.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionFormatError):
        list(iter_blocks(q))
    with pytest.raises(SessionFormatError, match="at least 1"):
        list(iter_blocks(q, chunk=0))


def test_a_session_of_column_major_arrays_is_written_so_that_it_streams(tmp_path, run):
    """Segments holding Fortran-ordered raw arrays (what `rimu detect` builds from a CSV's columns) are saved
    C-ordered: the file streams (rimu replay read it as 'stored in Fortran order' before) with the same values."""
    from rimu.session import Segment, Session

    s = run.session
    segs = [Segment(x.label, x.kind, x.t, {k: np.asfortranarray(v) for k, v in x.raw.items()}, rate_mb=x.rate_mb,
                    mat_ln_mb=x.mat_ln_mb, angle_mb=x.angle_mb, specific_force_mb=x.specific_force_mb)
            for x in s.segments[:1]]  # one segment: its stacked array keeps the Fortran order
    one = Session(segs, s.geometries, s.sample_rate, s.latitude, s.gravity)
    assert not np.vstack([x.raw["gyro"] for x in one.segments]).flags["C_CONTIGUOUS"]
    p = save_session(one, tmp_path / "f.npz")
    blocks = list(iter_blocks(p, chunk=100))
    for inst in ("gyro", "accel"):
        assert np.array_equal(np.vstack([b.raw[inst] for b in blocks]), segs[0].raw[inst])
