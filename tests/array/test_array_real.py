"""The array report on the shared real recordings with several triads (skipped when the data is absent).

A throw-away reader lives here on purpose: the project's readers for these formats belong to another issue.
Both recordings are from multicopters: rotor vibration is not rigid-body motion, so the fits run below 5 Hz
(:func:`rimu.array.lowpass`, every triad alike).
"""

from __future__ import annotations

import json
import lzma

import numpy as np
import pytest

from rimu.array import ArrayLayout, array_report
from tests.conftest import shared_data


def _xsens(run: str):
    base = shared_data("quadrotor_4x_xsens_dot") / run
    d = [np.loadtxt(lzma.open(base / f"IMU_{i}.csv.xz", "rt"), delimiter=",", skiprows=1) for i in range(1, 5)]
    n = min(len(x) for x in d)
    return (d[0][:n, 0], np.radians(np.stack([x[:n, 7:10] for x in d], axis=1)),
            np.stack([x[:n, 4:7] for x in d], axis=1))


def _pixhawk():
    x = np.loadtxt(lzma.open(shared_data("pixhawk1_dual_imu_flight") / "01_07_59_imu01.csv.xz", "rt"),
                   delimiter=",", skiprows=1)
    x = x[np.concatenate([[True], np.diff(x[:, 0]) > 0])]
    return x[:, 0], np.stack([x[:, 1:4], x[:, 8:11]], axis=1), np.stack([x[:, 4:7], x[:, 11:14]], axis=1)


def _falls(steps: dict) -> list[float]:
    v = [x.mean() for x in steps.values()]
    assert all(a > b for a, b in zip(v, v[1:]) if a != b), steps
    return v


def test_xsens_dot_parity_falls_and_positions_repeat_across_flights():
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 4, axis=0), np.zeros((4, 3)))
    positions = []
    for run in ("Horizontal/path_10", "Vertical/path_1"):
        t, gyro, accel = _xsens(run)
        rep = array_report(lay, t, gyro, accel, motion_threshold_deg_s=10.0, lowpass_hz=5.0)
        g = _falls(rep.gyro_steps)
        a = _falls(rep.accel_steps)
        assert g[-1] < 0.3 * g[0] and a[-1] < 0.4 * a[0], rep.to_markdown()
        # a term is named limiting only when it explains at least 10 % of what is left (issue 32)
        assert rep.limiting_term.split(" ")[0] in ("aa_sensitivity", "rate_nonlinearity", "g_sensitivity", "noise",
                                                   "unexplained")
        positions.append(rep.position_fit.positions_m - rep.position_fit.positions_m[0])
        tau = rep.gyro_fit.sampling_offset_s
        assert 2e-3 < abs(tau[2] - tau[0]) < 7e-3 and 2e-3 < abs(tau[3] - tau[0]) < 7e-3, tau
    # the four units did not move between the flights: their positions, fitted from each flight alone, agree
    assert np.abs(positions[0] - positions[1]).max() < 5e-3, positions
    d = np.linalg.norm(positions[0], axis=1)                     # a 37 mm x 99 mm rectangle
    assert 0.033 < d[1] < 0.043 and 0.094 < d[2] < 0.104, positions[0]


def test_pixhawk_two_imus_parity_falls():
    t, gyro, accel = _pixhawk()
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3)))
    rep = array_report(lay, t, gyro, accel, motion_threshold_deg_s=10.0, lowpass_hz=5.0)
    g = _falls(rep.gyro_steps)
    a = _falls(rep.accel_steps)
    assert g[-1] < 0.6 * g[0] and a[-1] < 0.9 * a[0], rep.to_markdown()
    assert any("do not fit the accelerometers" in n and "m/s^2" in n for n in rep.notes)  # what was seen, no guess
    from rimu.array.report import AA_STEP  # two triads: 6 unknowns per epoch, no parity left (issue 32)
    assert "not identifiable: 2 triads" in rep.refused[AA_STEP] and AA_STEP not in rep.accel_steps, rep.refused


def _mimu(n_last: int = 2500):
    """The MIMU4444 board, run 5: the last samples (the fast hand rotation), triads in the array frame."""
    base = shared_data("mimu4444_array")
    b = lzma.open(base / "exp_5.bin.xz").read()[4:]
    a = np.frombuffer(b[:len(b) // 106 * 106], dtype=np.uint8).reshape(-1, 106)
    a = a[(a[:, 0] == 0xAA) & (a[:, 3] == 100)]
    t = np.unwrap(a[:, 4:8].copy().view(">u4").ravel().astype(float), period=2.0**32) / 64e6
    v = a[:, 8:104].copy().view(">i2").reshape(-1, 8, 6).astype(float)
    keep = np.concatenate([[True], np.diff(t) > 0])
    t, v = t[keep][-n_last:], v[keep][-n_last:]
    C = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float)
    rot = np.array([np.eye(3) if j % 2 == 0 else C for j in range(8)])
    pos = np.loadtxt(base / "IMU_positions.csv", delimiter=",", skiprows=1, usecols=range(1, 9)).T
    return t - t[0], np.radians(v[:, :, 3:] / 16.4), v[:, :, :3] / 2048 * 9.80665, rot, pos


@pytest.mark.parametrize("name", ["xsens-horizontal", "xsens-vertical", "pixhawk", "mimu4444"])
def test_cli_array_defaults_never_worse_after_a_step(tmp_path, capsys, name):
    """rimu array with its defaults on each shared multi-IMU recording: no step raises the parity rms in motion
    (the Xsens DOT run used to go 2.293 -> 13.47 m/s^2); a refused step is named, not applied."""
    from rimu.cli import main

    extra = {}
    if name.startswith("xsens"):
        t, gyro, accel = _xsens("Horizontal/path_10" if name.endswith("horizontal") else "Vertical/path_1")
    elif name == "pixhawk":
        t, gyro, accel = _pixhawk()
    else:
        t, gyro, accel, rot, pos = _mimu()
        extra = {"rotations": rot, "positions_m": pos}
    f = tmp_path / "a.npz"
    np.savez(f, t=t, gyro=gyro, accel=accel, **extra)
    assert main(["array", str(f), "--json", str(tmp_path / "s.json"), "-o", str(tmp_path / "fit.json")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    doc = json.loads((tmp_path / "s.json").read_text())
    for key in ("gyro_parity_rms_deg_s", "accel_parity_rms_m_s2"):
        means = [float(np.mean(v)) for v in doc[key].values()]
        assert len(means) >= 2 and all(b <= a * (1 + 1e-3) for a, b in zip(means, means[1:])), (key, doc[key])
    # what is printed is what the steps say, first and last applied
    g = [float(np.mean(v)) for v in doc["gyro_parity_rms_deg_s"].values()]
    assert f"{g[0]:.4g} deg/s -> {g[-1]:.4g} deg/s" in out[-1], out
    assert any("low-pass" in n for n in doc["notes"])
    if name == "mimu4444":  # issue 32: the remainder of the fast rotation is no deterministic term, and not white
        r = doc["remainder"]
        assert max(r["shares_held_out"].values()) < 0.1 and doc["limiting_term"].startswith("unexplained"), r
        assert r["not_white_fraction"] > 0.5 and r["verdict"].startswith("not explained"), r
        assert "remainder: not explained by a deterministic term" in out[-1]
        # issue 32: the cut-off clears the hand rotation's band (90 % of its rate's power below 4.8 Hz), where the
        # disagreement is not vibration: no low-pass, and the positions near nominal (0.29-1.03 mm measured on these
        # 40 s with the clipped samples left in; within 1 mm without them, the test below; with the old 1.46 Hz cut-off
        # they came out about 13 mm off, all near the centre)
        assert any("no vibration to remove" in n and "no low-pass" in n for n in doc["notes"]), doc["notes"]
        fit = json.loads((tmp_path / "fit.json").read_text())["accel"]
        off = np.linalg.norm(np.array(fit["positions_m"]) - np.array(fit["nominal_m"]), axis=1)
        print(f"\n  MIMU4444 positions from nominal, default low-pass rule: {np.round(1e3 * off, 2)} mm")
        assert off.max() < 1.5e-3, off
        # the same cut-off given explicitly: applied, and the position step refused with the reason on one line
        assert main(["array", str(f), "--lowpass-hz", "1.46", "--no-held-out", "-o", str(tmp_path / "cut.json")]) == 0
        why = [ln for ln in capsys.readouterr().out.splitlines() if "'+ positions' not applied" in ln]
        assert len(why) == 1 and "below the motion's band" in why[0], why
        assert json.loads((tmp_path / "cut.json").read_text())["accel"] is None
    # the same recording in deg/s, or in g, read as SI: refused by the plausibility checks, one line, exit 2
    for g_f, a_f, opt in ((180 / np.pi, 1.0, "--gyro-unit deg/s"), (1.0, 1 / 9.80665, "--accel-unit g")):
        np.savez(f, t=t, gyro=gyro * g_f, accel=accel * a_f, **extra)
        assert main(["array", str(f)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and opt in err[0], err


def test_cli_array_mimu4444_accelerometers_fall_3x_held_out(tmp_path, capsys):
    """Issue 32, Done when: on the MIMU4444's raw triads (fast rotation of exp_5, clipped gyro samples left out, no
    low-pass) the accelerometer parity in motion falls at least 3x held out (fitted on the first half of the motion,
    judged on the second; raw -> the last step applied) with the positions within 1 mm of nominal. With the gyros'
    angular acceleration it falls only about 2x: the last step, the angular acceleration per epoch from the
    accelerometers themselves (Skog et al. 2016), is what gets it there."""
    from rimu.array.report import AA_STEP
    from rimu.cli import main

    t, gyro, accel, rot, pos = _mimu(2500)
    ok = (np.abs(np.degrees(gyro) * 16.4) < 32767 - 0.5).all(axis=(1, 2))   # a count at the int16 limit: clipped
    f = tmp_path / "a.npz"
    np.savez(f, t=t[ok], gyro=gyro[ok], accel=accel[ok], rotations=rot, positions_m=pos)
    assert main(["array", str(f), "--lowpass-hz", "none", "--json", str(tmp_path / "s.json"),
                 "-o", str(tmp_path / "fit.json")]) == 0
    capsys.readouterr()
    doc = json.loads((tmp_path / "s.json").read_text())
    ho = {k: float(np.mean(v)) for k, v in doc["accel_parity_rms_held_out_m_s2"].items()}
    names = list(ho)
    assert names[-1] == AA_STEP and AA_STEP in doc["accel_parity_rms_m_s2"], doc["refused"]
    assert ho["raw"] / ho[AA_STEP] >= 3.0, ho
    assert ho["raw"] / ho["+ positions"] < 2.5, ho                 # the gyros' angular acceleration alone: ~2x
    fit = json.loads((tmp_path / "fit.json").read_text())["accel"]
    off = np.linalg.norm(np.array(fit["positions_m"]) - np.array(fit["nominal_m"]), axis=1)
    assert off.max() < 1e-3, off
