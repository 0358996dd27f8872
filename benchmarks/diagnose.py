"""Benchmark: the diagnosis of the standard cone6 session (``rimu simulate``'s default: Cho & Park's procedure,
24 segments x 6000 samples, gyros and accelerometers; calibrated by ``rimu calibrate``) per instrument and
with its report, the candidates tested in the small space of one shared design (the default) against the
straightforward path that refits every candidate with the model on the samples (``method="refit"``), timed in
the same run; the command ``rimu diagnose SESSION --calibration CAL --report DIR`` as a user runs it (targets:
0.3 s per instrument, 3 s for the command); and diagnose + add/refit on a 20-segment session with a hidden
g-sensitivity against a plain numpy lstsq refit of the same size.

Prints a table and one JSON line. Usage: python benchmarks/diagnose.py [--repeat 5]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# one BLAS thread per process unless told otherwise: on a shared 2-core machine threaded BLAS on thin
# matrices oversubscribes the cores and runs several times slower (set OPENBLAS_NUM_THREADS to override)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import median_time  # noqa: E402

from rimu.calibration import Calibration  # noqa: E402
from rimu.calibration.effects import GSensitivity  # noqa: E402
from rimu.calibration.model import ErrorModel, contexts  # noqa: E402
from rimu.diagnose import diagnose, write_report  # noqa: E402
from rimu.diagnose.fitting import cached  # noqa: E402
from rimu.geometry import cone6  # noqa: E402
from rimu.session import load_session  # noqa: E402
from rimu.sim import Simulator, TruthEffect  # noqa: E402
from rimu.sim.procedures import cho_park_procedure  # noqa: E402
from rimu.units import DH_TO_RS, G0  # noqa: E402


def _cli(*args: str) -> tuple[float, float]:
    """Wall time and CPU time (user + system) of one ``rimu`` command in a fresh interpreter (imports included,
    as a user sees it; the CPU time is what the wall time would be on an otherwise idle machine)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rimu.cli", *args], check=True, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def _cpu(fn) -> float:
    """CPU time of one call of ``fn`` in this process, s (on a loaded machine, closer to the idle wall time)."""
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def standard_session(tmp: Path) -> tuple[Path, Path]:
    """The standard cone6 session and its calibration, made by the commands a user runs."""
    s, cal = tmp / "session.npz", tmp / "calibration.json"
    _cli("simulate", "-o", str(s), "-q")
    _cli("calibrate", str(s), "-o", str(cal), "-q")
    return s, cal


def model_and_sigma(session, cal_path: Path):
    """What ``rimu diagnose --calibration`` diagnoses: the calibration's effects and its noise level."""
    cal = Calibration.load(cal_path, session.geometries)
    model = {k: ErrorModel.from_names(["bias", "scale_misalignment"] + list(cal[k].effects)) for k in cal.instruments}
    sigma = {k: cal[k].noise_sigma / cal[k].scale for k in cal.instruments if cal[k].noise_sigma is not None}
    return model, sigma


def hidden_effect_session():
    proc = cho_park_procedure(duration=60.0)[:20]  # 10 static positions + 10 rate steps
    th = {1: [40 * DH_TO_RS / G0, -20 * DH_TO_RS / G0, 10 * DH_TO_RS / G0]}
    sim = Simulator({"gyro": cone6()}, sample_rate=100.0, arw_deg_sqrt_h=0.15, seed=0,
                    effects={"gyro": [TruthEffect(GSensitivity(), th)]})
    return sim.run(proc).session


def lstsq_refit(s) -> float:
    """Plain numpy: build the base design per sensor and solve it with lstsq (the refit of the same size)."""
    model = ErrorModel.base() + "g_sensitivity"
    t0 = time.perf_counter()
    for ctx in contexts(s, "gyro"):
        X = np.vstack([model.design(seg, ctx) for seg in s.segments])
        y = np.concatenate([seg.raw["gyro"][:, ctx.index] for seg in s.segments])
        np.linalg.lstsq(X, y, rcond=None)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rep = args.repeat
    res: dict = {"benchmark": "diagnose", "cpus": os.cpu_count(),
                 "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
                 "load_average_1min_at_start": os.getloadavg()[0]}  # > cpus: other work shares the machine
    rows: list[tuple[str, float, float | None]] = []
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        s_path, cal_path = standard_session(tmp)
        # the session as loaded: every diagnosis computes its inputs afresh (attitudes, specific force), as a
        # user's call does
        std = load_session(s_path)
        model, sigma = model_and_sigma(std, cal_path)
        res["standard_session"] = {"segments": len(std.segments), "samples": sum(g.n_samples for g in std.segments)}
        for k in std.instruments:
            fast = median_time(lambda k=k: diagnose(std, model, instruments=[k], sigma=sigma), rep)
            ref = median_time(lambda k=k: diagnose(std, model, instruments=[k], sigma=sigma, method="refit"), rep)
            res[f"{k}_diagnose_s_median"], res[f"{k}_diagnose_refit_s_median"] = fast, ref
            res[f"{k}_ratio_refit_over_fast"] = ref / fast
            rows.append((f"diagnose {k} (standard cone6)", fast, ref))
            cpu = float(np.median([_cpu(lambda k=k: diagnose(std, model, instruments=[k], sigma=sigma))
                                   for _ in range(rep)]))
            res[f"{k}_diagnose_cpu_s_median"] = cpu
            rows.append(("  the same, CPU time of this process", cpu, None))
        d = diagnose(std, model, sigma=sigma)
        d_ref = diagnose(std, model, sigma=sigma, method="refit")
        res["same_ranking_as_refit"] = all([t.name for t in d[k].tests] == [t.name for t in d_ref[k].tests]
                                           for k in d.instruments)
        fast = median_time(lambda: write_report(diagnose(std, model, sigma=sigma), tmp / "rep"), rep)
        ref = median_time(lambda: write_report(diagnose(std, model, sigma=sigma, method="refit"), tmp / "rep_ref"), rep)
        res["diagnose_and_report_s_median"], res["diagnose_and_report_refit_s_median"] = fast, ref
        rows.append(("diagnose + report, both instruments", fast, ref))
        cmd = ["diagnose", str(s_path), "--calibration", str(cal_path), "--report", str(tmp / "cli"), "-q"]
        runs = np.array([_cli(*cmd) for _ in range(max(3, rep // 2))])
        cli, cli_cpu = (float(x) for x in np.median(runs, axis=0))
        res["cli_diagnose_report_s_median"], res["cli_diagnose_report_cpu_s_median"] = cli, cli_cpu
        rows.append(("rimu diagnose --calibration --report (CLI)", cli, None))
        rows.append(("  the same, CPU time (user + system)", cli_cpu, None))
        res["meets_targets"] = bool(max(res[f"{k}_diagnose_s_median"] for k in std.instruments) < 0.3 and cli < 3.0)

    raw = hidden_effect_session()
    s = cached(raw)
    n = sum(seg.n_samples for seg in s.segments)
    diag_t, ref_t, cold_t = [], [], []
    for _ in range(rep):
        ref_t.append(lstsq_refit(s))
        t0 = time.perf_counter()
        dh = diagnose(s)
        comps = dh.add(dh["gyro"].top() or "g_sensitivity")
        diag_t.append(time.perf_counter() - t0)
        # cold: the uncached session (every input's attitude history computed afresh, as a user's first call)
        t0 = time.perf_counter()
        diagnose(raw).add("g_sensitivity")
        cold_t.append(time.perf_counter() - t0)
    cold = float(np.median(cold_t))
    md, mr = float(np.median(diag_t)), float(np.median(ref_t))
    res.update({"sensors": 6, "segments": len(s.segments), "samples_per_segment": n // len(s.segments),
                "candidates": len(dh["gyro"].tests), "diagnose_and_refit_s_median": md, "cold_s_median": cold,
                "numpy_lstsq_refit_s_median": mr, "ratio": md / mr, "ratio_cold": cold / mr, "top": dh["gyro"].top(),
                "chi2_after": comps["gyro"].chi2_after})
    rows += [("hidden g-sens: diagnose + add/refit (warm)", md, mr), ("hidden g-sens: same, cold session", cold, mr)]
    print(f"{'step':46s} {'median s':>9s} {'reference s':>12s} {'ratio':>7s}")
    for name, t, r in rows:
        print(f"{name:46s} {t:9.3f} " + (f"{r:12.3f} {r / t:7.1f}" if r is not None else f"{'-':>12s} {'-':>7s}"))
    print("reference: the refit of every candidate on the samples (diagnose rows; ratio = reference / fast), "
          "a plain numpy lstsq refit (hidden g-sens rows; ratio = lstsq / diagnosis)")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
