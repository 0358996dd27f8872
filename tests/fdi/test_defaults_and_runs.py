"""One default for re-admission across the manager, rimu replay, FdiSettings and rimu export-c; the count of
confirmed alarm runs that isolate nothing (rimu.fdi.unisolated_alarm_runs) on hand-made sequences."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from rimu.cli import build_parser
from rimu.cli.export_c import fdi_settings
from rimu.cli.replay import readmit_after
from rimu.export import FdiSettings
from rimu.fdi import FdiEvent, RedundancyManager, ReplayResult, SensorHealth, unisolated_alarm_runs
from rimu.fdi.health import READMIT_AFTER


def _args(*argv):
    return build_parser().parse_args(list(argv))


def test_one_readmit_default_everywhere():
    manager = inspect.signature(RedundancyManager.__init__).parameters["readmit_after"].default
    health = inspect.signature(SensorHealth.__init__).parameters["readmit_after"].default
    replay = readmit_after(_args("replay", "d.npz", "--calibration", "c.json"))
    export = fdi_settings(_args("export-c", "c.json", "-o", "out")).readmit_after
    assert manager == health == FdiSettings().readmit_after == replay == export == READMIT_AFTER
    assert READMIT_AFTER is not None and READMIT_AFTER >= 1
    # the options act the same way in both commands
    assert readmit_after(_args("replay", "d.npz", "--calibration", "c.json", "--readmit-after", "7")) == 7
    assert fdi_settings(_args("export-c", "c.json", "-o", "o", "--readmit-after", "7")).readmit_after == 7
    assert readmit_after(_args("replay", "d.npz", "--calibration", "c.json", "--no-readmit")) is None
    assert fdi_settings(_args("export-c", "c.json", "-o", "o", "--no-readmit")).readmit_after is None


def _result(alarm, events=(), t=None):
    a = np.asarray(alarm, bool)
    N = len(a)
    t = np.arange(N) * 0.5 if t is None else np.asarray(t, float)
    return ReplayResult(t, np.zeros((N, 3)), np.zeros(N), np.ones(N), a, np.zeros(N, np.int8), np.zeros(N, np.int8),
                        [FdiEvent(int(k), float(t[k]), kind, "x1", "") for k, kind in events], ["x1"])


def test_unisolated_alarm_runs_on_a_hand_made_sequence():
    #        0  1  2  3  4  5  6  7  8  9 10 11 12 13 14 15 16 17 18 19
    alarm = [1, 1, 1, 0, 1, 1, 0, 1, 1, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1]
    # runs of length 3, 2, 6 and 5: three reach 3 alarms, completing at samples 2, 9 and 17 (t = k / 2)
    assert unisolated_alarm_runs(_result(alarm)) == [1.0, 4.5, 8.5]
    # an isolation at the sample a run completes removes that run, one elsewhere does not
    assert unisolated_alarm_runs(_result(alarm, [(9, "isolated"), (12, "invalid_isolated")])) == [1.0, 8.5]
    assert unisolated_alarm_runs(_result(alarm, [(17, "invalid_isolated"), (2, "readmitted")])) == [1.0, 4.5]
    # confirm = 1: every run counts once at its first alarm; confirm longer than every run: none
    assert unisolated_alarm_runs(_result(alarm), confirm=1) == [0.0, 2.0, 3.5, 7.5]
    assert unisolated_alarm_runs(_result(alarm), confirm=7) == []
    assert unisolated_alarm_runs(_result([0, 0, 0])) == [] and unisolated_alarm_runs(_result([])) == []
    with pytest.raises(ValueError, match="confirm"):
        unisolated_alarm_runs(_result(alarm), confirm=0)


def test_unisolated_alarm_runs_of_a_manager_that_cannot_isolate():
    """Four sensors (a tetrad) detect but cannot isolate: a 12-sample bias gives one confirmed run and no
    isolation; the same fault on a cone of six is isolated, and its run then counts for nothing."""
    from rimu.calibration import InstrumentCalibration
    from rimu.fusion import InstrumentPipeline
    from rimu.geometry import cone6, tetrad4

    out = []
    for geom in (tetrad4(), cone6()):
        cal = InstrumentCalibration.nominal("gyro", geom, scale=1.0, noise_sigma=0.01)
        rng = np.random.default_rng(3)
        Y = cal.raw_output(np.array([0.1, 0.2, 0.3]))[None] + 0.01 * rng.standard_normal((60, geom.n))
        Y[20:32, 1] += 0.5                                          # 50 sigma on one sensor for 12 samples
        res = RedundancyManager(InstrumentPipeline(cal), confirm=3, sample_rate=10.0).run(Y)
        out.append((unisolated_alarm_runs(res), res.first("isolated")))
    (tetra_runs, tetra_iso), (cone_runs, cone_iso) = out
    assert tetra_iso is None and tetra_runs == [2.2]  # alarms from sample 20, the run completes at 22 (t = 2.2 s)
    assert cone_iso is not None and cone_iso.t == pytest.approx(2.2) and cone_runs == []
