"""``rimu replay --selfcal``: the runtime tracks the drift in flight from the command line; the summary, the events
JSON, the report and the estimates file show the tracked terms over time with their 1-sigma, and the command decides
as the API's Runtime with the same tracker does."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.calibration import Calibration
from rimu.cli import main
from rimu.epoch import EpochBlock
from rimu.export.estimates import read_estimates
from rimu.fdi import GltWindow, RedundancyManager, Runtime
from rimu.fdi.selfcal import SelfCalLoop, SelfCalSettings, SelfCalTracker, TrackedGltWindow
from rimu.fusion import InstrumentPipeline, Pipeline
from rimu.geometry import cone6
from rimu.session import Segment, Session, save_session
from tests.fdi.selfcal_flight import TC_SIGMA, flight

FS = 10.0


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay_selfcal")
    F = flight(cone6(), hours=0.1, fs=FS, seed=3)          # 6 min, a 30 K ramp: ~150 deg/h of temperature drift
    seg = Segment("flight", "motion", F.t, {"gyro": F.Y}, temperature=F.temperature)
    save_session(Session([seg], {"gyro": cone6()}, FS, raw_unit="rad/s"), d / "fl.npz")
    Calibration({"gyro": F.cal}, raw_unit="rad/s").save(d / "cal.json")
    return d, F


def _args(d, F, *more):
    q = float(np.asarray(F.settings.bias_rw)[0])
    return ["replay", str(d / "fl.npz"), "--calibration", str(d / "cal.json"), "--p-fa", "1e-6", *more,
            "--selfcal", "--selfcal-bias-rw", repr(q), "--selfcal-scale-rw", repr(F.settings.scale_rw),
            "--selfcal-temperature-orders", "3", "--selfcal-temperature-sigma", ",".join(map(repr, TC_SIGMA)),
            "--selfcal-window", "2", "--selfcal-hold", "3"]


def test_replay_selfcal_shows_the_tracked_terms_and_decides_as_the_runtime(log, capsys):
    d, F = log
    rc = main(_args(d, F, "--estimates", str(d / "est.csv"), "-o", str(d / "o"), "--json", str(d / "ev.json"),
                    "--report", str(d / "rep")))
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "windows absorbed" in out and "deg/h" in out and "ppm" in out and "deg/h/K^3" in out
    assert (d / "rep" / "selfcal-gyro.png").stat().st_size > 10000
    summary = json.loads((d / "o" / "summary.json").read_text())["gyro"]
    assert summary["isolations"] == 0 and summary["selfcal"]["windows_absorbed"] > 120
    ev = json.loads((d / "ev.json").read_text())["gyro"]
    assert ev["selfcal"] == summary["selfcal"]
    assert ev["final_state"] == summary["final_state"] and f"final state {ev['final_state']}" in out  # one end state
    # the held-out check: on this drifting flight the temperature terms lower the held-out parity and are applied
    g = summary["selfcal"]["guard"]
    assert g["enabled"] and g["groups"]["temperature"]["applied"] and g["groups"]["temperature"]["heldout_gain"] > 0
    assert g["heldout_rms_applied"] < g["heldout_rms_fixed"]
    assert "held-out check" in out
    est = read_estimates(d / "est.csv", {"gyro": 6})
    names = cone6().names
    blocks = ("bias", "scale", "tc1", "tc2", "tc3")
    assert set(est.extra) == {f"gyro_{b}_{nm}{s}" for b in blocks for nm in names for s in ("", "_sigma")}
    # over time: the first rows hold the prior (zero terms), the last the summary's (SI), with a 1-sigma that shrank
    for b in blocks:
        for i, nm in enumerate(names):
            v, s = est.extra[f"gyro_{b}_{nm}"], est.extra[f"gyro_{b}_{nm}_sigma"]
            assert v[0] == 0.0 and v[-1] == pytest.approx(summary["selfcal"]["sensors"][i][b], rel=1e-12, abs=1e-300)
            if b.startswith("tc"):            # from the prior down (the bias and scale start known and wander)
                assert s[-1] < 0.5 * s[0]
    # the API: the same managers and tracker through rimu.fdi.Runtime
    pipe = Pipeline(Calibration({"gyro": F.cal}), temperature=True)
    det = TrackedGltWindow(20, 1e-6)
    mgr = RedundancyManager(pipe["gyro"], det, p_fa=1e-6, sample_rate=FS)
    st = SelfCalSettings(**{**F.settings.__dict__, "window_s": 2.0, "hold_s": 3.0, "scale_sigma0": 0.0})
    rt = Runtime(pipe, managers={"gyro": mgr}, selfcal={"gyro": SelfCalLoop(SelfCalTracker(F.cal, st), FS, det)})
    r = rt.run(EpochBlock(F.t, {"gyro": F.Y}, temperature=F.temperature))["gyro"]
    np.testing.assert_allclose(est.x["gyro"], r.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose([summary["selfcal"]["sensors"][i]["bias"] for i in range(6)],
                               rt.selfcal_terms()["gyro"]["bias"][0], rtol=1e-12)
    # the fixed calibration on the same log through the same window GLT (vectorised): the temperature drift alarms
    P = InstrumentPipeline(F.cal).process(F.Y)
    stat, thr, _ = GltWindow(20, 1e-6).block(P.parity, InstrumentPipeline(F.cal).table.get(63).Vz, 3)
    fixed = int(np.sum(stat > thr))
    print(f"\nrimu replay, cone6 6 min, 30 K ramp: alarm samples {fixed} of {len(F.t)} with the fixed calibration, "
          f"{summary['alarms']} with --selfcal (isolations {summary['isolations']})")
    assert fixed > 10 * max(summary["alarms"], 1)


def test_replay_selfcal_refuses_a_detector_without_the_tracker_covariance(log, capsys):
    d, F = log
    rc = main(_args(d, F, "--detector", "cusum"))
    err = capsys.readouterr().err
    assert rc == 2 and "--selfcal" in err and "cusum" in err and len(err.strip().splitlines()) == 1


def test_replay_selfcal_refuses_a_window_longer_than_the_data(log, capsys):
    d, F = log
    rc = main(_args(d, F)[:-4] + ["--selfcal-window", "1e6"])
    err = capsys.readouterr().err
    assert rc == 2 and "--selfcal-window" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_replay_selfcal_starts_from_the_stated_uncertainty_of_the_calibration(log, capsys):
    """--selfcal-bias-sigma0 / --selfcal-scale-sigma0: the tracker starts with that spread (it was fixed at zero in
    the CLI, so a calibration's known uncertainty could not be corrected in flight); the first row of the estimates
    file holds the prior's 1-sigma (the biases' observable part, sqrt of diag(Pi P0 Pi^T) with Pi the tracker's
    parity projector; the relative scales' as given) and the command decides as the API's Runtime with the same settings."""
    d, F = log
    b0, s0 = 0.5 * F.cal.noise_sigma if np.ndim(F.cal.noise_sigma) == 0 else 1e-3, 2e-3
    rc = main(_args(d, F, "--estimates", str(d / "est0.csv"), "--selfcal-bias-sigma0", repr(b0),
                    "--selfcal-scale-sigma0", repr(s0), "-q"))
    assert rc == 0, capsys.readouterr()
    est = read_estimates(d / "est0.csv", {"gyro": 6})
    st = SelfCalSettings(**{**F.settings.__dict__, "window_s": 2.0, "hold_s": 3.0, "bias_sigma0": b0,
                            "scale_sigma0": s0})
    trk = SelfCalTracker(F.cal, st)
    for blk, sig in (("bias", b0), ("scale", s0)):
        want = sig * (np.sqrt(np.diag(trk.Pi @ trk.Pi.T)) if blk == "bias" else np.ones(6))
        got = [est.extra[f"gyro_{blk}_{nm}_sigma"][0] for nm in cone6().names]
        np.testing.assert_allclose(got, want, rtol=1e-9)
    pipe = Pipeline(Calibration({"gyro": F.cal}), temperature=True)
    det = TrackedGltWindow(20, 1e-6)
    mgr = RedundancyManager(pipe["gyro"], det, p_fa=1e-6, sample_rate=FS)
    rt = Runtime(pipe, managers={"gyro": mgr}, selfcal={"gyro": SelfCalLoop(trk, FS, det)})
    r = rt.run(EpochBlock(F.t, {"gyro": F.Y}, temperature=F.temperature))["gyro"]
    np.testing.assert_allclose(est.x["gyro"], r.x, rtol=0, atol=1e-12)
