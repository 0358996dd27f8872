"""The exported C fault management against rimu.fdi.RedundancyManager, sample by sample (skips without a C compiler).

Seeded runs with the faults of the fault-management campaign (rimu.experiments.scenarios: bias step, two faults at once,
an intermittent fault that clears so the sensor is re-admitted, a dropout of several sensors, a stuck output, a
ramp) plus a noise burst, a fault that keeps coming back (FAILED after ``fail_after`` isolations) and invalid
samples, replayed through the Python manager and the generated ``rimu_filter``: the same validity, set state and
per-sensor state on every sample, the estimate within 1e-12 relative (double) and 1e-5 (float).
"""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pytest
from scipy.stats import chi2

from rimu.errors import ExportError, SessionFormatError
from rimu.experiments.scenarios import ScenarioSpec, _inject
from rimu.export import Estimates, FdiSettings, estimate_columns, export_c, read_estimates, write_estimates
from rimu.export.target import synthetic_unit
from rimu.fdi import Runtime
from rimu.fdi.health import SensorState
from rimu.fdi.manager import STATE_CODES
from rimu.geometry import cone, cone6, tetrad4, triad3

CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")

FS = 100.0
N = 1600
K0 = 400
SETTINGS = FdiSettings(readmit_after=100, fail_after=3)
KINDS = ("single", "double", "intermittent", "dropout", "stuck", "ramp", "burst", "repeat", "invalid", "triple",
         "scale")


def _build(cal, d, real="double", fdi=SETTINGS):
    return _build_all(cal, {real: d}, fdi)[real]


def _build_all(cal, dirs: dict, fdi=SETTINGS):
    """Export and build one filter per real type, the compilers running side by side."""
    procs = {}
    for real, d in dirs.items():
        export_c(cal, d, real=real, fdi=fdi)
        procs[real] = subprocess.Popen(["make", "-s", f"CC={CC}"], cwd=d, stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True)
    for real, p in procs.items():
        _, err = p.communicate()
        assert p.returncode == 0, f"the {real} build failed: {err}"
    return {real: d / "rimu_filter" for real, d in dirs.items()}


def _run(exe, t, raw: dict, valid: dict, *args, temperature=None):
    rows = []
    for r in range(len(t)):
        cells = [repr(float(t[r]))]
        for k in raw:
            cells += [repr(float(v)) if valid[k][r, i] else "" for i, v in enumerate(raw[k][r])]
        if temperature is not None:
            cells.append(repr(float(temperature[r])))
        rows.append(",".join(cells))
    res = subprocess.run([str(exe), *args], input="\n".join(rows) + "\n", capture_output=True,
                         text=True, check=True)
    return res.stdout


def _table(text):
    lines = text.strip().splitlines()
    head = lines[0].split(",")
    cols = list(zip(*[ln.split(",") for ln in lines[1:]]))
    return {h: cols[j] for j, h in enumerate(head)}


def _scenario(cal, kind, seed, clean=None):
    """Raw samples (N, n) and validity of one seeded run with one injected fault (sizes in sigma); ``clean``: the
    noise-free raw outputs (default those of the swinging rates through the calibration's SF, M, B)."""
    rng = np.random.default_rng(seed)
    n = cal.geometry.n
    sig = np.broadcast_to(cal.noise_sigma, (n,))
    t = np.arange(N)[:, None] / FS
    u = math.radians(30.0) * np.sin(2 * np.pi * t / np.array([7.0, 11.0, 13.0]) + rng.uniform(0, 2 * np.pi, 3))
    Y = (cal.raw_output(u) if clean is None else clean) + rng.standard_normal((N, n)) * (sig / cal.scale)
    valid = np.ones((N, n), bool)
    raw = sig / cal.scale
    if kind in ("single", "double", "intermittent", "dropout", "stuck", "ramp"):
        spec = ScenarioSpec(duration=N / FS, onset=K0 / FS, sample_rate=FS, ramp_sigma_per_s=5.0)
        _inject(kind, Y, valid, K0, rng, spec, sig, cal.scale)
    elif kind == "burst":  # noise 20 times the sensor's for 2 s, then clean again
        j = int(rng.integers(n))
        Y[K0:K0 + 200, j] += 20 * raw[j] * rng.standard_normal(200)
    elif kind == "repeat":  # a bias that comes back after every re-admission: FAILED after fail_after isolations
        j = int(rng.integers(n))
        for a in range(K0, N, 250):
            Y[a:a + 60, j] += 15 * raw[j]
    elif kind == "triple":  # three ramps at once: more faults than the set test names (not isolable, long episode)
        j = rng.choice(n, 3, replace=False)
        for a, rate in zip(j, (3.0, -5.0, 8.0)):
            Y[K0:, a] += rate * raw[a] * np.arange(N - K0) / FS
    elif kind == "scale":  # scale-factor errors on two sensors under the swinging rate: faults that change sign
        j = rng.choice(n, 2, replace=False)
        Y[K0:, j] *= np.array([1.03, 0.96])
    else:  # invalid samples: one sensor out for 40 samples (isolated, later re-admitted), short gaps elsewhere
        j = int(rng.integers(n))
        valid[K0:K0 + 40, j] = False
        Y[K0 + 100:K0 + 103, (j + 1) % n] = np.nan
        valid[K0 + 300:K0 + 305, (j + 2) % n] = False
    return Y, valid


def _unit(geom, instruments=("gyro",), seed=0):
    return synthetic_unit(geom, instruments, seed)  # rimu.export.target's one definition (with the target's tests)


class _Counting:
    """Counts the set tests on an episode's scatter over several samples (the path through rimu_chi2_isf)."""

    def __init__(self, mgr):
        self.n = 0
        iso = mgr.isolator
        orig = iso.decide_scatter

        def wrapped(M, samples, Vz, dof):
            self.n += samples > 1 and dof >= 2
            return orig(M, samples, Vz, dof)

        iso.decide_scatter = wrapped


def _python(cal, raws, valids, t):
    out, events, scatter = {}, set(), 0
    for k in cal.instruments:
        mgr = _manager(SETTINGS, cal[k])
        cnt = _Counting(mgr)
        out[k] = mgr.run(raws[k], valids[k], t)
        events |= {(e.kind, e.sensor) for e in out[k].events}
        scatter += cnt.n
    return out, events, scatter


def _compare(cal, c, py, real):
    """Differences per instrument: samples whose decisions differ, and the largest relative estimate error."""
    worst = 0.0
    diffs = 0
    for k in cal.instruments:
        r = py[k]
        val = np.array(c[f"{k}_validity"], int)
        st = np.array(c[f"{k}_state"], int)
        sens = np.array([[int(v) for v in s.split(";")] for s in c[f"{k}_sensors"]])
        iso = np.array([[str(i) in s.split(";") for i in range(cal[k].geometry.n)] for s in c[f"{k}_isolated"]])
        bad = (val != r.validity) | (st != r.state) | (sens != r.sensor_state).any(axis=1) \
            | (iso != (r.sensor_state >= SensorState.ISOLATED)).any(axis=1)
        diffs += int(bad.sum())
        x = np.column_stack([np.array(c[f"{k}_{a}"], float) for a in "xyz"])
        none = r.validity == 2  # no estimate: NaN in both, a number everywhere else
        assert np.array_equal(np.isnan(x).any(axis=1), none) and np.array_equal(np.isnan(r.x).any(axis=1), none)
        err = np.abs(np.nan_to_num(x) - np.nan_to_num(r.x)).max(axis=1) / np.nanmax(np.abs(r.x))
        if real == "float":
            # float rounding of the inputs grows with the conditioning of the sensor set in use: a set of three
            # neighbours of a cone of nine has a covariance hundreds of times the full set's. The error is divided by
            # sqrt(trace P / trace P_full), the amplification of that set (1 for the full set).
            tr = r.P_diag.sum(axis=1)
            amp = np.sqrt(np.where(np.isfinite(tr), tr, np.inf) / tr[np.isfinite(tr)].min())
            err = np.where(np.isfinite(amp), err / np.maximum(amp, 1.0), err)
        worst = max(worst, float(err.max()))
    return diffs, worst


GEOMS = {"cone6": (cone6(), ("gyro", "accel")), "tetrad4": (tetrad4(), ("gyro",)), "triad3": (triad3(), ("gyro",)),
         "cone9": (cone(9, 50.0), ("gyro",))}
#: what each geometry's runs must have shown (so that agreement is not agreement on nothing)
EXPECT = {"cone6": {"isolated", "readmitted", "invalid_isolated", "failed", "transient"},
          "tetrad4": {"detected_not_isolable", "not_isolable_cleared", "invalid_isolated", "readmitted"},
          "triad3": set(),
          "cone9": {"isolated", "readmitted", "invalid_isolated", "failed"}}


@needs_cc
@pytest.mark.parametrize("name", list(GEOMS))
def test_same_decisions_as_the_manager_on_every_sample(name, tmp_path):
    geom, insts = GEOMS[name]
    cal = _unit(geom, insts)
    exe = _build_all(cal, {real: tmp_path / real for real in ("double", "float")})
    t = np.arange(N) / FS
    kinds_seen: set[str] = set()
    scatter = 0
    pairs = 0
    samples = 0
    for s, kind in enumerate(KINDS):
        if geom.n < 4 and kind in ("double", "dropout", "triple", "scale"):
            continue
        raws, valids = {}, {}
        for i, k in enumerate(cal.instruments):
            raws[k], valids[k] = _scenario(cal[k], kind if i == 0 else "single", 100 * s + i)
        py, events, sc = _python(cal, raws, valids, t)
        kinds_seen |= {e[0] for e in events}
        scatter += sc
        pairs += sum(int(np.any(np.sum(r.sensor_state >= SensorState.ISOLATED, axis=1) >= 2)) for r in py.values())
        samples += N
        for real, tol in (("double", 1e-12), ("float", 1e-5)):
            c = _table(_run(exe[real], t, raws, valids, "--detail"))
            diffs, err = _compare(cal, c, py, real)
            assert diffs == 0, f"{name} {kind} ({real}): {diffs} samples with other decisions"
            assert err <= tol, f"{name} {kind} ({real}): estimate off by {err:.2e} relative"
    assert EXPECT[name] <= kinds_seen, f"{name}: the runs never showed {EXPECT[name] - kinds_seen}"
    if name == "cone9":
        assert scatter > 0   # the scatter test over an episode of several samples ran
        assert pairs > 0     # two sensors out at once (the two-fault run)
    if name == "triad3":
        # no redundancy: nothing to decide; an invalid sample leaves it without an estimate (a state event)
        assert kinds_seen <= {"invalid_transient", "state"}


#: calibration -> its runs with further effects, (gyro scenario[, accelerometer scenario]) each: isolations
#: followed by re-admission
EFFECT_RUNS = {"cone6_every_effect": [("intermittent", "single"), ("dropout", "intermittent"), ("repeat", "ramp"),
                                      ("invalid", "stuck")],
               "cone9_exogenous": [("intermittent",), ("repeat",)]}


def _effects_unit(name):
    """cone6 gyros and accelerometers with every compensable effect at typical size (the gyro <-> accelerometer
    cycle included), the gyros' temperature effect 30 times and their g-sensitivity 10 times typical (several sigma
    over the run); or cone9 gyros with temperature and drift effects only (compensated in the raw domain)."""
    from rimu.sim.typical import with_effects

    if name == "cone6_every_effect":
        cal = with_effects(_unit(cone6(), ("gyro", "accel")))
        scale = {"bias_temperature": 30.0, "g_sensitivity": 10.0}
    else:
        cal = with_effects(_unit(cone(9, 50.0)), {"gyro": ["bias_temperature", "bias_temperature2", "bias_drift"]})
        scale = {"bias_temperature": 30.0, "bias_drift": 10.0}
    g = cal["gyro"]
    for eff, f in scale.items():
        g.effects[eff] = {p: f * v for p, v in g.effects[eff].items()}
    return cal


def _effects_inputs(seed):
    """Time, temperature (10 -> 50 degC) and the true rates and specific forces of one run."""
    from rimu.calibration.model import RuntimeInputs
    from rimu.units import G0

    rng = np.random.default_rng([seed, 77])
    t = np.arange(N) / FS
    T = 10.0 + 40.0 * t / t[-1]
    ph = rng.uniform(0, 2 * np.pi, 6)
    w = math.radians(60.0) * np.sin(2 * np.pi * t[:, None] / np.array([7.0, 11.0, 13.0]) + ph[:3])
    f = np.array([0.0, 0.0, -G0]) + 3.0 * np.sin(2 * np.pi * t[:, None] / np.array([5.0, 3.0, 9.0]) + ph[3:])
    return t, T, {"gyro": w, "accel": f}, RuntimeInputs(t=t, temperature=T, specific_force=f, angular_rate=w)


@needs_cc
@pytest.mark.parametrize("name", list(EFFECT_RUNS))
def test_same_decisions_with_further_effects(name, tmp_path):
    """Further effects compensated (rimu.fdi.UnitManager against the generated rimu_fdi_step, the temperature
    column read by the filter): the same validity, set state, per-sensor states and isolated set on every sample
    in double, the estimates within 1e-12, through isolations, re-admissions, FAILED sensors, invalid and
    clipped samples. The effects change the decisions (managers fed the device's raw values decide otherwise),
    and the loop matters where the compensation estimates the input: compensating the whole record first with
    no sensor isolated (the compensation's own estimates then use the faulty sensors) moves the estimates by far
    more than 1e-12."""
    from rimu.epoch import EpochBlock
    from rimu.fusion import EffectCompensation, Pipeline

    cal = _effects_unit(name)
    g = cal["gyro"]
    _, _, U, inputs = _effects_inputs(0)
    g.range_raw = np.quantile(np.abs(EffectCompensation(g).forward(U["gyro"], inputs)), 0.997, axis=0)
    exe = _build(cal, tmp_path / "c")
    seen: set[str] = set()
    clipped = differs_raw = 0
    open_loop = 0.0
    for s, kinds in enumerate(EFFECT_RUNS[name]):
        t, T, U, inputs = _effects_inputs(s)
        raws, valids = {}, {}
        for i, k in enumerate(cal.instruments):
            clean = EffectCompensation(cal[k]).forward(U[k], inputs)
            raws[k], valids[k] = _scenario(cal[k], kinds[i], 1000 + 10 * s + i, clean)
        raws["gyro"] = np.clip(raws["gyro"], -g.range_raw, g.range_raw)
        clipped += int(np.sum(np.abs(raws["gyro"]) >= g.range_raw))
        block = EpochBlock(t, {k: v.copy() for k, v in raws.items()}, {k: v.copy() for k, v in valids.items()}, T)
        py = Runtime(cal, SETTINGS).run(block)
        seen |= {e.kind for r in py.values() for e in r.events}
        c = _table(_run(exe, t, raws, valids, "--detail", temperature=T))
        diffs, err = _compare(cal, c, py, "double")
        assert diffs == 0, f"{kinds}: {diffs} samples with other decisions"
        assert err <= 1e-12, f"{kinds}: estimate off by {err:.2e} relative"
        for k in cal.instruments:  # the device's values, effects left in
            r = _manager(SETTINGS, cal[k]).run(raws[k], valids[k], t)
            differs_raw += int(np.sum((r.sensor_state != py[k].sensor_state).any(axis=1)))
        comp = Pipeline(cal).compensate(block)
        ol = {k: _manager(SETTINGS, cal[k]).run(comp.raw[k], valids[k], t) for k in cal.instruments}
        open_loop = max(open_loop, _compare(cal, c, ol, "double")[1])
    assert {"isolated", "readmitted"} <= seen
    assert clipped > 0 and differs_raw > 0
    if name == "cone6_every_effect":
        assert {"invalid_isolated", "failed"} <= seen
        assert open_loop > 1e-9  # the cross coupling and the cycle estimate the input: the loop matters
    else:
        assert open_loop <= 1e-12  # exogenous effects only: nothing in the compensation depends on the set


@needs_cc
def test_filter_writes_the_estimates_file_of_the_replay(tmp_path):
    """The default output is exactly the estimates file: read back, it equals the manager's replay written by
    rimu.export.write_estimates."""
    cal = _unit(cone6(), ("gyro", "accel"))
    exe = _build(cal, tmp_path / "c")
    t = np.arange(N) / FS
    raws, valids = {}, {}
    for i, k in enumerate(cal.instruments):
        raws[k], valids[k] = _scenario(cal[k], ("intermittent", "dropout")[i], 7 + i)
    out = _run(exe, t, raws, valids)
    assert out.splitlines()[0].split(",") == estimate_columns(cal)
    (tmp_path / "c.csv").write_text(out)
    c = read_estimates(tmp_path / "c.csv", cal)
    py, _, _ = _python(cal, raws, valids, t)
    write_estimates(tmp_path / "py.csv", Estimates.from_replay(t, py))
    p = read_estimates(tmp_path / "py.csv", cal)
    assert np.array_equal(c.t, p.t)
    for k in cal.instruments:
        assert np.array_equal(c.validity[k], p.validity[k])
        assert np.array_equal(c.isolated[k], p.isolated[k])
        assert np.allclose(c.x[k], p.x[k], rtol=0, atol=1e-12 * np.nanmax(np.abs(p.x[k])), equal_nan=True)
    assert c.isolated["gyro"].any()            # the intermittent fault was isolated
    assert (c.validity["accel"] == 2).any()     # four of six accelerometers invalid: unobservable samples


def test_estimates_file_rejects_a_wrong_header_and_bad_cells(tmp_path):
    f = tmp_path / "e.csv"
    f.write_text("t,gyro_x,gyro_y,gyro_z,gyro_validity\n0,1,2,3,0\n")
    with pytest.raises(SessionFormatError, match="header"):
        read_estimates(f, {"gyro": 6})
    f.write_text("t,gyro_x,gyro_y,gyro_z,gyro_validity,gyro_isolated\n0,1,2,3,0,7\n")
    with pytest.raises(SessionFormatError, match="index"):
        read_estimates(f, {"gyro": 6})
    f.write_text("t,gyro_x,gyro_y,gyro_z,gyro_validity,gyro_isolated\n0,1,2,3,5,\n")
    with pytest.raises(SessionFormatError, match="validity"):
        read_estimates(f, {"gyro": 6})


def test_the_set_tests_thresholds_are_one_table_written_at_export(tmp_path):
    """The set test's consistency thresholds over an episode, chi2_{1-alpha}(N (dof - k)), are a finite table: the
    scatter pools at most scatter_window samples, the exported table holds scatter_window (n - 4) numbers, each
    scipy's quantile (the double export's literal is the same binary64 number), and the Python manager, on
    unresolved episodes of up to 15 samples (three ramps at once on cone6) with a window of 4, asks for no N
    beyond 4, reaches it, and gets the table's numbers. No chi-square quantile is left in the generated code."""
    import re

    st = FdiSettings(scatter_window=4)
    cal = _unit(cone6())
    export_c(cal, tmp_path, fdi=st)
    src = (tmp_path / "rimu_unit.c").read_text()
    cells = re.search(r"rimu_fdi_chi2\[RIMU_FDI_NU \+ 1\] = \{([^}]*)\}", src).group(1).split(",")
    table = np.array([float(v) for v in cells])
    assert len(table) == 4 * (6 - 4) + 1 == len(st.set_thresholds(6))
    assert np.array_equal(table[1:], chi2.isf(st.alpha, np.arange(1, len(table))))
    assert not re.search(r"rimu_chi2_isf|lgamma|log1p|\bexp\(|\blog\(", src)
    mgr = _manager(st, cal["gyro"])
    asked = []
    orig = mgr.isolator.threshold

    def threshold(dof, size, samples=1):
        asked.append((dof, size, samples))
        return orig(dof, size, samples)

    mgr.isolator.threshold = threshold
    Y, valid = _scenario(cal["gyro"], "triple", 5)
    mgr.run(Y, valid)
    assert mgr.counts["detected_not_isolable"] >= 1   # the episodes stayed unresolved
    samples = np.array([a[2] for a in asked])
    assert samples.max() == 4 and samples.min() >= 1 and np.sum(samples == 4) >= 2
    assert all(orig(d, k, n) == table[n * (d - k)] for d, k, n in set(asked))
    with pytest.raises(ExportError, match="scatter_window"):
        FdiSettings(scatter_window=7)


@needs_cc
def test_noise_model_and_saturation(tmp_path):
    """With a calibration noise model the manager whitens its detection statistic (rimu.fdi.whitening); the C
    code uses the equivalent least-squares residual weighted with the model's variances. Saturated samples are
    routed around (not invalid). Same decisions either way."""
    from rimu.noise.model import InstrumentNoise

    geom = cone6()
    cal = _unit(geom)
    g = cal["gyro"]
    n = geom.n
    g.noise = InstrumentNoise.from_terms("gyro", list(geom.names), FS, white=g.noise_sigma / math.sqrt(FS),
                                         bias_instability=np.linspace(1e-5, 3e-5, n), rate_random_walk=1e-6)
    g.range_raw = np.full(n, 60.0)
    Y, valid = _scenario(g, "single", 5)
    Y[900:905, 2] = 70.0  # saturated for 5 samples
    exe = _build(cal, tmp_path / "c")
    t = np.arange(N) / FS
    mgr = _manager(SETTINGS, g)
    assert mgr.detector.noise is not None
    r = mgr.run(Y, valid, t)
    assert r.first("isolated") is not None
    c = _table(_run(exe, t, {"gyro": Y}, {"gyro": valid}, "--detail"))
    diffs, err = _compare(cal, c, {"gyro": r}, "double")
    assert diffs == 0 and err <= 1e-12
    assert np.all(np.array(c["gyro_validity"], int)[900:905] == 1)
    # the whitened statistic itself (not only the decisions): |L p|^2 of the manager on the clean part
    stat = np.array(c["gyro_statistic"], float)[:K0]
    assert np.allclose(stat, r.statistic[:K0], rtol=1e-10)
    assert not np.allclose(stat, np.array(_table(_run(exe, t, {"gyro": Y}, {"gyro": valid}, "--stats"))
                                          ["gyro_chi2"], float)[:K0], rtol=1e-3)


def test_settings_are_checked():
    with pytest.raises(ExportError, match="max_size"):
        FdiSettings(max_size=3)
    with pytest.raises(ExportError, match="confirm"):
        FdiSettings(confirm=0)
    with pytest.raises(ExportError, match="p_fa"):
        FdiSettings(p_fa=1.5)
    # the tables baked into the code are the manager's thresholds
    s = FdiSettings(readmit_after=40, backoff=1.5, fail_after=4)
    assert s.required() == [40, 60, 90]
    assert np.isclose(s.energy()[0], chi2.isf(chi2.sf(chi2.isf(1e-3, 1), 1), 40))



def test_codes_in_the_header_are_the_python_enums(tmp_path):
    """The integers the filter prints (validity, set state, sensor state) are rimu's enums."""
    import re

    from rimu.fusion.validity import Validity

    export_c(_unit(cone6()), tmp_path)
    h = (tmp_path / "rimu_unit.h").read_text()
    defs = {m[1]: int(m[2]) for m in re.finditer(r"#define RIMU_(\w+) (\d+)\n", h)}
    for s, code in STATE_CODES.items():
        assert defs[f"STATE_{s.name}"] == code
    for v in Validity:
        assert defs[v.name] == int(v)
    for st in SensorState:
        assert defs[st.name] == int(st)


@needs_cc
def test_cli_bakes_the_manager_settings(tmp_path, capsys):
    """`rimu export-c --confirm 1 --readmit-after 20 --fail-after 2 --max-set-size 1 --build`: the filter makes
    the decisions of the manager with those settings (and not those of the defaults)."""
    from rimu.cli import main

    cal = _unit(cone6())
    cal.save(tmp_path / "cal.json")
    args = ["--confirm", "1", "--readmit-after", "20", "--fail-after", "2", "--max-set-size", "1", "--p-fa", "1e-4"]
    assert main(["export-c", str(tmp_path / "cal.json"), "-o", str(tmp_path / "c"), "--build", *args]) == 0
    assert "built" in capsys.readouterr().out
    s = FdiSettings(confirm=1, readmit_after=20, fail_after=2, max_size=1, p_fa=1e-4)
    Y, valid = _scenario(cal["gyro"], "repeat", 11)
    t = np.arange(N) / FS
    r = _manager(s, cal["gyro"]).run(Y, valid, t)
    c = _table(_run(tmp_path / "c" / "rimu_filter", t, {"gyro": Y}, {"gyro": valid}, "--detail"))
    assert _compare(cal, c, {"gyro": r}, "double")[0] == 0
    default = _manager(SETTINGS, cal["gyro"]).run(Y, valid, t)
    assert not np.array_equal(default.sensor_state, r.sensor_state)  # the settings matter on this run
    assert (r.sensor_state == SensorState.FAILED).any()


def _manager(settings, inst):
    """The Python manager of one instrument calibration with these settings (the C's decisions)."""
    from rimu.fdi import RedundancyManager
    from rimu.fusion import InstrumentPipeline

    return RedundancyManager(InstrumentPipeline(inst), **settings.manager_kwargs())
