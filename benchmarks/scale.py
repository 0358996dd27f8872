#!/usr/bin/env python3
"""Runtime and FDI for many sensors: build time, peak memory and per-sample cost at n = 6, 24, 48, 96 axes.

For each unit (cone6, then 8, 16 and 32 skewed triads):

* build: ``InstrumentPipeline`` + ``RedundancyManager`` (active sets computed when they occur), median time
  and tracemalloc peak;
* set change: computing the matrices of one new active set (what an isolation or an invalid sample costs once);
* per sample: ``InstrumentPipeline.step`` and ``RedundancyManager.step`` (default GLT; and with the motion-aware
  GLT of :mod:`rimu.fdi.motion`), next to the bare numpy reference ``R @ y - off`` with the same matrix in the
  same run;
* the former full table (:class:`rimu.fusion.reference.FullProjectionTable`) where it fits: its build time and
  peak memory with every exclusion set up to the largest ``max_excluded`` that keeps it under 3000 sets, and the
  memory the table of every observable set would need (its parity array alone, n > 6).

Prints a table and one JSON line. ``python benchmarks/scale.py``.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import json
import math
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import interleaved_times, median_time, ratio_stats

from rimu.calibration import InstrumentCalibration
from rimu.fdi import MotionAwareGlt, MotionNoiseModel, RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.fusion.reference import FullProjectionTable
from rimu.geometry import cone6
from rimu.sim.multitriad import triad_array


def peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def unit(n: int):
    g = cone6() if n == 6 else triad_array(n // 3)
    return InstrumentCalibration.nominal("gyro", g, 0.01, 0.5, 0.003)


def one(n: int) -> dict:
    cal = unit(n)
    A, sig = cal.axes_mb(), cal.noise_sigma

    def build():
        RedundancyManager(InstrumentPipeline(cal))

    build()
    t_build = median_time(build, 5)
    mem_build = peak_bytes(build)

    pipe = InstrumentPipeline(cal)
    mgr = RedundancyManager(pipe)
    rng = np.random.default_rng(0)
    codes = [pipe.table.full_code & ~(1 << int(i)) & ~(1 << int(j)) for i, j in rng.integers(0, n, (40, 2))]
    t0 = time.perf_counter()
    for c in codes:
        pipe.table.get(c)
    t_set = (time.perf_counter() - t0) / len(codes)

    M = 5000
    Y = cal.raw_output(rng.standard_normal((M, 3))) + 0.3 * rng.standard_normal((M, n))
    rows = list(Y)
    full = pipe.table.get(pipe.table.full_code)
    R, off = full.R, full.off

    def step_loop():
        for y in rows:
            pipe.step(y)

    def mgr_loop():
        for y in rows:
            mgr.step(y)

    def bare_loop():
        for y in rows:
            R @ y - off

    for f in (step_loop, bare_loop):
        f()
    times = interleaved_times({"step": step_loop, "bare": bare_loop}, 7)  # in turn: a load change hits both
    t_step = statistics.median(times["step"]) / M
    t_bare = statistics.median(times["bare"]) / M
    step_ratio = ratio_stats(times, "step", "bare")
    mgr.reset()
    t_mgr = median_time(lambda: (mgr.reset(), mgr_loop()), 3) / M
    model = MotionNoiseModel(cal, scale_rel=0.005, misalignment_rad=0.005, time_offset_s=1e-3, rate_var=1e-6)
    mmgr = RedundancyManager(InstrumentPipeline(cal), MotionAwareGlt(model, sample_rate=100.0))
    Mm = 1000

    def motion_loop():
        mmgr.reset()
        for y in rows[:Mm]:
            mmgr.step(y)

    t_motion = median_time(motion_loop, 3) / Mm

    res = {"n": n, "geometry": cal.geometry.name, "build_s": t_build, "build_peak_MB": mem_build / 1e6,
           "new_set_s": t_set, "step_us": t_step * 1e6, "manager_step_us": t_mgr * 1e6, "motion_manager_step_us": t_motion * 1e6,
           "reference_matvec_us": t_bare * 1e6, "step_over_reference": step_ratio["median"],
           "step_over_reference_range": [step_ratio["min"], step_ratio["max"]]}
    # the former table of every exclusion set, where it fits
    if n <= 62:
        m = 0
        while m + 1 <= n - 3 and sum(math.comb(n, k) for k in range(m + 2)) <= 3000:
            m += 1
        sets = sum(math.comb(n, k) for k in range(m + 1))
        ft = median_time(lambda: FullProjectionTable(A, sig, m), 3 if sets < 500 else 1)
        fm = peak_bytes(lambda: FullProjectionTable(A, sig, m))
        res.update({"full_table_max_excluded": m, "full_table_sets": sets, "full_table_build_s": ft,
                    "full_table_peak_MB": fm / 1e6})
    all_sets = sum(math.comb(n, k) for k in range(n - 2))
    res["all_sets"] = all_sets
    res["all_sets_parity_GiB"] = all_sets * (n - 3) * n * 8 / 2**30
    return res


def main() -> list[dict]:
    out = [one(n) for n in (6, 24, 48, 96)]
    print(f"{'n':>3} {'build ms':>9} {'peak MB':>8} {'new set ms':>10} {'step us':>8} {'mgr step us':>11} "
          f"{'motion mgr us':>13} {'matvec us':>9} {'ratio':>6} | {'full table: max_excl':>20} {'sets':>6} {'build ms':>9} {'peak MB':>8} "
          f"| {'every set: count':>16} {'parity GiB':>11}")
    for r in out:
        ft = (f"{r['full_table_max_excluded']:>20d} {r['full_table_sets']:>6d} {1e3 * r['full_table_build_s']:>9.1f} "
              f"{r['full_table_peak_MB']:>8.2f}") if "full_table_sets" in r else f"{'-':>20} {'-':>6} {'-':>9} {'-':>8}"
        print(f"{r['n']:>3} {1e3 * r['build_s']:>9.2f} {r['build_peak_MB']:>8.2f} {1e3 * r['new_set_s']:>10.3f} "
              f"{r['step_us']:>8.2f} {r['manager_step_us']:>11.2f} {r['motion_manager_step_us']:>13.1f} "
              f"{r['reference_matvec_us']:>9.2f} "
              f"{r['step_over_reference']:>6.2f} | {ft} | {r['all_sets']:>16.3g} {r['all_sets_parity_GiB']:>11.3g}")
    print(json.dumps({"benchmark": "scale", "results": out}))
    return out


if __name__ == "__main__":
    main()
