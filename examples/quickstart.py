#!/usr/bin/env python3
"""Quick start: simulate a cone6 unit on a turntable, calibrate it, fuse its outputs, isolate a sensor.

Run from the repository root: ``python examples/quickstart.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rimu.calibration import Calibration
from rimu.calibration.lsq import fit_lsq
from rimu.errors import RankDeficientError
from rimu.fusion import Pipeline
from rimu.geometry import Geometry, cone6
from rimu.sim import Simulator, cho_park_procedure
from rimu.units import RS_TO_DS


def main() -> None:
    run = Simulator(seed=1).run(cho_park_procedure(duration=20.0))
    cal = Calibration({k: fit_lsq(run.session, instrument=k).to_calibration() for k in ("gyro", "accel")})
    path = cal.save("quickstart-cal.json")
    pipe = Pipeline(Calibration.load(path, geometries={"gyro": cone6(), "accel": cone6()}))
    out = pipe.process(run.block)
    err = (out["gyro"].x - run.truth_inputs["gyro"]) * RS_TO_DS
    print(f"gyro MB error: mean {err.mean(axis=0).round(4)} deg/s, std {err.std(axis=0).round(3)} deg/s")
    keep = np.arange(6) != 4  # Cho & Park Eq. 21: continue without y2 (the set is an argument of every call)
    err = (pipe["gyro"].process(run.block.raw["gyro"], active=keep).x - run.truth_inputs["gyro"]) * RS_TO_DS
    print(f"without y2:    mean {err.mean(axis=0).round(4)} deg/s, std {err.std(axis=0).round(3)} deg/s")
    try:
        Geometry(np.array([[1, 0, 0], [0, 1, 0], [np.sqrt(0.5), np.sqrt(0.5), 0]]))
    except RankDeficientError as exc:
        print(f"a coplanar geometry is refused: {exc}")


if __name__ == "__main__":
    main()
