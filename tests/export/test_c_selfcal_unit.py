"""``rimu export-c --selfcal`` end to end: the compiled filter of a self-calibrating unit against ``rimu replay
--selfcal`` on the same CSV log, sample for sample.

A simulated drifting unit (cone6, and an array of four parallel triads): biases drifting as random walks, a 30 K
temperature ramp with first- and second-order coefficients, flight-like motion, a sensor invalid for a few samples
and a step fault of 8 sigma on one sensor part-way. Both sides run with the same options (the CLI's defaults: the
window GLT whose thresholds carry the tracker's covariance, the 3 s hold, the held-out check with its 60 s memory).
The decisions (validity, isolated sensors) must be identical on every sample, the estimates and the tracked terms
with their 1-sigma equal to 1e-12 (of the noise for the estimates, relative for the terms). Skips without a C
compiler (and make).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import subprocess

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import main
from rimu.export.estimates import read_estimates
from rimu.geometry import cone6, triads
from rimu.session import Segment, Session
from rimu.session.native import save_session

needs_cc = pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")) or shutil.which("make") is None,
                              reason="no C compiler or make on this machine")

SIGMA = 0.01          # rad/s per sample
FS = 100.0            # Hz
BIAS_RW = 4e-7        # (rad/s)^2/s
DRIFT_RW = 3 * BIAS_RW  # (rad/s)^2/s: the unit's bias random walk (the tracker is told it)
OFFSET = 0.004        # rad/s: 1-sigma of each bias's error at the start (the tracker is told it)


def _unit(tmp_path, geo, seed: int, duration: float = 40.0):
    """The log (CSV + sidecar), the calibration file, and the sensor that fails."""
    rng = np.random.default_rng(seed)
    n, N = geo.n, int(duration * FS)
    inst = InstrumentCalibration.nominal("gyro", geo, 1.0, noise_sigma=SIGMA)
    t = 500.0 + np.arange(N) / FS
    T = 10.0 + 30.0 * np.arange(N) / (N - 1)                           # a 30 K ramp, degC
    u = np.column_stack([0.5 * np.sin(0.7 * t + i) + 0.2 * np.sin(2.3 * t + 2 * i) for i in range(3)])
    drift = np.cumsum(rng.standard_normal((N, n)) * np.sqrt(DRIFT_RW / FS), axis=0) + rng.normal(0, OFFSET, n)
    c1, c2 = rng.normal(0, 1e-4, n), rng.normal(0, 5e-6, n)             # rad/s/K, rad/s/K^2
    Y = u @ inst.axes_mb().T + drift + (T - 25.0)[:, None] * c1 + ((T - 25.0) ** 2)[:, None] * c2
    Y += rng.standard_normal((N, n)) * SIGMA
    bad = 2
    Y[np.arange(N) >= int(0.6 * N), bad] += 8 * SIGMA                  # the step fault
    Y[1000:1003, 4] = np.nan                                           # invalid for three samples
    seg = Segment("flight", "motion", t, {"gyro": Y}, temperature=T)
    log = save_session(Session([seg], {"gyro": geo}, FS, raw_unit="rad/s"), tmp_path / "log.csv")
    Calibration({"gyro": inst}, "rad/s", "nominal").save(tmp_path / "cal.json")
    return log, tmp_path / "cal.json", bad


def _run(argv: list[str]) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(argv)
    assert code == 0, buf.getvalue()
    return buf.getvalue()


@needs_cc
@pytest.mark.parametrize("geo,window,cusum", [(cone6(), None, False), (triads(4), 30, False), (cone6(), None, True)],
                         ids=["cone6", "triads4-window30", "cone6-cusum"])
def test_exported_selfcal_unit_decides_as_replay(tmp_path, geo, window, cusum):
    """cone6 with the default detector (the window GLT of the tracker's window); the triads with a window GLT of 30
    samples (replay --detector glt_window --window 30, export-c --selfcal-detector-window 30); cone6 with the CUSUM
    bank beside the window GLT (--selfcal-cusum on both sides)."""
    log, cal, bad = _unit(tmp_path, geo, seed=3)
    # the unit's drift as it is (told a slower one, the tracker is frozen by the alarms of the drift it may not
    # absorb, and healthy sensors are isolated before the step: tests/fdi/test_selfcal_isolation.py)
    opts = ["--selfcal-bias-rw", repr(DRIFT_RW), "--selfcal-bias-sigma0", repr(OFFSET), "--selfcal-window", "0.5"] \
        + (["--selfcal-cusum"] if cusum else [])
    det = [] if window is None else ["--detector", "glt_window", "--window", str(window)]
    _run(["replay", str(log), "--calibration", str(cal), "--selfcal", *opts, *det, "--estimates",
          str(tmp_path / "py.csv"), "--json", str(tmp_path / "py.json"), "-q"])
    _run(["export-c", str(cal), "-o", str(tmp_path / "c"), "--selfcal", "--sample-rate", repr(FS),
          "--selfcal-temperature", *opts, "--build"] + ([] if window is None else
                                                       ["--selfcal-detector-window", str(window)]))
    if window is not None:
        assert f"#define RIMU_GYRO_SC_GLT_WINDOW {window}" in (tmp_path / "c" / "rimu_gyro_sc.h").read_text()
    out = subprocess.run([str(tmp_path / "c" / "rimu_filter")], stdin=open(log), capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    py = read_estimates(tmp_path / "py.csv", {"gyro": geo.n})
    c = read_estimates(io.StringIO(out.stdout), {"gyro": geo.n})
    assert list(c.extra) == list(py.extra) and len(py.extra) == 2 * 4 * geo.n   # bias, scale, tc1, tc2: value, sigma
    # the decisions: identical on every sample
    assert np.array_equal(c.validity["gyro"], py.validity["gyro"])
    assert np.array_equal(c.isolated["gyro"], py.isolated["gyro"])
    assert py.isolated["gyro"][-1].nonzero()[0].tolist() == [bad]          # the fault was isolated ...
    ever = np.flatnonzero(py.isolated["gyro"].any(axis=0)).tolist()
    first = int(np.flatnonzero(py.isolated["gyro"][:, bad])[0])
    assert ever == [bad] and py.t[first] >= py.t[int(0.6 * len(py.t))], (ever, py.t[first])  # ... alone, after its step
    assert np.count_nonzero(py.validity["gyro"] == 1) > 0                  # ... after alarms
    # the estimates (from the corrected outputs): 1e-12 of the noise
    x_c, x_py = c.x["gyro"], py.x["gyro"]
    assert np.array_equal(np.isnan(x_c), np.isnan(x_py))
    err_x = float(np.nanmax(np.abs(x_c - x_py)))
    assert err_x <= 1e-12 * SIGMA, err_x
    # the tracked terms and their 1-sigma: 1e-12 relative to the scale of their block (every sensor's values)
    worst = 0.0
    for block in ("bias", "scale", "tc1", "tc2"):
        for suffix in ("", "_sigma"):
            names = [f"gyro_{block}_{nm}{suffix}" for nm in geo.names]
            v = np.array([py.extra[nm] for nm in names])
            w = np.array([c.extra[nm] for nm in names])
            worst = max(worst, float(np.abs(w - v).max()) / float(np.abs(v).max()))
    assert worst <= 1e-12, worst
    # the tracker did act: its terms moved, and the correction changed the estimates
    doc = json.loads((tmp_path / "py.json").read_text())["gyro"]
    detail = subprocess.run([str(tmp_path / "c" / "rimu_filter"), "--detail"], stdin=open(log), capture_output=True,
                            text=True, check=True).stdout
    alarms_c = sum(int(r["gyro_alarm"]) for r in csv.DictReader(io.StringIO(detail)))
    assert alarms_c == doc["alarms"] > 0                       # as many alarms (per sample: the next test)
    sc = doc["selfcal"]
    windows = len(py.t) // int(0.5 * FS)
    applied = {g: windows - v["suspended_windows"] for g, v in sc["guard"]["groups"].items()}
    assert sc["windows_absorbed"] >= 10 and sc["windows_discarded"] >= 1 and max(applied.values()) >= 10, sc
    assert min(applied.values()) < windows                 # the held-out check held a group back for a while
    print(f"\n{geo.name}: max |x_C - x_py| = {err_x:.3g} rad/s, terms max rel diff {worst:.3g}; windows applied "
          f"per group {applied} of {windows}")


@needs_cc
def test_exported_selfcal_with_further_effects_and_two_instruments(tmp_path):
    """The API (export_c(selfcal=...)) on a unit whose compensation couples the instruments (gyro g-sensitivity and
    temperature bias, accelerometer size effect: the gyro <-> accelerometer fixed point) with both instruments
    tracked (bias, scale, first-order temperature) and a step on one gyro: the C decides as rimu.fdi.Runtime on
    every sample, its estimates within 1e-12 (relative)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_c_effects import _base, _session

    from rimu.epoch import EpochBlock
    from rimu.export import export_c
    from rimu.fdi import Runtime
    from rimu.fdi.health import SensorState
    from rimu.fdi.selfcal import SelfCalSettings, SelfCalTracker
    from rimu.fdi.settings import FdiSettings
    from rimu.fusion import Pipeline
    from rimu.sim.typical import with_effects

    cal = with_effects(_base("cone6"), {"gyro": ["g_sensitivity", "bias_temperature"], "accel": ["size_effect"]})
    t, T, raw, _ = _session(cal, 2500, noise=True, seed=3)
    raw["gyro"][1500:, 1] += 12 * cal["gyro"].noise_sigma[1] / cal["gyro"].scale[1]
    trk = {k: SelfCalTracker(cal[k], SelfCalSettings(bias_rw=1e-8 if k == "gyro" else 1e-6, scale_rw=1e-9,
                                                     temperature_sigma=[1e-4], window_s=0.5, hold_s=2.0))
           for k in cal.instruments}
    res = Runtime(Pipeline(cal), FdiSettings(), selfcal=trk, sample_rate=FS).run(
        EpochBlock(t, raw, {k: np.isfinite(v) for k, v in raw.items()}, T))
    export_c(cal, tmp_path / "c", selfcal=trk, sample_rate=FS)
    made = subprocess.run(["make", "-s", "CFLAGS=-std=c99 -O0 -Wall -Wextra -Werror -pedantic"], cwd=tmp_path / "c",
                          capture_output=True, text=True)       # -O0: the build is most of this test's time
    assert made.returncode == 0, made.stderr
    names = ["t"] + [f"{k}_{nm}" for k in cal.instruments for nm in cal[k].geometry.names] + ["temperature"]
    rows = [",".join(names)] + [",".join([repr(float(t[i]))] + [
        "" if not np.isfinite(raw[k][i, j]) else repr(float(raw[k][i, j])) for k in cal.instruments for j in range(6)]
        + [repr(float(T[i]))]) for i in range(len(t))]
    out = subprocess.run([str(tmp_path / "c" / "rimu_filter")], input="\n".join(rows) + "\n", capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    est = read_estimates(io.StringIO(out.stdout), {k: 6 for k in cal.instruments})
    assert len(est.extra) == 2 * 2 * 3 * 6                      # two instruments, bias + scale + tc1, value + sigma
    for k in cal.instruments:
        x = np.asarray(res[k].x)
        assert np.array_equal(est.validity[k], res[k].validity)
        assert np.array_equal(est.isolated[k], np.asarray(res[k].sensor_state) >= SensorState.ISOLATED)
        rel = float(np.nanmax(np.abs(est.x[k] - x))) / float(np.nanmax(np.abs(x)))
        assert rel <= 1e-12, (k, rel)
        print(f"\n{k}: max |x_C - x_py| / max |x| = {rel:.3g}")
    assert est.isolated["gyro"][-1].nonzero()[0].tolist() == [1]
    # --detail: the alarm of every sample identical; the detection statistic (the tracked window GLT's): its root, the
    # parity's norm in sigma, within 1e-12 of the whitened outputs' size (the parity is their small difference)
    det = subprocess.run([str(tmp_path / "c" / "rimu_filter"), "--detail"], input="\n".join(rows) + "\n",
                         capture_output=True, text=True, check=True).stdout
    cols = list(csv.DictReader(io.StringIO(det)))
    for k in cal.instruments:
        alarm = np.array([int(r[f"{k}_alarm"]) for r in cols])
        stat = np.array([float(r[f"{k}_statistic"]) for r in cols])
        assert np.array_equal(alarm, np.asarray(res[k].alarm, int)), k
        ref = np.asarray(res[k].statistic, float)
        zmax = float(np.nanmax(np.abs(raw[k] * cal[k].scale - cal[k].bias) / cal[k].noise_sigma))
        err = float(np.abs(np.sqrt(stat) - np.sqrt(ref)).max())
        assert err <= 1e-12 * zmax, (k, err, zmax)
        print(f"\n{k}: max |sqrt(stat_C) - sqrt(stat_py)| = {err:.3g} sigma (outputs up to {zmax:.3g} sigma); "
              f"alarms {int(alarm.sum())}")
    assert int(np.sum(res["gyro"].alarm)) >= 5


@pytest.mark.skipif(shutil.which("cppcheck") is None, reason="cppcheck is not installed")
def test_selfcal_unit_misra_nothing_outside_the_documented_deviations(tmp_path):
    """rimu_unit.c/.h of a self-calibrating unit (the tracked step, rimu_selfcal_step) with MISRA C:2012: only the
    documented deviations (rimu.export.misra; the trackers' own sources: tests/export/test_c_selfcal.py)."""
    from rimu.export import export_c
    from rimu.export.misra import DEVIATIONS, misra_check
    from rimu.fdi.selfcal import SelfCalSettings, SelfCalTracker

    inst = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=SIGMA)
    trk = SelfCalTracker(inst, SelfCalSettings(bias_rw=BIAS_RW, scale_rw=1e-9, temperature_sigma=[1e-4]))
    export_c(Calibration({"gyro": inst}, "rad/s", "nominal"), tmp_path, selfcal={"gyro": trk}, sample_rate=FS)
    found = misra_check(tmp_path)
    assert sum(found["misra"].values()) > 0   # the addon ran and read the code
    assert set(found["misra"]) <= set(DEVIATIONS), set(found["misra"]) - set(DEVIATIONS)
    assert not found["other"], found["other"]
