"""``rimu monitor``: simulated device end to end, replay with a calibration file, clean Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rimu.cli import main
from rimu.fdi import Runtime
from rimu.fusion import Pipeline
from rimu.io.device import CanDevice
from rimu.io.recorded import CsvSource
from rimu.sim import Simulator, rotation

ROOT = Path(__file__).resolve().parents[2]


def test_monitor_simulated_device_isolates_the_fault(tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    rc = main(["monitor", "--simulate", "--sim-duration", "12", "--idle-timeout", "10", "--record", str(rec),
               "--json", "--status-interval", "0.2"])
    out = capsys.readouterr().out
    assert rc == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["epochs"] == 1200
    assert summary["accounting"]["identity_holds"]
    assert summary["accounting"]["received"] == summary["accounting"]["accepted"] == 6000
    assert [(e["instrument"], e["sensor"]) for e in summary["isolations"]] == [("gyro", "y2")]
    t_iso = summary["isolations"][0]["t"]
    assert 10.0 < t_iso < 10.1                         # a 10 sigma step at 10 s: within the confirmation
    assert "isolated y2" in out                                               # the status line shows it
    back = CsvSource(rec).read_block()
    assert len(back) == 1200
    # the runtime on the recorded epochs (what rimu replay and the exported C run): the same decision, same sample
    truth = Simulator(seed=0).run([rotation("manoeuvre", [0.0, 0.5236, 0.0], duration=12.0)]).truth
    ref = Runtime(Pipeline(truth)).run(back)
    iso = [(k, e.sensor, e.t) for k, r in ref.items() for e in r.events if e.kind == "isolated"]
    assert iso == [("gyro", "y2", t_iso)]


def test_monitor_replay_with_calibration_file(tmp_path, capsys):
    sim = Simulator(seed=4)
    run = sim.run([rotation("r", [0.2, 0.0, 0.0], duration=3.0)])
    cal = run.truth.save(tmp_path / "cal.json")
    log = tmp_path / "run.blf"
    CanDevice("cone6_rimu").write_log(log, run.block)
    rc = main(["monitor", "--replay", str(log), "--layout", "cone6_rimu", "--calibration", str(cal), "--json"])
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert rc == 0 and summary["epochs"] == 300 and summary["isolations"] == []
    assert summary["accounting"]["rejected_total"] == 0


def test_monitor_needs_a_calibration_for_real_sources(tmp_path, capsys):
    log = tmp_path / "x.asc"
    CanDevice("cone6_rimu").write_log(log, Simulator(seed=1).run([rotation("r", [0, 0, 0.1], duration=0.1)]).block)
    assert main(["monitor", "--replay", str(log)]) == 2
    assert "--calibration" in capsys.readouterr().err


@pytest.mark.skipif(os.name != "posix", reason="SIGINT delivery to a child process")
def test_monitor_ctrl_c_prints_a_summary():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "rimu.cli", "monitor", "--simulate", "--realtime",
                          "--sim-duration", "30", "--status-interval", "0.2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        deadline = time.monotonic() + 30
        line = ""
        while time.monotonic() < deadline:            # wait for the first status line
            line = p.stdout.readline()
            if line.startswith("t "):
                break
        assert line.startswith("t "), p.stderr.read()
        p.send_signal(signal.SIGINT)
        try:
            out, err = p.communicate(timeout=20)
        except subprocess.TimeoutExpired:               # a hang: show where every thread is (faulthandler)
            p.send_signal(signal.SIGABRT)
            out, err = p.communicate(timeout=10)
            pytest.fail(f"no exit within 20 s of Ctrl-C; threads:\n{err[-6000:]}")
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "rimu monitor: interrupted" in out
    assert "accounting identity received = accepted + rejected + pending: holds" in out
    assert "Traceback" not in err
