#!/usr/bin/env python3
"""Exported C runtime: nanoseconds per sample of the generated gyro step (gcc -O2) and the flash/RAM footprint of
its object file (``size``), for cone6, tetrad4, triad3, dodecahedron6 and 24/48/96-axis cones; the Python
pipeline's per-sample ``step`` is timed in the same run as the reference. Then whole units (gyros and
accelerometers, ``rimu_step`` per epoch) of cone6, tetrad4 and triad3 with scale/misalignment/bias only (``base``)
and with every compensable effect at typical size (``all``: temperature, drift, g-sensitivity, nonlinearity,
asymmetry, cross coupling, size effect; ``rimu.sim.typical``), against the Python ``Pipeline.step`` of the same
calibration and against ``base``.

    python benchmarks/export_c.py [--samples 200000]

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

from rimu.calibration.model import RuntimeInputs
from rimu.calibration.result import Calibration, InstrumentCalibration
from rimu.epoch import Epoch
from rimu.export import export_c
from rimu.fusion import EffectCompensation, InstrumentPipeline, Pipeline
from rimu.geometry import cone, cone6, dodecahedron6, tetrad4, triad3
from rimu.sim import cho_park_table3
from rimu.sim.truth import random_truth
from rimu.sim.typical import with_effects
from rimu.units import DEG_TO_RAD, G0

BENCH_MAIN = r"""
#include <stdio.h>
#include <time.h>
#include "rimu_unit.h"
int main(int argc, char **argv)
{
    long n = argc > 1 ? atol(argv[1]) : 100000, k;
    static rimu_real y[RIMU_GYRO_N];
    rimu_state st = {{0}};
    rimu_output out;
    struct timespec a, b;
    double acc = 0;
    int i;
    for (i = 0; i < RIMU_GYRO_N; ++i) y[i] = 100.0 + i;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (k = 0; k < n; ++k) {
        y[k % RIMU_GYRO_N] += 1e-3;
        rimu_gyro_step(&st, y, 0, &out);
        acc += out.x[0] + out.chi2;
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.3f %g\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / n, acc);
    return 0;
}
"""

BENCH_UNIT = r"""
#include <stdio.h>
#include <time.h>
#include "rimu_unit.h"
static rimu_real yg[RIMU_GYRO_N] = Y_GYRO;
static rimu_real ya[RIMU_ACCEL_N] = Y_ACCEL;
int main(int argc, char **argv)
{
    long n = argc > 1 ? atol(argv[1]) : 100000, k;
    rimu_state sg = {{0}}, sa = {{0}};
    rimu_output og, oa;
    struct timespec a, b;
    double acc = 0;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &a);
    for (k = 0; k < n; ++k) {
        yg[k % RIMU_GYRO_N] += 1e-9 * yg[k % RIMU_GYRO_N];
        ya[k % RIMU_ACCEL_N] -= 1e-9 * ya[k % RIMU_ACCEL_N];
        rimu_step((rimu_real)(0.01 * (double)k), (rimu_real)(30.0 + 1e-5 * (double)k), &sg, yg, 0, &og, &sa, ya, 0, &oa);
        acc += og.x[0] + oa.x[0] + og.chi2;
    }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &b);
    printf("%.3f %g\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / n, acc);
    return 0;
}
"""


def _unit(name: str, effects: bool) -> Calibration:
    if name == "cone6":
        cal = cho_park_table3()
    else:
        g = {"tetrad4": tetrad4(), "triad3": triad3()}[name]
        rng = np.random.default_rng(11)
        cal = Calibration({k: random_truth(g, k, rng) for k in ("gyro", "accel")})
    for k in cal.instruments:
        cal[k].noise_sigma = np.full(cal[k].geometry.n, 1e-3 if k == "gyro" else 1e-2)
    return with_effects(cal) if effects else with_effects(cal, {"gyro": [], "accel": []})


def _build(cc: str, d: str, main_c: str) -> tuple[int, int, int]:
    (Path(d) / "bench.c").write_text("#define _POSIX_C_SOURCE 199309L\n#include <stdlib.h>\n" + main_c)
    subprocess.run([cc, "-std=c99", "-O2", "-c", "rimu_unit.c"], cwd=d, check=True)
    subprocess.run([cc, "-std=c99", "-O2", "-o", "bench", "bench.c", "rimu_unit.o", "-lm"], cwd=d, check=True)
    sz = subprocess.run(["size", "rimu_unit.o"], cwd=d, capture_output=True, text=True)
    text, data, bss = (int(v) for v in sz.stdout.splitlines()[1].split()[:3])
    return text, data, bss


def units(cc: str, samples: int, repeats: int) -> list[dict]:
    """Whole units per epoch: C rimu_step against Python Pipeline.step, base and every effect."""
    rows = []
    print(f"\n{'unit':>8} {'effects':>8} {'C ns/epoch':>11} {'vs base':>8} {'Python step us':>15} {'ratio':>8} "
          f"{'text B':>8} {'data B':>7} {'bss B':>6}")
    for name in ("cone6", "tetrad4", "triad3"):
        base_ns = None
        for eff in (False, True):
            cal = _unit(name, eff)
            U = {"gyro": np.array([[70.0, -40.0, 50.0]]) * DEG_TO_RAD, "accel": np.array([[0.3, -0.2, 0.9]]) * G0}
            inputs = RuntimeInputs(t=np.zeros(1), temperature=np.array([30.0]), specific_force=U["accel"],
                                   angular_rate=U["gyro"])
            y = {k: EffectCompensation(cal[k]).forward(U[k], inputs)[0] for k in ("gyro", "accel")}
            init = {k: "{" + ", ".join(repr(float(v)) for v in y[k]) + "}" for k in y}
            with tempfile.TemporaryDirectory() as d:
                export_c(cal, d)
                main_c = BENCH_UNIT.replace("Y_GYRO", init["gyro"]).replace("Y_ACCEL", init["accel"])
                text, data, bss = _build(cc, d, main_c)
                ns = statistics.median(float(subprocess.run([str(Path(d) / "bench"), str(samples)],
                                                            capture_output=True, text=True, check=True)
                                             .stdout.split()[0]) for _ in range(repeats))
            pipe = Pipeline(cal, temperature=True)
            m = 5000
            epochs = [Epoch(0.01 * i, {k: y[k] * (1 + 1e-9 * i) for k in y}, temperature=30.0) for i in range(m)]
            ts = []
            for _ in range(repeats):
                t0 = time.process_time()
                for e in epochs:
                    pipe.step(e)
                ts.append((time.process_time() - t0) / m)
            py_us = statistics.median(ts) * 1e6
            if not eff:
                base_ns = ns
            row = {"unit": name, "effects": "all" if eff else "base", "c_ns_per_epoch": ns,
                   "c_over_base": ns / base_ns, "python_step_us": py_us, "python_over_c": py_us * 1e3 / ns,
                   "text_bytes": text, "data_bytes": data, "bss_bytes": bss}
            rows.append(row)
            print(f"{name:>8} {row['effects']:>8} {ns:11.1f} {row['c_over_base']:8.2f} {py_us:15.2f} "
                  f"{row['python_over_c']:8.0f} {text:8d} {data:7d} {bss:6d}")
    print("(one epoch = gyros and accelerometers; 'all' = every compensable effect, the gyro <-> accelerometer "
          "rounds included; CPU time of the process, C and Python alike, so that other load does not count)")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--samples", type=int, default=200000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    out = {"benchmark": "export_c", "compiler": cc, "rows": []}
    if cc is None:
        print("no C compiler here: nothing to measure")
        print(json.dumps(out))
        return 0
    geoms = [cone6(), tetrad4(), triad3(), dodecahedron6(), cone(24, 40.0), cone(48, 40.0), cone(96, 40.0)]
    print(f"{'geometry':>14} {'n':>4} {'C ns/sample':>12} {'Python step us':>15} {'ratio':>8} {'text B':>8} "
          f"{'data B':>7} {'bss B':>6}")
    for g in geoms:
        cal = InstrumentCalibration.nominal("gyro", g, scale=0.01, bias=0.3, noise_sigma=0.002)
        with tempfile.TemporaryDirectory() as d:
            export_c(Calibration({"gyro": cal}), d)
            (Path(d) / "bench.c").write_text("#define _POSIX_C_SOURCE 199309L\n#include <stdlib.h>\n" + BENCH_MAIN)
            subprocess.run([cc, "-std=c99", "-O2", "-c", "rimu_unit.c"], cwd=d, check=True)
            subprocess.run([cc, "-std=c99", "-O2", "-o", "bench", "bench.c", "rimu_unit.o", "-lm"], cwd=d, check=True)
            sz = subprocess.run(["size", "rimu_unit.o"], cwd=d, capture_output=True, text=True)
            text, data, bss = (int(v) for v in sz.stdout.splitlines()[1].split()[:3])
            ns = statistics.median(float(subprocess.run([str(Path(d) / "bench"), str(args.samples)], capture_output=True,
                                                        text=True, check=True).stdout.split()[0])
                                   for _ in range(args.repeats))
        # the Python reference: the pipeline's per-sample step (active sets computed when they occur)
        try:
            pipe = InstrumentPipeline(cal)
        except (OverflowError, MemoryError) as exc:  # the Python runtime's own limit, reported as such
            pipe, why = None, type(exc).__name__
        py_us = None
        if pipe is not None:
            y = cal.raw_output(np.array([0.1, -0.2, 0.3]))
            m = 20000
            ts = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                for _k in range(m):
                    pipe.step(y)
                ts.append((time.perf_counter() - t0) / m)
            py_us = statistics.median(ts) * 1e6
        row = {"geometry": g.name, "n": g.n, "c_ns_per_sample": ns, "python_step_us": py_us,
               "python_over_c": None if py_us is None else py_us * 1e3 / ns, "text_bytes": text, "data_bytes": data,
               "bss_bytes": bss}
        out["rows"].append(row)
        pys = f"{py_us:15.2f} {row['python_over_c']:8.0f}" if py_us is not None else f"{'(' + why + ')':>15} {'-':>8}"
        print(f"{g.name:>14} {g.n:>4} {ns:12.1f} {pys} {text:8d} {data:7d} {bss:6d}")
    print("(text = code + constant tables in flash; data + bss = RAM of the object file; the caller's rimu_state and "
          "rimu_output add n + 13 + n reals)")
    out["units"] = units(cc, args.samples, args.repeats)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
