"""`rimu apply`: every figure it prints, parsed with its unit and converted, equals the closed-form truth (issue 27).

A text log of counts with a known scale (a 16.4 count/(deg/s) gyro, a 2048 count/g accelerometer) and a calibration of
those counts: the calibrated means it prints are ``SF * mean(counts) - bias`` in the field unit they state
(rimu.units.fmt), the sample count and rate are the log's, the written recording holds them in SI.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import main
from rimu.geometry import triad3
from rimu.units import G0
from tests.cli.test_figures_per_command import to_si


def test_apply_prints_the_calibrated_means_of_counts_in_their_unit(tmp_path, capsys):
    rng = np.random.default_rng(1)
    n = 1000
    g = np.array([100, -200, 50]) + rng.integers(-3, 4, (n, 3))
    a = np.array([30, -10, 2048]) + rng.integers(-3, 4, (n, 3))
    with (tmp_path / "raw.csv").open("w") as fh:
        fh.write("Fs,100\nn,ax,ay,az,gx,gy,gz\n")
        np.savetxt(fh, np.column_stack([np.arange(n), a, g]), fmt="%d", delimiter=",")
    sg, sa = np.radians(1 / 16.4), G0 / 2048
    bg, ba = np.array([1e-3, 0.0, -1e-3]), np.array([0.01, 0.0, -0.02])
    geo = triad3()
    Calibration({"gyro": InstrumentCalibration("gyro", geo, np.full(3, sg), np.eye(3), bg),
                 "accel": InstrumentCalibration("accel", geo, np.full(3, sa), np.eye(3), ba)},
                raw_unit="count").save(tmp_path / "cal.json")
    assert main(["apply", str(tmp_path / "raw.csv"), "--calibration", str(tmp_path / "cal.json"), "-o",
                 str(tmp_path / "out.npz")]) == 0
    out = capsys.readouterr().out
    m = re.search(r"(\d+) samples at ([\d.]+) Hz; gyro mean \[([^\]]+)\] (\S+), accel mean \[([^\]]+)\] (\S+)", out)
    assert m, out
    assert int(m.group(1)) == n and float(m.group(2)) == pytest.approx(100.0)
    truth = {"rate": sg * g.mean(axis=0) - bg, "specific_force": sa * a.mean(axis=0) - ba}
    for (vals, u), q in (((m.group(3), m.group(4)), "rate"), ((m.group(5), m.group(6)), "specific_force")):
        got = np.array([to_si(float(v), u, q) for v in vals.split(",")])
        # four significant digits printed: half a unit of the fourth digit of the largest
        tol = 5e-4 * np.abs(truth[q]).max()
        np.testing.assert_allclose(got, truth[q], rtol=0, atol=tol)
    assert (m.group(4), m.group(6)) == ("deg/s", "m/s^2")   # 6.04 deg/s, 9.827 m/s^2: the field units of their size
    # the written recording holds the same calibrated samples in SI
    z = np.load(tmp_path / "out.npz")
    key = next(k for k in z.files if "gyro" in k and z[k].ndim == 2 and z[k].shape[1] == 3)
    np.testing.assert_allclose(z[key].mean(axis=0), truth["rate"], rtol=1e-9, atol=1e-12)
