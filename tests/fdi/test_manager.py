"""The redundancy manager: Cho & Park's fault scenario, successive faults, the tetrad, transients, re-admission."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.calibration import InstrumentCalibration
from rimu.experiments.faults import FAULTS, Injection, inject
from rimu.fdi import CusumBank, GltWindow, HealthState, RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6, tetrad4
from rimu.sim import Simulator, rotation
from rimu.units import DS_TO_RS


@pytest.fixture(scope="module")
def manoeuvre():
    geo = cone6()
    sim = Simulator({"gyro": geo, "accel": geo}, seed=11)
    return sim.run([rotation("m", [0, 30 * DS_TO_RS, 0], duration=30.0)])


def test_cho_park_scenario_detected_isolated_output_continues(manoeuvre):
    """Gyro y2 at 15 s and accelerometer x1 at 20 s (Cho & Park 2005, Fig. 6), 10 sigma step biases."""
    run = manoeuvre
    cal = run.truth
    blk = inject(run.block, [Injection("bias", "gyro", "y2", 15.0, 10, True),
                             Injection("bias", "accel", "x1", 20.0, 10, True)], cal)
    for k, name, t_f in (("gyro", "y2", 15.0), ("accel", "x1", 20.0)):
        mgr = RedundancyManager(InstrumentPipeline(cal[k]), confirm=3, sample_rate=100.0)
        res = mgr.run(blk.raw[k], blk.valid.get(k), blk.t)
        iso = [e for e in res.events if e.kind == "isolated"]
        assert [e.sensor for e in iso] == [name]
        assert t_f <= iso[0].t < t_f + 0.2
        assert mgr.state is HealthState.FAULT_ISOLATED
        assert np.all(np.isfinite(res.x))
        # the output continues without the fault: after isolation the error is noise of the 5-sensor set
        err = res.x - run.truth_inputs[k]
        after = res.t > iso[0].t + 0.05
        P5 = mgr.pipeline.table.P[mgr.pipeline.result.entry]
        z = err[after].mean(axis=0) / np.sqrt(np.diag(P5) / after.sum())
        assert np.all(np.abs(z) < 4.5)
        ratio = err[after].std(axis=0) / np.sqrt(np.diag(P5))
        assert np.all(np.abs(ratio - 1) < 0.1)


def test_two_successive_faults_then_a_third(manoeuvre):
    run = manoeuvre
    cal = run.truth["gyro"]
    blk = inject(run.block, [Injection("bias", "gyro", "x1", 5.0, 10, True),
                             Injection("ramp", "gyro", "y2", 10.0, 10, True),
                             Injection("bias", "gyro", "z2", 20.0, 12, True)], run.truth)
    mgr = RedundancyManager(InstrumentPipeline(cal), confirm=3, sample_rate=100.0)
    res = mgr.run(blk.raw["gyro"], None, blk.t)
    iso = [e.sensor for e in res.events if e.kind == "isolated"]
    assert iso == ["x1", "y2"]
    states = res.state_names()
    k5, k15, _k25 = (np.searchsorted(res.t, s) for s in (4.9, 15.0, 25.0))
    assert states[k5] == "nominal" and states[k15] == "detection_only" and states[-1] == "detection_only"
    # the ramp is ambiguous while it is still small (flagged, then withdrawn when y2 is isolated); the third
    # fault is reported as not isolable and stays reported
    nf = [e for e in res.events if e.kind == "detected_not_isolable"]
    assert nf and nf[-1].t >= 20.0
    y2 = res.first("isolated", "y2")
    assert all(e.t < y2.t for e in nf[:-1])
    assert (res.validity[res.t > 21.0] == 1).all()
    assert mgr.health.fault_not_isolable
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.statistic))
    # a fourth isolation would leave three sensors: the manager never claims one it cannot make
    assert ((res.sensor_state >= 2).sum(axis=1) <= 2).all()
    assert (res.n_active >= 3).all()    # alarm samples may leave suspects out of their own output, never blind


def test_no_redundancy_and_unobservable_states():
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    mgr = RedundancyManager(InstrumentPipeline(cal))
    y = cal.raw_output(np.array([0.1, 0.2, 0.3]))
    for i, want, val in ((0, "fault_isolated", 1), (1, "detection_only", 1), (2, "no_redundancy", 1),
                         (3, "unobservable", 2)):
        mgr.isolate(i)                                   # by command: the manager owns the active set
        r = mgr.step(y)
        assert mgr.state.value == want and r.state.value == want and int(r.validity) == val
        assert r.active.sum() == 5 - i and not mgr.pipeline.result.active[i]
    assert not r.observable and np.all(np.isnan(r.x)) and np.all(np.isinf(np.diag(r.P)))
    mgr.pipeline.step(y)                                 # the pipeline alone, on every sensor: no isolation state
    assert mgr.pipeline.result.active.all()
    assert not mgr.step(y).active[0]                     # the manager's set is an argument of each of its steps
    mgr.reset()
    r = mgr.step(y)
    assert r.active.all() and r.validity == 0 and mgr.state.value == "nominal"


def test_tetrad_never_claims_an_isolation():
    g = tetrad4()
    cal = InstrumentCalibration.nominal("gyro", g, 1.0, noise_sigma=0.01)
    rng = np.random.default_rng(0)
    Y = cal.raw_output(np.array([0.2, -0.1, 0.3])) + 0.01 * rng.standard_normal((3000, 4))
    Y[1000:, 1] += 0.1
    mgr = RedundancyManager(InstrumentPipeline(cal), confirm=3)
    res = mgr.run(Y)
    assert mgr.state is HealthState.DETECTION_ONLY
    assert not any(e.kind == "isolated" for e in res.events)
    assert res.first("detected_not_isolable").sample >= 1000
    assert set(res.state_names()) == {"detection_only"}


def test_transients_logged_not_isolated_and_readmission(manoeuvre):
    run = manoeuvre
    cal = run.truth["gyro"]
    blk = inject(run.block, [Injection("dropout", "gyro", "x1", 3.0, 0, False, 0.03),     # 3 samples
                             Injection("spikes", "gyro", "z1", 6.0, 30, True, 4.0, {"rate": 2.0}),
                             Injection("dropout", "gyro", "y1", 12.0, 0, False, 0.5),      # 50 samples
                             Injection("bias", "gyro", "z2", 20.0, 10, True)], run.truth)
    mgr = RedundancyManager(InstrumentPipeline(cal), confirm=3, invalid_persist=10, readmit_after=200,
                            sample_rate=100.0)
    res = mgr.run(blk.raw["gyro"], blk.valid["gyro"], blk.t)
    kinds = [(e.kind, e.sensor) for e in res.events]
    assert ("invalid_transient", "x1") in kinds
    assert ("transient", "z1") in kinds and ("isolated", "z1") not in kinds
    iso_y1 = res.first("invalid_isolated", "y1")
    back = res.first("readmitted", "y1")
    assert iso_y1 is not None and 12.0 <= iso_y1.t < 12.2
    assert back is not None and back.t > 12.5 + 2.0 - 0.05
    # the biased sensor is isolated and stays out
    assert ("isolated", "z2") in kinds and res.first("readmitted", "z2") is None
    assert mgr.health.isolated == ["z2"]
    assert np.all(np.isfinite(res.x))


def test_non_finite_values_never_reach_the_outputs(manoeuvre):
    run = manoeuvre
    blk = inject(run.block, [Injection("nonfinite", "gyro", "x2", 5.0, 0, False, 0.05),
                             Injection("nonfinite", "gyro", "y1", 8.0)], run.truth)
    mgr = RedundancyManager(InstrumentPipeline(run.truth["gyro"]), sample_rate=100.0)
    res = mgr.run(blk.raw["gyro"], None, blk.t)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.statistic))
    assert res.first("invalid_transient", "x2") is not None
    assert res.first("invalid_isolated", "y1") is not None


@pytest.mark.parametrize("det", ["window", "cusum"])
def test_other_detectors_in_the_manager(manoeuvre, det):
    run = manoeuvre
    cal = run.truth["gyro"]
    blk = inject(run.block, [Injection("bias", "gyro", "y2", 15.0, 4 if det == "cusum" else 8, True)], run.truth)
    pipe = InstrumentPipeline(cal)
    d = GltWindow(5) if det == "window" else CusumBank(2.0 * pipe.table.sigma, 1e5)
    mgr = RedundancyManager(pipe, d, confirm=1 if det == "cusum" else 3, sample_rate=100.0)
    res = mgr.run(blk.raw["gyro"], None, blk.t)
    iso = [e for e in res.events if e.kind == "isolated"]
    assert [e.sensor for e in iso] == ["y2"] and iso[0].t >= 15.0


# (type, sensor, start s, size sigma, duration s or None)
_fault = st.tuples(st.sampled_from(sorted(FAULTS)), st.integers(0, 5), st.floats(0.2, 2.5),
                   st.floats(0.0, 30.0), st.one_of(st.none(), st.floats(0.01, 1.0)))


@settings(max_examples=15, deadline=None)
@given(faults=st.lists(_fault, min_size=1, max_size=4), seed=st.integers(0, 1000))
def test_any_fault_sequence_keeps_the_invariants(faults, seed):
    """Whatever happens: outputs finite, the state matches the active set, isolation only where isolable."""
    cal = InstrumentCalibration.nominal("gyro", cone6(), 0.001, bias=0.1, noise_sigma=0.01)
    rng = np.random.default_rng(seed)
    N = 300
    t = np.arange(N) / 100.0
    u = np.array([0.3, -0.2, 0.5]) + 0.1 * np.sin(t)[:, None]
    from rimu.calibration import Calibration
    from rimu.epoch import EpochBlock

    blk = EpochBlock(t, {"gyro": cal.raw_output(u) + 0.01 / 0.001 * rng.standard_normal((N, 6))})
    inj = [Injection(k, "gyro", i, start, size, True, dur) for k, i, start, size, dur in faults]
    blk = inject(blk, inj, Calibration({"gyro": cal}), seed=seed)
    mgr = RedundancyManager(InstrumentPipeline(cal), confirm=2, invalid_persist=5, readmit_after=50,
                            sample_rate=100.0)
    res = mgr.run(blk.raw["gyro"], blk.valid["gyro"], t)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.statistic))
    assert sum(1 for e in res.events if e.kind == "isolated") <= 2 + sum(1 for e in res.events if e.kind == "readmitted")
    n_act = 6 - len(mgr.health.isolated)
    assert int(res.n_active[-1]) <= n_act   # alarm samples may leave suspects out of their own output
    expect = {6: {"nominal", "fault_isolated"}, 5: {"fault_isolated"}, 4: {"detection_only"},
              3: {"no_redundancy"}}.get(n_act, {"unobservable"})
    assert mgr.state.value in expect


def test_the_state_changes_on_the_isolation_sample():
    """Cho & Park's scenario (gyro y2 fails, 10 sigma step): on the sample of the ``isolated`` event the state, the
    active set, x, P and the parity already describe the set without y2, and the ``state`` event carries that
    sample (before: the state changed one sample after the isolation that caused it)."""
    from rimu.sim import Simulator, rotation
    from rimu.units import DS_TO_RS

    sim = Simulator(seed=4)
    run = sim.run([rotation("M", [0, 30 * DS_TO_RS, 0], duration=6.0)])
    cal = run.truth["gyro"]
    Y = run.block.raw["gyro"].copy()
    i = cal.geometry.index("y2")
    Y[run.block.t >= 3.0, i] += 10 * sim.noise_sigma("gyro") / cal.scale[i]
    mgr = RedundancyManager(InstrumentPipeline(cal), sample_rate=sim.sample_rate)
    res = mgr.run(Y)
    iso = res.first("isolated", "y2")
    k = iso.sample
    assert res.state_names()[k] == "fault_isolated" and not res.active[k, i]
    # on every sample the state is the state of the set the estimate used (all six: nominal; five: fault_isolated,
    # on the alarm samples before the confirmation too, where y2 is already left out as the suspect)
    names = np.array(res.state_names())
    five = res.active.sum(axis=1) == 5
    assert set(names[five]) == {"fault_isolated"} and set(names[res.active.all(axis=1)]) == {"nominal"}
    assert five[:k].any() and not five[:int(3.0 * sim.sample_rate)].any()
    assert res.first("state").sample == k and "-> fault_isolated" in res.first("state").message
    assert np.allclose(res.P_diag[k], np.diag(mgr.pipeline.table.get(mgr.pipeline.table.full_code & ~(1 << i)).P))
