"""`rimu import` (issue 27's property test: samples, duration in s, rate in Hz, units converted from) of a file in the two-IMU Pixhawk CSV layout whose values are deg/s and g (written by another tool):
refused at the door as deg/s taken for rad/s, then read right when the units are declared (the declaration was
ignored, so the refusal's own advice could not be followed)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

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


def _empty_imu1_gyro(path, rows) -> None:  # type: ignore[no-untyped-def]
    """Blank imu1's three gyro cells on the given lines of a file written by :func:`_write` (line 0: the header)."""
    lines = path.read_text().splitlines()
    for r in rows:
        cells = lines[r].split(",")
        cells[8:11] = ["", "", ""]
        lines[r] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_declared_deg_s_and_g_are_applied(tmp_path, capsys):  # type: ignore[no-untyped-def]
    _write(tmp_path / "flight.csv", np.random.default_rng(3))
    assert main(["import", str(tmp_path / "flight.csv"), "-o", str(tmp_path / "a.npz")]) != 0
    err = capsys.readouterr().err
    assert "--gyro-unit" in err and "--accel-unit" in err and not (tmp_path / "a.npz").exists()
    assert main(["import", str(tmp_path / "flight.csv"), "-o", str(tmp_path / "b.npz"), "--gyro-unit", "deg/s",
                 "--accel-unit", "g", "--json", str(tmp_path / "b.json")]) == 0
    out = capsys.readouterr().out
    # the figures it prints, in their units: 2000 samples of each IMU over 19.99 s at 100 Hz, converted from deg/s, g
    for name in ("imu0", "imu1"):
        line = next(ln for ln in out.splitlines() if ln.startswith(name + ":"))
        m = re.match(rf"{name}: (\d+) samples, ([0-9.]+) s, ([0-9.]+) Hz; rejected: none$", line)
        assert m, line
        assert int(m[1]) == 2000 and float(m[2]) == pytest.approx(19.99, abs=5e-4)
        assert float(m[3]) == pytest.approx(100.0, rel=1e-3)
    assert "gyro declared (deg/s)" in out and "accel declared (g)" in out
    from rimu.io.formats import read_log

    rec = read_log(tmp_path / "b.npz")
    for u in rec.units:
        assert abs(np.nanmean(np.linalg.norm(u.accel, axis=1)) - G0) < 0.01 * G0          # g -> m/s^2
        assert abs(np.nanmax(np.abs(u.gyro[:, 0])) - np.radians(90.0)) < np.radians(1.0)  # deg/s -> rad/s
    summary = json.loads((tmp_path / "b.json").read_text())
    assert "deg/s" in json.dumps(summary) and "g" in json.dumps(summary)


def test_setup_and_replay_take_the_log_itself(tmp_path, capsys):  # type: ignore[no-untyped-def]
    """`rimu replay LOG --calibration` on a log, not a session: the log's session is written to a scratch file and
    read back in the same command (it was held back by the command's output group: 'fl_csv.npz does not exist')."""
    _write(tmp_path / "fl.csv", np.random.default_rng(4))
    units = ["--gyro-unit", "deg/s", "--accel-unit", "g"]
    # 20 epochs (rows 1500-1519) where imu1's gyro cells are empty: replayed as invalid samples, not dropped
    _empty_imu1_gyro(tmp_path / "fl.csv", range(1501, 1521))
    assert main(["setup", str(tmp_path / "fl.csv"), *units, "-o", str(tmp_path / "u.json"), "--average", "0",
                 "-q"]) == 0
    assert main(["replay", str(tmp_path / "fl.csv"), *units, "--calibration", str(tmp_path / "u.json"),
                 "--json", str(tmp_path / "r.json")]) == 0, capsys.readouterr().err
    doc = json.loads((tmp_path / "r.json").read_text())
    out = capsys.readouterr().out
    assert "replayed 2000 samples" in out, out               # every epoch, the 20 with imu1's gyro empty included
    assert "gyro: 2000 samples" in out and json.dumps(doc)


def test_a_command_that_takes_all_valid_epochs_counts_what_it_leaves_out(tmp_path, capsys):  # type: ignore
    """`rimu noise` of a log whose imu1 gyro is empty on 20 rows: those epochs are left out of its session, and the
    command says how many, of how many (they vanished without a word before)."""
    _write(tmp_path / "fl.csv", np.random.default_rng(5))
    _empty_imu1_gyro(tmp_path / "fl.csv", range(101, 121))
    main(["noise", str(tmp_path / "fl.csv"), "--gyro-unit", "deg/s", "--accel-unit", "g"])
    err = capsys.readouterr().err
    assert "20 of 2000 epochs left out: not every IMU has a valid sample there" in err, err
