"""``rimu monitor --selfcal``: the live path runs the in-flight self-calibration through the same runtime as ``rimu
replay --selfcal``. The simulated cone6 device on python-can's virtual bus (``--simulate``, a 10-sigma step on y2
part-way) is monitored with the tracker; its recording replayed with the same options must give, epoch for epoch,
the same decisions, the same estimates and the same tracked terms with their 1-sigma (1e-12)."""

from __future__ import annotations

import contextlib
import csv
import io
import json

import numpy as np

from rimu.cli import main
from rimu.sim import Simulator, rotation

OPTS = ["--selfcal", "--selfcal-bias-rw", "1e-9", "--selfcal-window", "0.5", "--selfcal-hold", "1"]


def _read(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [r[k] for r in rows] for k in rows[0]}


def test_monitor_selfcal_on_the_simulated_device_decides_as_replay(tmp_path):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["monitor", "--simulate", "--sim-duration", "8", "--fault", "gyro:y2:4:10", *OPTS,
                   "--selfcal-temperature", "--estimates", str(tmp_path / "m.csv"), "-o", str(tmp_path / "rec.csv"),
                   "--json", str(tmp_path / "m.json")])
    text = out.getvalue()
    assert rc == 0, text
    assert "self-calibration of gyro, accel at 100 Hz" in text and "windows absorbed" in text
    summary = json.loads((tmp_path / "m.json").read_text())
    assert summary["epochs"] == 800 and [e["sensor"] for e in summary["isolations"]] == ["y2"]
    sc = summary["selfcal"]["gyro"]
    assert sc["windows_absorbed"] >= 3 and sc["blocks"] == ["bias", "scale", "tc1", "tc2"]
    # the same epochs replayed offline with the simulated unit's calibration (the truth the device was made from)
    sim = Simulator(seed=0)
    sim.run([rotation("manoeuvre", [0.0, 0.5236, 0.0], duration=8.0)]).truth.save(tmp_path / "truth.json")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(tmp_path / "rec.csv"), "--calibration", str(tmp_path / "truth.json"), *OPTS,
                     "--estimates", str(tmp_path / "r.csv"), "-q"]) == 0
    a, b = _read(tmp_path / "m.csv"), _read(tmp_path / "r.csv")
    assert list(a) == list(b) and len(a["t"]) == 800
    assert sum(1 for c in a if c.startswith("gyro_tc1_")) == 12          # value and sigma of each of 6 sensors
    worst = 0.0
    for name in a:
        if name.endswith(("_isolated", "_validity")):
            assert a[name] == b[name], name                                # the decisions, every epoch
            continue
        x, y = np.array(a[name], dtype=float), np.array(b[name], dtype=float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), name
        scale = max(float(np.nanmax(np.abs(y))), 1e-300)
        worst = max(worst, float(np.nanmax(np.abs(x - y))) / scale)
    assert worst <= 1e-12, worst
    assert "4" in a["gyro_isolated"][-1]                                    # y2 (index 4) out at the end
    assert any(float(v) != 0.0 for v in a["gyro_bias_x1"])                # the terms moved (and were compared)


def test_monitor_selfcal_temperature_without_a_temperature_stops_with_one_line(tmp_path, capsys):
    from rimu.calibration import Calibration, InstrumentCalibration
    from rimu.epoch import EpochBlock
    from rimu.geometry import cone6
    from rimu.io.recorded import write_csv

    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    Calibration({"gyro": cal}, "rad/s", "nominal").save(tmp_path / "cal.json")
    t = np.arange(200) / 100.0
    write_csv(tmp_path / "rec.csv", EpochBlock(t, {"gyro": np.random.default_rng(0).normal(0, 0.01, (200, 6))}))
    rc = main(["monitor", "--csv", str(tmp_path / "rec.csv"), "--calibration", str(tmp_path / "cal.json"),
               "--sample-rate", "100", *OPTS, "--selfcal-temperature", "--estimates", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--selfcal-temperature" in err[0] and "no temperature" in err[0], err
    assert not (tmp_path / "e.csv").exists()                              # no half-written estimates file
