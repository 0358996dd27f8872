"""The block fast path of RedundancyManager.run against the per-sample path: every output and event identical."""

import dataclasses

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.fdi import RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6

pytest.importorskip("numba", reason="the fast path needs the compiled backend (rimu[fast])")


def _stream(N: int = 6000, seed: int = 3) -> tuple[InstrumentCalibration, np.ndarray, np.ndarray]:
    cal = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0, noise_sigma=0.01)
    rng = np.random.default_rng(seed)
    w = 0.3 * np.sin(np.arange(N)[:, None] * np.array([1e-3, 2e-3, 3e-3]))
    Y = np.array([cal.raw_output(x) for x in w]) + 0.01 * rng.standard_normal((N, 6))
    valid = np.ones((N, 6), bool)
    Y[1000:1400, 2] += 0.3          # a bias fault on y3: isolated, then re-admitted once it is gone
    Y[2500:2503, 4] = np.nan        # a short dropout (routed around)
    valid[3000:3040, 1] = False     # flagged invalid long enough to isolate y2
    Y[4000:4005, 0] = 50.0          # clipped at the range
    Y[4500, 5] += 0.08              # a single-sample transient near the threshold
    Y[5000:5200, 3] += 0.02 * np.sin(np.arange(200))  # a small oscillating fault
    return cal, Y, valid


def _run(cal: InstrumentCalibration, Y: np.ndarray, valid: np.ndarray, chunks: list[int]):
    mgr = RedundancyManager(InstrumentPipeline(cal, range_raw=10.0, backend="numba"), sample_rate=1000.0,
                            readmit_after=50)
    out, k = [], 0
    for c in chunks:
        out.append(mgr.run(Y[k:k + c], valid[k:k + c]))
        k += c
    return out, mgr


def test_block_fast_path_equals_per_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    cal, Y, valid = _stream()
    chunks = [1000, 37, 2963, 2000]
    bulk = []
    quiet_block = RedundancyManager._quiet_block

    def counted(self, *a):
        bulk.append(quiet_block(self, *a))
        return bulk[-1]

    monkeypatch.setattr(RedundancyManager, "_quiet_block", counted)
    fast, mf = _run(cal, Y, valid, chunks)
    assert sum(bulk) > 0.8 * len(Y)  # the fast path took most samples
    monkeypatch.setattr(RedundancyManager, "_is_quiet", lambda self: False)
    slow, ms = _run(cal, Y, valid, chunks)
    kinds = {e.kind for r in slow for e in r.events}
    assert {"isolated", "readmitted", "invalid_isolated"} <= kinds, kinds  # the stream exercises the events
    for a, b in zip(fast, slow):
        for f in dataclasses.fields(a):
            va, vb = getattr(a, f.name), getattr(b, f.name)
            if isinstance(va, np.ndarray):
                np.testing.assert_array_equal(va, vb, err_msg=f.name)  # bit for bit, NaN where NaN
            else:
                assert va == vb, f.name
    assert mf.samples == ms.samples == len(Y) and mf.pipeline.samples == ms.pipeline.samples
    assert mf.counts == ms.counts and mf.health == ms.health
    np.testing.assert_array_equal(mf.result.x, ms.result.x)
