"""The exported C runtime against the Python pipeline, sample by sample (skips without a C compiler)."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from rimu.calibration import ChoPark
from rimu.calibration.result import Calibration, InstrumentCalibration
from rimu.errors import ExportError
from rimu.export import export_c
from rimu.fusion import Pipeline
from rimu.geometry import cone, cone6, dodecahedron6, tetrad4, triad3
from rimu.sim import Simulator, cho_park_procedure

CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")


def _build(cal, tmp_path, real="double"):
    d = tmp_path / f"c_{real}"
    export_c(cal, d, real=real)
    subprocess.run(["make", "-s", f"CC={CC}"], cwd=d, check=True, capture_output=True, text=True)
    return d / "rimu_filter"


def _run(exe, t, raw: dict, valid: dict | None = None, T=None):
    cols = [t[:, None]] + [raw[k] for k in raw]
    rows = []
    for r in range(len(t)):
        cells = [repr(float(t[r]))]
        for k in raw:
            for i, v in enumerate(raw[k][r]):
                ok = valid is None or k not in valid or valid[k][r, i]
                cells.append(repr(float(v)) if ok else "")
        if T is not None:  # the temperature column, read by a filter whose effects need it
            cells.append(repr(float(T[r])))
        rows.append(",".join(cells))
    del cols
    res = subprocess.run([str(exe), "--stats"], input="\n".join(rows) + "\n", capture_output=True, text=True,
                         check=True)
    lines = res.stdout.strip().splitlines()
    head = lines[0].split(",")
    data = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]])
    return {h: data[:, j] for j, h in enumerate(head)}


@pytest.fixture(scope="module")
def unit():
    run = Simulator(seed=7).run(cho_park_procedure(duration=3.0))
    return run, ChoPark().fit(run.session).to_calibration()


def _python(cal, block, valid=None):
    blk = block if valid is None else type(block)(block.t, block.raw, valid)
    out = Pipeline(cal).process(blk)
    return out


@needs_cc
@pytest.mark.parametrize("real,tol", [("double", 1e-12), ("float", 1e-5)])
def test_cone6_matches_python_on_every_sample(unit, tmp_path, real, tol):
    run, cal = unit
    block = run.block
    n = min(len(block), 1500)
    t = block.t[:n]
    raw = {k: block.raw[k][:n] for k in cal.instruments}
    rng = np.random.default_rng(3)
    valid = {k: rng.random(raw[k].shape) > 0.02 for k in raw}  # invalid samples are routed around
    valid["gyro"][100, :4] = False                             # an unobservable sample (2 sensors left)
    exe = _build(cal, tmp_path, real)
    c = _run(exe, t, raw, valid)
    from rimu.epoch import EpochBlock

    py = Pipeline(cal).process(EpochBlock(t, {k: raw[k].copy() for k in raw}, {k: valid[k] for k in raw}))
    for k in cal.instruments:
        x = np.column_stack([c[f"{k}_x"], c[f"{k}_y"], c[f"{k}_z"]])
        obs = c[f"{k}_observable"].astype(bool)
        assert np.array_equal(obs, py[k].observable)
        scale = np.abs(py[k].x[obs]).max()
        assert np.max(np.abs(x[obs] - py[k].x[obs])) <= tol * scale * 10
        assert np.all(np.isnan(x[~obs])) and np.all(np.isfinite(x[obs]))  # no estimate: NaN, never a number
        assert np.array_equal(c[f"{k}_dof"][obs].astype(int), py[k].dof[obs])
        chi2_py = np.sum(py[k].parity[obs] ** 2, axis=1)
        assert np.allclose(c[f"{k}_chi2"][obs], chi2_py, rtol=max(tol, 1e-10) * 1e3, atol=1e-9 if real == "double" else 1e-3)
    assert not c["gyro_observable"][100]


@needs_cc
@pytest.mark.parametrize("geom", [tetrad4(), triad3(), dodecahedron6(), cone(24, 40.0)], ids=lambda g: g.name)
def test_other_geometries_and_many_axes(geom, tmp_path):
    """The same arithmetic for any geometry, 24 axes included (no table of active sets)."""
    rng = np.random.default_rng(5)
    cal = InstrumentCalibration.nominal("gyro", geom, scale=0.01, bias=0.3, noise_sigma=0.002)
    u = rng.normal(0, 1, (200, 3))
    y = np.array([cal.raw_output(v) for v in u]) + rng.normal(0, 0.2, (200, geom.n))
    exe = _build(Calibration({"gyro": cal}), tmp_path)
    c = _run(exe, np.arange(200) * 0.01, {"gyro": y})
    from rimu.fusion import InstrumentPipeline

    py = InstrumentPipeline(cal).process(y)  # active sets are computed when they occur: no table to limit
    x = np.column_stack([c["gyro_x"], c["gyro_y"], c["gyro_z"]])
    assert np.allclose(x, py.x, rtol=1e-12, atol=1e-12 * np.abs(py.x).max())
    assert np.allclose(c["gyro_chi2"], np.sum(py.parity ** 2, axis=1), rtol=1e-9, atol=1e-9)


def test_refuses_what_it_cannot_fly(tmp_path):
    cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.3)
    with pytest.raises(ExportError, match="noise_sigma"):
        export_c(Calibration({"gyro": cal}), tmp_path)
    cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.3, noise_sigma=0.01)
    cal.effects = {"g_sensitivity": {"x1.g_x": 1e-5}}
    with pytest.raises(ExportError, match="g_sensitivity"):
        export_c(Calibration({"gyro": cal}), tmp_path)
    with pytest.raises(ExportError, match="real"):
        export_c(Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, noise_sigma=0.1)}),
                 tmp_path, real="half")


@needs_cc
def test_cli_exports_and_builds(unit, tmp_path, capsys):
    from rimu.cli import main

    _, cal = unit
    cal.save(tmp_path / "cal.json")
    assert main(["export-c", str(tmp_path / "cal.json"), "-o", str(tmp_path / "c"), "--build"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "built" in out[0]
    assert (tmp_path / "c" / "rimu_filter").exists()


@needs_cc
@pytest.mark.parametrize("effects", [False, True], ids=["base", "every_effect"])
def test_saturated_outputs_are_routed_around_as_in_python(unit, tmp_path, effects):
    """A raw output at its range limit is no measurement: the Python runtime leaves it out of the estimate (and
    of the compensation's own estimates, handing it on as it came); the exported statistics-only ``rimu_step``
    must do the same, sample for sample, or the flight code would fly on a clipped gyro that Python ignores."""
    from rimu.epoch import EpochBlock

    run, cal = unit
    if effects:
        from rimu.sim.typical import with_effects

        cal = with_effects(cal, {"gyro": ["g_sensitivity", "sf_quadratic"], "accel": ["bias_temperature"]})
    block = run.block
    n = min(len(block), 1500)
    t = block.t[:n]
    raw = {k: block.raw[k][:n].copy() for k in cal.instruments}
    g = cal["gyro"]
    g.range_raw = np.quantile(np.abs(raw["gyro"]), 0.99, axis=0)   # about 1 % of the outputs clipped
    raw["gyro"] = np.clip(raw["gyro"], -g.range_raw, g.range_raw)
    clipped = np.abs(raw["gyro"]) >= g.range_raw
    assert clipped.any(axis=1).sum() >= 20
    T = np.full(n, 25.0)
    exe = _build(cal, tmp_path)
    c = _run(exe, t, raw, T=T if effects else None)
    py = Pipeline(cal, temperature=effects or None).process(
        EpochBlock(t, {k: raw[k].copy() for k in raw}, temperature=T if effects else None))
    for k in cal.instruments:
        x = np.column_stack([c[f"{k}_x"], c[f"{k}_y"], c[f"{k}_z"]])
        obs = c[f"{k}_observable"].astype(bool)
        assert np.array_equal(obs, py[k].observable)
        assert np.max(np.abs(x[obs] - py[k].x[obs])) <= 1e-12 * np.abs(py[k].x[obs]).max() * 10, k
        assert np.array_equal(c[f"{k}_dof"][obs].astype(int), py[k].dof[obs])
    rows = clipped.any(axis=1) & py["gyro"].observable
    assert np.all(c["gyro_dof"][rows] < 3)  # the clipped sensors were left out


@needs_cc
def test_filter_maps_columns_by_name_and_refuses_mismatches(unit, tmp_path):
    """The generated filter reads its header: rimu's own session CSV (with its segment column) runs; columns in
    another order give the same estimates; a file whose columns do not match the calibration is refused with one
    line and exit 2 (it used to be processed by position with exit 0)."""
    from rimu.session import save_session

    run, cal = unit
    exe = _build(cal, tmp_path)
    sess = type(run.session)(run.session.segments[:3], run.session.geometries, run.session.sample_rate,
                             run.session.latitude, run.session.gravity, run.session.raw_unit, run.session.meta)
    save_session(sess, tmp_path / "s.csv")
    text = (tmp_path / "s.csv").read_text()
    header, *rows = text.strip().splitlines()
    names = header.split(",")
    raw_cols = [j for j, n in enumerate(names) if n.startswith(("gyro_", "accel_"))]
    assert names[:2] == ["t", "segment"] and len(raw_cols) == 12
    ref = subprocess.run([str(exe), "--stats"], input=text, capture_output=True, text=True)
    assert ref.returncode == 0 and len(ref.stdout.splitlines()) == 1 + len(rows), ref.stderr
    # the same data, headerless, in the calibration's order (t and the 12 raw columns): the same estimates
    plain = "\n".join(",".join([c[0]] + [c[j] for j in raw_cols]) for c in (r.split(",") for r in rows)) + "\n"
    same = subprocess.run([str(exe), "--stats"], input=plain, capture_output=True, text=True)
    assert same.returncode == 0 and same.stdout == ref.stdout
    # columns shuffled under their header: mapped by name, the same estimates
    perm = np.random.default_rng(0).permutation(len(names))
    shuffled = "\n".join(",".join(np.array(r.split(","))[perm]) for r in [header] + rows) + "\n"
    out = subprocess.run([str(exe), "--stats"], input=shuffled, capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout == ref.stdout, out.stderr
    bad = {
        "7 columns, no header": ("\n".join(",".join(r.split(",")[:7]) for r in rows), "has 7 fields and no header"),
        "a missing column": ("\n".join(",".join(c for j, c in enumerate(r.split(",")) if j != 5)
                                       for r in [header] + rows), f"has no column {names[5]}"),
        "a repeated column": (header + "," + names[3] + "\n" + "\n".join(r + ",0" for r in rows), "twice"),
        "a short row": (header + "\n" + rows[0] + "\n" + ",".join(rows[1].split(",")[:-1]), f"row 3 has {len(names) - 1} fields"),
        "a word in a sensor column": (header + "\n" + rows[0].replace(rows[0].split(",")[4], "abc", 1),
                                      "not a number"),
    }
    for case, (data, msg) in bad.items():
        r = subprocess.run([str(exe), "--stats"], input=data + "\n", capture_output=True, text=True)
        err = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(err) == 1 and msg in err[0], (case, r.returncode, err)
