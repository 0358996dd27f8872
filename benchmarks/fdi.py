"""FDI benchmarks: per-sample cost of detection + isolation beside the bare compensation step, and campaign
throughput with 1 and 2 workers. Prints a table and one JSON line (medians of repeated runs; the reference, the
bare pipeline step, is timed in the same run).

    python benchmarks/fdi.py [--samples 20000] [--repeats 5] [--tasks 48]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from rimu.fdi import CusumBank, GltSnapshot, GltWindow, ParityKalman, RedundancyManager
from rimu.fdi.campaign import CampaignSpec, run_campaign
from rimu.fusion import InstrumentPipeline
from rimu.sim import cho_park_table3
from rimu.units import DS_TO_RS


def per_sample(fn, Y, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(Y)
        times.append((time.perf_counter() - t0) / len(Y))
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tasks", type=int, default=48)
    args = ap.parse_args()
    cal = cho_park_table3(gyro_sigma=0.01)["gyro"]
    rng = np.random.default_rng(0)
    u = rng.standard_normal((args.samples, 3)) * 30 * DS_TO_RS
    Y = cal.raw_output(u) + 0.01 / cal.scale * rng.standard_normal((args.samples, 6))

    pipe = InstrumentPipeline(cal)

    def bare(Y):
        step = pipe.step
        for y in Y:
            step(y)

    rows = {"compensation + projection + parity (bare step)": per_sample(bare, Y, args.repeats)}
    for name, make in (("+ GLT snapshot, confirmation, isolation", lambda p: GltSnapshot(1e-3)),
                       ("+ GLT window 5", lambda p: GltWindow(5)),
                       ("+ CUSUM bank", lambda p: CusumBank(p.table.sigma, 1e5)),
                       ("+ Kalman (filterpy)", lambda p: ParityKalman(20.0)),
                       ("+ Kalman (steady-state engine)", lambda p: ParityKalman(20.0, engine="steady"))):
        p2 = InstrumentPipeline(cal)
        mgr = RedundancyManager(p2, make(p2))

        def managed(Y, mgr=mgr):
            step = mgr.step
            for y in Y:
                step(y)
            mgr.reset()

        rows[name] = per_sample(managed, Y, args.repeats)
    ref = rows["compensation + projection + parity (bare step)"]
    print(f"{'per-sample cost (cone6 gyros, one instrument)':<52} {'us':>8} {'ratio':>7}")
    for k, v in rows.items():
        print(f"{k:<52} {v * 1e6:8.2f} {v / ref:7.2f}")

    reps = max(1, args.tasks // 12)
    spec = CampaignSpec(faults=["bias", "ramp"], sizes=[6, 10], repetitions=reps, sensors=[0, 1, 2], base_seed=1)
    n_tasks = len(spec.tasks())
    thr = {}
    for w in (1, 2):
        times = []
        for _ in range(max(1, args.repeats // 2)):
            res = run_campaign(spec, workers=w)
            times.append(res.elapsed_s)
        thr[w] = n_tasks / float(np.median(times))
    serial = []
    for _ in range(max(1, args.repeats // 2)):
        serial.append(run_campaign(spec, workers=0).elapsed_s)
    thr[0] = n_tasks / float(np.median(serial))
    print(f"\ncampaign throughput ({n_tasks} tasks of 10 s at 100 Hz, open + closed loop):")
    print(f"  in-process (no pool): {thr[0]:6.1f} tasks/s")
    print(f"  1 worker:             {thr[1]:6.1f} tasks/s")
    print(f"  2 workers:            {thr[2]:6.1f} tasks/s  (speed-up {thr[2] / thr[1]:.2f}x over 1 worker)")
    print(json.dumps({"benchmark": "fdi", "per_sample_us": {k: v * 1e6 for k, v in rows.items()},
                      "ratio_to_bare": {k: v / ref for k, v in rows.items()},
                      "campaign_tasks_per_s": {"in_process": thr[0], "1_worker": thr[1], "2_workers": thr[2]},
                      "samples": args.samples, "repeats": args.repeats, "tasks": n_tasks}))


if __name__ == "__main__":
    main()
