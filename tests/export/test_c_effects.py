"""The exported C compensation of every further effect against the Python runtime (rimu.fusion.Pipeline), sample
by sample: cone6 (Cho & Park Table 3), tetrad4 and triad3 units with every compensable effect at grade-typical
size (rimu.sim.typical), temperature ramping 10 -> 50 degC, rates up to ~600 deg/s and forces up to ~6 g; then
each effect alone, so that a wrong effect is named. Skips without a C compiler; clang is used too where present.
The Python reference is the numpy backend of the pipeline.
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from rimu.calibration.model import RuntimeInputs
from rimu.calibration.result import Calibration
from rimu.epoch import EpochBlock
from rimu.errors import ExportError
from rimu.export import export_c
from rimu.fusion import EffectCompensation, Pipeline
from rimu.geometry import tetrad4, triad3
from rimu.sim import cho_park_table3
from rimu.sim.truth import random_truth
from rimu.sim.typical import TYPICAL_EFFECTS, with_effects
from rimu.units import DEG_TO_RAD, G0

CC = shutil.which("cc") or shutil.which("gcc")
CLANG = shutil.which("clang")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
CFLAGS = "-std=c99 -Wall -Wextra -Werror -pedantic"
TOL = {"double": 1e-12, "float": 1e-5}


def _base(geometry: str) -> Calibration:
    if geometry == "cone6":
        cal = cho_park_table3()
    else:
        g = {"tetrad4": tetrad4(), "triad3": triad3()}[geometry]
        rng = np.random.default_rng(11)
        cal = Calibration({k: random_truth(g, k, rng) for k in ("gyro", "accel")})
    for k in cal.instruments:
        cal[k].noise_sigma = np.linspace(1.0, 1.5, cal[k].geometry.n) * (1e-3 if k == "gyro" else 1e-2)
    return cal


def _session(cal: Calibration, N: int, noise: bool, seed: int = 0):
    """Raw outputs of the calibrated model itself (every effect, EffectCompensation.forward) for random motion:
    rates ~N(0, 200 deg/s), forces ~N(0, 2 g) per axis, temperature 10 -> 50 degC, time from 100 s (the drift
    origin is the first sample); a few outputs are NaN (invalid: routed around by both runtimes)."""
    rng = np.random.default_rng(seed)
    t = 100.0 + np.arange(N) * 0.01
    T = 10.0 + 40.0 * np.arange(N) / N
    U = {"gyro": rng.standard_normal((N, 3)) * 200 * DEG_TO_RAD, "accel": rng.standard_normal((N, 3)) * 2 * G0}
    inputs = RuntimeInputs(t=t - t[0], temperature=T, specific_force=U["accel"], angular_rate=U["gyro"])
    raw = {}
    for k in cal.instruments:
        y = EffectCompensation(cal[k]).forward(U[k], inputs)
        if noise:
            y = y + rng.normal(0.0, 1.0, y.shape) * cal[k].noise_sigma / cal[k].scale
            y[rng.random(y.shape) < 0.01] = np.nan
        raw[k] = y
    return t, T, raw, U


def _build(cal: Calibration, d, real: str = "double", cc: str | None = None, opt: str = "-O2"):
    export_c(cal, d, real=real)
    res = subprocess.run(["make", "-s", f"CC={cc or CC}", f"CFLAGS={CFLAGS} {opt}"], cwd=d, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr  # -Wall -Wextra -Werror -pedantic clean
    return d / "rimu_filter"


def _run(exe, t, raw: dict, T=None) -> dict:
    rows = []
    for r in range(len(t)):
        cells = [repr(float(t[r]))]
        for k in raw:
            cells += ["" if not np.isfinite(v) else repr(float(v)) for v in raw[k][r]]
        if T is not None:
            cells.append(repr(float(T[r])))
        rows.append(",".join(cells))
    # --stats: the step's own statistics, without the redundancy manager's decisions (a filter without options
    # ignores it)
    res = subprocess.run([str(exe), "--stats"], input="\n".join(rows) + "\n", capture_output=True, text=True,
                         check=True)
    lines = res.stdout.strip().splitlines()
    head = lines[0].split(",")
    data = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]])
    return {h: data[:, j] for j, h in enumerate(head)}


def _compare(cal, c: dict, py: dict, tol: float) -> dict[str, float]:
    """Largest per-sample relative difference of the estimates (|dx|_inf / |x|_inf); observability equal and
    unobservable samples NaN in both (no estimate), every other a number."""
    worst = {}
    for k in cal.instruments:
        x = np.column_stack([c[f"{k}_x"], c[f"{k}_y"], c[f"{k}_z"]])
        obs = c[f"{k}_observable"].astype(bool)
        assert np.array_equal(obs, py[k].observable)
        assert np.all(np.isnan(x[~obs])) and np.all(np.isnan(py[k].x[~obs])) and np.all(np.isfinite(x[obs]))
        xp = py[k].x[obs]
        rel = np.abs(x[obs] - xp).max(axis=1) / np.abs(xp).max(axis=1)
        worst[k] = float(rel.max())
        assert worst[k] <= tol, (k, worst[k], int(np.argmax(rel)))
    return worst


@pytest.fixture(scope="module", params=["cone6", "tetrad4", "triad3"])
def unit(request, tmp_path_factory):
    """A unit with every compensable effect, its noisy session, the Python estimates and the C filters (double,
    float; gcc/cc, and clang where present), built once per geometry."""
    cal = with_effects(_base(request.param))
    if request.param == "tetrad4":  # a calibration's own reference temperature (25 degC by default)
        cal.metadata["reference_temperature"] = 35.0
    t, T, raw, _ = _session(cal, 2000, noise=True)
    py = Pipeline(cal, backend="numpy").process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T))
    d = tmp_path_factory.mktemp(f"ce_{request.param}")
    exes = {}
    if CC is not None:
        for real in ("double", "float"):
            exes["cc", real] = _build(cal, d / f"cc_{real}", real)
            if CLANG is not None:
                exes["clang", real] = _build(cal, d / f"clang_{real}", real, CLANG)
    return request.param, cal, t, T, raw, py, exes


@needs_cc
@pytest.mark.parametrize("compiler", ["cc", pytest.param("clang", marks=pytest.mark.skipif(
    CLANG is None, reason="clang is not installed"))])
@pytest.mark.parametrize("real", ["double", "float"])
def test_every_effect_matches_python_on_every_sample(unit, compiler, real):
    _, cal, t, T, raw, py, exes = unit
    assert set(cal["gyro"].effects) == set(TYPICAL_EFFECTS["gyro"])
    assert set(cal["accel"].effects) == set(TYPICAL_EFFECTS["accel"])
    c = _run(exes[compiler, real], t, raw, T)
    _compare(cal, c, py, TOL[real])
    if (compiler, real) != ("cc", "double"):
        return
    # the per-sample path (Pipeline.step) too, on the first 200 epochs
    pipe = Pipeline(cal, backend="numpy")
    block = EpochBlock(t[:200], {k: v[:200].copy() for k, v in raw.items()}, temperature=T[:200])
    for i, e in enumerate(block.epochs()):
        r = pipe.step(e)
        for k in cal.instruments:
            x = np.array([c[f"{k}_x"][i], c[f"{k}_y"][i], c[f"{k}_z"][i]])
            if not r[k].observable:  # no estimate: NaN on both sides
                assert np.all(np.isnan(x)) and np.all(np.isnan(r[k].x)), (k, i)
                continue
            assert np.abs(x - r[k].x).max() <= TOL[real] * max(np.abs(r[k].x).max(), 1e-300), (k, i)
    # the effects are not small against the tolerance: without them the estimate moves by far more
    plain = Calibration({k: type(cal[k])(k, cal[k].geometry, cal[k].scale, cal[k].misalignment, cal[k].bias,
                                         cal[k].noise_sigma) for k in cal.instruments})
    base = Pipeline(plain, backend="numpy").process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T))
    for k in cal.instruments:
        obs = py[k].observable
        assert np.abs(base[k].x[obs] - py[k].x[obs]).max() > 1e6 * TOL["double"] * np.abs(py[k].x[obs]).max()


def _single(instrument: str, name: str) -> Calibration:
    names = {"gyro": [], "accel": []}
    names[instrument] = [name]
    return with_effects(_base("cone6"), names)


@needs_cc
@pytest.mark.parametrize("instrument,effect", [(k, e) for k in ("gyro", "accel") for e in TYPICAL_EFFECTS[k]],
                         ids=lambda v: str(v))
def test_each_effect_alone(instrument, effect, tmp_path):
    """One effect at a time on cone6, noise-free: C equals Python to 1e-12 on every sample, and both return the
    true input of the forward model (the inversion is exact, not first order)."""
    cal = _single(instrument, effect)
    t, T, raw, U = _session(cal, 600, noise=False, seed=3)
    py = Pipeline(cal, backend="numpy").process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T))
    needs_t = "temperature" in EffectCompensation(cal[instrument]).needs
    c = _run(_build(cal, tmp_path / "c", opt="-O0"), t, raw, T if needs_t else None)
    _compare(cal, c, py, TOL["double"])
    for k in cal.instruments:
        x = np.column_stack([c[f"{k}_x"], c[f"{k}_y"], c[f"{k}_z"]])
        assert np.abs(x - U[k]).max() <= 1e-10 * np.abs(U[k]).max()


@needs_cc
@pytest.mark.parametrize("names", [{"gyro": ["g_sensitivity"], "accel": ["size_effect"]},
                                   {"gyro": ["g2_sensitivity", "sf_quadratic"], "accel": ["size_effect", "sf_cubic"]}],
                         ids=["cycle", "cycle+output-side"])
def test_the_gyro_accelerometer_cycle(names, tmp_path):
    """Both instruments need the other's estimate: the rounds of Pipeline._preliminary_rate, in C."""
    cal = with_effects(_base("tetrad4"), names)
    t, T, raw, U = _session(cal, 600, noise=False, seed=5)
    py = Pipeline(cal, backend="numpy").process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T))
    c = _run(_build(cal, tmp_path / "c"), t, raw)
    _compare(cal, c, py, TOL["double"])
    for k in cal.instruments:
        x = np.column_stack([c[f"{k}_x"], c[f"{k}_y"], c[f"{k}_z"]])
        assert np.abs(x - U[k]).max() <= 1e-10 * np.abs(U[k]).max()


@needs_cc
def test_temperature_column_is_required_when_needed(tmp_path):
    cal = _single("gyro", "bias_temperature")
    exe = _build(cal, tmp_path / "c")
    assert "#define RIMU_NEEDS_TEMPERATURE 1" in (tmp_path / "c" / "rimu_unit.h").read_text()
    t, _, raw, _ = _session(cal, 3, noise=False)
    row = ",".join([repr(float(t[0]))] + [repr(float(v)) for k in raw for v in raw[k][0]])
    res = subprocess.run([str(exe)], input=row + "\n", capture_output=True, text=True)
    assert res.returncode == 2 and "temperature" in res.stderr
    # without temperature effects the filter reads no such column, and rimu_step ignores its argument
    cal = _single("gyro", "sf_quadratic")
    _build(cal, tmp_path / "d")
    assert "#define RIMU_NEEDS_TEMPERATURE 0" in (tmp_path / "d" / "rimu_unit.h").read_text()


def test_refuses_what_it_cannot_compensate(tmp_path, monkeypatch):
    cal = _base("cone6")
    cal["gyro"].effects = {"earth_rate": {"x1.k": 1.0}}  # fitted and diagnosed, never compensated
    with pytest.raises(ExportError, match="earth_rate"):
        export_c(cal, tmp_path / "a")
    g = Calibration({"gyro": with_effects(_base("cone6"), {"gyro": ["g_sensitivity"], "accel": []})["gyro"]})
    with pytest.raises(ExportError, match="g_sensitivity.*accelerometers"):
        export_c(g, tmp_path / "b")
    # an effect without a compiled form (the Python runtime evaluates its runtime_columns): no C for it
    from rimu.calibration.effects.sf_quadratic import ScaleQuadratic

    monkeypatch.setattr(ScaleQuadratic, "runtime_form", lambda self, ctxs: None)
    with pytest.raises(ExportError, match="sf_quadratic.*compiled"):
        export_c(_single("gyro", "sf_quadratic"), tmp_path / "c")
    assert not (tmp_path / "c" / "rimu_unit.c").exists()


@needs_cc
def test_base_calibration_keeps_the_per_instrument_steps(tmp_path):
    """Without further effects the per-instrument steps stay public and rimu_step calls them."""
    cal = _base("triad3")
    _build(cal, tmp_path / "c")
    h = (tmp_path / "c" / "rimu_unit.h").read_text()
    assert "void rimu_gyro_step(" in h and "void rimu_accel_step(" in h and "void rimu_step(" in h
    cal = _single("accel", "size_effect")
    _build(cal, tmp_path / "d")
    h = (tmp_path / "d" / "rimu_unit.h").read_text()
    assert "void rimu_gyro_step(" in h and "void rimu_accel_step(" not in h
    # the parameters of rimu_step are gyros then accelerometers, whatever the calibration's order
    flipped = Calibration({"accel": cal["accel"], "gyro": cal["gyro"]})
    export_c(flipped, tmp_path / "e")
    h = (tmp_path / "e" / "rimu_unit.h").read_text()
    assert "rimu_step(rimu_real t, rimu_real temperature, const rimu_state *gyro_state," in h


@needs_cc
def test_the_documented_main_loop_compiles(tmp_path):
    """docs/flying.md's main-loop example compiles against the export of a unit with every effect."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "flying.md").read_text()
    snippet = doc.split("```c\n", 1)[1].split("```", 1)[0]
    export_c(with_effects(_base("cone6")), tmp_path)
    stubs = ("void use_rate(const rimu_real *x);\nextern const rimu_real threshold[];\n"
             "void hold_last_or_switch_source(void);\n")
    head, body = snippet.split("\n", 1)
    (tmp_path / "main_loop.c").write_text(head + "\n" + stubs + body)
    res = subprocess.run([CC, *CFLAGS.split(), "-c", "main_loop.c"], cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


@needs_cc
def test_cli_exports_a_calibration_file_with_effects(tmp_path, capsys):
    from rimu.cli import main

    cal = with_effects(_base("triad3"))
    cal.metadata["reference_temperature"] = 20.0
    cal.save(tmp_path / "cal.json")
    assert main(["export-c", str(tmp_path / "cal.json"), "-o", str(tmp_path / "c"), "--build"]) == 0
    assert "built" in capsys.readouterr().out
    h = (tmp_path / "c" / "rimu_unit.h").read_text()
    assert "#define RIMU_NEEDS_TEMPERATURE 1" in h and "#define RIMU_REFERENCE_TEMPERATURE 20.0" in h
    cal["gyro"].effects["earth_rate"] = {"x.k": 1.0}
    cal.save(tmp_path / "bad.json")
    assert main(["export-c", str(tmp_path / "bad.json"), "-o", str(tmp_path / "d")]) == 2
    assert "earth_rate" in capsys.readouterr().err


@needs_cc
def test_isolated_sensors_leave_the_compensation_too(tmp_path):
    """With a sensor of each instrument isolated (rimu_state.isolated), the estimates inside the compensation (cross
    coupling, the gyro <-> accelerometer rounds) leave it out, as the pipeline's active sets do in Python."""
    cal = with_effects(_base("cone6"))
    t, T, raw, _ = _session(cal, 500, noise=True, seed=9)
    raw["gyro"][:, 1] += 0.2 / cal["gyro"].scale[1]   # the isolated sensors are faulty: 0.2 rad/s, 0.5 m/s^2
    raw["accel"][:, 4] -= 0.5 / cal["accel"].scale[4]
    pipe = Pipeline(cal, backend="numpy")
    py = pipe.process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T),
                      active={"gyro": np.arange(6) != 1, "accel": np.arange(6) != 4})
    d = tmp_path / "c"
    export_c(cal, d)
    src = (d / "rimu_filter.c").read_text()
    mark = '    printf("t,'
    assert src.count(mark) == 1
    (d / "rimu_filter.c").write_text(src.replace(mark, "    st_gyro.isolated[1] = 1;\n    st_accel.isolated[4] = 1;\n"
                                                 + mark))
    res = subprocess.run(["make", "-s", f"CC={CC}", f"CFLAGS={CFLAGS} -O0"], cwd=d, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    c = _run(d / "rimu_filter", t, raw, T)
    _compare(cal, c, py, TOL["double"])
    assert np.all(c["gyro_dof"][c["gyro_observable"] == 1] <= 2)  # five sensors at most


@needs_cc
def test_many_axes_with_every_effect(tmp_path):
    """A 24-axis unit (one sub-unit: cross coupling with 23 partners per sensor) with every effect."""
    from rimu.geometry import cone

    g = cone(24, 40.0)
    rng = np.random.default_rng(2)
    cal = Calibration({k: random_truth(g, k, rng) for k in ("gyro", "accel")})
    for k in cal.instruments:
        cal[k].noise_sigma = np.full(g.n, 1e-3 if k == "gyro" else 1e-2)
    cal = with_effects(cal)
    t, T, raw, _ = _session(cal, 300, noise=True, seed=4)
    py = Pipeline(cal, backend="numpy").process(EpochBlock(t, {k: v.copy() for k, v in raw.items()}, temperature=T))
    c = _run(_build(cal, tmp_path / "c", opt="-O0"), t, raw, T)
    _compare(cal, c, py, TOL["double"])


@needs_cc
def test_float_coefficients_out_of_range(tmp_path):
    """In float, a coefficient below FLT_MIN is 0 (a literal that rounds to zero fails -Werror) and one above
    FLT_MAX is refused."""
    cal = _single("gyro", "sf_quadratic")
    cal["gyro"].effects["sf_quadratic"]["x1.k2"] = 1e-50
    _build(cal, tmp_path / "a", real="float")
    cal["gyro"].effects["sf_quadratic"]["x1.k2"] = 1e50
    with pytest.raises(ExportError, match="float range"):
        export_c(cal, tmp_path / "b", real="float")
    _build(cal, tmp_path / "c", real="double")


@needs_cc
def test_an_invalid_value_does_not_enter_the_compensation(tmp_path):
    """A value flagged invalid stays out of the compensation's estimates, whatever it holds: the filter made to
    store 1e6 (not 0) for an empty field gives the same numbers, bit for bit. (Python's Pipeline, which takes every
    finite output into those estimates, is moved by hundreds of rad/s by such a value.)"""
    cal = with_effects(_base("cone6"))
    t, T, raw, _ = _session(cal, 300, noise=True, seed=8)
    d = tmp_path / "c"
    ref = _run(_build(cal, d, opt="-O0"), t, raw, T)
    src = (d / "rimu_filter.c").read_text()
    assert src.count("*val = 0;") == 1
    (d / "rimu_filter.c").write_text(src.replace("*val = 0;", "*val = 1e6;"))
    res = subprocess.run(["make", "-s", f"CC={CC}", f"CFLAGS={CFLAGS} -O0"], cwd=d, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    c = _run(d / "rimu_filter", t, raw, T)
    assert any(not np.all(np.isfinite(v)) for v in raw.values())
    for h in ref:
        assert np.array_equal(c[h], ref[h]), h


@pytest.mark.skipif(shutil.which("cppcheck") is None, reason="cppcheck is not installed")
@pytest.mark.parametrize("effects", [{"gyro": ["g_sensitivity"], "accel": ["size_effect"]},
                                     {"gyro": ["g_sensitivity", "bias_temperature"]}], ids=["no-drift", "temperature"])
def test_effects_unit_misra_only_the_documented_deviations(tmp_path, effects):
    """rimu_unit.c of a unit with coupled effects and no drift term (the time not read) or no temperature term:
    MISRA C:2012 finds only the documented deviations (it assigned an int 0 to the real parameter t: rule 10.3,
    four findings)."""
    from rimu.export.misra import DEVIATIONS, misra_check

    export_c(with_effects(_base("cone6"), effects), tmp_path)
    found = misra_check(tmp_path)
    assert sum(found["misra"].values()) > 0
    assert set(found["misra"]) <= set(DEVIATIONS), set(found["misra"]) - set(DEVIATIONS)
    assert not found["other"], found["other"]
