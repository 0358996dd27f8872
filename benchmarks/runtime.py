#!/usr/bin/env python3
"""Runtime pipeline throughput on cone6 (gyros + accelerometers, Cho & Park Table 3), each path and backend next to
its references timed in the same run, interleaved.

* Blocks: ``Pipeline.process(block, out=buffers)`` (the whole call: checks, the compiled pass, the result objects)
  on blocks of 1e5 and 1e3 epochs, against
  (a) the fixed-size C kernel a C programmer writes for this unit (``benchmarks/_ckernel.py``, ``build_fixed``:
  sizes fixed at compile time, range and finiteness tested once per block, gcc ``-O3 -march=native``, timed
  inside C: no call overhead), the same outputs (estimate and parity of both instruments) into the same buffers;
  (b) rimu's exported C of the same calibration (``rimu_step`` per epoch, estimates copied out; ``-O3
  -march=native``; it also solves the covariance and the chi-square per sample: a weaker reference);
  (c) numpy's ``Y @ R.T`` of both instruments (new arrays; no offset, no checks): the BLAS floor.
  ``process`` without ``out=`` (two fresh result arrays per instrument) and the numpy backend are timed too.
  Targets (issue 28): numba >= 0.7x the fixed-size C kernel's throughput at 1e5 epochs, >= 0.5x at 1e3.
* Per-call overhead: ``Pipeline.process`` of a one-epoch block with ``out=`` against one bare numpy mat-vec
  ``R @ y`` (6 x 6). Target: under 2 us.
* ``InstrumentPipeline.step``, both backends, against a loop of one bare numpy mat-vec per sample (``G @ y``), the
  loop included on both sides. Targets: numpy <= 3x, numba <= 1.5x its time.

Every candidate is timed once per round, in turn (a load change hits all alike), on the CPU-time clock of the thread
(``time.thread_time``; the C kernels read it around their loop), so that the slices the shared cores give to other
processes do not count; times are medians over rounds, ratios the median of the per-round ratios, with their min
and max. BLAS threads are pinned to one here.
Prints a table and one JSON line.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ckernel import build_exported, build_fixed
from _timing import interleaved_times, load, ratio_stats, round_ratio

from rimu.epoch import EpochBlock
from rimu.fusion import Pipeline, numba_available
from rimu.sim import cho_park_table3

BLOCKS = (100_000, 1_000)
INSTS = ("gyro", "accel")
ROUNDS = 41
#: CPU time of this thread: the time slices that the shared cores give to other processes do not count (the
#: C kernels read the same clock around their loop)
CLOCK = time.thread_time


def _fmt(r: dict) -> str:
    return f"{r['median']:.2f} [{r['min']:.2f}, {r['max']:.2f}]"


def _blocks(N: int, pipes: dict, backends: list, Yall: dict, Rs: list, offs: list, lims: list, ck, ce) -> dict:
    """Every block candidate at N epochs, interleaved; ns/epoch and per-round throughput ratios."""
    Ys = [np.ascontiguousarray(Yall[k][:N]) for k in INSTS]
    block = EpochBlock(np.arange(N) * 1e-3, dict(zip(INSTS, Ys)))
    inner = max(1, 20_000 // N)  # calls per timed run (timer resolution at small N)
    reps = ROUNDS
    fns: dict = {}
    outs = {b: {k: np.empty((N, 6)) for k in INSTS} for b in backends}
    for b, p in pipes.items():
        p.process(block, outs[b])

        def run(p=p, o=outs[b]):
            for _ in range(inner):
                p.process(block, o)
        fns[b] = run
    if "numba" in pipes:
        pn = Pipeline(pipes["numba"].calibration, backend="numba")  # its own pipeline: no state shared with "numba"
        pn.process(block)

        def run_alloc(pn=pn):
            for _ in range(inner):
                pn.process(block)
        fns["numba_alloc"] = run_alloc

    def floor():
        for _ in range(inner):
            for Y, R in zip(Ys, Rs):
                Y @ R.T
    fns["numpy_matmul"] = floor
    cout = [np.empty((N, 6)) for _ in INSTS]
    if ck is not None:
        fns["c_fixed"] = lambda: ck.block(Ys, Rs, offs, lims, cout, inner)[0] * inner
    eout = [np.empty((N, 3)) for _ in INSTS]
    if ce is not None:
        fns["c_export"] = lambda: ce.block(Ys[0], Ys[1], eout[0], eout[1], inner)[0] * inner
    for f in fns.values():
        f()
    times = interleaved_times(fns, reps, CLOCK)
    row: dict = {f"{k}_ns_per_epoch": float(np.median(ts)) / (inner * N) * 1e9 for k, ts in times.items()}
    # it computed the same: rimu against the C kernels (and the numpy backend against numba)
    for j, k in enumerate(INSTS):
        for b in backends:
            o = outs[b][k]
            if ck is not None:
                np.testing.assert_allclose(o, cout[j], rtol=1e-9, atol=1e-9 * np.abs(cout[j]).max())
            if ce is not None:
                np.testing.assert_allclose(o[:, :3], eout[j], rtol=1e-9, atol=1e-9 * np.abs(eout[j]).max())
    for b in [*backends, "numba_alloc"] if "numba" in backends else backends:
        for refname in ("c_fixed", "c_export", "numpy_matmul"):
            if refname in times:  # throughput of b / throughput of the reference = t_ref / t_b, per round
                row[f"{b}_vs_{refname}"] = ratio_stats(times, refname, b)
    return row


def main() -> dict:
    cal = cho_park_table3(gyro_sigma=0.008)
    for k in INSTS:  # the exported C needs the noise (the fusion weights)
        if cal[k].noise_sigma is None:
            cal[k].noise_sigma = np.full(cal[k].geometry.n, 1e-3 if k == "gyro" else 1e-2)
    backends = ["numpy"] + (["numba"] if numba_available() else [])
    pipes = {b: Pipeline(cal, backend=b) for b in backends}
    ref = pipes["numpy"]
    rng = np.random.default_rng(0)
    Nmax = max(BLOCKS)
    Yall = {k: cal[k].raw_output(rng.standard_normal((Nmax, 3))) + rng.standard_normal((Nmax, 6)) for k in INSTS}
    sets = {k: ref[k].table.get(ref[k].table.full_code) for k in INSTS}
    Rs = [np.ascontiguousarray(sets[k].R) for k in INSTS]
    offs = [np.ascontiguousarray(sets[k].off) for k in INSTS]
    lims = [np.full(ref[k].n, np.inf) if ref[k].range_raw is None else ref[k].range_raw.copy() for k in INSTS]
    ck = build_fixed([(ref[k].n, Rs[j].shape[0]) for j, k in enumerate(INSTS)])
    ce = build_exported(cal)
    for c in (ck, ce):
        if c is not None:
            c.clock = CLOCK
    res: dict = {"benchmark": "runtime", "geometry": "cone6 gyro + accel", "backends": backends,
                 "c_compiler": None if ck is None else ck.compiler, "load": load(), "block": {},
                 "targets": {"numba_block_vs_c_min": {str(BLOCKS[0]): 0.7, str(BLOCKS[1]): 0.5},
                             "process_overhead_us_max": 2.0, "step_time_ratio_max": {"numpy": 3.0, "numba": 1.5}},
                 "includes": {
                     "rimu": "Pipeline.process(block, out=): checks, one compiled pass over both instruments "
                             "(R y - off, estimate + parity, range and finiteness), result objects",
                     "rimu_alloc": "the same without out= (a pipeline of its own): a fresh result array per "
                                   "instrument, freed by the caller",
                     "c_fixed": "fixed-size C (gcc -O3 -march=native): R y - off of both instruments into the "
                                "same buffers, range and finiteness once per block; timed inside C",
                     "c_export": "rimu's exported C rimu_step per epoch (WLS estimate, covariance, chi-square, "
                                 "isolation statistics), estimates copied; timed inside C",
                     "numpy_matmul": "Y @ R.T of both instruments, new arrays, no offset, no checks"}}
    for N in BLOCKS:
        res["block"][str(N)] = _blocks(N, pipes, backends, Yall, Rs, offs, lims, ck, ce)

    # per-call overhead: a one-epoch block with out=, against one bare mat-vec
    b1 = EpochBlock(np.zeros(1), {k: Yall[k][:1].copy() for k in INSTS})
    y1 = Yall["gyro"][0].copy()
    R0 = Rs[0]
    calls = 20_000
    over: dict = {}
    for b, p in pipes.items():
        o1 = {k: np.empty((1, 6)) for k in INSTS}
        p.process(b1, o1)

        def one(p=p, o1=o1):
            for _ in range(calls):
                p.process(b1, o1)
        over[b] = one

    def matvec():
        for _ in range(calls):
            R0 @ y1
    over["matvec"] = matvec
    times = interleaved_times(over, ROUNDS, CLOCK)
    res["process_call_us"] = {k: float(np.median(ts)) / calls * 1e6 for k, ts in times.items()}
    res["process_call_vs_matvec"] = {b: ratio_stats(times, b, "matvec") for b in backends}

    # step against bare G @ y
    M = 50_000
    rows = list(Yall["gyro"][:M].copy())
    G = sets["gyro"].G

    def bare_loop():
        for y in rows:
            G @ y

    steps = {}
    for b, p in pipes.items():
        def step_loop(ip=p["gyro"]):
            step = ip.step
            for y in rows:
                step(y)
        step_loop()
        steps[b] = step_loop
    bare_loop()
    times = interleaved_times({"bare": bare_loop, **steps}, 9, CLOCK)
    res["bare_matvec_us_per_sample"] = float(np.median(times["bare"])) / M * 1e6
    res["step"] = {}
    for b in steps:
        res["step"][b] = {"us_per_sample": float(np.median(times[b])) / M * 1e6,
                          "time_ratio_to_bare": round_ratio(times, b, "bare"),
                          "time_ratio_to_bare_range": ratio_stats(times, b, "bare")}
    res["load_after"] = load()

    print(f"blocks of cone6 gyro + accel epochs (Pipeline.process); ns/epoch (thread CPU time), medians of {ROUNDS} "
          "interleaved rounds; "
          f"ratios = throughput vs the reference, median [min, max] of per-round ratios; {res['load']}")
    for name, what in res["includes"].items():
        print(f"  {name:>12}: {what}")
    print(f"\n{'epochs':>8} {'candidate':>12} {'ns/epoch':>9}   {'vs fixed C':>20} {'vs exported C':>20} "
          f"{'vs Y @ R.T':>20}  target")
    for N in BLOCKS:
        r = res["block"][str(N)]
        for ref_name in ("c_fixed", "c_export", "numpy_matmul"):
            if f"{ref_name}_ns_per_epoch" in r:
                print(f"{N:>8} {ref_name:>12} {r[f'{ref_name}_ns_per_epoch']:>9.2f}")
        for b in [*backends, "numba_alloc"] if "numba" in backends else backends:
            cells = [(_fmt(r[f"{b}_vs_{x}"]) if f"{b}_vs_{x}" in r else "-") for x in ("c_fixed", "c_export",
                                                                                      "numpy_matmul")]
            tgt = f">= {res['targets']['numba_block_vs_c_min'][str(N)]} of fixed C" if b == "numba" else ""
            print(f"{N:>8} {b:>12} {r[f'{b}_ns_per_epoch']:>9.2f}   {cells[0]:>20} {cells[1]:>20} {cells[2]:>20}  {tgt}")
    print(f"\nPipeline.process of a one-epoch block with out= (per call), us; one bare 6x6 mat-vec R @ y: "
          f"{res['process_call_us']['matvec']:.3f} us")
    for b in backends:
        print(f"{b:>9} {res['process_call_us'][b]:>8.3f} us  = {_fmt(res['process_call_vs_matvec'][b])} x mat-vec"
              + ("  target < 2 us" if b == "numba" else ""))
    print(f"\nInstrumentPipeline.step (per sample), us; bare numpy G @ y: {res['bare_matvec_us_per_sample']:.3f} us")
    for b in backends:
        s = res["step"][b]
        print(f"{b:>9}{s['us_per_sample']:>10.3f} us {_fmt(s['time_ratio_to_bare_range'])} x bare  target <= "
              f"{res['targets']['step_time_ratio_max'][b]}x")
    print(f"({res['load_after']} at the end)")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
