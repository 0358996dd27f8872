"""Never a wrong number, per command (issue 27): on simulated recordings with known truth, every figure a command
prints and writes equals the truth in the unit it states. Each printed unit is parsed and converted with
rimu.units.FIELD_UNITS (a wrong label fails), and compared with the truth (closed form or the simulation's
coefficients) within the uncertainty the command states or the sampling theory gives. calibrate, diagnose, noise
and array: tests/test_figures_units.py; demo: tests/test_cli.py.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from scipy.linalg import null_space
from scipy.stats import chi2, ncx2

from rimu.cli import main
from rimu.units import FIELD_UNITS


def to_si(value: float, unit: str, quantity: str) -> float:
    """A printed value in its printed unit, in SI; a unit that is not one of the quantity's fails the test."""
    units = dict(FIELD_UNITS[quantity])
    assert unit in units, (unit, quantity, sorted(units))
    return float(value) / units[unit]


def _cli(capsys, *argv) -> list[str]:
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert rc == 0, (argv, cap.err)
    return cap.out.splitlines()


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    """A simulated cone6 unit on the turntable (Cho & Park Table 1 + 2, 1 s a segment): the session of counts, the
    true coefficients and the calibration rimu fits."""
    d = tmp_path_factory.mktemp("unit")
    assert main(["simulate", "-o", str(d / "s.npz"), "--truth", str(d / "truth.json"), "--duration", "1", "-q"]) == 0
    assert main(["calibrate", str(d / "s.npz"), "-o", str(d / "cal.json"), "-q"]) == 0
    return d


def test_simulate_writes_counts_of_the_stated_scale(unit, capsys, tmp_path):
    out = _cli(capsys, "simulate", "-o", tmp_path / "s.npz", "--duration", "1", "--sample-rate", "50")
    m = re.search(r"(\d+) segments, (\d+) samples at (\S+) Hz", out[0])
    assert m, out
    from rimu.calibration import Calibration
    from rimu.session import load_session

    s = load_session(tmp_path / "s.npz")
    assert (int(m.group(1)), int(m.group(2)), float(m.group(3))) == (len(s), sum(g.n_samples for g in s.segments),
                                                                       s.sample_rate) == (24, 1200, 50.0)
    # the counts have the truth's scale: compensated with the true coefficients, each static segment's mean
    # specific force is the gravity the rig states, within 5 standard errors of the truth's noise
    s1 = load_session(unit / "s.npz")
    truth = Calibration.load(unit / "truth.json")
    acc = truth["accel"]
    se = float(np.max(acc.noise_sigma)) / math.sqrt(s1.segments[0].n_samples) * math.sqrt(3)
    checked = 0
    for seg in s1.segments:
        if seg.kind == "static" and seg.specific_force_mb is not None:
            f = np.linalg.lstsq(acc.axes_mb(), acc.compensate(seg.raw["accel"]).mean(axis=0), rcond=None)[0]
            assert np.linalg.norm(f - seg.specific_force_mb) < 5 * se, (seg.label, f, seg.specific_force_mb)
            checked += 1
    assert checked == 10


def test_design_prints_eq19_in_the_units_of_its_header(capsys, tmp_path):
    # a navigation-grade noise (ug, deg/h) and a very noisy one (mg, deg/s, %, deg): each column in the field
    # unit of its figures (rimu.units.fmt), every figure the JSON's SI value in the unit its header states
    heads = []
    for noise in ([], ["--vrw", "200000", "--arw", "1000"]):
        out = _cli(capsys, "design", "--duration", "10", *noise, "--json", tmp_path / "d.json")
        doc = json.loads((tmp_path / "d.json").read_text())["predicted_std_si"]
        i = next(k for k, ln in enumerate(out) if ln.strip().startswith("sensor"))
        cols = re.findall(r"(acc|gyro) (SF|mis|bias) (\S+)", out[i])
        assert len(cols) == 6, out[i]
        heads.append([c[2] for c in cols])
        quantity = {"SF": "ratio", "mis": "angle"}
        rows = [ln.split() for ln in out[i + 1:i + 7]]
        for r in rows:
            name = r[0]
            for (inst, what, u), v in zip(cols, map(float, r[1:])):
                d = doc["accel" if inst == "acc" else "gyro"]
                q = quantity.get(what, "specific_force" if inst == "acc" else "rate")
                si = to_si(v, u, q)
                truth = (max(x for k, x in d.items() if k.startswith(name + ".mis")) if what == "mis"
                         else d[f"{name}.{'scale' if what == 'SF' else 'bias'}"])
                assert si == pytest.approx(truth, rel=1e-3), (name, inst, what, v, u)
    assert heads == [["ppm", "arcsec", "ug", "ppm", "arcsec", "deg/h"], ["%", "deg", "mg", "%", "deg", "deg/s"]]
    _cli(capsys, "design", "--duration", "10", "--json", tmp_path / "d.json")
    doc = json.loads((tmp_path / "d.json").read_text())["predicted_std_si"]
    # Cho & Park Eq. 19: the standard deviations fall as 1/sqrt(samples): four times the duration, half of each
    _cli(capsys, "design", "--duration", "40", "--json", tmp_path / "d4.json")
    doc4 = json.loads((tmp_path / "d4.json").read_text())["predicted_std_si"]
    for k in doc:
        for n, v in doc[k].items():
            assert doc4[k][n] == pytest.approx(v / 2, rel=1e-6), (k, n)


def test_monitor_prints_the_chi2_thresholds_and_the_fault_time(capsys):
    out = _cli(capsys, "monitor", "--simulate", "--duration", "4", "--fault", "gyro:x1:2:10")
    # the status line: FD statistic/threshold per instrument; the GLT threshold is chi2_(1-p_fa)(dof) with the
    # parity dimension of the sensors in use (cone6: 3; 2 after one isolation), p_fa 1e-3
    # (the last status line is always printed; the others follow the wall clock)
    last = [ln for ln in out if ln.startswith("t ")][-1]
    thr = {k: float(v) for k, v in re.findall(r"(gyro|accel) \d/6 ok \S+ FD\s+\S+/(\S+)", last)}
    assert "gyro 5/6 ok fault_isolated" in last and "isolated x1" in last, last
    assert thr == pytest.approx({"gyro": chi2.isf(1e-3, 2), "accel": chi2.isf(1e-3, 3)}, abs=0.05), last
    t_last = re.match(r"t\s+(\S+) (\S+) \|", last)
    assert to_si(float(t_last.group(1)), t_last.group(2), "time") == pytest.approx(4.0), last
    # the isolation: after the fault's onset (2 s) by the confirmation (3 samples at 100 Hz) and a few samples
    m = re.search(r"isolated: gyro x1 at t = (\S+) (\S+) \(epoch (\d+)\)", "\n".join(out))
    t_iso = to_si(float(m.group(1)), m.group(2), "time")
    assert 2.0 + 0.02 <= t_iso <= 2.0 + 0.1 and int(m.group(3)) == round(t_iso * 100), m.group(0)
    m = re.search(r"(\d+) epochs over (\S+) (\S+) of data", "\n".join(out))
    assert int(m.group(1)) == 401 and to_si(float(m.group(2)), m.group(3), "time") == pytest.approx(4.0)


def test_replay_prints_the_estimate_error_of_least_squares(unit, capsys, tmp_path):
    """With the true calibration the runtime's estimate error is the least-squares one: per axis
    sigma sqrt(diag((H^T H)^-1)), sigma / sqrt(2) for cone6 (H^T H = 2 I); the segment means over 100 samples,
    a tenth of it."""
    from rimu.calibration import Calibration
    from rimu.geometry import cone6

    out = _cli(capsys, "replay", unit / "s.npz", "--calibration", unit / "truth.json", "-o", tmp_path / "r")
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    truth = Calibration.load(unit / "truth.json")
    H = cone6().H
    lines = [ln for ln in out if "runtime error:" in ln]
    assert len(lines) == 2
    for k, ln in zip(("gyro", "accel"), lines):
        q = "rate" if k == "gyro" else "specific_force"
        m = re.search(r"segment_error_rms (\S+) (\S+) over (\d+) segments, sample_error_rms (\S+) (\S+)", ln)
        seg_si, smp_si = to_si(float(m.group(1)), m.group(2), q), to_si(float(m.group(4)), m.group(5), q)
        assert seg_si == pytest.approx(summary[k]["segment_error_rms"], rel=1e-3)
        assert smp_si == pytest.approx(summary[k]["sample_error_rms"], rel=1e-3)
        sigma = float(np.mean(truth[k].noise_sigma))
        per_axis = sigma * math.sqrt(float(np.mean(np.diag(np.linalg.inv(H.T @ H)))))
        n = summary[k]["samples"] * 3                       # components: relative sd of an rms 1/sqrt(2n)
        assert smp_si == pytest.approx(per_axis, rel=3 / math.sqrt(2 * n)), (k, smp_si, per_axis)
        n_seg = int(m.group(3)) * 3                         # 72 segment means of 100 samples each
        assert seg_si == pytest.approx(per_axis / 10, rel=3 / math.sqrt(2 * n_seg)), (k, seg_si, per_axis / 10)


def test_campaign_prints_the_noncentral_chi2_theory(capsys, tmp_path):
    out = _cli(capsys, "campaign", "--faults", "bias", "--sizes", "3,6", "--repetitions", "1", "--duration", "2",
               "--fault-start", "1", "--open-loop-only", "--json", tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    from rimu.geometry import cone6

    V = null_space(cone6().H.T).T                           # the parity space (rows orthonormal, V H = 0)
    v = np.linalg.norm(V, axis=0)                           # the fraction of a bias each sensor shows in it
    thr = chi2.isf(doc["spec"]["p_fa"], V.shape[0])
    rows = [ln for ln in out if re.match(r"\s+bias\s+\d", ln)]
    assert len(rows) == 2
    for ln, s in zip(rows, doc["summary"]):
        size = float(ln.split()[1])
        theory = float(np.mean(ncx2.sf(thr, V.shape[0], (size * v) ** 2)))   # per-sample detection, closed form
        m = re.search(r"\|\s+(\S+) \[(\S+), (\S+)\]\s+(\S+) \|", ln)
        assert float(m.group(4)) == pytest.approx(theory, abs=1e-4), (ln, theory)
        # the measured Pd within its 99 % interval of the theory's, and the printed figures the JSON's
        assert float(m.group(2)) <= theory <= float(m.group(3)), (ln, theory)
        assert float(m.group(1)) == pytest.approx(s["pd"], abs=1e-4)
        wi = re.search(r"\|\s+(\S+) (%)\s+\|", ln)
        assert to_si(float(wi.group(1)), wi.group(2), "ratio") == pytest.approx(s["wrong_isolation"], abs=1e-5)


def test_check_prints_the_misfits_in_the_units_it_states(unit, capsys, tmp_path):
    out = _cli(capsys, "check", unit / "s.npz", "--calibration", unit / "truth.json", "--json", tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    pairs = [ln for ln in out if re.match(r"\s+R\d+/R\d+ ", ln)]
    segs = [ln for ln in out if re.match(r"\s+P\d+ ", ln)]
    assert len(pairs) == 7 and len(segs) == 10, out
    from rimu.units import ARCSEC_TO_RAD, UG_TO_MS2

    for ln, p in zip(pairs, doc["gyro"]["pairs"]):
        (n, nu), (c, cu) = re.findall(r"(\S+) (arcsec|deg)", ln)
        assert to_si(float(n), nu, "angle") == pytest.approx(p["nominal_arcsec"] * ARCSEC_TO_RAD, rel=1e-3)
        assert to_si(float(c), cu, "angle") == pytest.approx(p["misalignment_arcsec"] * ARCSEC_TO_RAD, rel=1e-3)
        # Bonferroni over the 7 pairs, parity dimension 3 (de Oliveira Eq. 25)
        assert float(ln.split()[-1]) == pytest.approx(chi2.isf(1e-3 / 7, 3), abs=0.05)
    stats = []
    for ln, s in zip(segs, doc["accel"]["segments"]):
        v, u = re.search(r"\|\s+(\S+) (ug|mg|m/s\^2) \|", ln).groups()
        assert to_si(float(v), u, "specific_force") == pytest.approx(s["misfit_ug"] * UG_TO_MS2, rel=1e-3)
        assert float(ln.split()[-1]) == pytest.approx(chi2.isf(1e-3 / 10, 3), abs=0.05)
        stats.append(s["statistic"])
    # the true calibration: each statistic is chi2(3); their mean 3 within 3 standard errors (sd sqrt(6/10))
    assert abs(np.mean(stats) - 3.0) < 3 * math.sqrt(6 / 10) and out[-1].startswith("rimu check: GOOD")


def test_detect_prints_poses_inside_the_true_ones(capsys, tmp_path):
    from rimu.sim.handheld import handheld_run

    run = handheld_run(n_poses=6, static_s=2.5, initial_still_s=5.0, seed=5)
    raw = tmp_path / "log.csv"
    with raw.open("w") as fh:
        fh.write("Fs,100\nn,ax,ay,az,gx,gy,gz\n")
        np.savetxt(fh, np.column_stack([np.arange(len(run.t)), run.raw["accel"], run.raw["gyro"]]), fmt="%d",
                   delimiter=",")
    out = _cli(capsys, "detect", raw, "-o", tmp_path / "s.npz", "--init-still", "4", "--json", tmp_path / "d.json")
    doc = json.loads((tmp_path / "d.json").read_text())
    poses = [re.match(r"\s+(P\d+) static_unknown\s+(\S+) -\s+(\S+) (\S+) \(\s*(\S+) (\S+)\)", ln) for ln in out]
    poses = [m for m in poses if m]
    assert len(poses) == doc["poses"] >= 6
    truth = [(sl.start / 100.0, sl.stop / 100.0) for sl in run.pose_slices]
    for m, seg in zip(poses, [s for s in doc["segments"] if s["kind"] == "static_unknown"]):
        a, b = (to_si(float(m.group(i)), m.group(4), "time") for i in (2, 3))
        assert to_si(float(m.group(5)), m.group(6), "time") == pytest.approx(b - a, abs=0.011)
        assert (a, b) == pytest.approx((seg["start"] / 100.0, seg["end"] / 100.0), abs=0.006)
        assert any(t0 - 0.006 <= a < b <= t1 + 0.006 for t0, t1 in truth), (m.group(0), truth)


def test_export_c_writes_the_chi2_thresholds_it_states(unit, capsys, tmp_path):
    out = _cli(capsys, "export-c", unit / "cal.json", "-o", tmp_path / "c", "--p-fa", "1e-4", "--confirm", "4")
    m = re.search(r"fault management p_fa (\S+), confirm (\d+)", out[-1])
    assert float(m.group(1)) == 1e-4 and int(m.group(2)) == 4, out
    src = (tmp_path / "c" / "rimu_unit.c").read_text()
    mean_thr = float(re.search(r"#define RIMU_FDI_MEAN_THR (\S+)", src).group(1))
    sample_thr = float(re.search(r"#define RIMU_FDI_SAMPLE_THR (\S+)", src).group(1))
    assert mean_thr == pytest.approx(chi2.isf(1e-4, 1), rel=1e-12)       # chi2_(1-p_fa)(1): re-admission
    assert sample_thr == pytest.approx(chi2.isf(1e-6, 1), rel=1e-12)     # chi2_(1-1e-6)(1): a clean sample
    # the calibration's figures are written as they are (SI per count): the scale factors of cal.json
    from rimu.calibration import Calibration

    cal = Calibration.load(unit / "cal.json")
    text = src + (tmp_path / "c" / "rimu_unit.h").read_text()
    numbers = [float(x) for x in re.findall(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?", text)]
    for k in ("gyro", "accel"):
        for sf in cal[k].scale:
            assert any(abs(x - sf) <= 1e-12 * abs(sf) for x in numbers), (k, sf)
