"""Benchmark: residual statistics, candidate tests and a refit for a 6-sensor session of 20 segments x 6000
samples (one instrument), against a plain numpy lstsq refit of the same size timed in the same run.

Prints a table and one JSON line. Usage: python benchmarks/diagnose.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# one BLAS thread per process unless told otherwise: on a shared 2-core machine threaded BLAS on thin
# matrices oversubscribes the cores and runs several times slower (set OPENBLAS_NUM_THREADS to override)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rimu.calibration.effects import GSensitivity
from rimu.calibration.model import ErrorModel, contexts
from rimu.diagnose import diagnose
from rimu.diagnose.fitting import cached
from rimu.geometry import cone6
from rimu.sim import Simulator, TruthEffect
from rimu.sim.procedures import cho_park_procedure
from rimu.units import DH_TO_RS, G0


def session():
    proc = cho_park_procedure(duration=60.0)[:20]  # 10 static positions + 10 rate steps
    th = {1: [40 * DH_TO_RS / G0, -20 * DH_TO_RS / G0, 10 * DH_TO_RS / G0]}
    sim = Simulator({"gyro": cone6()}, sample_rate=100.0, arw_deg_sqrt_h=0.15, seed=0,
                    effects={"gyro": [TruthEffect(GSensitivity(), th)]})
    return sim.run(proc).session


def reference(s) -> float:
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
    raw = session()
    s = cached(raw)
    n = sum(seg.n_samples for seg in s.segments)
    diag_t, ref_t, cold_t = [], [], []
    for _ in range(args.repeat):
        ref_t.append(reference(s))
        t0 = time.perf_counter()
        d = diagnose(s)
        comps = d.add(d["gyro"].top() or "g_sensitivity")
        diag_t.append(time.perf_counter() - t0)
        # cold: the uncached session (every input's attitude history computed afresh, as a user's first call)
        t0 = time.perf_counter()
        diagnose(raw).add("g_sensitivity")
        cold_t.append(time.perf_counter() - t0)
    cold = float(np.median(cold_t))
    md, mr = float(np.median(diag_t)), float(np.median(ref_t))
    res = {"benchmark": "diagnose", "sensors": 6, "segments": len(s.segments), "samples_per_segment": n // len(s.segments),
           "candidates": len(d["gyro"].tests), "diagnose_and_refit_s_median": md, "cold_s_median": cold,
           "numpy_lstsq_refit_s_median": mr, "ratio": md / mr, "ratio_cold": cold / mr, "top": d["gyro"].top(),
           "chi2_after": comps["gyro"].chi2_after, "cpus": os.cpu_count(),
           "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default")}
    print(f"{'step':40s} {'median s':>10s}")
    print(f"{'diagnose + add/refit (warm session)':40s} {md:10.3f}")
    print(f"{'diagnose + add/refit (cold session)':40s} {cold:10.3f}")
    print(f"{'numpy lstsq refit (same size)':40s} {mr:10.3f}")
    print(f"{'ratio (warm)':40s} {md / mr:10.1f}")
    print(f"{'ratio (cold)':40s} {cold / mr:10.1f}")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
