"""The fault-management campaign (docs/fdi.md): no fault type leaves a biased output marked nominal, dropouts and
intermittent faults end with every sensor back in and no ping-pong, double faults on cone6 are isolated or
flagged, CUSUM's wrong-isolation rate next to the set GLT's."""

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.experiments.campaign import CampaignSpec, clopper_pearson, run_campaign
from rimu.experiments.scenarios import SCENARIOS, ScenarioSpec, run_scenarios, scenario_table, summarise
from rimu.fdi import CusumBank, RedundancyManager
from rimu.fdi.multiple import FaultSetGlt
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6


@pytest.fixture(scope="module")
def campaign():
    spec = ScenarioSpec(runs=2, duration=26.0, base_seed=2026)
    rows = run_scenarios(spec)
    return spec, rows, summarise(rows)


def test_no_biased_output_while_nominal(campaign):
    _spec, _rows, summ = campaign
    assert len(summ) == 3 * len(SCENARIOS)
    for s in summ:
        assert s["biased_while_nominal"] == 0, s
        assert s["all_finite"] and s["false_isolations"] == 0, s
        assert s["detected"] == 1.0, s
    table = scenario_table(summ)
    assert table.count("\n") == 2 + 3 * len(SCENARIOS) - 1 and "| cone6 | double |" in table


def test_dropouts_and_intermittent_faults_end_readmitted_without_ping_pong(campaign):
    _spec, _rows, summ = campaign
    for s in summ:
        if s["scenario"] in ("dropout", "intermittent"):
            assert s["readmitted_at_end"] == 1.0, s
            assert s["max_isolations"] <= (3 if s["scenario"] == "intermittent" else 4), s   # three bursts
        if s["scenario"] == "intermittent" and s["geometry"] != "tetrad4":
            assert s["correct"] == 1.0, s


def test_double_faults_isolated_or_flagged_and_singles_isolated(campaign):
    _spec, rows, _summ = campaign
    for r in rows:
        if r["geometry"] in ("cone6", "dodecahedron6") and r["scenario"] in ("single", "double", "stuck", "ramp"):
            assert r["correct"] or r["flagged"], r
            assert not r["wrong"], r
        if r["geometry"] == "tetrad4" and r["scenario"] in ("single", "stuck"):
            assert r["flagged"] and r["degraded_share"] > 0.9, r          # detection only, said so


def test_cusum_wrong_isolation_rate_next_to_the_set_glt():
    """Open loop, cone6, 1 sigma biases: the CUSUM bank names a wrong sensor in several per cent of its alarms
    (docs/fdi.md: 7 %, 99 % interval 5.5-8.9 %). In closed loop at 2 sigma the same CUSUM detection with the set
    GLT as isolator makes no wrong isolation in the runs where the CUSUM's own choice makes some."""
    spec = CampaignSpec(faults=["bias"], sizes=[1.0], repetitions=4, closed_loop=False, detector="cusum",
                        cusum_bias=1.0, arl0=1e4, duration=30.0, fault_start=5.0, base_seed=66)
    s = run_campaign(spec, workers=0).summary()[0]
    lo, hi = s["wrong_isolation_ci"]
    assert lo <= 0.07 <= hi and lo > 0.03, (s["wrong_isolation"], lo, hi)

    sig = 0.01
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=sig)
    wrong = {}
    for name, iso, confirm in (("cusum", "detector", 1), ("set_glt", FaultSetGlt(1e-4), 3)):
        mgr = RedundancyManager(InstrumentPipeline(cal), CusumBank(2 * sig * np.ones(6), 1e4), confirm=confirm,
                                isolator=iso)
        rng = np.random.default_rng(5)
        w = 0
        for run in range(30):
            mgr.reset()
            Y = cal.raw_output(np.array([0.1, 0.2, 0.3])) + sig * rng.standard_normal((700, 6))
            Y[100:, run % 6] += 2 * sig
            ev = [e for e in mgr.run(Y).events if e.kind == "isolated"]
            w += bool(ev) and ev[0].sensor != mgr.names[run % 6]
        wrong[name] = w
    assert wrong["cusum"] >= 1 and wrong["set_glt"] == 0, wrong
    lo, hi = clopper_pearson(wrong["cusum"], 30, 0.99)
    assert lo <= 0.07 <= hi


def test_the_campaign_gives_the_same_rows_on_a_process_pool():
    """run_scenarios shares run_campaign's loop: two worker processes give the rows of one process, in order."""
    spec = ScenarioSpec(geometries=["tetrad4"], scenarios=["single", "stuck"], runs=2, duration=6.0, onset=2.0)
    assert run_scenarios(spec, workers=2) == run_scenarios(spec)
