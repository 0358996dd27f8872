"""Done-when of issue 19: a full replay of every shared real multi-IMU recording, fault-free as recorded, ends
with every unit that delivers data active and no isolation. Skips cleanly when the data are absent.

The unit is set up by the recipe of docs/real-units.md from the first half of each recording (clock offsets,
axis alignment, bias differences, noise from the disagreement, 0.1 s block averages) and replayed whole through
a fresh :class:`RedundancyManager` per instrument (GLT snapshot, p_fa 1e-3, 3 confirmations). Failures name the
isolations (sensor, time) and the parity rms, which is what the motion-aware thresholds must bring down.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rimu.calibration.multi_imu import setup_multi_imu
from rimu.fdi import HealthState, RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.io.pixhawk_dual import read_pixhawk_dual
from rimu.io.xsens_dot import read_xsens_dot_run
from tests.conftest import shared_data

XSENS = ("Horizontal/path_10", "Horizontal/path_11", "Vertical/path_1", "Vertical/path_8", "Vertical/path_30",
         "StraightLine/path_1")
CASES = [("pixhawk", "")] + [("xsens", r) for r in XSENS]


def _load(kind: str, run: str):
    if kind == "pixhawk":
        return read_pixhawk_dual(shared_data("pixhawk1_dual_imu_flight"))
    d = shared_data("quadrotor_4x_xsens_dot") / run
    if not Path(d).exists():
        pytest.skip(f"run {run} is not in the shared data")
    return read_xsens_dot_run(d)


@pytest.mark.parametrize("kind, run", CASES, ids=[f"{k}-{r}" if r else k for k, r in CASES])
def test_full_replay_without_isolation(kind, run):
    rec = _load(kind, run)
    t_end = max(u.t[-1] for u in rec.units)
    su = setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, 0.5 * t_end))
    assert su.delivering == rec.names           # every unit of these recordings delivers data
    problems = []
    for inst in su.calibration.instruments:
        pipe = InstrumentPipeline(su.calibration[inst])
        mgr = RedundancyManager(pipe, p_fa=1e-3, confirm=3)
        res = mgr.run(su.block.raw[inst], su.block.valid[inst], su.block.t)
        iso = [(e.sensor, round(e.t, 2)) for e in res.events if e.kind in ("isolated", "invalid_isolated")]
        P = mgr.pipeline.process(su.block.raw[inst], su.block.valid[inst])
        dof = int(P.dof.max())
        rms = float(np.sqrt(np.mean(P.parity[:, :dof] ** 2))) if dof else 0.0
        if iso or mgr.isolated.any():
            problems.append(f"{inst}: isolations {iso}, parity rms {rms:.2f} sigma, "
                            f"alarm rate {res.alarm.mean():.3%}")
        # the alarm rate is far above the design 0.1 % (heavy-tailed flight disagreement); the confirmation carries
        # it today (docs/real-units.md: "up to 10 %")
        assert res.alarm.mean() < 0.10, (inst, res.alarm.mean())
        # the unit's state is the one its geometry allows, with every sensor active
        k = len(rec.names)
        want = {1: HealthState.NO_REDUNDANCY, 2: HealthState.DETECTION_ONLY}.get(k, HealthState.NOMINAL)
        # (at the last sample where every unit delivered: at the very end units whose clocks were shifted have no
        # data, and the state is the set of that sample's valid sensors)
        # (and where the estimate used them all: on an alarm sample the state is that of the set without the
        # suspects, the set x, P and the parity describe)
        last = int(np.flatnonzero(su.block.valid[inst].all(axis=1) & res.active.all(axis=1))[-1])
        assert res.state_names()[last] == want.value, (inst, res.state_names()[last])
    assert not problems, "; ".join(problems)


def test_motion_aware_thresholds_stop_the_flight_alarms():
    """Held out: the motion terms are fitted (margin 10) on the first half of each fault-free recording and the
    second half is replayed. Under the test's model a run of 3 consecutive alarms has probability about
    p_fa^3 = 1e-9 per sample, so none is expected in these few thousand samples; the plain GLT raises such runs
    in flight (the disagreement between triads grows with the motion), the motion-aware GLT must raise none,
    and neither isolates anything."""
    from rimu.fdi import fit_motion_detector, unisolated_alarm_runs

    plain_runs = motion_runs = 0
    n_total = 0
    for kind, run in CASES:
        if kind == "xsens" and run == "Vertical/path_30":
            continue                               # one unit only: no parity
        try:
            rec = _load(kind, run)
        except pytest.skip.Exception:
            continue
        t_end = max(u.t[-1] for u in rec.units)
        su = setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, 0.5 * t_end))
        b, cal = su.block, su.calibration["gyro"]
        first = b.t < 0.5 * t_end
        fs = 1.0 / float(np.median(np.diff(b.t)))
        det = fit_motion_detector(cal, b.raw["gyro"][first], b.valid["gyro"][first], fs, margin=10.0)
        for d in (None, det):
            mgr = RedundancyManager(InstrumentPipeline(cal), d, p_fa=1e-3, confirm=3)
            res = mgr.run(b.raw["gyro"][~first], b.valid["gyro"][~first], b.t[~first])
            assert not [e for e in res.events if e.kind in ("isolated", "invalid_isolated")], (kind, run, d)
            if d is None:
                plain_runs += len(unisolated_alarm_runs(res))
            else:
                motion_runs += len(unisolated_alarm_runs(res))
        n_total += int((~first).sum())
    if n_total == 0:
        pytest.skip("no shared multi-IMU recording here")
    assert plain_runs > 0          # the flights do excite what the plain test leaves out (else this shows nothing)
    assert motion_runs == 0, (motion_runs, n_total)
