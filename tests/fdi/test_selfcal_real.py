"""Issue 30 on the shared real recordings: with the tracker running, the parity rms over the second half of the
flight is lower than with the fixed calibration fitted on the first half, and nothing is isolated (recipe and
drift model in tests/fdi/selfcal_real.py; figures in docs/selfcal.md). Skips cleanly when the data are absent.

The quadrotor run Vertical/path_30 has one unit only (no parity) and is not a redundant recording. The MIMU4444
board (mimu4444_array) is not here: set up from its first half (static poses), both replays isolate 21 of its
24 gyros in the violent rotation of the second half (docs/selfcal.md); it needs misalignment terms and the array
calibration as the starting point, and its five runs take 30 s.
"""

from __future__ import annotations

import pytest

from tests.conftest import shared_data
from tests.fdi.selfcal_real import XSENS, compare, hindsight

CASES = [("pixhawk1_dual_imu_flight", "")] + [("quadrotor_4x_xsens_dot", r) for r in XSENS]
# known not met: the second half of this run is 12 s (119 averaged samples); tracked 1.048 against fixed 1.041 sigma
NOT_MET = {"StraightLine/path_1"}


def _load(folder: str, run: str):
    from rimu.io.pixhawk_dual import read_pixhawk_dual
    from rimu.io.xsens_dot import read_xsens_dot_run

    d = shared_data(folder)
    if not run:
        return read_pixhawk_dual(d)
    if not (d / run).exists():
        pytest.skip(f"run {run} is not in the shared data")
    return read_xsens_dot_run(d / run)


@pytest.mark.parametrize("folder, run", [pytest.param(f, r, marks=pytest.mark.xfail(
    strict=True, reason="second half of 12 s: tracking does not lower the parity rms (1.048 vs 1.041 sigma)"))
    if r in NOT_MET else (f, r) for f, r in CASES], ids=[r or f for f, r in CASES])
def test_tracking_lowers_the_second_half_parity_without_isolation(folder, run):
    c = compare(_load(folder, run))
    print(f"\n{folder} {run}: {c['n']} gyros, {c['samples']} samples of the second half at {c['rate_hz']:.0f} Hz; parity "
          f"rms {c['rms_fixed']:.3f} sigma fixed, {c['rms_tracked']:.3f} tracked; isolations {c['isolations_fixed']} "
          f"fixed, {c['isolations_tracked']} tracked; alarm rate {c['alarms_fixed']:.2%} fixed, "
          f"{c['alarms_tracked']:.2%} tracked")
    assert c["isolations_tracked"] == 0
    assert c["rms_tracked"] < c["rms_fixed"]


@pytest.mark.parametrize("run", sorted(NOT_MET))
def test_where_tracking_does_not_help_there_is_no_drift_to_track(run):
    """StraightLine/path_1: even with hindsight, constant biases and relative scales fitted to the second half's own
    parity lower its rms by less than one sampling standard error: the disagreement left is noise, not drift the model
    could track (so the tracker cannot be shown to lower it; docs/selfcal.md)."""
    c = compare(_load("quadrotor_4x_xsens_dot", run))
    h = hindsight(c)
    print(f"\n{run}: parity rms fixed {c['rms_fixed']:.3f}, tracked {c['rms_tracked']:.3f}, hindsight bias+scale "
          f"{h['rms']:.3f} ({h['dof_corrected']:.3f} per degree of freedom left); standard error {h['se']:.3f} sigma")
    assert c["rms_fixed"] - h["dof_corrected"] < h["se"]
    assert abs(c["rms_tracked"] - c["rms_fixed"]) < h["se"]
