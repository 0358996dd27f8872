"""Per-sensor health under real faults: dropouts, intermittent faults, stuck values, scale faults, all-NaN samples;
consistent per-sample results, explicit state, no silent noise default."""

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.errors import MissingNoiseError
from rimu.fdi import RedundancyManager
from rimu.fdi.health import SensorState
from rimu.fusion import InstrumentPipeline
from rimu.fusion.validity import Validity
from rimu.geometry import cone6

SIG = 0.01


def _unit(seed=0, n_samples=3000, amp=0.3):
    cal = InstrumentCalibration.nominal("gyro", cone6(), 0.002, bias=0.05, noise_sigma=SIG)
    rng = np.random.default_rng(seed)
    k = np.arange(n_samples)[:, None]
    u = np.array([0.2, -0.1, 0.3]) + amp * np.sin(2 * np.pi * k / 400.0 + np.array([0.0, 2.0, 4.0]))
    Y = cal.raw_output(u) + SIG / 0.002 * rng.standard_normal((n_samples, 6))
    return cal, u, Y


def _mgr(cal, **kw):
    kw.setdefault("confirm", 3)
    kw.setdefault("readmit_after", 100)
    return RedundancyManager(InstrumentPipeline(cal), sample_rate=100.0, **kw)


def test_dropout_on_four_channels_all_readmitted():
    """20 samples without data on four channels: unobservable meanwhile (never 'nominal'), three sensors isolated
    (the fourth would leave the unit blind), every one re-admitted once the data is back and clean."""
    cal, _u, Y = _unit(1, 1000)
    valid = np.ones(Y.shape, bool)
    valid[300:320, :4] = False
    Y[300:320, :4] = 0.0
    mgr = _mgr(cal, invalid_persist=10)
    res = mgr.run(Y, valid)
    assert (res.validity[300:320] == Validity.UNOBSERVABLE).all()
    assert set(res.state_names()[300:320]) == {"unobservable"}
    assert sum(1 for e in res.events if e.kind == "invalid_isolated") == 3
    back = [e for e in res.events if e.kind == "readmitted"]
    assert len(back) == 3 and all(e.sample < 320 + 100 + 5 for e in back)
    assert not mgr.isolated.any() and mgr.sensor_states == {n: "healthy" for n in mgr.names}
    assert (res.validity[450:] == Validity.NOMINAL).mean() > 0.98
    # no estimate while nothing spans 3-D: NaN there, and a state event that says so; numbers everywhere else
    assert np.array_equal(np.isnan(res.x).any(axis=1), res.validity == Validity.UNOBSERVABLE)
    assert np.all(np.isfinite(res.x[res.validity != Validity.UNOBSERVABLE]))
    gone = [e for e in res.events if e.kind == "state" and "-> unobservable" in e.message]
    assert [e.sample for e in gone] == [300] and "(2 sensors delivering usable data)" in gone[0].message


def test_all_nan_samples_are_unobservable_not_nominal():
    cal, _u, Y = _unit(2, 600)
    Y[200:260] = np.nan
    mgr = _mgr(cal)
    res = mgr.run(Y)
    assert (res.validity[200:260] == Validity.UNOBSERVABLE).all()
    assert "nominal" not in res.state_names()[200:260]
    # no estimate is NaN, never a plausible 0 rad/s; an event names it when it starts and when it ends
    assert np.all(np.isnan(res.x[200:260])) and np.all(np.isfinite(np.delete(res.x, np.s_[200:260], 0)))
    st = [(e.sample, e.message.split(" (")[0]) for e in res.events if e.kind == "state"]
    assert (200, "state nominal -> unobservable") in st and any(s == 260 and "unobservable ->" in m for s, m in st)
    assert "(0 sensors delivering usable data)" in res.first("state").message
    assert (res.n_active[200:260] == 0).all()
    assert not mgr.isolated.any()                     # everything re-admitted afterwards
    assert res.validity[-1] == Validity.NOMINAL


def test_intermittent_fault_no_ping_pong_and_readmitted_at_the_end():
    """A 15 sigma bias on z1 in bursts of 1 s every 4 s (five bursts), then clean: each burst isolates the sensor
    at most once, re-admission waits longer after each isolation (backoff), at the end it is back in."""
    cal, _u, Y = _unit(3, 4000)
    bursts = [(400 + 400 * b, 500 + 400 * b) for b in range(5)]
    for a, z in bursts:
        Y[a:z, 2] += 15 * SIG / 0.002
    mgr = _mgr(cal, fail_after=10)
    res = mgr.run(Y)
    iso = [e for e in res.events if e.kind == "isolated"]
    back = [e for e in res.events if e.kind == "readmitted"]
    assert {e.sensor for e in iso} == {"z1"} and 1 <= len(iso) <= len(bursts)
    assert all(any(a <= e.sample < z for a, z in bursts) for e in iso)   # isolated only during a burst
    assert len(back) == len(iso) and back[-1].sensor == "z1"
    assert not mgr.isolated.any() and res.transitions("z1") == 2 * len(iso)
    # the clean period doubles: gaps between a burst's end and the re-admission grow
    waits = [e.sample - max(z for a, z in bursts if z <= e.sample) for e in back]
    assert waits == sorted(waits)
    assert (res.validity[bursts[-1][1] + 900:] == Validity.NOMINAL).mean() > 0.98  # false alarms: a few samples


def test_fault_that_keeps_coming_back_ends_failed():
    cal, _u, Y = _unit(4, 6000)
    for b in range(10):
        Y[300 + 500 * b: 400 + 500 * b, 4] += 20 * SIG / 0.002
    mgr = _mgr(cal, fail_after=3, readmit_after=50, backoff=1.0)
    res = mgr.run(Y)
    assert mgr.sensor_states["y2"] == "failed" and mgr.isolated[4]
    assert sum(1 for e in res.events if e.kind == "isolated") == 3
    assert res.transitions("y2") == 5                        # in/out/in/out/in: bounded by 2 fail_after - 1
    mgr.readmit("y2")                                        # a command brings it back
    assert not mgr.isolated[4] and mgr.sensor_states["y2"] == "healthy"


def test_scale_fault_does_not_flap():
    """+3 % scale factor on y1 with an input swinging through zero: isolated, not switched in and out."""
    cal, _u, Y = _unit(5, 8000, amp=4.0)
    Y[1000:, 1] = (Y[1000:, 1] * 0.002 - 0.05) * 1.03 / 0.002 + 0.05 / 0.002  # 3 % on the SI output
    mgr = _mgr(cal)
    res = mgr.run(Y)
    assert mgr.isolated[1]
    assert res.transitions("y1") <= 3, [(e.kind, e.sample) for e in res.events if e.sensor == "y1"]
    assert sum(1 for e in res.events if e.kind == "isolated" and e.sensor != "y1") == 0


def test_stuck_sensor_isolated_and_estimate_unbiased():
    cal, u, Y = _unit(6, 2000)
    Y[500:, 3] = Y[500, 3]
    mgr = _mgr(cal)
    res = mgr.run(Y)
    assert mgr.isolated.tolist() == [False, False, False, True, False, False]
    P5 = mgr.pipeline.table.P[mgr.pipeline.result.entry]
    err = (res.x - u)[600:]
    z = err.mean(axis=0) / np.sqrt(np.diag(P5) / len(err))
    assert np.all(np.abs(z) < 4.5)
    assert (res.validity[600:] == Validity.DEGRADED).all()


def test_isolation_sample_is_consistent():
    """On every sample x, P, parity and active describe one set: x = G_e z and parity = Vz_e z for that set."""
    cal, _u, Y = _unit(7, 400)
    Y[200:, 4] += 12 * SIG / 0.002
    mgr = _mgr(cal)
    tab = mgr.pipeline.table
    Z = cal.scale * Y - cal.bias
    seen_exclusion = 0
    for k in range(len(Y)):
        r = mgr.step(Y[k])
        e = tab.entry_for(r.active)
        assert e == r.entry and np.array_equal(r.P, tab.P[e])
        np.testing.assert_allclose(r.x, tab.G[e] @ Z[k], atol=1e-9)
        np.testing.assert_allclose(r.parity[:r.dof], (tab.Vz[e] @ Z[k])[:r.dof], atol=1e-6)
        seen_exclusion += bool(r.alarm and not r.active[4])
        if k >= 200 and r.alarm:
            assert r.validity == Validity.DEGRADED
    assert mgr.isolated[4] and seen_exclusion >= 1
    # the isolation sample itself: logged sample k, and its output already without y2
    k_iso = next(e.sample for e in mgr.events if e.kind == "isolated")
    assert 200 <= k_iso < 210


def test_run_continues_state_and_reset_starts_over():
    cal, _u, Y = _unit(8, 1200)
    Y[400:, 0] += 12 * SIG / 0.002
    a = _mgr(cal)
    whole = a.run(Y)
    b = _mgr(cal)
    parts = [b.run(Y[:500]), b.run(Y[500:])]
    np.testing.assert_array_equal(whole.x, np.vstack([p.x for p in parts]))
    np.testing.assert_array_equal(whole.validity, np.concatenate([p.validity for p in parts]))
    assert [(e.kind, e.sample) for e in whole.events] == [(e.kind, e.sample) for p in parts for e in p.events]
    b.reset()
    again = b.run(Y)
    np.testing.assert_array_equal(whole.x, again.x)
    assert b.samples == len(Y)


def test_missing_noise_is_an_error_unless_given():
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0)
    with pytest.raises(MissingNoiseError, match="noise_sigma"):
        RedundancyManager(InstrumentPipeline(cal))
    mgr = RedundancyManager(InstrumentPipeline(cal, sigma=0.01))  # explicit: accepted
    assert mgr.pipeline.table.sigma[0] == 0.01
    assert issubclass(MissingNoiseError, ValueError)


def test_sensor_states_cover_the_machine():
    cal, _u, Y = _unit(9, 700)
    Y[100:400, 5] += 15 * SIG / 0.002
    mgr = _mgr(cal)
    res = mgr.run(Y)
    seen = set(np.unique(res.sensor_state[:, 5]).tolist())
    assert {SensorState.HEALTHY, SensorState.ISOLATED, SensorState.RECOVERING} <= seen
    assert res.sensor_state[-1, 5] == SensorState.HEALTHY
