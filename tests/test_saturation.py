"""Saturation and range (issue 19, item 3): a value at the range limit is invalid, not faulty -- routed around for
that sample, counted as saturated, the output DEGRADED while it lasts, never an isolation; the validity flag."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.calibration.result import document_text
from rimu.errors import ShapeError
from rimu.fdi import RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.fusion.validity import Validity
from rimu.geometry import cone6
from rimu.sim.multitriad import handheld_motion, random_multitriad, triad_array
from rimu.units import DS_TO_RS

RANGE = 3000.0


def _cal(range_raw=None):
    cal = InstrumentCalibration.nominal("gyro", cone6(), 0.001, 0.05, 0.002)
    cal.range_raw = range_raw
    return cal


def test_a_clipped_value_is_routed_around_and_counted_as_saturated():
    cal = _cal(np.full(6, RANGE))
    pipe, ref = InstrumentPipeline(cal), InstrumentPipeline(cal)
    u = np.array([0.5, -1.0, 0.8])
    y = cal.raw_output(u)
    r = pipe.step(y)
    assert r.validity == Validity.NOMINAL and not r.saturated.any()
    y_sat = y.copy()
    y_sat[2] = -RANGE  # clipped at the negative limit
    r = pipe.step(y_sat)
    np.testing.assert_allclose(r.x, ref.step(y_sat, active=np.arange(6) != 2).x, atol=1e-12)  # exactly the estimate without sensor 2
    np.testing.assert_allclose(r.x, u, atol=1e-9)
    assert r.validity == Validity.DEGRADED and r.saturated.tolist() == [False, False, True, False, False, False]
    assert not r.invalid.any() and r.dof == 2 and not r.active[2]
    assert pipe.saturated_count.tolist() == [0, 0, 1, 0, 0, 0] and pipe.invalid_count.sum() == 0
    r = pipe.step(y)
    assert r.validity == Validity.NOMINAL and not r.saturated.any() and r.dof == 3


def test_saturation_never_isolates_but_a_dropout_does():
    cal = _cal(np.full(6, RANGE))
    rng = np.random.default_rng(0)
    u = np.array([0.3, 0.2, -0.1])
    Y = cal.raw_output(u) + 2.0 * rng.standard_normal((600, 6))
    Y[100:500, 4] = RANGE  # 400 samples at the limit: 40 times invalid_persist
    mgr = RedundancyManager(InstrumentPipeline(cal), confirm=3, invalid_persist=10)
    res = mgr.run(Y)
    assert not mgr.isolated.any() and mgr.state.value == "nominal"
    assert not [e for e in res.events if e.kind in ("isolated", "invalid_isolated")]
    assert mgr.pipeline.saturated_count[4] == 400 and mgr.pipeline.invalid_count.sum() == 0
    assert np.abs(res.x[100:500] - u).max() < 0.05  # routed around: the estimate is good throughout
    # the same run without a known range: the clipped value is a gross fault and gets isolated
    mgr2 = RedundancyManager(InstrumentPipeline(_cal(None)), confirm=3)
    res2 = mgr2.run(Y)
    # (re-admitted once the values are clean again after sample 500)
    assert {e.sensor for e in res2.events if e.kind == "isolated"} == {cal.geometry.names[4]}
    # and a dropout (non-finite) of the same length is isolated after invalid_persist samples
    Yn = Y.copy()
    Yn[100:500, 4] = np.nan
    mgr3 = RedundancyManager(InstrumentPipeline(cal), confirm=3, invalid_persist=10)
    ev = mgr3.run(Yn).first("invalid_isolated")
    assert ev is not None and ev.sample == 109


def test_validity_over_a_block_and_unobservable_is_flagged_not_nan():
    cal = _cal(np.full(6, RANGE))
    pipe = InstrumentPipeline(cal)
    Y = np.tile(cal.raw_output(np.array([0.1, 0.2, 0.3])), (5, 1))
    Y[1, 0] = RANGE
    Y[2, [0, 1, 2, 3]] = RANGE  # two left: no estimate
    Y[3, 5] = np.nan
    blk = pipe.process(Y)
    assert blk.validity.tolist() == [Validity.NOMINAL, Validity.DEGRADED, Validity.UNOBSERVABLE, Validity.DEGRADED,
                                     Validity.NOMINAL]
    assert blk.saturated.sum(axis=1).tolist() == [0, 1, 4, 0, 0] and blk.invalid.sum(axis=1).tolist() == [0, 0, 0, 1, 0]
    assert np.all(np.isnan(blk.x[2])) and np.all(np.isfinite(np.delete(blk.x, 2, 0))) and not blk.observable[2]
    assert np.all(np.isinf(np.diag(blk.covariance()[2])))
    steps = [InstrumentPipeline(cal).step(y) for y in Y]
    assert [s.validity for s in steps] == blk.validity.tolist()
    # isolation also degrades: fewer sensors than expected
    assert pipe.step(Y[0], active=np.arange(6) != 3).validity == Validity.DEGRADED


def test_hand_held_motion_beyond_the_range_raises_no_isolation():
    """Four skewed triads turned by hand at 600 deg/s rms, gyros clipping at +-1000 deg/s (a few % of samples)."""
    g = triad_array(4, seed=3)
    truth = random_multitriad(g, scale_rel=0.0, misalignment_rad=0.0, time_offset_s=0.0, vibration=0.0, seed=1)
    lim = 1000 * DS_TO_RS
    t = np.arange(0, 20, 0.01)
    Y = truth.output(handheld_motion(600.0, seed=2), t, seed=3, range_raw=lim)
    clipped = np.abs(Y) >= lim
    assert 0.005 < clipped.mean() < 0.1
    mgr = RedundancyManager(InstrumentPipeline(truth.calibration(range_raw=lim)), confirm=3)
    res = mgr.run(Y)
    assert not mgr.isolated.any() and res.first("isolated") is None
    assert mgr.pipeline.saturated_count.sum() == clipped.sum()
    blind = RedundancyManager(InstrumentPipeline(truth.calibration()), confirm=3)  # range unknown
    assert blind.run(Y).first("isolated") is not None


def test_range_in_the_calibration_file_round_trips_and_old_files_load(tmp_path):
    cal = Calibration({"gyro": _cal(np.arange(1.0, 7.0) * 1000)})
    back = Calibration.load(cal.save(tmp_path / "c.json"))
    assert back["gyro"].range_raw.tolist() == [1000.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0]
    assert InstrumentPipeline(back["gyro"]).range_raw.tolist() == back["gyro"].range_raw.tolist()
    payload = cal.to_payload()
    del payload["instruments"]["gyro"]["range_raw"]  # a file written before the field existed
    del payload["instruments"]["gyro"]["units"]["range_raw"]
    old = tmp_path / "old.json"
    old.write_text(document_text(payload))
    assert Calibration.load(old)["gyro"].range_raw is None
    assert "range_raw" not in old.read_text()
    with pytest.raises(ShapeError, match="range_raw"):
        replace(_cal(), range_raw=np.zeros(6))
    assert InstrumentPipeline(back["gyro"], range_raw=10.0).range_raw.tolist() == [10.0] * 6  # argument wins
