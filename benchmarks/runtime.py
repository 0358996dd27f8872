#!/usr/bin/env python3
"""Runtime pipeline throughput on cone6, each path and backend next to its references timed in the same run.

* block path (``InstrumentPipeline.process``), numpy and numba backends, on blocks of 1e5 and 1e3 samples, against
  (a) a C kernel of the same arithmetic (range check, ``R y - off``, finiteness check per sample; built at run
  time with the system compiler, ``-O3 -march=native``, timed inside C) and (b) one fused numpy product
  ``Y @ K.T`` over the same array (the numpy memory floor). Targets: numba process >= 0.7x the C kernel's
  throughput at 1e5 samples, >= 0.5x at 1e3 (a whole ``process`` call, result object included). The numba
  backend projects blocks of up to 512 samples with its kernel and longer ones with numpy's chunked BLAS
  product, which is faster there; the kernel alone is timed too ("kernel" rows).
* ``step`` path, both backends, against a loop of one bare numpy mat-vec per sample (``G @ y``). Targets: numpy
  <= 3x, numba <= 1.5x its time.

Prints a table and one JSON line. Every candidate is timed once per round, in turn (a load change hits all
alike); times are medians over rounds, ratios medians of the per-round ratios.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ckernel import build
from _timing import interleaved_times, round_ratio

from rimu.fusion import InstrumentPipeline, numba_available
from rimu.sim import cho_park_table3

BLOCKS = (100_000, 1_000)


def main() -> dict:
    cal = cho_park_table3(gyro_sigma=0.008)["gyro"]
    backends = ["numpy"] + (["numba"] if numba_available() else [])
    pipes = {b: InstrumentPipeline(cal, backend=b) for b in backends}
    rng = np.random.default_rng(0)
    Nmax = max(BLOCKS)
    Yall = cal.raw_output(rng.standard_normal((Nmax, 3))) + rng.standard_normal((Nmax, 6))
    ref = pipes["numpy"]
    K = ref.table.get(ref.table.full_code).R
    off = ref.table.get(ref.table.full_code).off
    ck = build()
    res: dict = {"benchmark": "runtime", "geometry": "cone6", "backends": backends,
                 "c_compiler": None if ck is None else ck.compiler, "block": {}, "targets": {
                     "numba_block_vs_c_min": {str(BLOCKS[0]): 0.7, str(BLOCKS[1]): 0.5},
                     "step_time_ratio_max": {"numpy": 3.0, "numba": 1.5}}}
    for N in BLOCKS:
        Y = np.ascontiguousarray(Yall[:N])
        reps = max(5, 2_000_000 // N // 20)
        inner = max(1, 200_000 // N)  # calls per timed run at small N (timer resolution)
        row: dict = {}
        fns: dict = {}  # every candidate once per round, in turn: a load change hits all alike
        for b, p in pipes.items():
            p.process(Y)

            def run(p=p, Y=Y, inner=inner):
                for _ in range(inner):
                    p.process(Y)
            fns[b] = run

        if "numba" in pipes:  # the compiled kernel itself (process takes the BLAS path past 512 samples)
            pn = pipes["numba"]
            buf = np.empty((N, 3 + pn.r))

            def kern(Y=Y, inner=inner, pn=pn, buf=buf):
                for _ in range(inner):
                    pn._kblock(Y, pn._Re, pn._offe, pn._range, buf)
            kern()
            fns["numba_kernel"] = kern

        def floor(Y=Y, inner=inner):
            for _ in range(inner):
                Y @ K.T
        fns["numpy_matmul"] = floor
        if ck is not None:
            out = np.empty((N, K.shape[0]))
            rr = np.full(6, np.inf)
            fns["c"] = lambda Y=Y, out=out, rr=rr, inner=inner: ck.project_block(Y, K, off, rr, out, inner)[0] * inner
        times = interleaved_times(fns, reps)
        for k, ts in times.items():
            row[f"{k}_ns_per_sample"] = float(np.median(ts)) / (inner * N) * 1e9
        if ck is not None:
            np.testing.assert_allclose(out, Y @ K.T - off, rtol=1e-9, atol=1e-9)  # it computed the same
            for b in backends:  # median over rounds of the ratio within a round
                row[f"{b}_vs_c"] = round_ratio(times, "c", b)
            if "numba_kernel" in times:
                row["numba_kernel_vs_c"] = round_ratio(times, "c", "numba_kernel")
        for b in backends:
            row[f"{b}_vs_matmul"] = round_ratio(times, "numpy_matmul", b)
        res["block"][str(N)] = row

    M = 50_000
    rows = list(Yall[:M].copy())
    G = ref.table.G[0]

    def bare_loop():
        for y in rows:
            G @ y

    steps = {}
    for b, p in pipes.items():
        def step_loop(p=p):
            step = p.step
            for y in rows:
                step(y)
        step_loop()
        steps[b] = step_loop
    bare_loop()
    times = interleaved_times({"bare": bare_loop, **steps}, 7)
    res["bare_matvec_us_per_sample"] = float(np.median(times["bare"])) / M * 1e6
    res["step"] = {}
    for b in steps:
        res["step"][b] = {"us_per_sample": float(np.median(times[b])) / M * 1e6,
                          "time_ratio_to_bare": round_ratio(times, b, "bare")}
    # former keys (numpy backend, 1e5 block against Y @ K.T)
    res["block_throughput_ratio"] = res["block"][str(BLOCKS[0])]["numpy_vs_matmul"]
    res["step_time_ratio"] = res["step"]["numpy"]["time_ratio_to_bare"]

    print(f"block (process), ns/sample; ratios are throughput vs the reference (higher is better); C: "
          f"{res['c_compiler'] or 'no compiler found'}")
    print(f"{'samples':>9}{'backend':>9}{'process':>10}{'C kernel':>10}{'Y @ K.T':>10}{'vs C':>8}{'vs Y@K.T':>10}  target")
    for N in BLOCKS:
        r = res["block"][str(N)]
        for b in backends:
            c = r.get("c_ns_per_sample", float("nan"))
            vc = r.get(f"{b}_vs_c", float("nan"))
            tgt = f">= {res['targets']['numba_block_vs_c_min'][str(N)]} of C" if b == "numba" else ""
            print(f"{N:>9}{b:>9}{r[f'{b}_ns_per_sample']:>10.2f}{c:>10.2f}{r['numpy_matmul_ns_per_sample']:>10.2f}"
                  f"{vc:>8.2f}{r[f'{b}_vs_matmul']:>10.2f}  {tgt}")
        if "numba_kernel_ns_per_sample" in r:
            print(f"{N:>9}{'kernel':>9}{r['numba_kernel_ns_per_sample']:>10.2f}{r.get('c_ns_per_sample', 0):>10.2f}"
                  f"{'':>10}{r.get('numba_kernel_vs_c', float('nan')):>8.2f}{'':>10}  (numba kernel alone)")
    print(f"\nstep (per sample), us; bare numpy G @ y: {res['bare_matvec_us_per_sample']:.3f} us")
    for b in backends:
        s = res["step"][b]
        print(f"{b:>9}{s['us_per_sample']:>10.3f} us{s['time_ratio_to_bare']:>8.2f}x bare  target <= "
              f"{res['targets']['step_time_ratio_max'][b]}x")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
