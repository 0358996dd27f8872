"""Calibrate a simulated cone6 redundant IMU with Cho & Park 2005 (Tables 1 and 2, Table 3 as truth), print the
coefficient table with uncertainties, compare with the truth in units of the reported sigma, write the
calibration file and a residual plot.

    python examples/calibrate_cho_park.py [out_folder]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from rimu.calibration import ChoPark
from rimu.calibration.montecarlo import normalised_errors
from rimu.calibration.plots import plot_residuals
from rimu.session import save_session
from rimu.sim import Simulator, cho_park_procedure

out = Path(sys.argv[1] if len(sys.argv) > 1 else "rimu-example")
out.mkdir(parents=True, exist_ok=True)
run = Simulator(seed=4).run(cho_park_procedure(duration=30.0))
save_session(run.session, out / "cho_park_session.npz")
result = ChoPark().fit(run.session)
print(result.table())
cal = result.to_calibration()
for inst in ("gyro", "accel"):
    names, z = normalised_errors(cal[inst], run.truth[inst])
    print(f"{inst}: error / sigma: max |z| = {np.max(np.abs(z)):.2f}, rms = {np.sqrt(np.mean(z**2)):.2f}")
cal.save(out / "calibration.json")
plot_residuals(result, path=str(out / "residuals.png"))
print(f"written: {out / 'calibration.json'}, {out / 'residuals.png'}, {out / 'cho_park_session.npz'}")
