"""The hand-held estimator checks its gyro misalignment step on held-out motions (issue 27): the full gyro model
(every component of each row, relative to the accelerometers) against nominal axes with a scale and a bias per
gyro, on the motions it was fitted on and on motions left out in turn, judged by the rotation misfit (the gravity
direction after a motion against the integrated rotation). Applied only when it lowers the held-out misfit."""

from __future__ import annotations

import re

import numpy as np

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.calibration.handheld import HandHeld, gauge_fixed
from rimu.geometry import triad3
from rimu.sim.handheld import handheld_run, mems_truth
from rimu.units import FIELD_UNITS


def _note(res) -> str:
    return next(n for n in res.notes if n.startswith("gyro: the misalignment step"))


def _figures(note: str) -> list[float]:
    units = dict(FIELD_UNITS["angle"])
    return [float(v) / units[u] for v, u in re.findall(r"(\S+) (arcsec|deg)\b", note)]


def _truth_misfit(res, run) -> float:
    """rms rotation misfit (rad) of the true gyro coefficients (in the fit's gauge frame) on every motion."""
    gf, af = res.fits["gyro"][0], res.fits["accel"][0]
    W, c = gauge_fixed(run.truth["accel"], af.triple, run.truth["gyro"])
    r = gf.problem["rotation_misfit"](np.concatenate([W.ravel(), c]))
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1))))


def test_the_gyro_step_lowers_the_held_out_misfit_to_the_truth_s_and_is_applied():
    # MEMS truth: gyro axes ~5 mrad off the accelerometers', scales +-3 %; 16 poses, 15 motions in 4 groups
    run = handheld_run(n_poses=16, static_s=1.0, seed=1)
    res = HandHeld().fit(run.session)
    note = _note(res)
    ins_sb, ins_f, out_sb, out_f = _figures(note)
    check = res.extra["held_out_gyro"][0]
    np.testing.assert_allclose([ins_sb, ins_f, out_sb, out_f], check["in_sample"] + check["held_out"], rtol=1e-3)
    assert "not applied" not in note and check["folds"] == 4
    # the figures of the implementation that refitted every fold from scratch (issue 27's code)
    np.testing.assert_allclose(check["in_sample"] + check["held_out"], [0.014636566462023543, 0.0005944487746747687,
                                                                        0.02146336476282908, 0.0010840929603815606],
                               rtol=1e-9)
    truth = _truth_misfit(res, run)  # the noise floor: the true coefficients' misfit (measured 0.056 deg)
    # held out, the full model's misfit is that of the truth (measured 0.062 deg against 0.056 deg); nominal axes
    # leave the 5 mrad misalignments in it (measured 1.23 deg)
    assert out_f < 1.5 * truth, (out_f, truth)
    assert out_sb > 10 * truth, (out_sb, truth)
    # applied: the gyro axes are the full fit's, closer to the true ones than the 5 mrad the step removes
    gf = res.fits["gyro"][0]
    W, _ = gauge_fixed(run.truth["accel"], res.fits["accel"][0].triple, run.truth["gyro"])
    unit = lambda A: A / np.linalg.norm(A, axis=1)[:, None]  # noqa: E731
    err = np.arccos(np.clip(np.sum(unit(gf.W) * unit(W), axis=1), -1, 1))
    off = np.arccos(np.clip(np.sum(np.eye(3) * unit(W), axis=1), -1, 1))
    assert err.max() < 0.25 * off.max(), (err, off)


def test_the_gyro_step_on_a_nominal_truth_raises_the_held_out_misfit_and_is_refused():
    g = {"gyro": triad3(), "accel": triad3()}
    t = mems_truth(g, seed=2)
    nominal = Calibration({k: InstrumentCalibration(k, t[k].geometry, t[k].scale, np.eye(3), t[k].bias)
                           for k in ("gyro", "accel")})
    run = handheld_run(n_poses=10, static_s=1.0, truth=nominal, seed=4)
    res = HandHeld().fit(run.session)
    note = _note(res)
    _, _, out_sb, out_f = _figures(note)
    # nominal axes are the truth: six more parameters fit the 9 motions' noise, held out they raise the misfit
    # (measured 237 arcsec -> 368 arcsec); the nominal model is as good as the truth's own misfit
    assert out_f > out_sb and "not applied" in note, note
    assert out_sb < 2.0 * _truth_misfit(res, run)
    cal = res.to_calibration()["gyro"]
    ref = HandHeld(held_out=False).fit(run.session)
    assert "held_out_gyro" not in ref.extra
    np.testing.assert_allclose(cal.misalignment, np.eye(3), atol=1e-9)   # refused: nominal axes in the gauge frame
    assert not np.allclose(ref.to_calibration()["gyro"].misalignment, np.eye(3), atol=1e-4)
    assert res.extra["steps"][-1]["applied"] is False and res.extra["steps"][-1]["unit"] == "rad"


def test_the_mpu6050_session_s_gyro_step_from_the_cli(tmp_path, capsys):
    """The figures docs/calibration.md states for the real MPU-6050 hand-held session (rimu detect, then rimu
    calibrate --method handheld): 7 motions (2 clipped left out), each left out in turn."""
    import json

    from rimu.cli import main
    from tests.conftest import shared_data

    raw = shared_data("mpu6050_handheld_session") / "calibration_data" / "example_data_calibration.csv"
    assert main(["detect", str(raw), "-o", str(tmp_path / "s.csv"), "-q"]) == 0
    assert main(["calibrate", str(tmp_path / "s.csv"), "--method", "handheld", "-o", str(tmp_path / "c.json"),
                 "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    note = next(n for n in json.loads((tmp_path / "r.json").read_text())["notes"]
                if n.startswith("gyro: the misalignment step"))
    assert note in out and "(each left out in turn)" in note and "not applied" not in note, note
    np.testing.assert_allclose(_figures(note), np.radians([4.33, 2.209, 7.209, 7.172]), rtol=2e-3)


def test_a_fold_fit_started_from_the_whole_fit_reaches_the_minimum_of_the_nominal_start():
    # held_out_gyro starts each fold's fit from the fit on every motion (fewer integrations); the minimum must be
    # the one the nominal start reaches, to the solver's tolerance (1e-8 of the typical sizes)
    from rimu.calibration.handheld import _dirs_with_jacobian, _statics, fit_gyro, pose_windows, white_noise_sigma_hf

    run = handheld_run(n_poses=12, static_s=1.0, seed=1)
    s = run.session
    res = HandHeld(instruments=["accel"]).fit(s)
    dirs = _dirs_with_jacobian(res.fits["accel"][0], _statics(s), s, white_noise_sigma_hf(s, "accel"))[0]
    sg, win = white_noise_sigma_hf(s, "gyro"), pose_windows(s)
    keep = [w for m, w in enumerate(win) if m % 4 != 1]
    for model in ("scale_bias", "full"):
        whole = fit_gyro(s, win, dirs, None, None, [0, 1, 2], sg, np.eye(3), model=model)
        cold = fit_gyro(s, keep, dirs, None, None, [0, 1, 2], sg, np.eye(3), model=model)
        warm = fit_gyro(s, keep, dirs, None, None, [0, 1, 2], sg, np.eye(3), model=model, _start=whole.theta)
        assert np.max(np.abs(whole.theta - cold.theta)) > 1e-6 * np.max(np.abs(cold.theta))  # a different fit
        np.testing.assert_allclose(warm.theta, cold.theta, rtol=1e-6, atol=1e-9 * np.max(np.abs(cold.theta)))
        np.testing.assert_allclose(warm.problem["rotation_misfit"](warm.theta),
                                   cold.problem["rotation_misfit"](cold.theta), rtol=1e-4, atol=1e-9)
        # held_out_gyro's folds also reuse the whole fit's window sums and its pre-integration at its parameters
        # (subsets: the same numbers), and integrate only the left-out motions for their misfit
        sel = np.array([m for m in range(len(win)) if m % 4 != 1])
        pre = whole.problem["integrate"](whole.theta)
        shared = fit_gyro(s, keep, dirs, None, None, [0, 1, 2], sg, np.eye(3), model=model, _start=whole.theta,
                          _share=(whole.problem["setup"], sel), _pre=(pre[0], *(x[sel] for x in pre[1:4]), *pre[4:]))
        np.testing.assert_allclose(shared.theta, warm.theta, rtol=1e-12, atol=0)
        out = np.array([m for m in range(len(win)) if m % 4 == 1])
        np.testing.assert_allclose(whole.problem["rotation_misfit"](shared.theta, out),
                                   whole.problem["rotation_misfit"](shared.theta)[out], rtol=1e-12, atol=0)
