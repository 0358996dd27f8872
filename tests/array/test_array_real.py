"""The array report on the shared real recordings with several triads (skipped when the data is absent).

A throw-away reader lives here on purpose: the project's readers for these formats belong to another issue.
Both recordings are from multicopters: rotor vibration is not rigid-body motion, so the fits run below 5 Hz
(:func:`rimu.array.lowpass`, every triad alike).
"""

from __future__ import annotations

import lzma

import numpy as np

from rimu.array import ArrayLayout, array_report
from tests.conftest import shared_data


def _xsens(run: str):
    base = shared_data("quadrotor_4x_xsens_dot") / run
    d = [np.loadtxt(lzma.open(base / f"IMU_{i}.csv.xz", "rt"), delimiter=",", skiprows=1) for i in range(1, 5)]
    n = min(len(x) for x in d)
    return (d[0][:n, 0], np.radians(np.stack([x[:n, 7:10] for x in d], axis=1)),
            np.stack([x[:n, 4:7] for x in d], axis=1))


def _pixhawk():
    x = np.loadtxt(lzma.open(shared_data("pixhawk1_dual_imu_flight") / "01_07_59_imu01.csv.xz", "rt"),
                   delimiter=",", skiprows=1)
    x = x[np.concatenate([[True], np.diff(x[:, 0]) > 0])]
    return x[:, 0], np.stack([x[:, 1:4], x[:, 8:11]], axis=1), np.stack([x[:, 4:7], x[:, 11:14]], axis=1)


def _falls(steps: dict) -> list[float]:
    v = [x.mean() for x in steps.values()]
    assert all(a > b for a, b in zip(v, v[1:]) if a != b), steps
    return v


def test_xsens_dot_parity_falls_and_positions_repeat_across_flights():
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 4, axis=0), np.zeros((4, 3)))
    positions = []
    for run in ("Horizontal/path_10", "Vertical/path_1"):
        t, gyro, accel = _xsens(run)
        rep = array_report(lay, t, gyro, accel, motion_threshold_deg_s=10.0, lowpass_hz=5.0)
        g = _falls(rep.gyro_steps)
        a = _falls(rep.accel_steps)
        assert g[-1] < 0.3 * g[0] and a[-1] < 0.4 * a[0], rep.to_markdown()
        # a term is named limiting only when it explains at least 10 % of what is left (issue 32)
        assert rep.limiting_term.split(" ")[0] in ("aa_sensitivity", "rate_nonlinearity", "g_sensitivity", "noise",
                                                   "unexplained")
        positions.append(rep.position_fit.positions_m - rep.position_fit.positions_m[0])
        tau = rep.gyro_fit.sampling_offset_s
        assert 2e-3 < abs(tau[2] - tau[0]) < 7e-3 and 2e-3 < abs(tau[3] - tau[0]) < 7e-3, tau
    # the four units did not move between the flights: their positions, fitted from each flight alone, agree
    assert np.abs(positions[0] - positions[1]).max() < 5e-3, positions
    d = np.linalg.norm(positions[0], axis=1)                     # a 37 mm x 99 mm rectangle
    assert 0.033 < d[1] < 0.043 and 0.094 < d[2] < 0.104, positions[0]


def test_pixhawk_two_imus_parity_falls():
    t, gyro, accel = _pixhawk()
    lay = ArrayLayout(np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3)))
    rep = array_report(lay, t, gyro, accel, motion_threshold_deg_s=10.0, lowpass_hz=5.0)
    g = _falls(rep.gyro_steps)
    a = _falls(rep.accel_steps)
    assert g[-1] < 0.6 * g[0] and a[-1] < 0.9 * a[0], rep.to_markdown()
    assert any("separate chips" in n for n in rep.notes)
