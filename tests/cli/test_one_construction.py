"""One construction path for the runtime: ``rimu replay`` of a recording and ``rimu monitor`` fed the same recording
build their managers, detectors, isolators and self-calibration loops through :class:`rimu.fdi.Runtime` alone, so
they decide alike on every epoch (validity, isolated set, estimates to 1e-12, tracked terms, events), for a plain
unit, one with a noise model (the GLT whitened with it: replay's plain GLT once left it out), a self-calibrating one
(the rate measured on the recording's first epochs), a unit set up on 0.1 s averages (its noise converted to the stream's rate, which monitor
measures on the first epochs) and a motion-aware unit of eight triads (gyro and accelerometer motion terms stored in
the unit file; the accelerometers' test takes the motion from the gyro manager).

A unit set up on averages is monitored at its design alarm rate: the rest alarm rate of ``rimu monitor`` at full
rate is within twice ``--p-fa``, where the noise taken as it stands (that of 10-sample averages, sqrt(10) too small)
alarms on most samples. And no CLI module imports another's private names.
"""

from __future__ import annotations

import ast
import contextlib
import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import main
from rimu.epoch import EpochBlock
from rimu.fdi import MotionAwareGlt, MotionNoiseModel
from rimu.fdi.motion import motion_detector_to_dict
from rimu.geometry import cone6, preset
from rimu.io.recorded import write_csv
from rimu.units import G0

FS = 100.0
SELFCAL = ["--selfcal", "--selfcal-bias-rw", "1e-9", "--selfcal-window", "0.5", "--selfcal-hold", "1"]


def _unit(kind: str) -> Calibration:
    geo = preset("mimu4444") if kind == "motion" else cone6()  # eight triads
    g = InstrumentCalibration.nominal("gyro", geo, 1.0, noise_sigma=0.01)
    a = InstrumentCalibration.nominal("accel", geo, 1.0, noise_sigma=0.02)
    if kind == "noise_model":  # rimu noise: a noise model, whose per-sample variances the GLT whitens with
        from rimu.noise import InstrumentNoise

        g.noise = InstrumentNoise.from_terms("gyro", g.geometry.names, FS,
                                             white=0.01 / np.sqrt(FS) * np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0]))
    if kind == "averaged":  # rimu setup --average 0.1: the noise of 10-sample averages
        g.noise_sigma, a.noise_sigma = g.noise_sigma / np.sqrt(10), a.noise_sigma / np.sqrt(10)
        g.noise_period_s = a.noise_period_s = 0.1
    cal = Calibration({"gyro": g, "accel": a}, raw_unit="SI", method="nominal")
    if kind == "motion":  # rimu setup --motion-fit: the gyro terms, and the accelerometers' (motion from the gyros)
        dg = MotionAwareGlt(MotionNoiseModel(g, scale_rel=0.003), sample_rate=FS)
        dg.envelope = (1.0, 50.0)
        da = MotionAwareGlt(MotionNoiseModel(a), sample_rate=FS, input_is_rate=False)
        da.envelope = (1.0, 1e4)
        cal.metadata["motion_terms"] = {"gyro": motion_detector_to_dict(dg), "accel": motion_detector_to_dict(da)}
    return cal


def _stream(cal: Calibration, n: int = 1200) -> EpochBlock:
    """Rest, a turn at 2 rad/s (beyond the motion terms' 1 rad/s), rest; a gyro fault at rest, an accelerometer
    that disagrees while turning and again at rest, a dropout."""
    rng = np.random.default_rng(7)
    t = np.arange(n) / FS
    w = np.zeros((n, 3))
    w[400:600, 2] = 2.0
    w[400:600, 0] = 0.3 * np.sin(2 * np.pi * t[400:600])
    f = np.tile([0.0, 0.0, G0], (n, 1))
    yg = cal["gyro"].raw_output(w) + 0.01 * rng.standard_normal((n, cal["gyro"].geometry.n))  # per sample at 100 Hz
    ya = cal["accel"].raw_output(f) + 0.02 * rng.standard_normal((n, cal["accel"].geometry.n))
    yg[200:300, 1] += 0.2                       # 20 sigma on one gyro at rest: isolated (re-admitted after)
    ya[450:550, 0] += 0.5                       # an accelerometer off while turning ...
    ya[800:900, 0] += 0.5                       # ... and at rest
    yg[1000:1010, 2] = np.nan                   # one gyro without data for 0.1 s
    return EpochBlock(t, {"gyro": yg, "accel": ya})


def _read(path: Path) -> dict[str, list[str]]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [r[k] for r in rows] for k in rows[0]}


def _run(argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(argv)
    assert rc == 0, out.getvalue()
    return out.getvalue()


@pytest.mark.parametrize("kind", ["plain", "noise_model", "selfcal", "averaged", "motion"])
def test_replay_and_monitor_of_one_recording_decide_alike(kind, tmp_path):
    cal = _unit("plain" if kind == "selfcal" else kind)
    cal.save(tmp_path / "cal.json")
    rec = tmp_path / "rec.csv"
    write_csv(rec, _stream(cal))
    opts = SELFCAL if kind == "selfcal" else []
    geo = ["--geometry", "mimu4444"] if kind == "motion" else []
    said = _run(["monitor", "--csv", str(rec), "--calibration", str(tmp_path / "cal.json"), *opts, *geo,
                 "--estimates", str(tmp_path / "m.csv"), "--json", str(tmp_path / "m.json")])
    told = _run(["replay", str(rec), "--calibration", str(tmp_path / "cal.json"), *opts,
                 "--estimates", str(tmp_path / "r.csv"), "--json", str(tmp_path / "r.json")])
    a, b = _read(tmp_path / "m.csv"), _read(tmp_path / "r.csv")
    assert list(a) == list(b) and len(a["t"]) == len(b["t"]) == 1200
    for name in a:
        if name.endswith(("_isolated", "_validity")):
            assert a[name] == b[name], name                                  # the decisions, every epoch
            continue
        x, y = np.array(a[name], dtype=float), np.array(b[name], dtype=float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), name
        ok = ~np.isnan(x)
        np.testing.assert_allclose(x[ok], y[ok], rtol=0, atol=1e-12 * max(1.0, float(np.abs(y[ok]).max())),
                                   err_msg=name)
    # the same events (not only the same estimates), and enough of them that agreement is not agreement on nothing
    m, r = json.loads((tmp_path / "m.json").read_text()), json.loads((tmp_path / "r.json").read_text())
    mon = sorted((e["instrument"], e["kind"], e["sensor"] or "", e["sample"]) for e in m["events"])
    rep = sorted((k, e["kind"], e["sensor"] or "", e["sample"]) for k in ("gyro", "accel") for e in r[k]["events"])
    assert mon == rep
    kinds = {(k, kd, s) for k, kd, s, _ in mon}
    assert ("gyro", "isolated", cal["gyro"].geometry.names[1]) in kinds, kinds
    assert any(k == "accel" and kd == "isolated" for k, kd, _ in kinds), kinds
    if kind == "motion":
        assert "motion-aware test of the unit file" in said and "motion terms of the calibration" in told
        assert ("accel", "model_exceeded", "") in {(k, kd, "") for k, kd, _ in kinds}, kinds  # the turn: no isolation
        iso = [s for k, kd, _s, s in mon if k == "accel" and kd == "isolated"]
        assert iso and all(not 400 <= s < 600 for s in iso), mon
    if kind == "selfcal":
        assert any(c.startswith("gyro_bias_") for c in a)                    # the tracked terms, compared too
        assert "stream's rate 100 Hz (measured on its first 50 epochs)" in said
    if kind == "averaged":
        assert "stated for epochs of 0.1 s" in said and "x3.16 per sample" in said, said
        assert "stated for epochs of 0.1 s" in told and "x3.16 per sample" in told, told


def test_monitor_of_a_unit_set_up_on_averages_alarms_at_the_design_rate(tmp_path, capsys):
    from rimu.fdi import Runtime
    from rimu.io.recorded import CsvSource
    from tests.cli.test_noise_period import _log

    log, unit, js, rec = tmp_path / "px.csv", tmp_path / "unit.json", tmp_path / "m.json", tmp_path / "rec.csv"
    _log(log, n=6000)                                      # two IMUs at rest, 100 Hz, 0.01 rad/s white gyro noise
    assert main(["setup", str(log), "-o", str(unit), "--average", "0.1"]) == 0
    cal = Calibration.load(unit)
    assert cal["gyro"].noise_period_s == pytest.approx(0.1)
    capsys.readouterr()
    assert main(["monitor", "--replay", str(log), "--calibration", str(unit), "--json", str(js), "-o", str(rec)]) == 0
    said = capsys.readouterr().out
    doc = json.loads(js.read_text())
    n, n_alarm = doc["epochs"], doc["alarms"]["gyro"]
    assert n == 6000 and doc["isolations"] == [], doc["isolations"]
    assert "stream's rate 100 Hz (measured on its first 50 epochs)" in said and "x3.16 per sample" in said, said
    # p_fa 1e-3 per sample: 6 expected; within twice the design rate (Poisson mean 6: P(> 12) < 1 %)
    assert n_alarm <= 2 * 1e-3 * n, n_alarm
    # the same epochs with the noise as it stands (that of the averages, sqrt(10) too small): most samples alarm
    blk = EpochBlock.from_epochs(list(CsvSource(rec)))
    assert len(blk.t) == n
    raw = Runtime(Calibration({"gyro": cal["gyro"]}, cal.raw_unit)).run(
        EpochBlock(blk.t, {"gyro": blk.raw["gyro"]}, {"gyro": blk.valid["gyro"]}))["gyro"]
    assert np.mean(raw.alarm) > 100 * 1e-3, np.mean(raw.alarm)


def test_a_stream_whose_rate_cannot_be_known_is_refused_with_one_line(tmp_path, capsys):
    cal = _unit("averaged")
    cal.save(tmp_path / "cal.json")
    write_csv(tmp_path / "one.csv", EpochBlock(np.zeros(1), {k: np.zeros((1, 6)) for k in ("gyro", "accel")}))
    rc = main(["monitor", "--csv", str(tmp_path / "one.csv"), "--calibration", str(tmp_path / "cal.json"),
               "--estimates", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "rate cannot be measured" in err[0] and "--sample-rate" in err[0], err
    assert not (tmp_path / "e.csv").exists()


def test_no_cli_module_imports_another_cli_modules_private_names():
    cli = Path(__file__).resolve().parents[2] / "rimu" / "cli"
    bad = []
    for p in sorted(cli.glob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                # _common and _inputs are the shared helper modules (their public names); another command's
                # private name is not for import
                bad += [f"{p.name}: from .{node.module} import {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, bad


def test_replay_noise_option_equals_a_stated_noise(tmp_path, capsys):
    """``rimu replay --noise`` for a calibration that states none decides exactly as the same unit with that noise
    stated (a new calibration object, not a write into the loaded one); without it, one line and exit 2."""
    stated = _unit("plain")
    stated.save(tmp_path / "stated.json")
    bare = Calibration({k: InstrumentCalibration.nominal(k, cone6(), 1.0) for k in ("gyro", "accel")},
                       raw_unit="SI", method="nominal")
    assert bare["gyro"].noise_sigma is None
    bare.save(tmp_path / "bare.json")
    rec = tmp_path / "rec.csv"
    write_csv(rec, _stream(stated))
    capsys.readouterr()
    assert main(["replay", str(rec), "--calibration", str(tmp_path / "bare.json"), "--estimates",
                 str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--noise" in err[0], err
    # gyro 0.01 and accel 0.02 rad/s, m/s^2 in _unit: one --noise for both, so compare the gyro of a unit whose
    # accelerometers state the same 0.01 too
    same = _unit("plain")
    same["accel"].noise_sigma = np.full(6, 0.01)
    same.save(tmp_path / "same.json")
    _run(["replay", str(rec), "--calibration", str(tmp_path / "bare.json"), "--noise", "0.01",
          "--estimates", str(tmp_path / "n.csv")])
    _run(["replay", str(rec), "--calibration", str(tmp_path / "same.json"), "--estimates", str(tmp_path / "s.csv")])
    a, b = _read(tmp_path / "n.csv"), _read(tmp_path / "s.csv")
    assert a == b and len(a["t"]) == 1200
    assert sum(v != "" for v in a["gyro_isolated"]) >= 100  # the faulty gyro isolated: agreement on decisions
