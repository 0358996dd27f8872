"""Diagnosis of unknown-attitude (hand-held) sessions: residuals per pose and per motion, and the missing-effect
ranking on the attitude-resolved session; ``rimu diagnose`` accepts such sessions."""

from __future__ import annotations

import numpy as np

from rimu.cli import main
from rimu.diagnose import diagnose
from rimu.diagnose.handheld import diagnose_handheld, unknown_attitude
from rimu.session import save_session
from rimu.sim.handheld import handheld_run


def test_hidden_gyro_g_sensitivity_is_ranked_first_and_nothing_without_it():
    """0.28 deg/s/g of gyro g-sensitivity hidden in a 24-pose hand-held recording: the diagnosis names it;
    the same recording without it: nothing missing."""
    clean = handheld_run(n_poses=24, static_s=2.5, seed=3)
    assert unknown_attitude(clean.session)
    d = diagnose(clean.session)
    assert d.nothing_missing and d.summary().startswith("hand-held session: 24 poses")
    assert not any(t["significant"] for t in d.settings["handheld"]["motion_tests"])
    hidden = handheld_run(n_poses=24, static_s=2.5, seed=3, gyro_g_sensitivity=np.diag([1.0, -1.0, 1.0]) * 5e-4)
    res, d = diagnose_handheld(hidden.session)
    assert d["gyro"].top() == "g_sensitivity" and d["accel"].top() is None
    # the pose residuals are at their noise, the motion residuals report every motion
    assert len(res.norm_residual) == 24 and len(res.rotation_residual_deg) == 23
    assert 0.3 < float(np.mean(res.norm_z**2)) < 3.0
    assert res.motion_tests[0].name == "g_sensitivity" and res.motion_tests[0].significant


def test_motion_residuals_find_a_smaller_g_sensitivity():
    """0.11 deg/s/g: below what the poses at rest reveal against the hand's sway, but the rotations between
    poses integrate it: the F-test on the motion residuals names it, and only it."""
    run = handheld_run(n_poses=24, static_s=2.5, seed=3, gyro_g_sensitivity=np.diag([1.0, -1.0, 1.0]) * 2e-4)
    res, _ = diagnose_handheld(run.session, candidates=["g_sensitivity"])
    sig = [t.name for t in res.motion_tests if t.significant]
    assert sig == ["g_sensitivity"] and res.motion_tests[0].explained > 0.5


def test_rimu_diagnose_accepts_a_handheld_session_file(tmp_path, capsys):
    run = handheld_run(n_poses=16, static_s=2.0, seed=9)
    path = save_session(run.session, tmp_path / "hh.npz")
    assert main(["diagnose", str(path), "--instrument", "accel", "--json"]) == 0
    out = capsys.readouterr().out
    import json

    data = json.loads(out)
    assert data["diagnosis"]["settings"]["handheld"]["poses"][0] == "P1"
    assert list(data["diagnosis"]["instruments"]) == ["accel"]
