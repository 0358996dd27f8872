"""The command line: the demo runs end to end and tells the truth; simulate writes data."""

from __future__ import annotations

import json
import shutil

import numpy as np

from rimu.cli import main


def test_demo_end_to_end(tmp_path, capsys):
    code = main(["demo", "--out", str(tmp_path / "demo")])   # its run time is reported, not asserted (load-dependent)
    assert code == 0
    rep = json.loads((tmp_path / "demo" / "report.json").read_text())
    assert {(e["instrument"], e["sensor"]) for e in rep["events"]} == {("gyro", "y2"), ("accel", "x1")}
    assert all(0 <= e["delay_s"] < 0.5 for e in rep["events"])
    # the uncertainty the calibration reports is honest: normalised errors of rms about 1
    assert 0.5 < rep["calibration"]["normalised_error_rms_without_x2_gyro"] < 1.6
    # the hidden gyro g-sensitivity is named, on the right sensor, and recovered within 3 sigma
    dg = rep["diagnosis"]
    assert dg["top"] == "g_sensitivity" and dg["sensor"] == "x2"
    assert dg["chi2_after"] < dg["chi2_before"] and 0.8 < dg["chi2_after"] < 1.25
    for (v, sd), truth in zip([dg["gsens_x2"][f"gsens_{a}"] for a in "xyz"], dg["gsens_x2_truth_si"]):
        assert abs(v - truth) < 3 * sd
    assert rep["states"] == {"gyro": "fault_isolated", "accel": "fault_isolated"}
    for k in ("gyro", "accel"):
        s = rep["std"][k]
        ratio = np.array(s["ratio_measured"]) / np.array(s["ratio_predicted"])
        assert np.all(np.abs(ratio - 1) < 0.15), (k, ratio)
    assert (tmp_path / "demo" / "demo.png").stat().st_size > 10_000
    assert (tmp_path / "demo" / "calibration.json").exists()
    # the flight code: exported, built and equal to the Python runtime on every sample (where a compiler is)
    fc = rep["flight_code"]
    if (shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")) and shutil.which("make"):
        assert fc["built"] and fc["decisions_equal"] and fc["max_rel_diff"] < 1e-12 and fc["samples"] == 3000
    else:
        assert fc == {"built": False}
    assert "isolated" in capsys.readouterr().out


def test_simulate_writes_a_file(tmp_path):
    out = tmp_path / "s.npz"
    assert main(["simulate", "--procedure", "cho_park_table1", "-o", str(out)]) == 0
    d = np.load(out)
    assert d["raw_gyro"].shape[1] == 6 and np.all(np.isfinite(d["raw_gyro"]))


def test_no_command_prints_help():
    assert main([]) == 2
