"""Static/rotation detection on the real Ferraris recording and on simulated data; the calibrate, design and
simulate commands end to end."""

from __future__ import annotations

import json

import numpy as np

from rimu.calibration.detect import detect_intervals, plot_detection, session_from_detection
from rimu.cli import main
from rimu.geometry import triad3
from tests.conftest import shared_data


def _ferraris():
    return shared_data("imucal_ferraris_session", "example_ferraris_session.csv")


def test_detection_finds_the_labelled_sections_of_real_data(tmp_path):
    folder = _ferraris()
    d = np.loadtxt(folder / "example_ferraris_session.csv", delimiter=",", skiprows=1)
    labels = json.loads((folder / "example_ferraris_session_list.json").read_text())
    det = detect_intervals(d[:, 4:7], 102.4, gyro=d[:, 1:4])
    for name, se in labels.items():
        s, e = se["start"], se["end"]
        kind = "rotation" if name.endswith("rot") else "static"
        best = max((min(e, iv.end) - max(s, iv.start)) for iv in det.intervals if iv.kind == kind)
        assert best >= 0.9 * (e - s), (name, best, e - s)
    fig = plot_detection(det, d[:, 4:7], 102.4, {k: (v["start"], v["end"]) for k, v in labels.items()},
                         str(tmp_path / "det.png"))
    assert (tmp_path / "det.png").stat().st_size > 10_000
    fig.clf()
    # detected statics become attitude-free segments (for Zhang's norm-based method)
    s = session_from_detection(det, np.arange(len(d)) / 102.4, {"gyro": d[:, 1:4], "accel": d[:, 4:7]},
                               {"gyro": triad3(), "accel": triad3()}, 102.4)
    assert len(s) == len(det.static) and all(x.kind == "static_unknown" for x in s)


def test_detection_on_white_noise_and_steps():
    rng = np.random.default_rng(0)
    fs = 100.0
    acc = rng.normal(0, 0.01, (3000, 3)) + [0, 0, 9.8]
    acc[1000:1500] += rng.normal(0, 1.0, (500, 3))  # handling between two still periods
    det = detect_intervals(acc, fs, min_static_s=2.0)
    st = det.static
    assert len(st) == 2
    assert abs(st[0].end - 1000) < 100 and abs(st[1].start - 1500) < 100


def test_simulate_calibrate_design_commands(tmp_path, capsys):
    sess = tmp_path / "cp.csv"
    assert main(["simulate", "--procedure", "cho_park_table1", "--seed", "3", "--duration", "5", "-o", str(sess),
                 "--truth", str(tmp_path / "truth.json")]) == 0
    assert sess.exists() and sess.with_suffix(".json").exists()
    # table 1 alone: the gyros cannot be calibrated by Cho & Park (no rate pairs); the command says which
    rc = main(["calibrate", str(sess), "--method", "cho", "-o", str(tmp_path / "c.json")])
    assert rc == 2 and "cannot identify" in capsys.readouterr().err
    rc = main(["calibrate", str(sess), "--method", "cho", "--instruments", "accel", "-o", str(tmp_path / "c.json"),
               "--plot", str(tmp_path / "res.png")])
    out = capsys.readouterr().out
    assert rc == 0 and "x1.scale" in out and "arcsec" in out and (tmp_path / "res.png").exists()
    from rimu.calibration import Calibration

    cal = Calibration.load(tmp_path / "c.json")
    assert cal.method == "Cho & Park 2005" and cal["accel"].covariance is not None
    rc = main(["calibrate", str(sess), "--method", "lsq", "--instruments", "accel", "-o", str(tmp_path / "l.json")])
    assert rc == 0
    # short sessions of the other procedures, written in the official format by the library
    from rimu.geometry import tetrad4
    from rimu.session import save_session
    from rimu.sim import Simulator, oliveira_table1, zhang_scheme

    g = triad3()
    z = save_session(Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.01, seed=1).run(
        zhang_scheme(static_duration=5.0, rotation_duration=36.0)).session, tmp_path / "z.npz")
    assert main(["calibrate", str(z), "--method", "zhang", "-o", str(tmp_path / "z.json")]) == 0
    o = save_session(Simulator({"gyro": tetrad4(), "accel": g}, seed=1).run(oliveira_table1(turns=1)).session,
                     tmp_path / "o.npz")
    assert main(["calibrate", str(o), "--method", "oliveira", "--wavelet", "-o", str(tmp_path / "o.json")]) == 0
    capsys.readouterr()
    assert main(["design", "--geometry", "tetrad4", "--plot", str(tmp_path / "fig3.png")]) == 0
    out = capsys.readouterr().out
    assert "Eq. 19" in out and "greedy" in out and (tmp_path / "fig3.png").exists()
