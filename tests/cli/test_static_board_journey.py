"""Issue 32, "other real units kept apart": the journey of docs/real-units.md on the public static recording of four
MPU-9250s (lauratrain99/Attitude-multi-IMU-filter, ``real-data/static/imu{1..4}_raw.mat``; see that page). The
files are third-party data, not in the repository: put the four files in a folder named ``mpu9250x4_static``
anywhere under ``RIMU_EXTERNAL_LOGS``; without it the test skips.

    RIMU_EXTERNAL_LOGS=/tmp/rimu-ext python -m pytest tests/cli/test_static_board_journey.py

Checked, at 0.1 s averages: the setup refuses the rotations with the reason (one direction of gravity, no motion);
with ``--parallel``, a fault-free replay ends nominal with no isolation and the alarm rate at rest of the held-out
half within twice the design rate; a 1 deg/s bias on one sensor of each triad at rest is isolated on its sensor
within 1 s; the PX4-style rule flags none of them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from rimu.cli import main
from tests.cli.test_mimu4444_journey import _slots

DEG = np.pi / 180.0


def _folder() -> Path:
    base = os.environ.get("RIMU_EXTERNAL_LOGS")
    hits = sorted(Path(base).rglob("mpu9250x4_static")) if base and Path(base).is_dir() else []
    if not hits:
        pytest.skip("the public static recording of four MPU-9250s is not here (RIMU_EXTERNAL_LOGS/.../mpu9250x4_static)")
    return hits[0]


@pytest.mark.slow
def test_the_journey_on_the_static_board(tmp_path, capsys):
    log = _folder()
    f = {k: str(tmp_path / k) for k in ("unit.json", "unit.npz", "setup.json", "free.json", "faults.json")}
    setup = ["setup", str(log), "-o", f["unit.json"], "--fit-window", ":50%", "--average", "0.1", "--motion-fit",
             "--session", f["unit.npz"], "--json", f["setup.json"]]
    assert main(setup) == 2
    err = capsys.readouterr().err
    assert "no motion" in err and "one direction only" in err, err
    assert main(setup + ["--parallel"]) == 0
    s = json.loads(Path(f["setup.json"]).read_text())
    half, names = s["fit_window_s"][1], s["imus"]
    replay = ["replay", f["unit.npz"], "--calibration", f["unit.json"], "--common-cause", "--instrument", "gyro"]
    assert main(replay + ["--json", f["free.json"]]) == 0
    g = json.loads(Path(f["free.json"]).read_text())["gyro"]
    assert g["isolations"] == 0 and g["final_state"] == "nominal"
    held = [x for x in g["segments"] if x["kind"] == "static_unknown" and x["t_start_s"] >= half]
    a, n = sum(x["alarms"] for x in held), sum(x["samples"] for x in held)
    assert n > 1000 and a / n <= 2e-3, (a, n)
    onsets = _slots(s, [2.0] * len(names))
    sensors = [f"{nm}_{'xyz'[j % 3]}" for j, nm in enumerate(names)]
    inject = [f"--inject=bias:gyro:{x}:{t}:{DEG:.9g}:2" for x, t in zip(sensors, onsets)]
    assert main(replay + ["--px4", "--json", f["faults.json"]] + inject) == 0
    doc = json.loads(Path(f["faults.json"]).read_text())
    for x, t in zip(sensors, onsets):
        first = [e for e in doc["gyro"]["events"] if e["kind"] == "isolated" and t <= e["t"] < t + 2.0]
        assert first and first[0]["sensor"] == x and first[0]["t"] - t <= 1.0, (x, t, first[:2])
    assert not [p for p in doc["px4"]["flags"] if any(t <= p["t"] < t + 2.0 for t in onsets)]
