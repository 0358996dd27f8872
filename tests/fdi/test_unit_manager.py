"""rimu.fdi.UnitManager: redundancy management closed loop with the compensation of further effects.

The re-admission of an isolated sensor with a large temperature effect, at the sample an independent evaluation of
the re-admission rule (the clean-period tests of rimu.fdi.health, written out here from its docstring) gives on
the compensated outputs; the residual of the raw output (what a manager fed the device's values computes) never
lets the sensor back. Without further effects the unit manager is the per-instrument managers.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.epoch import Epoch, EpochBlock
from rimu.fdi import RedundancyManager, UnitManager
from rimu.fusion import InstrumentPipeline, Pipeline
from rimu.geometry import cone, cone6

N, K0, K_CLEAR, R = 900, 200, 500, 100
SIG = 0.002          # rad/s per sample
J = 2                # the sensor with the temperature effect and the fault
T_REF, T_HOT = 25.0, 45.0
EFFECT_SIGMA = 40.0  # its temperature effect at T_HOT, in sigma


def _unit(effect_sigma=EFFECT_SIGMA):
    rng = np.random.default_rng(4)
    g = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0, noise_sigma=np.full(6, SIG))
    g.scale = 0.01 * (1 + 0.01 * rng.standard_normal(6))
    g.bias = 0.3 * rng.standard_normal(6)
    tc = np.sign(g.bias[J]) * effect_sigma * SIG / (T_HOT - T_REF)  # rad/s per degC, |raw| grows with it
    g.effects = {"bias_temperature": {f"{nm}.bias_tc1": (tc if i == J else 0.0) for i, nm in enumerate(g.geometry.names)}}
    return Calibration({"gyro": g}), tc


def _data(cal, tc, u=None):
    """Swinging rates (or ``u``, (N, 3) rad/s); the unit at the reference temperature until the fault, then heating to T_HOT; a 60 sigma
    bias on sensor J from K0 until K_CLEAR. Returns t, temperature, raw and the compensated outputs q (SI)."""
    rng = np.random.default_rng(9)
    g = cal["gyro"]
    t = np.arange(N) / 100.0
    T = np.clip(T_REF + (T_HOT - T_REF) * (np.arange(N) - K0) / 100.0, T_REF, T_HOT)
    if u is None:
        u = np.radians(30.0) * np.sin(2 * np.pi * t[:, None] / np.array([7.0, 11.0, 13.0]) + np.array([0.3, 1.0, 2.0]))
    q = u @ g.axes_mb().T + SIG * rng.standard_normal((N, 6))  # what an ideal sensor measures
    q_fault = q.copy()
    q_fault[K0:K_CLEAR, J] += 60 * SIG
    effect = np.zeros((N, 6))
    effect[:, J] = tc * (T - T_REF)
    raw = (q_fault + effect + g.bias) / g.scale                  # z = SF y - b = q + effect (+ fault)
    return t, T, raw, q


def _expected_readmission(z, axes, sig, j, start, p_fa=1e-3):
    """First sample at which the rule of rimu.fdi.health re-admits sensor j, from its normalised residual against
    the weighted least-squares estimate of the others: ``R`` consecutive samples each with z^2 < chi2_(1-1e-6)(1),
    then their mean (sum^2 / R < chi2_(1-p_fa)(1)) and energy (sum z^2 < chi2_(1-p_fa)(R)); a failed sample or a
    failed final test restarts the count. None if never."""
    others = np.arange(len(sig)) != j
    A, w = axes[others], 1.0 / sig[others] ** 2
    P = np.linalg.inv(A.T @ (A * w[:, None]))
    x = (z[:, others] * w) @ A @ P
    zn = (z[:, j] - x @ axes[j]) / np.sqrt(sig[j] ** 2 + axes[j] @ P @ axes[j])
    thr_s, thr_m, thr_e = chi2.isf(1e-6, 1), chi2.isf(p_fa, 1), chi2.isf(p_fa, R)
    n = s = ss = 0
    for k in range(start, len(zn)):
        if not zn[k] ** 2 < thr_s:
            n = s = ss = 0
            continue
        n, s, ss = n + 1, s + zn[k], ss + zn[k] ** 2
        if n == R:
            if s * s / R < thr_m and ss < thr_e:
                return k
            n = s = ss = 0
    return None


def test_readmitted_when_the_temperature_effect_is_compensated():
    cal, tc = _unit()
    t, T, raw, _ = _data(cal, tc)
    g = cal["gyro"]
    axes, sig = g.axes_mb(), np.full(6, SIG)
    # the compensated outputs (the effect removed), from the data and the calibration, not from rimu's runtime
    z_comp = raw * g.scale - g.bias
    z_comp[:, J] -= tc * (T - T_REF)
    expected = _expected_readmission(z_comp, axes, sig, J, K0)
    assert expected is not None and K_CLEAR + R - 1 <= expected < N - 50
    # the raw output's residual (the effect left in: 40 sigma while hot) never passes
    assert _expected_readmission(raw * g.scale - g.bias, axes, sig, J, K0) is None

    um = UnitManager(Pipeline(cal, temperature=True), confirm=3, readmit_after=R)
    res = um.run(EpochBlock(t, {"gyro": raw}, temperature=T))["gyro"]
    iso, back = res.first("isolated", "z1"), res.first("readmitted", "z1")
    assert iso is not None and K0 <= iso.sample < K0 + 10
    assert back is not None and back.sample == expected
    assert not res.alarm[iso.sample + 1:expected + 1].any()  # the others agree: nothing delays the clean period
    assert res.sensor_state[expected, J] == 0 and res.sensor_state[expected - 1, J] == 3  # RECOVERING -> HEALTHY
    # a manager fed the device's values (the residual of SF y - b, the effect left in): same isolation, never back
    raw_mgr = RedundancyManager(InstrumentPipeline(g), confirm=3, readmit_after=R).run(raw, None, t)
    assert raw_mgr.first("isolated", "z1").sample == iso.sample
    assert raw_mgr.first("readmitted") is None


def test_clipped_samples_restart_the_clean_period():
    """A clipped output is no measurement: an isolated sensor at its range limit on one sample of its clean period
    starts the period again (rimu.fusion.InstrumentPipeline.usable), in the unit manager as in the exported C
    (tests/export/test_c_fdi.py). A rate pulse along sensor J's axis in its clean period and its range set at the
    pulse's peak: that one sample is clipped while its value still agrees with the others (no temperature effect
    here, so that the clipped value, handed on uncompensated, is the compensated one)."""
    cal, tc = _unit(effect_sigma=0.0)
    g = cal["gyro"]
    clip_at = K_CLEAR + 40
    k = np.arange(N)[:, None]
    u = np.radians(5.0) * np.sin(k / 300.0 + np.array([0.0, 1.0, 2.0])) \
        + 0.5 * np.sign(g.bias[J]) * g.axes_mb()[J] * np.exp(-(((k - clip_at) / 8.0) ** 2))  # 250 sigma, |y| up
    t, T, raw, _ = _data(cal, tc, u)
    g.range_raw = np.full(6, 1e9)
    g.range_raw[J] = abs(raw[clip_at, J])
    assert np.array_equal(np.flatnonzero(np.abs(raw[:, J]) >= g.range_raw[J]), [clip_at])
    res = UnitManager(Pipeline(cal, temperature=True), confirm=3, readmit_after=R).run(
        EpochBlock(t, {"gyro": raw}, temperature=T))["gyro"]
    assert res.first("readmitted", "z1").sample == clip_at + R  # R clean samples after the clipped one
    g.range_raw = None  # the same data without a range: back at the end of the first clean period
    res = UnitManager(Pipeline(cal, temperature=True), confirm=3, readmit_after=R).run(
        EpochBlock(t, {"gyro": raw}, temperature=T))["gyro"]
    assert res.first("readmitted", "z1").sample == K_CLEAR + R - 1


def test_without_effects_it_is_the_instrument_managers():
    rng = np.random.default_rng(2)
    cal = Calibration({k: InstrumentCalibration.nominal(k, cone6(), 1.0, noise_sigma=0.01) for k in ("gyro", "accel")})
    Y = {k: cal[k].raw_output(np.array([0.1, 0.2, 0.3]))[None] + 0.01 * rng.standard_normal((300, 6)) for k in cal.instruments}
    Y["gyro"][100:150, 4] += 0.3
    Y["accel"][50:, 1] += 0.3
    t = np.arange(300) / 100.0
    um = UnitManager(Pipeline(cal), confirm=3, readmit_after=40).run(EpochBlock(t, {k: v.copy() for k, v in Y.items()}))
    stepped = UnitManager(Pipeline(cal), confirm=3, readmit_after=40)  # epoch by epoch: the same
    for i in range(300):
        r = stepped.step(Epoch(t[i], {k: Y[k][i] for k in Y}))
        assert all(np.array_equal(r[k].x, um[k].x[i]) for k in Y)
    for k in cal.instruments:
        ref = RedundancyManager(InstrumentPipeline(cal[k]), confirm=3, readmit_after=40).run(Y[k], None, t)
        assert np.array_equal(um[k].x, ref.x) and np.array_equal(um[k].sensor_state, ref.sensor_state)
        assert [(e.sample, e.kind, e.sensor) for e in um[k].events] == [(e.sample, e.kind, e.sensor) for e in ref.events]
    assert um["gyro"].first("readmitted") is not None and um["accel"].first("readmitted") is None


def test_managers_must_be_built_on_the_pipelines_own_instruments():
    cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)})
    pipe = Pipeline(cal)
    with pytest.raises(ValueError, match="own gyro pipeline"):
        UnitManager(pipe, {"gyro": RedundancyManager(InstrumentPipeline(cal["gyro"]))})
    with pytest.raises(TypeError, match="settings"):
        UnitManager(pipe, {"gyro": RedundancyManager(pipe["gyro"])}, confirm=2)


def test_run_in_blocks_is_the_closed_loop_epoch_by_epoch():
    """``UnitManager.run`` compensates runs of epochs at once with the sets of the run's start, stops a run where
    a set changes and redoes an epoch closed loop where a manager's estimate is not the compensation's (an alarm
    episode): its decisions must be those of :meth:`UnitManager.step` on every epoch,
    and its estimates within rounding, on a unit whose gyros take the accelerometers' estimate (g-sensitivity,
    the gyro <-> accelerometer cycle) through isolations, re-admissions, alarm episodes, clipped and invalid
    samples, whatever the length of a run."""
    from rimu.sim.typical import with_effects

    rng = np.random.default_rng(12)
    cals = {}
    for k, sig in (("gyro", 0.002), ("accel", 0.02)):
        c = InstrumentCalibration.nominal(k, cone6(), scale=1.0, noise_sigma=np.full(6, sig))
        c.scale = 0.01 * (1 + 0.01 * rng.standard_normal(6))
        c.bias = 0.3 * rng.standard_normal(6)
        cals[k] = c
    cal = with_effects(Calibration(cals))
    g = cal["gyro"]
    g.effects["g_sensitivity"] = {p: 10.0 * v for p, v in g.effects["g_sensitivity"].items()}
    n = 1200
    t = np.arange(n) / 100.0
    T = 20.0 + 10.0 * t / t[-1]
    w = np.radians(60.0) * np.sin(2 * np.pi * t[:, None] / np.array([7.0, 11.0, 13.0]))
    f = np.array([0.0, 0.0, -9.81]) + 3.0 * np.sin(2 * np.pi * t[:, None] / np.array([5.0, 3.0, 9.0]))
    from rimu.calibration.model import RuntimeInputs
    from rimu.fusion import EffectCompensation

    inputs = RuntimeInputs(t=t, temperature=T, specific_force=f, angular_rate=w)
    raw, valid = {}, {}
    for k, u in (("gyro", w), ("accel", f)):
        c = cal[k]
        z = EffectCompensation(c).forward(u, inputs)
        raw[k] = z + rng.standard_normal(z.shape) * c.noise_sigma / c.scale
        valid[k] = np.ones((n, 6), bool)
    raw["accel"][300:500, 2] += 40 * 0.02 / cal["accel"].scale[2]   # a fault that clears: isolated, re-admitted
    raw["gyro"][700:900, 4] += 8 * 0.002 / g.scale[4]               # a small one: alarm episodes before isolation
    valid["gyro"][1000:1004, 1] = False                             # invalid samples
    g.range_raw = np.quantile(np.abs(raw["gyro"]), 0.998, axis=0)   # a few clipped outputs
    raw["gyro"] = np.clip(raw["gyro"], -g.range_raw, g.range_raw)

    def block():
        return EpochBlock(t, {k: v.copy() for k, v in raw.items()}, {k: v.copy() for k, v in valid.items()}, T)

    def managers():
        return UnitManager(Pipeline(cal, temperature=True), confirm=3, readmit_after=R)

    um = managers()
    ref = {k: [] for k in cal.instruments}
    for ep in block().epochs():
        for k, r in um.step(ep).items():
            ref[k].append((r.x.copy(), r.validity, r.alarm, tuple(um.managers[k].health.isolated)))
    kinds = {e.kind for m in um.managers.values() for e in m.events}
    assert {"isolated", "readmitted"} <= kinds
    assert np.any(np.abs(raw["gyro"]) >= g.range_raw)
    for chunk in (1, 7, 4096):
        res = managers().run(block(), chunk=chunk)
        for k in cal.instruments:
            x = np.array([r[0] for r in ref[k]])
            assert np.abs(res[k].x - x).max() <= 1e-12 * np.abs(x).max(), (chunk, k)
            assert np.array_equal(res[k].alarm, [r[2] for r in ref[k]]), (chunk, k)
            assert np.array_equal(res[k].validity, [int(r[1]) for r in ref[k]]), (chunk, k)
            assert [(e.kind, e.t) for e in res[k].events] == [(e.kind, e.t) for e in um.managers[k].events]


def test_a_projection_cache_of_one_set_recomputes_for_every_caller():
    """Random set changes (invalid sensors, faults that get isolated and re-admitted) through the runtime with a
    projection cache of one set besides the full one: every caller (pipeline, detector, set test, remap, state)
    gets its set again when it was evicted, and the outputs are those of the default cache (issue 32 item 1:
    once ``KeyError: entry 39 is not in the projection cache``)."""
    from rimu.fdi import Runtime

    rng = np.random.default_rng(32)
    cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone(8, 50.0), 1.0, noise_sigma=0.01)})
    N = 1500
    u = 0.3 * np.sin(np.arange(N)[:, None] / np.array([70.0, 50.0, 110.0]))
    Y = cal["gyro"].raw_output(u) + 0.01 * rng.standard_normal((N, 8))
    valid = rng.random((N, 8)) > 0.03                     # scattered invalid samples: a new set almost every sample
    valid[600:640, 2] = False                             # one sensor out long enough to be isolated
    for a in range(200, N, 400):                          # faults on random sensors, isolated and re-admitted
        Y[a:a + 60, rng.integers(8)] += 0.3
    block = EpochBlock(np.arange(N) / 100.0, {"gyro": Y}, {"gyro": valid})
    small = Runtime(Pipeline(cal, cache_size=1), readmit_after=40).run(block)["gyro"]
    ref = Runtime(Pipeline(cal), readmit_after=40).run(block)["gyro"]
    assert Pipeline(cal, cache_size=1)["gyro"].table.cache_size == 1
    np.testing.assert_array_equal(small.validity, ref.validity)
    np.testing.assert_array_equal(small.sensor_state, ref.sensor_state)
    np.testing.assert_array_equal(small.active, ref.active)
    np.testing.assert_allclose(small.x, ref.x, rtol=0, atol=1e-12)
    assert [(e.kind, e.sensor, e.sample) for e in small.events] == [(e.kind, e.sensor, e.sample) for e in ref.events]
    kinds = {e.kind for e in ref.events}
    assert {"isolated", "readmitted", "invalid_isolated"} <= kinds, kinds
