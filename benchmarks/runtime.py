#!/usr/bin/env python3
"""Runtime pipeline throughput on cone6, each path next to its reference timed in the same run.

* block path (``InstrumentPipeline.process``) vs one fused matrix product ``Y @ K.T`` over the same array,
  K being the same (n x n) matrix the pipeline applies (estimate and parity rows): the memory-bound floor.
  Target: at least 0.5 of the reference's throughput.
* ``step`` path vs a loop of one bare numpy mat-vec per sample (``G @ y``). Target: at most 3x its time.

Prints a table and one JSON line. Medians over repeats; ratios are what to compare across machines.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time

from rimu.fusion import InstrumentPipeline
from rimu.sim import cho_park_table3


def main() -> dict:
    cal = cho_park_table3(gyro_sigma=0.008)["gyro"]
    pipe = InstrumentPipeline(cal)
    rng = np.random.default_rng(0)
    N = 1_000_000
    Y = cal.raw_output(rng.standard_normal((N, 3))) + rng.standard_normal((N, 6))
    K = pipe.table.get(pipe.table.full_code).R

    def block():
        pipe.process(Y)

    def reference_block():
        Y @ K.T

    block()
    reference_block()
    t_blk = median_time(block, 9)
    t_ref = median_time(reference_block, 9)

    M = 50_000
    Ys = Y[:M].copy()
    rows = list(Ys)
    G = pipe.table.G[0]

    def step_loop():
        step = pipe.step
        for y in rows:
            step(y)

    def bare_loop():
        for y in rows:
            G @ y

    step_loop()
    bare_loop()
    t_step = median_time(step_loop, 7)
    t_bare = median_time(bare_loop, 7)

    res = {
        "benchmark": "runtime",
        "geometry": "cone6",
        "block_samples": N,
        "block_samples_per_s": N / t_blk,
        "reference_block_samples_per_s": N / t_ref,
        "block_throughput_ratio": t_ref / t_blk,
        "step_us_per_sample": t_step / M * 1e6,
        "bare_matvec_us_per_sample": t_bare / M * 1e6,
        "step_time_ratio": t_step / t_bare,
        "targets": {"block_throughput_ratio_min": 0.5, "step_time_ratio_max": 3.0},
    }
    print(f"{'path':<34}{'throughput':>16}{'reference':>16}{'ratio':>9}  target")
    print(f"{'block (process)':<34}{res['block_samples_per_s'] / 1e6:>12.1f} M/s"
          f"{res['reference_block_samples_per_s'] / 1e6:>12.1f} M/s{res['block_throughput_ratio']:>9.2f}  >= 0.5 of Y @ K.T")
    print(f"{'step (per sample)':<34}{res['step_us_per_sample']:>13.2f} us{res['bare_matvec_us_per_sample']:>13.2f} us"
          f"{res['step_time_ratio']:>9.2f}  <= 3x bare G @ y")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
