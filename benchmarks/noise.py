"""Benchmark: ``rimu noise`` on a simulated cone6 static recording (gyros + accelerometers, 1 h at 100 Hz),
against allantools' overlapping Allan deviation of the same 12 sensors at the same averaging times timed in the
same run; the fitted terms against the simulated truth; and the detectors' false-alarm rates under bias
instability with and without the noise model.

Prints a table and one JSON line. Usage: python benchmarks/noise.py [--duration 3600] [--repeat 3]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rimu.calibration import Calibration  # noqa: E402
from rimu.cli import main  # noqa: E402
from rimu.noise import NoiseModel  # noqa: E402
from rimu.noise.allan import require_allantools, tau_grid  # noqa: E402
from rimu.session import load_session, save_session  # noqa: E402
from rimu.sim import Simulator, static  # noqa: E402

TRUTH = {"arw_deg_sqrt_h": 0.3, "vrw_ug_sqrt_hz": 50.0, "gyro_bias_instability_deg_h": 3.0,
         "accel_bias_instability_ug": 20.0}


def make_recording(folder: Path, duration: float) -> tuple[Path, Path, float]:
    t0 = time.perf_counter()
    run = Simulator(seed=3, **TRUTH).run([static("rest", (0, 0, -1), duration=duration)])
    rec, cal = folder / "rest.npz", folder / "truth.json"
    save_session(run.session, rec)
    run.truth.save(cal)
    return rec, cal, time.perf_counter() - t0


def reference(rec: Path, cal: Path) -> float:
    """allantools.oadev on the 12 compensated outputs at the command's taus (no intervals, no fit)."""
    at = require_allantools()
    s = load_session(rec)
    c = Calibration.load(cal)
    seg = s.segments[0]
    t0 = time.perf_counter()
    for k in ("gyro", "accel"):
        z = c[k].compensate(seg.raw[k])
        m = tau_grid(len(z))
        for i in range(z.shape[1]):
            at.oadev(z[:, i] - z[:, i].mean(), rate=s.sample_rate, data_type="freq", taus=m / s.sample_rate)
    return time.perf_counter() - t0


def command(rec: Path, cal: Path, out: Path, report: Path | None) -> float:
    argv = ["noise", str(rec), "--calibration", str(cal), "-o", str(out)]
    if report is not None:
        argv += ["--report", str(report)]
    t0 = time.perf_counter()
    with open(os.devnull, "w") as null:
        old, sys.stdout = sys.stdout, null
        try:
            code = main(argv)
        finally:
            sys.stdout = old
    assert code == 0
    return time.perf_counter() - t0


def subprocess_wall(rec: Path, cal: Path, out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rimu.cli", "noise", str(rec), "--calibration", str(cal), "-o", str(out)],
                   check=True, capture_output=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return time.perf_counter() - t0


def truth_check(out: Path) -> dict[str, dict[str, float]]:
    m = NoiseModel.load(out)
    want = {("gyro", "white"): TRUTH["arw_deg_sqrt_h"], ("gyro", "bias_instability"): TRUTH["gyro_bias_instability_deg_h"],
            ("accel", "white"): TRUTH["vrw_ug_sqrt_hz"] * 1e-6 * 9.80665 * 60.0,
            ("accel", "bias_instability"): TRUTH["accel_bias_instability_ug"]}
    res = {}
    for (inst, term), v in want.items():
        rows = m[inst].table_rows()
        est = np.array([r[term] for r in rows])
        sd = np.array([r[term + "_sigma"] for r in rows])
        e = (est - v) / sd
        res[f"{inst}.{term}"] = {"truth": v, "mean": float(est.mean()), "sigma": float(sd.mean()),
                                 "max_abs_err_over_sigma": float(np.abs(e).max()),
                                 "rms_err_over_sigma": float(np.sqrt(np.mean(e ** 2)))}
    res["parity"] = {k: {"white": v["white"], "independent": v["independent"]} for k, v in m.parity.items()}
    return res


def false_alarms() -> dict[str, dict[str, float]]:
    """The test suite's setting (tests/noise/test_noise_fdi.py): rate of each detector at the horizon."""
    sys.path.insert(0, str(ROOT))
    from rimu.fdi import CusumBank, GltSnapshot, GltWindow, ParityKalman
    from rimu.fdi.whitening import NoiseSettings
    from tests.noise import test_noise_fdi as t

    ns = NoiseSettings(t._model(), horizon_s=t.HORIZON, reference_s=t.T_REF)
    P = t.realisations(1000, 200, 1)
    out = {}
    for name, make in (("glt_snapshot", lambda nz: GltSnapshot(t.P_FA, noise=nz)),
                       ("glt_window_100", lambda nz: GltWindow(100, t.P_FA, noise=nz)),
                       ("kalman_tau_20", lambda nz: ParityKalman(20, t.P_FA, engine="steady", noise=nz))):
        out[name] = {"design": t.P_FA, "with_model": t._rate_at_end(make(ns), P),
                     "white_only": t._rate_at_end(make(None), P)}
    R, w, arl0 = 250, 2000, 1000.0
    P = t.realisations(R, w, 2)
    for label, nz in (("with_model", ns), ("white_only", None)):
        bank = CusumBank(0.5 * t.SIG, arl0, noise=nz)
        U, d, thr, _ = bank.design(t.VZ, 3)
        X = P @ U
        S = np.zeros((2, R, t.N_SENS))
        alarms = 0
        for k in range(w):
            S[0] += d * (X[k] - d / 2)
            S[1] += d * (-X[k] - d / 2)
            np.maximum(S, 0.0, out=S)
            hit = (S / thr).max(axis=(0, 2)) > 1.0
            alarms += int(hit.sum())
            S[:, hit, :] = 0.0
        out.setdefault("cusum_arl0_1000", {"design": 1.0 / arl0})[label] = alarms / (R * w)
    return out


def run(duration: float, repeat: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        rec, cal, t_sim = make_recording(d, duration)
        out = d / "noise.json"
        cmd = [command(rec, cal, out, None) for _ in range(repeat)]
        rep = [command(rec, cal, out, d / "rep") for _ in range(repeat)]
        ref = [reference(rec, cal) for _ in range(repeat)]
        wall = subprocess_wall(rec, cal, d / "n2.json")
        truth = truth_check(out)
    return {"duration_s": duration, "sample_rate": 100.0, "sensors": 12, "simulate_s": t_sim,
            "command_median_s": statistics.median(cmd), "command_with_report_median_s": statistics.median(rep),
            "allantools_oadev_median_s": statistics.median(ref), "subprocess_wall_s": wall,
            "ratio_command_to_allantools": statistics.median(cmd) / statistics.median(ref),
            "truth": truth, "false_alarms": false_alarms()}


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    r = run(a.duration, a.repeat)
    print(f"rimu noise on a cone6 static recording: {r['duration_s']:.0f} s at 100 Hz, 12 sensors")
    print("| what | median s |")
    print("|---|---|")
    print(f"| rimu noise (Allan deviation + intervals + fit + parity check, 12 sensors) | {r['command_median_s']:.2f} |")
    print(f"| rimu noise --report (plus 4 PNG and markdown) | {r['command_with_report_median_s']:.2f} |")
    print(f"| reference: allantools.oadev alone on the same 12 series and taus | {r['allantools_oadev_median_s']:.2f} |")
    print(f"| `python -m rimu.cli noise` in a subprocess (imports included) | {r['subprocess_wall_s']:.2f} |")
    print(f"ratio command / allantools: {r['ratio_command_to_allantools']:.2f}")
    print()
    print("| term | truth | mean estimate | mean sigma | max abs(err)/sigma | rms(err/sigma) |")
    print("|---|---|---|---|---|---|")
    for k, v in r["truth"].items():
        if k != "parity":
            print(f"| {k} | {v['truth']:.4g} | {v['mean']:.4g} | {v['sigma']:.2g} | {v['max_abs_err_over_sigma']:.2f} "
                  f"| {v['rms_err_over_sigma']:.2f} |")
    print(f"parity verdicts: {r['truth']['parity']}")
    print()
    print("| detector | design | with the noise model | white-noise model only |")
    print("|---|---|---|---|")
    for k, v in r["false_alarms"].items():
        print(f"| {k} | {v['design']:.3g} | {v['with_model']:.3g} | {v['white_only']:.3g} |")
    print(json.dumps(r))


if __name__ == "__main__":
    main_()
