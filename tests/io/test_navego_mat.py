"""Issue 32: the ``navego-mat`` log format (MATLAB level-5 files of NaveGo IMU structs ``t``, ``wb``, ``fb``), on
files written here by scipy: found by content, every struct one IMU on its own stamps in SI, a stamp back in time
dropped and counted, a file without such a struct, a v7.3 file and a damaged file refused with one line naming
the file; and the journey of docs/real-units.md from the command line on a static recording of four simulated
units (biases of 2-3 deg/s, near the setup's motion threshold) kept in that format, as the public static recording
of four MPU-9250s of that page is: the setup refuses the rotations with the reason (gravity in one direction, no
motion), ``--parallel`` sets the unit up, a fault-free replay isolates nothing and a 1 deg/s bias on one gyro is
isolated on its sensor within 1 s.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io as sio

from rimu.cli import main
from rimu.errors import SessionFormatError
from rimu.io.formats import find_format, read_log

DEG = np.pi / 180.0


def _struct(t, wb, fb):
    return {"t": t.reshape(-1, 1), "wb": wb, "fb": fb, "mb": np.zeros_like(fb)}


def _static(folder, n=3000, fs=20.0, seed=0):
    """Four units at rest in one pose, each its own file (NaveGo structs), gyro biases 2-3 deg/s."""
    rng = np.random.default_rng(seed)
    folder.mkdir()
    t = np.arange(n) / fs
    for k in range(4):
        b = rng.uniform(2.0, 3.0, 3) * rng.choice([-1, 1], 3) * DEG
        wb = b + 0.1 * DEG * rng.standard_normal((n, 3))
        fb = [0.3 * k, -0.2, 9.79] + 0.03 * rng.standard_normal((n, 3))
        sio.savemat(folder / f"imu{k + 1}_raw.mat", {f"imu{k + 1}_raw": _struct(t, wb, fb)})


def test_navego_structs_are_read_as_imus(tmp_path):
    t = np.arange(100) / 50.0
    wb, fb = np.full((100, 3), 0.01), np.tile([0.0, 0.0, 9.81], (100, 1))
    t_bad = t.copy()
    t_bad[40] = t_bad[39]                                     # a repeated stamp: dropped, counted
    sio.savemat(tmp_path / "two.mat", {"imuA": _struct(t, wb, fb), "imuB": _struct(t_bad, 2 * wb, fb),
                                       "notes": np.arange(3.0)})
    assert find_format(tmp_path / "two.mat") == "navego-mat"
    rec = read_log(tmp_path / "two.mat")
    assert rec.names == ["imuA", "imuB"]
    assert len(rec["imuA"].t) == 100 and len(rec["imuB"].t) == 99
    assert rec.meta["rejected"] == {"imuB": {"time_not_increasing": 1}}
    np.testing.assert_allclose(rec["imuB"].gyro, 0.02)
    np.testing.assert_allclose(rec["imuA"].accel[:, 2], 9.81)
    sio.savemat(tmp_path / "none.mat", {"x": np.arange(4.0)})
    with pytest.raises(SessionFormatError, match="none.mat.*t, wb and fb"):
        read_log(tmp_path / "none.mat", format="navego-mat")
    (tmp_path / "v73.mat").write_bytes(b"MATLAB 7.3 MAT-file, Platform: x" + b"\0" * 200)
    with pytest.raises(SessionFormatError, match="v7.3"):
        read_log(tmp_path / "v73.mat", format="navego-mat")
    (tmp_path / "cut.mat").write_bytes((tmp_path / "two.mat").read_bytes()[:300])
    with pytest.raises(SessionFormatError, match="cut.mat"):
        read_log(tmp_path / "cut.mat")


def test_the_journey_on_a_static_recording_of_four_units(tmp_path, capsys):
    _static(tmp_path / "log")
    out = {k: str(tmp_path / k) for k in ("unit.json", "unit.npz", "setup.json", "free.json", "fault.json")}
    setup = ["setup", str(tmp_path / "log"), "-o", out["unit.json"], "--fit-window", ":50%", "--average", "0.1",
             "--motion-fit", "--session", out["unit.npz"], "--json", out["setup.json"]]
    assert main(setup) == 2
    err = capsys.readouterr().err
    assert "no motion" in err and "one direction" in err and "--parallel" in err and "Traceback" not in err
    assert main(setup + ["--parallel"]) == 0
    said = capsys.readouterr().out
    assert "no motion term fitted" in said and "no bias tracker: 1 spans at rest" in said, said
    replay = ["replay", out["unit.npz"], "--calibration", out["unit.json"], "--common-cause", "--instrument", "gyro"]
    assert main(replay + ["--json", out["free.json"]]) == 0
    free = json.loads((tmp_path / "free.json").read_text())["gyro"]
    assert free["isolations"] == 0 and free["final_state"] == "nominal"
    rest = [s for s in free["segments"] if s["kind"] == "static_unknown"]
    assert sum(s["alarms"] for s in rest) <= 10                       # design 1e-3 of ~1500 epochs: Poisson 1.5
    onset = 100.0
    assert main(replay + ["--json", out["fault.json"], f"--inject=bias:gyro:imu3_raw_y:{onset}:{DEG:.9g}:5"]) == 0
    ev = [e for e in json.loads((tmp_path / "fault.json").read_text())["gyro"]["events"] if e["kind"] == "isolated"]
    assert ev and ev[0]["sensor"] == "imu3_raw_y" and 0 <= ev[0]["t"] - onset <= 1.0, ev[:2]
