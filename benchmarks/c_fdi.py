#!/usr/bin/env python3
"""Exported C fault management: nanoseconds per sample of the generated ``rimu_gyro_fdi_step`` (gcc -O2) on a
fault-free stream and on a stream with three simultaneous ramps (an alarm on every sample: the set test over
every pair, the scatter's chi-square quantile on the target), and the size of the manager's state
(``sizeof(rimu_fdi)``), for cone6, dodecahedron6 and 9/24/48/96-axis cones. The Python reference,
:meth:`rimu.fdi.RedundancyManager.run` on the same samples, is timed in the same run.

    python benchmarks/c_fdi.py [--samples 4000] [--repeats 3]

Prints a table and one JSON line. Skips (and says so) without a C compiler.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import ratio_stats

from rimu.calibration.result import Calibration, InstrumentCalibration
from rimu.export import FdiSettings, export_c
from rimu.geometry import cone, cone6, dodecahedron6

BENCH_MAIN = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "rimu_unit.h"
int main(int argc, char **argv)
{
    long n = atol(argv[2]), reps = atol(argv[3]), k, r;
    static rimu_real y[200000 * RIMU_GYRO_N];
    static double buf[RIMU_GYRO_N];
    static rimu_fdi m;
    rimu_fdi_output out;
    struct timespec a, b;
    double acc = 0, best = 1e300;
    FILE *f = fopen(argv[1], "rb");
    for (k = 0; k < n; ++k) {
        int i;
        if (fread(buf, sizeof(double), RIMU_GYRO_N, f) != RIMU_GYRO_N) return 2;
        for (i = 0; i < RIMU_GYRO_N; ++i) y[k * RIMU_GYRO_N + i] = (rimu_real)buf[i];
    }
    fclose(f);
    for (r = 0; r < reps; ++r) {
        double ns;
        rimu_fdi_reset(&m);
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (k = 0; k < n; ++k) {
            rimu_gyro_fdi_step(&m, y + k * RIMU_GYRO_N, 0, &out);
            acc += out.x[0] + out.validity;
        }
        clock_gettime(CLOCK_MONOTONIC, &b);
        ns = ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / n;
        if (ns < best) best = ns;
    }
    printf("%.3f %lu %g\n", best, (unsigned long)sizeof(rimu_fdi), acc);
    return 0;
}
"""


def _stream(cal: InstrumentCalibration, N: int, faulty: bool, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = cal.geometry.n
    t = np.arange(N)[:, None] / 100.0
    u = 0.5 * np.sin(2 * np.pi * t / np.array([7.0, 11.0, 13.0]))
    raw = cal.noise_sigma / cal.scale
    Y = cal.raw_output(u) + rng.standard_normal((N, n)) * raw
    if faulty:
        for j, rate in zip((0, 2, 4), (30.0, -50.0, 80.0)):  # sigma per second, from the first sample
            Y[:, j] += rate * raw[j] * t[:, 0]
    return Y


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--samples", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    out = {"benchmark": "c_fdi", "compiler": cc, "samples": args.samples, "rows": []}
    if cc is None:
        print("no C compiler here: nothing to measure")
        print(json.dumps(out))
        return 0
    s = FdiSettings()
    geoms = [cone6(), dodecahedron6(), cone(9, 50.0), cone(24, 40.0), cone(48, 40.0), cone(96, 40.0)]
    print(f"{'geometry':>14} {'n':>4} {'stream':>7} {'C ns/sample':>12} {'Python us/sample':>17} {'ratio':>8} "
          f"{'alarms':>7} {'state B':>8}")
    for g in geoms:
        cal = InstrumentCalibration.nominal("gyro", g, scale=0.01, bias=0.3, noise_sigma=0.002)
        with tempfile.TemporaryDirectory() as d:
            export_c(Calibration({"gyro": cal}), d, fdi=s)
            (Path(d) / "bench.c").write_text(BENCH_MAIN)
            subprocess.run([cc, "-std=c99", "-O2", "-o", "bench", "bench.c", "rimu_unit.c", "-lm"], cwd=d, check=True)
            for faulty in (False, True):
                Y = _stream(cal, args.samples, faulty)
                np.ascontiguousarray(Y, dtype="<f8").tofile(Path(d) / "y.bin")
                mgr = _manager(s, cal)

                def py(mgr=mgr, Y=Y):
                    mgr.reset()
                    return mgr.run(Y)

                py()
                times: dict[str, list[float]] = {"c": [], "py": []}
                for _ in range(args.repeats):  # interleaved: one C run (its own loop time) and one Python run
                    res = subprocess.run([str(Path(d) / "bench"), str(Path(d) / "y.bin"), str(args.samples), "1"],
                                         capture_output=True, text=True, check=True)
                    times["c"].append(float(res.stdout.split()[0]) * 1e-9 * args.samples)
                    t0 = time.perf_counter()
                    py()
                    times["py"].append(time.perf_counter() - t0)
                state_b = int(res.stdout.split()[1])
                c_ns = statistics.median(times["c"]) / args.samples * 1e9
                alarms = int(py().alarm.sum())
                py_us = statistics.median(times["py"]) / args.samples * 1e6
                rr = ratio_stats(times, "py", "c")
                row = {"geometry": g.name, "n": g.n, "stream": "faults" if faulty else "clean", "c_ns": c_ns,
                       "python_us": py_us, "ratio": rr["median"], "ratio_range": [rr["min"], rr["max"]],
                       "alarms": alarms, "state_bytes": state_b}
                out["rows"].append(row)
                print(f"{g.name:>14} {g.n:>4} {row['stream']:>7} {c_ns:>12.1f} {py_us:>17.1f} {row['ratio']:>8.0f} "
                      f"{alarms:>7} {state_b:>8}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())


def _manager(settings, inst):
    """The Python manager of one instrument calibration with these settings (the C's decisions)."""
    from rimu.fdi import RedundancyManager
    from rimu.fusion import InstrumentPipeline

    return RedundancyManager(InstrumentPipeline(inst), **settings.manager_kwargs())
