"""`rimu import` of a file in the two-IMU Pixhawk CSV layout whose values are deg/s and g (written by another tool):
refused at the door as deg/s taken for rad/s, then read right when the units are declared (the declaration was
ignored, so the refusal's own advice could not be followed)."""

from __future__ import annotations

import json

import numpy as np

from rimu.cli import main
from rimu.units import G0


def _write(path, rng):  # type: ignore[no-untyped-def]
    n, fs = 2000, 100.0
    t = np.arange(n) / fs
    cols = [t]
    for _ in range(2):
        w = 90.0 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.array([1.0, 0.5, -0.3]) + 0.1 * rng.standard_normal((n, 3))
        w[: n // 2] = 0.1 * rng.standard_normal((n // 2, 3))      # still first half: gravity at rest
        a = np.array([0.0, 0.0, -1.0]) + 0.002 * rng.standard_normal((n, 3))
        cols += [w, a, np.full((n, 1), 35.0)]
    head = "t_s," + ",".join(f"imu{i}_{c}" for i in range(2) for c in ("gx", "gy", "gz", "ax", "ay", "az", "tempC"))
    np.savetxt(path, np.column_stack(cols), fmt="%.6f", delimiter=",", header=head, comments="")


def test_declared_deg_s_and_g_are_applied(tmp_path, capsys):  # type: ignore[no-untyped-def]
    _write(tmp_path / "flight.csv", np.random.default_rng(3))
    assert main(["import", str(tmp_path / "flight.csv"), "-o", str(tmp_path / "a.npz")]) != 0
    err = capsys.readouterr().err
    assert "--gyro-unit" in err and "--accel-unit" in err and not (tmp_path / "a.npz").exists()
    assert main(["import", str(tmp_path / "flight.csv"), "-o", str(tmp_path / "b.npz"), "--gyro-unit", "deg/s",
                 "--accel-unit", "g", "--json", str(tmp_path / "b.json")]) == 0
    from rimu.io.formats import read_log

    rec = read_log(tmp_path / "b.npz")
    for u in rec.units:
        assert abs(np.nanmean(np.linalg.norm(u.accel, axis=1)) - G0) < 0.01 * G0          # g -> m/s^2
        assert abs(np.nanmax(np.abs(u.gyro[:, 0])) - np.radians(90.0)) < np.radians(1.0)  # deg/s -> rad/s
    summary = json.loads((tmp_path / "b.json").read_text())
    assert "deg/s" in json.dumps(summary) and "g" in json.dumps(summary)
