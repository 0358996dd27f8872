"""Times of the redundancy manager's samples and events: seconds from the sample rate (index / fs), the same
whether a stream goes through step() or through run() in blocks; sample indices when no rate is known."""

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.fdi import RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6


def _stream() -> tuple[InstrumentCalibration, np.ndarray]:
    cal = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0, noise_sigma=0.01)
    rng = np.random.default_rng(1)
    Y = cal.raw_output(np.tile([0.1, 0.2, 0.3], (400, 1))) + 0.01 * rng.standard_normal((400, 6))
    Y[250:, 4] += 0.3                                      # 30 sigma bias on y2 from sample 250
    return cal, Y


@pytest.mark.parametrize("fs", [200.0, None])
def test_run_times_are_index_over_sample_rate(fs):
    cal, Y = _stream()
    mgr = RedundancyManager(InstrumentPipeline(cal), sample_rate=fs)
    r1, r2 = mgr.run(Y[:100]), mgr.run(Y[100:])
    scale = 1.0 / fs if fs else 1.0
    np.testing.assert_allclose(np.concatenate([r1.t, r2.t]), np.arange(400) * scale, rtol=1e-15)
    events = r1.events + r2.events
    iso = [e for e in events if e.kind == "isolated"]
    assert [e.sensor for e in iso] == ["y2"] and iso[0].sample >= 250
    for e in events:
        assert e.t == pytest.approx(e.sample * scale, rel=1e-15)
    ref = RedundancyManager(InstrumentPipeline(cal), sample_rate=fs)
    for y in Y:
        ref.step(y)
    assert [(e.sample, e.t, e.kind) for e in ref.events] == [(e.sample, e.t, e.kind) for e in events]


def test_given_times_are_kept():
    cal, Y = _stream()
    t = 12.5 + np.arange(400) / 100.0
    res = RedundancyManager(InstrumentPipeline(cal), sample_rate=200.0).run(Y, None, t)
    np.testing.assert_array_equal(res.t, t)
    iso = next(e for e in res.events if e.kind == "isolated")
    assert iso.t == t[iso.sample]
