"""The array report on a simulated raw array, and the errors that name a missing excitation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.array import ArrayLayout, array_report, fit_positions, fit_relative_gyro
from rimu.errors import IdentifiabilityError
from rimu.sim.array import HandheldMotion, random_array_truth, simulate_array


def test_report_falls_with_each_step_and_names_the_hidden_term(tmp_path):
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.012)
    rng = np.random.default_rng(4)
    true_pos = lay.positions_m + rng.normal(0, 5e-4, lay.positions_m.shape)
    tr = random_array_truth(lay.with_positions(true_pos), seed=4, sampling_offset_sigma_s=300e-6,
                            nonlinearity_sigma_s_rad=3e-4, centre_gyro_common_mode=True)
    rec = simulate_array(tr, duration_s=2.0, seed=4)
    rep = array_report(lay, rec.t, rec.gyro, rec.accel)
    g = [v.mean() for v in rep.gyro_steps.values()]
    a = [v.mean() for v in rep.accel_steps.values()]
    assert list(rep.gyro_steps) == ["raw", "relative gain+bias", "+ sampling offsets"]
    assert g[0] > 3 * g[1] and g[1] > g[2], rep.gyro_steps          # raw triads: at least 3x
    assert all(x > y for x, y in zip(a, a[1:])), rep.accel_steps
    assert rep.limiting_term == "rate_nonlinearity"
    d = json.loads(json.dumps(rep.to_dict()))
    assert d["limiting_term"] == "rate_nonlinearity" and len(d["gyro_parity_rms_deg_s"]["raw"]) == lay.k
    md = rep.to_markdown()
    assert "**rate_nonlinearity**" in md and "| + positions |" in md
    assert rep.plot(tmp_path / "a.png").stat().st_size > 1000


def test_positions_need_rotation():
    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.01)
    tr = random_array_truth(lay, seed=2)
    rec = simulate_array(tr, duration_s=1.0, seed=2, motion=HandheldMotion(rms_rate_deg_s=1.0, seed=2))
    gf = fit_relative_gyro(lay, rec.t, rec.gyro, candidates=None, motion_threshold_deg_s=1.0)
    with pytest.raises(IdentifiabilityError, match="positions need angular rate and angular acceleration") as ei:
        fit_positions(lay, rec.t, rec.accel, gf, rec.gyro, gain="none")
    assert ei.value.parameters == ["position"]


def test_cli_array(tmp_path, capsys):
    from rimu.cli import main

    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.012)
    tr = random_array_truth(lay, seed=6, centre_gyro_common_mode=True)
    rec = simulate_array(tr, duration_s=1.5, seed=6)
    f = tmp_path / "arr.npz"
    np.savez(f, t=rec.t, gyro=rec.gyro, accel=rec.accel, rotations=lay.rotations, positions_m=lay.positions_m)
    rc = main(["array", str(f), "-o", str(tmp_path / "fit.json"), "--report", str(tmp_path / "rep"),
               "--json", str(tmp_path / "sum.json")])
    out = capsys.readouterr().out.strip().splitlines()
    assert rc == 0 and out[-1].startswith("array of 4 triads: gyro parity rms in motion")
    assert all(x.startswith("note: ") for x in out[:-1]), out
    fit = json.loads((tmp_path / "fit.json").read_text())
    np.testing.assert_allclose(np.mean(fit["gyro"]["gain"], axis=0), np.eye(3), atol=1e-12)
    assert json.loads((tmp_path / "sum.json").read_text())["triads"] == ["T1", "T2", "T3", "T4"]
    assert (tmp_path / "rep" / "array_report.md").exists() and (tmp_path / "rep" / "array_report.png").exists()
    np.savez(tmp_path / "bad.npz", t=rec.t)
    assert main(["array", str(tmp_path / "bad.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lacks gyro" in err[0]
