"""Calibrate an IMU without a turntable: from a raw hand-held log to a calibration file.

A consumer MEMS triad (MPU-6050 class, raw counts) is held by hand in 30 random orientations for 3 s each and
turned by hand between them (tremor and sway included). The logger writes a plain CSV: a sample-rate row, a
header, counts. We then

1. detect the still poses and the motions (``rimu detect``), with the thresholds adapted to the data;
2. calibrate accelerometers (gravity norm, Zhang et al. 2010) and gyros (rotations between poses, Tedaldi et al.
   2014) with uncertainties (``rimu calibrate --method handheld``);
3. compare with the truth of the simulation, expressed in the calibration's frame;
4. diagnose the model against the measurement (``rimu diagnose``).

With a real recording, start at step 1 with your file (see docs/handheld.md).

Run: python examples/handheld.py [OUT_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from rimu.calibration import Calibration
from rimu.calibration.handheld import gauge_fixed
from rimu.cli import main as rimu
from rimu.sim.handheld import handheld_run


def run(out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    sim = handheld_run(n_poses=30, static_s=3.0, initial_still_s=5.0, seed=12)
    log = out / "handheld_log.csv"
    with log.open("w") as fh:
        fh.write("Fs,100\nsample,ax,ay,az,gx,gy,gz\n")
        data = np.column_stack([np.arange(len(sim.t)), sim.raw["accel"], sim.raw["gyro"]])
        np.savetxt(fh, data, fmt="%d", delimiter=",")
    print(f"raw log: {log} ({len(sim.t)} samples)\n")
    assert rimu(["detect", str(log), "-o", str(out / "session.npz"), "--init-still", "4",
                 "--report", str(out / "detection")]) == 0
    print()
    assert rimu(["calibrate", str(out / "session.npz"), "--method", "handheld", "-o", str(out / "cal.json")]) == 0
    cal = Calibration.load(out / "cal.json")
    print("\nagainst the simulation's truth (in the calibration's frame):")
    worst = {}
    for k in ("accel", "gyro"):
        W, _c = gauge_fixed(sim.truth["accel"], (0, 1, 2), sim.truth[k])
        sf_true = 1.0 / np.linalg.norm(W, axis=1)
        err_ppm = (cal[k].scale / sf_true - 1) * 1e6
        print(f"  {k}: scale error {np.round(err_ppm, 0)} ppm")
        worst[k] = float(np.max(np.abs(err_ppm)))
    print()
    assert rimu(["diagnose", str(out / "session.npz"), "--report", str(out / "diagnosis")]) == 0
    return worst


if __name__ == "__main__":
    run(Path(sys.argv[1] if len(sys.argv) > 1 else "rimu-handheld"))
