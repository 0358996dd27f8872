"""Runtime compensation of every calibrated effect (issue 11): exact inversion of the calibrated model, step ==
block, inputs refused at build, and on held-out simulated sessions the error falls where users see it."""

from __future__ import annotations

import numpy as np
import pytest
from scenarios import SCENARIOS, _ctx, rich_procedure

from rimu.calibration import Calibration, InstrumentCalibration, LeastSquares
from rimu.calibration.model import ErrorModel, RuntimeInputs, effect
from rimu.epoch import EpochBlock
from rimu.errors import CalibrationFileError, MissingInputError, NotCompensableError
from rimu.fdi import RedundancyManager
from rimu.fusion import EffectCompensation, Pipeline, compensable_effects, replay_errors
from rimu.geometry import cone6
from rimu.sim import Simulator, TruthEffect, cho_park_table3
from rimu.sim.typical import TYPICAL_EFFECTS, effect_parameters, with_effects
from rimu.units import DEG_TO_RAD, G0

INSTS = ("gyro", "accel")

ALL_EFFECTS = TYPICAL_EFFECTS


def _params(name: str, instrument: str, theta, sensors, g) -> dict[str, float]:
    return effect_parameters(name, InstrumentCalibration.nominal(instrument, g), theta, sensors)


def _all_effects_calibration() -> Calibration:
    """Cho & Park Table 3 (misalignments up to 1.6 deg) with every compensable effect on every sensor."""
    base = cho_park_table3(gyro_sigma=1e-4)
    for k in INSTS:
        base[k].noise_sigma = np.full(6, 1e-3)
    return with_effects(base)


#: compensable effects without a compiled runtime form (the generic path evaluates them; the C export refuses them),
#: with their own tests: bias_temperature3 in tests/fdi/test_selfcal_tc3.py
GENERIC_ONLY = {"bias_temperature3"}


def test_every_compensable_effect_is_covered():
    """A new compensable effect must join the tables below (and earth_rate is the one that is not)."""
    assert set(compensable_effects()) == set(ALL_EFFECTS["gyro"]) | set(ALL_EFFECTS["accel"]) | GENERIC_ONLY
    assert set(compensable_effects()) - GENERIC_ONLY == set(SCENARIOS) - {"earth_rate"}


def _forward(cal: Calibration, U: dict[str, np.ndarray], t: np.ndarray, T: np.ndarray) -> dict[str, np.ndarray]:
    """Noise-free raw outputs of the calibrated model (the forward model of every effect)."""
    out = {}
    for k in INSTS:
        comp = EffectCompensation(cal[k])
        inputs = RuntimeInputs(t=t - t[0], temperature=T, specific_force=U["accel"], angular_rate=U["gyro"])
        out[k] = comp.forward(U[k], inputs)
    return out


def _random_inputs(rng, N):
    w = rng.standard_normal((N, 3)) * 150 * DEG_TO_RAD
    f = rng.standard_normal((N, 3)) * 0.8 * G0
    return {"gyro": w, "accel": f}


def test_exact_inversion_of_every_effect_at_once():
    """Forward model with every effect on both instruments (the g-sensitivity <-> size-effect cycle included), then
    the pipeline: the inputs come back to 1e-10 of their size, far below any effect (the first-order guess
    ``z - c(z)`` misses by ~1e-6)."""
    cal = _all_effects_calibration()
    rng = np.random.default_rng(11)
    N = 400
    t = 100.0 + np.arange(N) * 0.01
    T = 25.0 + 20.0 * rng.uniform(-1, 1, N)
    U = _random_inputs(rng, N)
    raw = _forward(cal, U, t, T)
    pipe = Pipeline(cal, temperature=True)
    out = pipe.process(EpochBlock(t, raw, temperature=T))
    for k in INSTS:
        scale = np.abs(U[k]).max()
        err = np.abs(out[k].x - U[k]).max() / scale
        assert err < 1e-10, (k, err)
        np.testing.assert_allclose(out[k].parity, 0.0, atol=1e-6)
    # without the stage the same data are off by the effects (so the check above can fail)
    base = Calibration({k: InstrumentCalibration(k, cal[k].geometry, cal[k].scale, cal[k].misalignment, cal[k].bias,
                                                 cal[k].noise_sigma) for k in INSTS})
    off = Pipeline(base).process(EpochBlock(t, raw, temperature=T))
    assert np.abs(off["gyro"].x - U["gyro"]).max() / np.abs(U["gyro"]).max() > 1e-4


def test_step_equals_block_with_every_effect():
    cal = _all_effects_calibration()
    rng = np.random.default_rng(12)
    N = 60
    t = np.arange(N) * 0.01
    T = 30.0 + rng.standard_normal(N)
    U = _random_inputs(rng, N)
    raw = _forward(cal, U, t, T)
    raw = {k: v + rng.standard_normal(v.shape) * 0.5 for k, v in raw.items()}
    raw["gyro"][7, 2] = np.nan  # an invalid sample is routed around in both paths
    block = EpochBlock(t, raw, temperature=T)
    blk = Pipeline(cal, temperature=True).process(block)
    pipe = Pipeline(cal, temperature=True)
    for k_ep, ep in enumerate(block.epochs()):
        r = pipe.step(ep)
        for k in INSTS:
            np.testing.assert_allclose(r[k].x, blk[k].x[k_ep], rtol=0, atol=1e-12 * max(1.0, np.abs(U[k]).max()))
            np.testing.assert_allclose(r[k].parity, blk[k].parity[k_ep], rtol=0, atol=1e-9)
    assert np.isfinite(blk["gyro"].x).all() and not blk["gyro"].active[7, 2]


def test_missing_inputs_are_refused_when_the_pipeline_is_built():
    cal = _all_effects_calibration()
    with pytest.raises(MissingInputError, match="bias_temperature.*temperature") as exc:
        Pipeline(cal, temperature=False)
    assert exc.value.input_name == "temperature"
    gyro_only = Calibration({"gyro": cal["gyro"]})
    with pytest.raises(MissingInputError, match="g_sensitivity.*specific force") as exc:
        Pipeline(gyro_only, temperature=True)
    assert exc.value.effect == "g_sensitivity"
    accel_only = Calibration({"accel": cal["accel"]})
    with pytest.raises(MissingInputError, match="size_effect.*angular rate"):
        Pipeline(accel_only, temperature=True)
    # temperature left open: a block without it is refused by name, not compensated with a guess
    pipe = Pipeline(cal)
    raw = {k: np.ones((3, 6)) for k in INSTS}
    with pytest.raises(MissingInputError, match="temperature"):
        pipe.process(EpochBlock(np.arange(3.0), raw))


def test_not_compensable_and_foreign_parameters_are_named():
    g = cone6()
    c = InstrumentCalibration.nominal("gyro", g, 0.01)
    c.effects = {"earth_rate": {f"{nm}.earth_k": 1.0 for nm in g.names}}
    with pytest.raises(NotCompensableError, match="earth_rate"):
        Pipeline(Calibration({"gyro": c}))
    c.effects = {"sf_quadratic": {"q9.k2": 1e-5}}
    with pytest.raises(CalibrationFileError, match="q9.k2"):
        Pipeline(Calibration({"gyro": c}))


# ---------------------------------------------------------------------------------------------- held-out replays
#: (instrument, coefficient multiplier against the diagnosis scenario): the scenario's grade-typical size, made
#: larger where it sits at the noise floor of these short sessions
CASES = {
    "sf_quadratic": ("gyro", 1.0),
    "sf_cubic": ("gyro", 3.0),
    "sf_asymmetry": ("gyro", 1.0),
    "g_sensitivity": ("gyro", 1.0),
    "g2_sensitivity": ("gyro", 2.0),
    "bias_temperature": ("gyro", 1.0),
    "bias_temperature2": ("accel", 1.0),
    "scale_temperature": ("gyro", 1.0),
    "scale_temperature2": ("gyro", 1.0),
    "bias_drift": ("gyro", 2.0),
    "size_effect": ("accel", 1.0),
    "cross_coupling": ("gyro", 1.0),
}
LOW_NOISE = {"arw_deg_sqrt_h": 0.03, "vrw_ug_sqrt_hz": 10.0}


def _simulate(name: str, seed: int):
    sc = SCENARIOS[name]
    k, mult = CASES[name]
    g = cone6()
    eff = effect(name)
    truth = {i: [mult * v for v in sc.theta(i)][: len(eff.physical_parameters(_ctx(k, g, i)))] for i in sc.sensors(g)}
    sim_kw = {**sc.sim, **LOW_NOISE}
    sim = Simulator({"gyro": g, "accel": cone6()}, sample_rate=20.0, effects={k: [TruthEffect(eff, truth)]},
                    seed=seed, **sim_kw)
    return sim.run(rich_procedure(static_s=4.0, rate_s=4.0)), truth


@pytest.mark.parametrize("name", sorted(CASES))
def test_held_out_replay_error_falls_with_the_effect(name):
    """Calibrate on one session, replay another of the same unit: the segment error with the effect in the model
    is >= 5x lower than without it and within 1.5x of the same pipeline with the true coefficients; a fault-free
    replay with the effect compensated raises no isolation."""
    k, _ = CASES[name]
    cal_run, truth = _simulate(name, seed=1)
    val_run, _ = _simulate(name, seed=2)
    sig = {i: cal_run.truth[i].noise_sigma / cal_run.truth[i].scale for i in INSTS}
    base = LeastSquares(ErrorModel.base(), sigma=sig).fit(cal_run.session).to_calibration()
    fitted = LeastSquares(ErrorModel.base() + name, sigma=sig, instruments=[k]).fit(cal_run.session).to_calibration()
    full = Calibration({i: fitted[i] if i == k else base[i] for i in INSTS})
    g = cone6()
    tr = val_run.truth
    true_cal = Calibration({i: InstrumentCalibration(i, g, tr[i].scale, tr[i].misalignment, tr[i].bias, tr[i].noise_sigma,
                                                     effects={name: _params(name, k, lambda j: truth[j], truth, g)}
                                                     if i == k else {}) for i in INSTS})
    e_base = replay_errors(val_run.session, base)[k].segment_error_rms
    e_full = replay_errors(val_run.session, full)[k].segment_error_rms
    e_true = replay_errors(val_run.session, true_cal)[k].segment_error_rms
    assert e_base >= 5.0 * e_full, (e_base, e_full)
    assert e_full <= 1.5 * e_true, (e_full, e_true)
    # fault-free: the FDI on the compensated stream isolates nothing
    pipe = Pipeline(full, temperature=True)
    comp = pipe.compensate(val_run.block)
    for i in INSTS:
        res = RedundancyManager(pipe[i], p_fa=1e-3, confirm=3).run(comp.raw[i], None, comp.t)
        assert not [e for e in res.events if e.kind == "isolated"], (i, res.events[:3])


def test_replay_cli_reports_the_runtime_error(tmp_path, capsys):
    """``rimu replay SESSION --calibration CAL -o DIR``: summary.json holds the same numbers as the API, and
    the calibration with the effect shows the lower error; ``--out`` still works."""
    import json

    from rimu.cli import main
    from rimu.session import save_session

    name = "g_sensitivity"
    cal_run, _ = _simulate(name, seed=1)
    val_run, _ = _simulate(name, seed=2)
    save_session(val_run.session, tmp_path / "val.npz")
    sig = {i: cal_run.truth[i].noise_sigma / cal_run.truth[i].scale for i in INSTS}
    base = LeastSquares(ErrorModel.base(), sigma=sig).fit(cal_run.session).to_calibration()
    gy = LeastSquares(ErrorModel.base() + name, sigma=sig, instruments=["gyro"]).fit(cal_run.session).to_calibration()
    full = Calibration({"gyro": gy["gyro"], "accel": base["accel"]})
    base.save(tmp_path / "base.json")
    full.save(tmp_path / "full.json")
    docs = {}
    for lab, flag in (("base", "--out"), ("full", "-o")):
        rc = main(["replay", str(tmp_path / "val.npz"), "--calibration", str(tmp_path / f"{lab}.json"),
                   flag, str(tmp_path / lab)])
        assert rc == 0
        docs[lab] = json.loads((tmp_path / lab / "summary.json").read_text())
    text = capsys.readouterr().out
    assert "segment_error_rms" in text and "isolation" in text.strip().splitlines()[-1]
    api = replay_errors(val_run.session, full)
    # the CLI reports the FDI manager's output, which leaves suspect sensors out on its (false) alarm samples;
    # the API replays the bare pipeline: equal but for those few samples
    assert docs["full"]["gyro"]["segment_error_rms"] == pytest.approx(api["gyro"].segment_error_rms, rel=1e-2)
    assert docs["full"]["accel"]["sample_error_rms"] == pytest.approx(api["accel"].sample_error_rms, rel=1e-2)
    assert docs["base"]["gyro"]["segment_error_rms"] > 4 * docs["full"]["gyro"]["segment_error_rms"]
    assert docs["full"]["gyro"]["isolations"] == 0 and docs["full"]["gyro"]["unit"] == "rad/s"


@pytest.mark.parametrize("instrument", INSTS)
def test_runtime_columns_equal_the_calibration_columns(instrument):
    """What the runtime subtracts is what the calibration fitted: for segments with known inputs, every effect's
    ``runtime_columns`` equal its ``columns`` (static positions, and rotations for the size effect)."""
    from rimu.calibration.model import contexts
    from rimu.sim.procedures import rotation, static

    def temp(t):
        return 30.0 + 10.0 * np.sin(t / 3.0)
    sim = Simulator({"gyro": cone6(), "accel": cone6()}, sample_rate=10.0, seed=3, temperature=temp)
    proc = [static("S1", np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81]), 2.0),
            rotation("R1", np.array([0.4, -1.1, 0.7]), 2.0)]
    session = sim.run(proc).session
    ctxs = contexts(session, instrument)
    for seg in session.segments:
        u = ctxs[0].input(seg)
        inputs = RuntimeInputs(t=seg.t, axis_input=u @ cone6().H.T, temperature=seg.temperature,
                               specific_force=seg.specific_force(session.gravity), angular_rate=seg.angular_rate(
                                   session.latitude, include_earth=False), input=u)
        for name in TYPICAL_EFFECTS[instrument]:
            eff = effect(name)
            rc = eff.runtime_columns(inputs, ctxs)
            for c in ctxs:
                col = eff.columns(seg, c)
                np.testing.assert_allclose(rc[:, c.index, :col.shape[1]], col, rtol=1e-12, atol=1e-12,
                                           err_msg=f"{name} {seg.label} {c.name}")


@pytest.mark.parametrize("instrument", INSTS)
def test_compiled_forms_equal_runtime_columns(instrument):
    """The compiled path (RuntimeForm matrices) gives the numbers of every effect's runtime_columns and slopes."""
    from rimu.fusion.effects import monomial_values

    cal = _all_effects_calibration()[instrument]
    comp = EffectCompensation(cal)
    assert not comp.has_generic
    rng = np.random.default_rng(5)
    N = 50
    U = _random_inputs(rng, N)
    s = rng.standard_normal((N, 6)) * 3.0
    inputs = RuntimeInputs(t=rng.uniform(0, 500, N), temperature=rng.uniform(-10, 60, N),
                           specific_force=U["accel"], angular_rate=U["gyro"])
    K = comp._coefficient_arrays(monomial_values(inputs, 25.0))
    ref = comp.exogenous_error(inputs)
    np.testing.assert_allclose(K.get("exo", 0.0), ref, rtol=1e-12, atol=1e-15 * np.abs(ref).max())
    inputs.input = rng.standard_normal((N, 3)) * 3.0
    c, dc = comp._output_poly(s, K, inputs)
    inputs.axis_input = s
    c_ref = comp.output_error(inputs)
    dc_ref = comp._sum(comp.output_side, inputs, slope=True)
    np.testing.assert_allclose(c, c_ref, rtol=1e-12, atol=1e-15 * np.abs(c_ref).max())
    np.testing.assert_allclose(dc, dc_ref, rtol=1e-12, atol=1e-15 * np.abs(dc_ref).max())
    # and the slope is the derivative of the columns (finite differences, own input only)
    h = 1e-6
    for i in range(6):
        sp = s.copy()
        sp[:, i] += h
        inputs.axis_input = sp
        num = (comp.output_error(inputs)[:, i] - c_ref[:, i]) / h
        np.testing.assert_allclose(dc_ref[:, i], num, rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("how", ["invalid", "saturated"])
def test_a_value_that_is_not_a_measurement_does_not_move_the_compensation(how):
    """The compensation's own estimates (the specific force for g-sensitivity, the rate for the size effect and
    cross coupling) leave out a value flagged invalid or clipped at the range limit, as the projection does: the
    outputs equal those with that value replaced by NaN, block and step (the exported C does the same). Before,
    a finite value flagged invalid moved the gyro estimate by hundreds of rad/s."""
    from rimu.epoch import Epoch

    cal = _all_effects_calibration()
    rng = np.random.default_rng(5)
    N = 50
    t = np.arange(N) * 0.01
    T = 25.0 + np.linspace(0, 5, N)
    Y = _forward(cal, _random_inputs(rng, N), t, T)
    valid = {k: np.ones((N, 6), bool) for k in INSTS}
    bad = {k: Y[k].copy() for k in INSTS}
    ref = {k: Y[k].copy() for k in INSTS}
    rng_raw = {k: None for k in INSTS}
    for k in INSTS:
        if how == "invalid":
            bad[k][::3, 2] = 1e4                      # a wild finite value, flagged invalid
            valid[k][::3, 2] = False
        else:
            rng_raw[k] = float(np.abs(Y[k]).max() * 1.5)
            bad[k][::3, 2] = rng_raw[k]               # clipped at the range limit
        ref[k][::3, 2] = np.nan
    for backend in ("numpy", "auto"):            # auto: the compiled backend when numba is installed
        pb = Pipeline(cal, range_raw=rng_raw, backend=backend)
        pr = Pipeline(cal, range_raw=rng_raw, backend=backend)
        out_b = pb.process(EpochBlock(t, bad, valid, T))
        out_r = pr.process(EpochBlock(t, ref, None, T))
        for k in INSTS:
            np.testing.assert_allclose(out_b[k].x, out_r[k].x, rtol=0, atol=1e-12 * np.abs(out_r[k].x).max())
        ps = Pipeline(cal, range_raw=rng_raw, backend=backend)
        for j in (0, 3, 6):
            r = ps.step(Epoch(float(t[j]), {k: bad[k][j] for k in INSTS}, {k: valid[k][j] for k in INSTS},
                              float(T[j])))
            for k in INSTS:
                np.testing.assert_allclose(r[k].x, out_r[k].x[j], rtol=0, atol=1e-12 * np.abs(out_r[k].x).max())
