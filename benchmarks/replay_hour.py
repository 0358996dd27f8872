#!/usr/bin/env python3
"""Throughput where users feel it: ``rimu replay`` with fault detection and isolation on one hour of an 8-IMU unit
at 1 kHz (8 triads at random attitudes: 24 gyro + 24 accelerometer axes; Cho & Park's procedure, 24 segments of
150 s; 3.6 million epochs, a 1.4 GB session file), against the exported C filter of the same calibration.

* rimu: ``rimu replay FILE --calibration CAL -o DIR -q`` in a fresh process (GLT detector, p_fa 1e-3, confirm 3,
  the defaults): both passes over the file in chunks (format and plausibility checks, then the runtime), the
  compensation, projection, parity, detection and isolation of every epoch, the summary. Its CPU time (user +
  system of the process) and wall time, and its peak resident memory (``VmHWM``). Targets (issue 28): at least
  100x faster than real time on one core (3600 s / CPU s), peak memory under 200 MB.
* reference: the exported C filter of the same calibration (:func:`rimu.export.export_c`, ``rimu_fdi_step`` per
  epoch: both instruments' estimate, parity test and isolation logic; gcc ``-O3 -march=native``) over the first
  200 000 epochs of the same data held in memory (no file reading), timed on the thread's CPU clock in this process.

The two are interleaved (``--rounds`` rounds, each: the replay, then the C filter); the ratio is the median of the
per-round ratios of throughput (epochs per CPU second), with min and max. BLAS threads are pinned to one, in this
script and in the replay's process. Prints a table and one JSON line.

    python benchmarks/replay_hour.py [--minutes 60] [--rounds 2]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import ctypes
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ckernel import _compile
from _timing import load

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, resource, sys, time
data, cal, out = sys.argv[1:4]
from rimu.cli import main
import rimu.cli.replay, rimu.fdi, rimu.fusion, rimu.session  # imports untimed
r0 = resource.getrusage(resource.RUSAGE_SELF)
t0 = time.perf_counter()
assert main(["replay", data, "--calibration", cal, "-o", out, "-q"]) == 0
dt = time.perf_counter() - t0
r1 = resource.getrusage(resource.RUSAGE_SELF)
cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
hwm = next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:"))
print(json.dumps({"wall_s": dt, "cpu_s": cpu, "rss_mb": hwm / 1024, "summary": json.load(open(out + "/summary.json"))}))
"""

DRIVER = r"""
#include <stdint.h>
#include "rimu_unit.h"
/* every epoch through rimu_fdi_step (both instruments), from a reset state; returns the number of epochs whose
   outputs were observable */
int64_t fdi_block(int64_t N, const double *Yg, const double *Ya, double *acc) {
    static rimu_fdi mg, ma;
    rimu_fdi_output og, oa;
    int64_t obs = 0;
    double s = 0.0;
    rimu_fdi_reset(&mg);
    rimu_fdi_reset(&ma);
    for (int64_t k = 0; k < N; k++) {
        rimu_fdi_step(0.001 * (double)k, 25.0, &mg, Yg + k * RIMU_GYRO_N, 0, &og, &ma, Ya + k * RIMU_ACCEL_N, 0,
                      &oa);
        s += og.x[0] + oa.x[0];
        obs += og.validity != RIMU_UNOBSERVABLE && oa.validity != RIMU_UNOBSERVABLE;
    }
    *acc = s;
    return obs;
}
"""


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=60.0, help="length of the recording (default one hour)")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    from scipy.spatial.transform import Rotation

    from rimu.export import export_c
    from rimu.geometry import triads
    from rimu.session import save_session
    from rimu.sim import Simulator, cho_park_procedure

    g = triads(rotations=Rotation.random(8, random_state=1).as_matrix())
    seconds = 60.0 * args.minutes
    res: dict = {"benchmark": "replay_hour", "unit": "8 triads (24 gyro + 24 accel axes)", "sample_rate_hz": 1000.0,
                 "seconds": seconds, "load": load(), "targets": {"real_time_factor_min": 100.0, "rss_mb_max": 200.0},
                 "includes": {
                     "rimu": "rimu replay FILE --calibration CAL -o DIR -q in a fresh process: both passes over the "
                             "file, compensation, projection, parity, GLT detection and isolation of every epoch, "
                             "summary; CPU time of the process",
                     "c_filter": "exported C rimu_fdi_step per epoch (both instruments) over 200 000 epochs in "
                                 "memory, gcc -O3 -march=native; CPU time of the thread"}}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t0 = time.perf_counter()
        sim = Simulator({"gyro": g, "accel": g}, sample_rate=1000.0, seed=1)
        run = sim.run(cho_park_procedure(duration=seconds / 24.0))
        cal = run.truth
        for k in ("gyro", "accel"):
            if cal[k].noise_sigma is None:
                raise SystemExit("the simulated truth has no noise figures")
        data = save_session(run.session, d / "hour.npz")
        cal.save(d / "cal.json")
        N = len(run.block)
        M = min(N, 200_000)
        Yg = np.ascontiguousarray(run.block.raw["gyro"][:M])
        Ya = np.ascontiguousarray(run.block.raw["accel"][:M])
        del run, sim
        res["epochs"] = N
        res["file_mb"] = data.stat().st_size / 1e6
        res["setup_s"] = time.perf_counter() - t0
        export_c(cal, d / "c")
        built = _compile(DRIVER, ["rimu_unit.c"], d / "c")
        if built is None:
            raise SystemExit("no C compiler: the reference cannot be built")
        lib = built[0]
        lib.fdi_block.restype = ctypes.c_int64
        acc = ctypes.c_double()
        P = ctypes.POINTER(ctypes.c_double)

        def c_filter() -> float:
            t = time.thread_time()
            obs = lib.fdi_block(ctypes.c_int64(M), Yg.ctypes.data_as(P), Ya.ctypes.data_as(P), ctypes.byref(acc))
            dt = time.thread_time() - t
            assert obs == M, obs
            return dt / M

        env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                   MKL_NUM_THREADS="1")
        rounds = []
        for r in range(args.rounds):
            p = subprocess.run([sys.executable, "-c", CHILD, str(data), str(d / "cal.json"), str(d / f"out{r}")],
                               capture_output=True, text=True, env=env, check=True)
            rimu_run = json.loads(p.stdout.strip().splitlines()[-1])
            c_s = c_filter()
            rounds.append({"rimu_cpu_s": rimu_run["cpu_s"], "rimu_wall_s": rimu_run["wall_s"],
                           "rimu_rss_mb": rimu_run["rss_mb"], "c_s_per_epoch": c_s,
                           "rimu_over_c_throughput": (c_s * N) / rimu_run["cpu_s"]})
            res["summary"] = rimu_run["summary"]
    res["rounds"] = rounds
    cpu = statistics.median(r["rimu_cpu_s"] for r in rounds)
    wall = statistics.median(r["rimu_wall_s"] for r in rounds)
    ratios = [r["rimu_over_c_throughput"] for r in rounds]
    res["rimu_cpu_s"] = cpu
    res["rimu_wall_s"] = wall
    res["real_time_factor_cpu"] = seconds / cpu
    res["real_time_factor_wall"] = seconds / wall
    res["rimu_rss_mb"] = max(r["rimu_rss_mb"] for r in rounds)
    res["c_epochs_per_s"] = 1.0 / statistics.median(r["c_s_per_epoch"] for r in rounds)
    res["rimu_epochs_per_cpu_s"] = N / cpu
    res["rimu_vs_c"] = {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios)}
    res["load_after"] = load()
    print(f"rimu replay, {seconds / 3600:g} h of {res['unit']} at 1 kHz ({N} epochs, {res['file_mb']:.0f} MB file), "
          f"fault detection on; {args.rounds} rounds interleaved with the exported C filter; {res['load']}")
    for k, v in res["includes"].items():
        print(f"  {k:>8}: {v}")
    print(f"  rimu replay: {cpu:.1f} s CPU ({wall:.1f} s wall) = {res['real_time_factor_cpu']:.0f}x real time on one "
          f"core (wall: {res['real_time_factor_wall']:.0f}x); target >= 100x")
    print(f"  peak memory (VmHWM) {res['rimu_rss_mb']:.0f} MB; target < 200 MB")
    print(f"  C filter: {res['c_epochs_per_s']:.3g} epochs/s; rimu: {res['rimu_epochs_per_cpu_s']:.3g} epochs/CPU s "
          f"= {res['rimu_vs_c']['median']:.3f} [{res['rimu_vs_c']['min']:.3f}, {res['rimu_vs_c']['max']:.3f}] x the C "
          "filter's throughput")
    alarms = {k: v.get("alarms") for k, v in res["summary"].items() if isinstance(v, dict)}
    print(f"  alarms on the fault-free hour: {alarms}; ({res['load_after']} at the end)")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
