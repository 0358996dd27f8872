"""The array report on the shared real recordings with several triads (skipped when the data is absent).

A throw-away reader lives here on purpose: the project's readers for these formats belong to another issue.
"""

from __future__ import annotations

import lzma

import numpy as np

from conftest import shared_data
from rimu.array import ArrayLayout, array_report


def _xsens(run: str):
    base = shared_data("quadrotor_4x_xsens_dot") / run
    d = [np.loadtxt(lzma.open(base / f"IMU_{i}.csv.xz", "rt"), delimiter=",", skiprows=1) for i in range(1, 5)]
    n = min(len(x) for x in d)
    return (d[0][:n, 0], np.radians(np.stack([x[:n, 7:10] for x in d], axis=1)),
            np.stack([x[:n, 4:7] for x in d], axis=1))


def _pixhawk():
    x = np.loadtxt(lzma.open(shared_data("pixhawk1_dual_imu_flight") / "01_07_59_imu01.csv.xz", "rt"),
                   delimiter=",", skiprows=1)
    keep = np.concatenate([[True], np.diff(x[:, 0]) > 0])
    x = x[keep]
    return x[:, 0], np.stack([x[:, 1:4], x[:, 8:11]], axis=1), np.stack([x[:, 4:7], x[:, 11:14]], axis=1)


def test_xsens_parity_falls_with_each_step(tmp_path):
    t, gyro, accel = _xsens("Horizontal/path_10")
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 4, axis=0), np.zeros((4, 3)))
    rep = array_report(lay, t, gyro, accel)
    g = [v.mean() for v in rep.gyro_steps.values()]
    a = [v.mean() for v in rep.accel_steps.values()]
    assert g[0] > g[1] > g[2] and a[0] > a[2] > a[3], rep.to_markdown()
    assert rep.limiting_term != "noise"
    (tmp_path / "report.md").write_text(rep.to_markdown())
    assert rep.plot(tmp_path / "array.png").stat().st_size > 1000


def test_pixhawk_two_imus_parity_falls():
    t, gyro, accel = _pixhawk()
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3)))
    rep = array_report(lay, t, gyro, accel, motion_threshold_deg_s=10.0)
    g = [v.mean() for v in rep.gyro_steps.values()]
    assert g[0] > g[-1], rep.to_markdown()
    a = [v.mean() for v in rep.accel_steps.values()]
    assert a[0] > a[2] >= a[3], rep.to_markdown()
