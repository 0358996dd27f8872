"""Real data (the Ferraris hand calibration), the report and the command line."""

import json
from pathlib import Path

import numpy as np
import pytest
from scenarios import known_sigma, simulate

from rimu.cli import main
from rimu.diagnose import diagnose, iterate, write_report
from rimu.session import load_ferraris


def _ferraris() -> Path:
    here = Path(__file__).resolve()
    for base in (here.parents[2] / ".." / "shared" / "data", Path("/work/shared/data")):
        p = base / "imucal_ferraris_session"
        if (p / "example_ferraris_session.csv").exists():
            return p
    pytest.skip("the Ferraris recording is not available")


def test_real_ferraris_diagnosis_improves_fit_and_report_renders(tmp_path):
    session = load_ferraris(_ferraris())
    it = iterate(session)
    start = it.rounds[0][0] if it.rounds else it.final
    acc = start["accel"]
    # the gyros cannot be diagnosed sample by sample (rotations are angle segments): said, with the reason
    assert "angle" in start.errors["gyro"]
    # the base model does not explain this real sensor; the diagnosis names what improves it and by how much
    assert acc.fit.chi2_dof > 1.2
    assert it.rounds, "some effect should improve the fit of the real accelerometers"
    comps = [c for _, cs in it.rounds for c in cs.values()]
    first = comps[0]
    assert first.chi2_after < first.chi2_before
    assert np.all(first.after.rms_si() <= first.before.rms_si())
    print("\n".join(first.lines()))
    # untestable things are said with the test that would make them testable
    nt = {c.name: c for c in acc.not_testable}
    assert "bias_temperature" in nt and "temperature" in nt["bias_temperature"].reason
    assert "cross_coupling" in nt and "45 deg" in nt["cross_coupling"].advice
    # sf_quadratic and sf_asymmetry are indistinguishable with axis-aligned positions only: |f| = g on the axis
    groups = [f.effects for f in it.final["accel"].findings if f.confounded]
    assert any({"sf_quadratic", "sf_asymmetry"} <= set(g) for g in groups) or it.final["accel"].nothing_missing
    md = write_report(it, tmp_path / "rep")
    text = md.read_text()
    assert "## accel" in text and "Add it and watch the error fall" in text and "Not testable" in text
    for line in text.splitlines():
        if line.startswith("!["):
            assert (md.parent / line.split("](")[1].rstrip(")")).exists(), line
    assert (tmp_path / "rep" / "report.html").read_text().count("<img") >= 4
    json.loads((tmp_path / "rep" / "diagnosis.json").read_text())


def test_cli_on_simulated_npz_with_add_report_and_json(tmp_path, capsys):
    npz = tmp_path / "s.npz"
    assert main(["simulate", "--procedure", "cho_park", "--sample-rate", "10", "--seed", "1", "-o", str(npz)]) == 0
    capsys.readouterr()
    assert main(["diagnose", str(npz), "--add", "g_sensitivity", "--json"]) == 0
    out = capsys.readouterr().out
    data = json.loads(out)
    assert set(data["diagnosis"]["instruments"]) == {"gyro", "accel"}
    # clean simulated data: nothing missing, and adding g-sensitivity changes chi2/dof only by noise
    assert data["diagnosis"]["nothing_missing"]
    comp = data["comparisons"][0]
    assert comp["added"] == ["g_sensitivity"] and abs(comp["chi2_after"] - comp["chi2_before"]) < 0.01


def test_cli_reads_the_csv_session_format(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--procedure", "cho_park", "--sample-rate", "10", "--seed", "3", "-o", str(csv)]) == 0
    capsys.readouterr()
    assert main(["diagnose", str(csv), "--instrument", "accel", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert list(data["diagnosis"]["instruments"]) == ["accel"]
    assert data["diagnosis"]["nothing_missing"]


def test_cli_text_lists_effects_and_errors(tmp_path, capsys):
    assert main(["diagnose", "x", "--list-effects"]) == 0
    out = capsys.readouterr().out
    assert "g2_sensitivity" in out and "size_effect" in out
    assert main(["diagnose", str(tmp_path / "missing.npz")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_report_of_simulated_hidden_effect(tmp_path):
    run, _truth, _sc = simulate("size_effect", "triad3", seed=1)
    d = diagnose(run.session, sigma={"accel": known_sigma(run, "accel")})
    comps = list(d.add("size_effect").values())
    md = write_report(d, tmp_path, comps, html_page=False, figures=False)
    text = md.read_text()
    assert "missing: size_effect" in text
    assert "r_x" in text and "mm" in text


def test_cli_with_calibration_file_defines_model_and_noise(tmp_path, capsys):
    from rimu.calibration import Calibration
    from rimu.calibration.lsq import fit_lsq
    from rimu.calibration.model import ErrorModel
    from rimu.cli.diagnose import load_session

    npz = tmp_path / "s.npz"
    assert main(["simulate", "--procedure", "cho_park", "--sample-rate", "10", "--seed", "2", "-o", str(npz)]) == 0
    session = load_session(npz)
    cals = {k: fit_lsq(session, ErrorModel.base() + "g_sensitivity" if k == "gyro" else None, k).to_calibration()
            for k in ("gyro", "accel")}
    path = Calibration(cals, method="test").save(tmp_path / "cal.json")
    capsys.readouterr()
    assert main(["diagnose", str(npz), "--calibration", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert "g_sensitivity" in data["diagnosis"]["instruments"]["gyro"]["model"]
    assert "g_sensitivity" not in data["diagnosis"]["instruments"]["accel"]["model"]
    # noise from the file: sigma known, chi2/dof near 1
    assert all(s["sigma_known"] for s in data["diagnosis"]["instruments"]["gyro"]["sensors"])
    assert abs(data["diagnosis"]["instruments"]["gyro"]["chi2_dof"] - 1.0) < 0.05
