"""The command line: the demo runs end to end and tells the truth; simulate writes data."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest

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
    out = capsys.readouterr().out
    assert "isolated" in out
    # every printed figure is the report's, in the unit it states (parsed and converted: a wrong label fails)
    from rimu.geometry import cone6
    from rimu.units import FIELD_UNITS

    def si(v: str, u: str, q: str) -> float:
        units = dict(FIELD_UNITS[q])
        assert u in units, (u, q)
        return float(v) / units[u]

    iso = list(re.finditer(r"t = \s*(\S+) (\S+)\s+(gyro|accel)\s+(\S+) isolated \(fault at (\S+) (\S+), "
                         r"delay (\S+) (\S+)\)", out))
    assert len(iso) == 2, out
    for m in iso:
        e = next(e for e in rep["events"] if e["instrument"] == m.group(3))
        t, t0, delay = si(m.group(1), m.group(2), "time"), si(m.group(5), m.group(6), "time"), si(m.group(7), m.group(8), "time")
        assert t == pytest.approx(e["t"], abs=0.006) and delay == pytest.approx(e["delay_s"], abs=1e-6 + 5e-4 * delay)
        assert delay == pytest.approx(t - t0, abs=0.006)
    cal = json.loads((tmp_path / "demo" / "calibration.json").read_text())["payload"]["instruments"]
    H = cone6().H
    for k in ("gyro", "accel"):
        q = "rate" if k == "gyro" else "specific_force"
        lines = re.findall(rf"  {k}\s+([xyz]):\s+(\S+) ->\s+(\S+) (\S+)   ratio", out)
        assert len(lines) == 3 and rep["std"][k]["unit"] == ("rad/s" if k == "gyro" else "m/s^2"), lines
        sigma = float(np.mean(cal[k]["noise_sigma"]))
        for (ax, b, a, u), sb, sa, p in zip(lines, rep["std"][k]["before"], rep["std"][k]["after"],
                                            np.diag(np.linalg.inv(H.T @ H))):
            assert si(b, u, q) == pytest.approx(sb, rel=1e-3) and si(a, u, q) == pytest.approx(sa, rel=1e-3)
            # before the fault: the least-squares error, sigma sqrt(diag((H^T H)^-1)), within 10 %
            assert sb == pytest.approx(sigma * np.sqrt(p), rel=0.1), (k, ax, sb, sigma * np.sqrt(p))


def test_simulate_writes_a_file(tmp_path):
    out = tmp_path / "s.npz"
    assert main(["simulate", "--procedure", "cho_park_table1", "-o", str(out)]) == 0
    d = np.load(out)
    assert d["raw_gyro"].shape[1] == 6 and np.all(np.isfinite(d["raw_gyro"]))


def test_no_command_prints_help():
    assert main([]) == 2
