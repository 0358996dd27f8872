"""rimu replay, rimu campaign and rimu check end to end (small inputs)."""

import json

import numpy as np
import pytest

from rimu.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from rimu.fdi import stated_covariance
    from rimu.geometry import tetrad4, triad3
    from rimu.sim import Simulator

    d = tmp_path_factory.mktemp("fdi-cli")
    assert main(["simulate", "--procedure", "cho_park_table2", "--sample-rate", "10", "-o", str(d / "t2.npz")]) == 0
    Simulator(seed=0, sample_rate=10.0).truth_calibration().save(d / "cal6.json")
    assert main(["simulate", "--procedure", "oliveira_table1", "--sample-rate", "10", "--arw", "0.1",
                 "-o", str(d / "ol.npz")]) == 0
    sim = Simulator({"gyro": tetrad4(), "accel": triad3()}, seed=0, sample_rate=10.0, arw_deg_sqrt_h=0.1)
    cal = sim.truth_calibration()
    cal.instruments_cal["gyro"] = stated_covariance(cal["gyro"], np.radians(0.01), 1e-4)
    cal.save(d / "cal4.json")
    g = cal["gyro"]
    m = g.misalignment.copy()
    E, _ = g.geometry.off_axis_basis(2)
    m[2] = m[2] + np.radians(0.5) * E[0]
    m[2] /= np.linalg.norm(m[2])
    g.misalignment = m
    cal.save(d / "cal4-bad.json")
    return d


def test_replay_with_injection(files, capsys):
    d = files
    rc = main(["replay", str(d / "t2.npz"), "--calibration", str(d / "cal6.json"),
               "--inject", "bias:gyro:y2:15:10sigma", "--inject", "dropout:accel:z2:100:0:0.3",
               "--out", str(d / "replay")])
    out = capsys.readouterr().out
    assert rc == 0 and "isolated" in out and "y2" in out
    doc = json.loads((d / "replay" / "replay.json").read_text())
    iso = [e for e in doc["gyro"]["events"] if e["kind"] == "isolated"]
    # 10 Hz: the set GLT first rejects every pair without y2 (about 5 samples at 10 sigma), then confirms (3)
    assert iso[0]["sensor"] == "y2" and 15.0 <= iso[0]["t"] < 16.2
    assert any(e["kind"] == "invalid_transient" and e["sensor"] == "z2" for e in doc["accel"]["events"])
    assert (d / "replay" / "replay.png").exists()


def test_replay_rejects_a_bad_spec(files, capsys):
    rc = main(["replay", str(files / "t2.npz"), "--calibration", str(files / "cal6.json"), "--inject", "bias:gyro"])
    assert rc == 2 and "TYPE:INSTRUMENT:SENSOR:START" in capsys.readouterr().err


def test_campaign_cli_json(files, capsys):
    out = files / "camp.json"
    rc = main(["campaign", "--faults", "bias", "--sensors", "0", "--sizes", "8", "--repetitions", "2",
               "--workers", "0", "--json", str(out), "--plot", str(files / "camp.png")])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["summary"][0]["pd_theory"] > 0.9 and len(doc["rows"]) == 2
    text = capsys.readouterr().out
    assert "Pd" in text and "successive faults that can be isolated: 2" in text


def test_check_good_and_bad(files, capsys):
    d = files
    assert main(["check", str(d / "ol.npz"), "--calibration", str(d / "cal4.json"), "--instrument", "gyro"]) == 0
    assert "verdict: GOOD" in capsys.readouterr().out
    rc = main(["check", str(d / "ol.npz"), "--calibration", str(d / "cal4-bad.json"), "--instrument", "gyro",
               "--out", str(d / "chk")])
    out = capsys.readouterr().out
    assert rc == 1 and "verdict: BAD" in out
    assert json.loads((d / "chk" / "check.json").read_text())["gyro"]["verdict"] == "bad"
