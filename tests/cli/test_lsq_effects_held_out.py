"""rimu calibrate --method lsq --effects: an added effect that raises the residual on held-out segments is not
applied (the fit without it is kept) and the console, the result's notes and the report say so with the figures;
--keep-worse-effects applies it anyway with the caution; an effect the truth has lowers it and is applied."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np

from rimu.calibration import Calibration
from rimu.cli import main
from rimu.session import load_session
from rimu.session.native import save_session
from rimu.units import DH_TO_RS, G0

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root, for tests.diagnose

from tests.diagnose.scenarios import simulate

EFFECTS = "bias,scale_misalignment,g_sensitivity"


def _calibrate(capsys, tmp_path, session, *extra):
    rc = main(["calibrate", str(session), "--method", "lsq", "--effects", EFFECTS, "-o", str(tmp_path / "cal.json"),
               "--json", str(tmp_path / "c.json"), *extra])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    line = next(ln for ln in cap.out.splitlines() if "adding g_sensitivity" in ln)
    b, a, unit = re.search(r"(\S+) -> (\S+) (\S+) \(mean over the sensors\)", line).groups()
    return line, float(b), float(a), unit, json.loads((tmp_path / "c.json").read_text())


def test_an_effect_that_raises_the_held_out_residual_is_dropped_unless_asked_to_keep(tmp_path, capsys):
    assert main(["simulate", "-o", str(tmp_path / "s.npz"), "--duration", "1"]) == 0   # no g-sensitivity
    capsys.readouterr()
    s = tmp_path / "s.npz"
    line, b, a, unit, doc = _calibrate(capsys, tmp_path, s)
    assert a > b and line.startswith("caution: gyro:") and "not applied" in line, line   # 0.497 -> 0.5021 deg/s
    assert unit == "deg/s"
    assert any("not applied" in n and "g_sensitivity" in n for n in doc["notes"])
    assert "gyro without g_sensitivity" in doc["method"]
    # the report shows every note of the result (rimu.calibration.report; tests/test_reports_browser.py)
    sess = load_session(s)
    cal = Calibration.load(tmp_path / "cal.json", sess.geometries)
    assert "g_sensitivity" not in cal["gyro"].effects
    # the fit kept is the one without it: the same coefficients as asking for scale, misalignment and bias alone
    assert main(["calibrate", str(s), "--method", "lsq", "--effects", "bias,scale_misalignment", "-o",
                 str(tmp_path / "base.json")]) == 0
    base = Calibration.load(tmp_path / "base.json", sess.geometries)
    np.testing.assert_allclose(cal["gyro"].scale, base["gyro"].scale, rtol=1e-12)
    np.testing.assert_allclose(cal["gyro"].bias, base["gyro"].bias, rtol=1e-12, atol=1e-15)
    # asked to keep it: applied, with the caution and the same figures
    line2, b2, a2, _, doc2 = _calibrate(capsys, tmp_path, s, "--keep-worse-effects")
    assert (b2, a2) == (b, a) and "applied as asked (--keep-worse-effects)" in line2
    assert "g_sensitivity" in Calibration.load(tmp_path / "cal.json", sess.geometries)["gyro"].effects
    assert "without" not in doc2["method"]


def test_an_effect_the_truth_has_lowers_the_held_out_residual_and_is_applied(tmp_path, capsys):
    run, truth, _ = simulate("g_sensitivity")   # 40, -25, 30 (deg/h)/g on sensor 0
    save_session(run.session, tmp_path / "g.npz")
    line, b, a, unit, doc = _calibrate(capsys, tmp_path, tmp_path / "g.npz")
    assert a < 0.95 * b and line.startswith("note: gyro:") and line.endswith("applied"), line  # 47.45 -> 40.36 deg/h
    assert unit == "deg/h"
    gs = doc["instruments"]["gyro"]
    name = run.session.geometries["gyro"].names[0]
    for k, ax in enumerate("xyz"):
        v, sd = gs["values_si"][f"{name}.gsens_{ax}"], gs["std_si"][f"{name}.gsens_{ax}"]
        assert abs(v - truth[0][k]) < 4 * sd, (ax, v / (DH_TO_RS / G0), truth[0][k] / (DH_TO_RS / G0))
