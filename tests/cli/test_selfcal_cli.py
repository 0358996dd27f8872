"""``rimu selfcal``: the offline fit of the tracker's drift and temperature model to a log, checked against the
simulated truth through the covariance it writes (normalised errors over the observable directions)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rimu.calibration import Calibration
from rimu.cli import main
from rimu.fdi.selfcal import unobservable_basis
from rimu.fusion import InstrumentPipeline
from rimu.session import Segment, Session, save_session
from rimu.sim.multitriad import triad_array
from tests.fdi.selfcal_flight import flight


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("selfcal")
    geo = triad_array(8)
    F = flight(geo, hours=0.5, fs=10.0, seed=21)
    seg = Segment("flight", "motion", F.t, {"gyro": F.Y}, temperature=F.temperature)
    save_session(Session([seg], {"gyro": geo}, 10.0, raw_unit="rad/s"), d / "flight.npz")
    Calibration({"gyro": F.cal}, raw_unit="rad/s").save(d / "cal.json")
    return d, F


def test_selfcal_writes_the_fitted_terms_with_their_covariance(log, capsys):
    d, F = log
    q = float(np.asarray(F.settings.bias_rw)[0])
    tsig = ",".join(str(s) for s in F.settings.temperature_sigma)
    rc = main(["selfcal", str(d / "flight.npz"), "--calibration", str(d / "cal.json"), "-o", str(d / "cal2.json"),
               "--bias-rw", repr(q), "--scale-rw", repr(F.settings.scale_rw), "--temperature-orders", "3",
               "--temperature-sigma", tsig, "--json", str(d / "s.json"), "--report", str(d / "rep")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "deg/h" in out and "ppm" in out and "K^3" in out
    assert (d / "rep" / "selfcal-gyro.png").stat().st_size > 10000
    c2 = Calibration.load(d / "cal2.json")["gyro"]
    names = list(F.cal.geometry.names)
    n = len(names)
    # the written terms against the truth at the end of the log: bias, relative scale, tc1, tc2, tc3 (in the
    # bias_temperature, bias_temperature2 and bias_temperature3 effects)
    k = len(F.t) - 1
    rel = F.cal.scale / c2.scale - 1.0                     # SF' = SF / (1 + k)
    bias = c2.bias * (1.0 + rel) - F.cal.bias
    tc1 = np.array([c2.effects["bias_temperature"][f"{nm}.bias_tc1"] for nm in names])
    tc2 = np.array([c2.effects["bias_temperature2"][f"{nm}.bias_tc2"] for nm in names])
    tc3 = np.array([c2.effects["bias_temperature3"][f"{nm}.bias_tc3"] for nm in names])
    est = np.concatenate([bias, rel, tc1, tc2, tc3])
    truth = np.concatenate([F.bias[k], F.scale[k], F.tc[0], F.tc[1], F.tc[2]])
    order = [f"{nm}.{p}" for p in ("bias", "scale", "bias_tc1", "bias_tc2", "bias_tc3") for nm in names]
    idx = [c2.param_names.index(p) for p in order]
    C = c2.covariance[np.ix_(idx, idx)]
    # the scale's covariance is written in SI per raw unit (d SF = -SF dk): back to relative
    J = np.ones(5 * n)
    J[n:2 * n] = -1.0 / F.cal.scale
    C = C * np.outer(J, J)
    U = unobservable_basis(F.cal.axes_mb(), ["bias", "scale", "tc1", "tc2", "tc3"])
    Po = np.eye(5 * n) - U @ U.T
    e = Po @ (est - truth)
    lam, Q = np.linalg.eigh(Po @ C @ Po)
    keep = lam > 1e-12 * lam.max()
    z = (Q[:, keep].T @ e) / np.sqrt(lam[keep])
    rms = float(np.sqrt(np.mean(z**2)))
    print(f"\nrimu selfcal, 8 triads, 30 min: normalised errors of the written terms rms {rms:.3f} over {z.size}")
    assert 0.8 <= rms <= 1.25
    summary = json.loads((d / "s.json").read_text())
    assert summary["instruments"]["gyro"]["windows_absorbed"] > 1500
    # every printed term, parsed with its printed unit and converted, equals the SI value the summary writes
    from tests.cli.test_figures_per_command import to_si

    rows = {r["sensor"]: r for r in summary["instruments"]["gyro"]["sensors"]}
    pat = re.compile(r"(bias|scale|tc\d) ([-+0-9.eE]+) ([a-z/]+?)(?:/K\^\d)? \+- ([-+0-9.eE]+) ([a-z/]+?)(?:/K\^\d)?(?:,|$)")
    checked = 0
    for line in out.splitlines():
        words = line.split()
        if not words or words[0] not in rows:
            continue
        for term, v, unit, sd, unit2 in pat.findall(line.split(None, 1)[1]):
            q = "ratio" if term == "scale" else "rate"
            assert unit == unit2
            mant, _, exp = v.lower().partition("e")
            last = 0.5 * 10.0 ** (int(exp or 0) - len(mant.partition(".")[2]))                 # half the last digit
            assert to_si(float(v), unit, q) == pytest.approx(rows[words[0]][term], abs=to_si(last, unit, q)), line
            assert to_si(float(sd), unit, q) == pytest.approx(rows[words[0]][term + "_sigma"], rel=2e-2), line
            checked += 1
    assert checked == 5 * n, checked
    # the updated calibration takes the drift out of the end of the log: parity rms over the last 5 min
    tail = slice(len(F.t) - 3000, None)
    from rimu.epoch import EpochBlock
    from rimu.fusion import Pipeline

    blk = EpochBlock(F.t[tail], {"gyro": F.Y[tail]}, temperature=F.temperature[tail])
    Y2 = Pipeline(Calibration({"gyro": c2})).compensate(blk).raw["gyro"]
    p_old = InstrumentPipeline(F.cal).process(F.Y[tail]).parity
    p_new = InstrumentPipeline(c2).process(Y2).parity
    r_old, r_new = float(np.sqrt(np.mean(p_old**2))), float(np.sqrt(np.mean(p_new**2)))
    print(f"parity rms over the last 5 min: {r_old:.2f} sigma with the old calibration, {r_new:.2f} with the new")
    assert r_new < 1.1 and r_new < r_old


def test_selfcal_without_a_drift_rate_says_what_to_do(log, capsys):
    d, _ = log
    rc = main(["selfcal", str(d / "flight.npz"), "--calibration", str(d / "cal.json"), "-o", str(d / "x.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "--bias-rw" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (d / "x.json").exists()
