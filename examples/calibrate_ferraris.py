"""Calibrate imucal's real Ferraris recording (a hand-moved triad) with rimu's generic least squares: known
attitudes for the accelerometers, integrated 360 deg turns for the gyros. Also detect the static and rotating
intervals from the unlabelled data and plot what was found.

    python examples/calibrate_ferraris.py [folder_of_the_recording] [out_folder]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rimu.calibration import LeastSquares
from rimu.calibration.detect import detect_intervals, plot_detection
from rimu.calibration.plots import plot_residuals
from rimu.session import load_ferraris
from rimu.units import G0

folder = Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/imucal_ferraris_session")
out = Path(sys.argv[2] if len(sys.argv) > 2 else "rimu-example")
out.mkdir(parents=True, exist_ok=True)
session = load_ferraris(folder)
result = LeastSquares().fit(session)
print(result.table())
cal = result.to_calibration()
for seg in session.segments:
    c = cal["accel"] if seg.kind == "static" else cal["gyro"]
    x = np.linalg.solve(c.axes_mb(), c.compensate(seg.raw[c.instrument]).T).T
    if seg.kind == "static":
        print(f"{seg.label}: |f| = {np.linalg.norm(x.mean(axis=0)) / G0:.5f} g")
    else:
        print(f"{seg.label}: turn = {np.degrees(np.linalg.norm(x.sum(axis=0) / session.sample_rate)):.2f} deg")
cal.save(out / "ferraris_calibration.json")
plot_residuals(result, path=str(out / "ferraris_residuals.png"))
d = np.loadtxt(folder / "example_ferraris_session.csv", delimiter=",", skiprows=1)
det = detect_intervals(d[:, 4:7], session.sample_rate, gyro=d[:, 1:4])
plot_detection(det, d[:, 4:7], session.sample_rate, path=str(out / "ferraris_detection.png"))
print(f"detected {len(det.static)} static intervals and {len(det.rotations)} rotations -> "
      f"{out / 'ferraris_detection.png'}")
