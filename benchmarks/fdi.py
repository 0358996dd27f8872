"""FDI benchmarks: per-sample cost of detection + isolation beside the bare compensation step; the block
(vectorised) paths of the GLT, the CUSUM bank and the Kalman detector side by side on the same blocks, the CUSUM and
Kalman ones for the numpy backend and, where numba is installed, the compiled one (the GLT is the reference, timed in
the same run, interleaved); the detectors' design figures measured next to their theory
(CUSUM detection delay and in-control run length, false-alarm rates); campaign throughput with 1 and 2 workers.
Prints tables and one JSON line (medians of repeated runs).

    python benchmarks/fdi.py [--samples 20000] [--repeats 5] [--tasks 48] [--block 100000]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import time

import numpy as np
from scipy.stats import norm

from rimu.experiments.campaign import CampaignSpec, clopper_pearson, run_campaign
from rimu.fdi import CusumBank, GltSnapshot, GltWindow, ParityKalman, RedundancyManager, markov_arl, siegmund_arl
from rimu.fdi.cusum import bias_delays
from rimu.fusion import InstrumentPipeline, numba_available
from rimu.geometry import cone6
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
    ap.add_argument("--block", type=int, default=100_000, help="samples per block of the block-path timing")
    args = ap.parse_args()
    blocks = block_paths(args.block, max(args.repeats, 5))
    figures = design_figures()
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
                       ("+ Kalman (steady-state engine, the default)", lambda p: ParityKalman(20.0)),
                       ("+ Kalman (filterpy engine, the reference)", lambda p: ParityKalman(20.0, engine="filterpy"))):
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
    print(json.dumps({"benchmark": "fdi", "block_paths": blocks, "design_figures": figures,
                      "per_sample_us": {k: v * 1e6 for k, v in rows.items()},
                      "ratio_to_bare": {k: v / ref for k, v in rows.items()},
                      "campaign_tasks_per_s": {"in_process": thr[0], "1_worker": thr[1], "2_workers": thr[2]},
                      "samples": args.samples, "repeats": args.repeats, "tasks": n_tasks}))


V6 = cone6().parity_matrix()


class _NoRestart:
    """The CUSUM bank's block path with the manager's semantics (nothing restarts at an alarm)."""

    def __init__(self, bank: CusumBank) -> None:
        self.bank = bank

    def block(self, P, Vz, dof):  # type: ignore[no-untyped-def]
        return self.bank.block(P, Vz, dof, restart=False)


def block_paths(N: int, repeats: int) -> dict:
    """ns per sample of each detector's block() on the same parity blocks (cone6, dof 3), interleaved so that
    the machine's load hits every detector alike; ratio = median over repeats of (detector / GLT of that repeat)."""
    rng = np.random.default_rng(1)
    quiet = rng.standard_normal((N, 3))
    faulty = quiet.copy()
    faulty[N // 2:] += 1.0 * V6[:, 2]                     # 1 sigma bias in the second half: CUSUM alarms ~ every 40
    large = quiet.copy()
    large[N // 2:] += 10.0 * V6[:, 2]                     # 10 sigma: an alarm every second sample
    dets = {"GLT snapshot (reference)": GltSnapshot(1e-3),
            "CUSUM bank, ARL0 1e5, numpy": CusumBank(1.0, 1e5, backend="numpy"),
            "CUSUM, no restart, numpy": _NoRestart(CusumBank(1.0, 1e5, backend="numpy"))}
    if numba_available():
        dets["CUSUM bank, ARL0 1e5, numba"] = CusumBank(1.0, 1e5, backend="numba")
        dets["CUSUM, no restart, numba"] = _NoRestart(CusumBank(1.0, 1e5, backend="numba"))
    for be in ("numpy", "numba") if numba_available() else ("numpy",):
        dets[f"Kalman, estimate test, {be}"] = ParityKalman(20.0, 1e-3, backend=be)
        dets[f"Kalman, innovation test, {be}"] = ParityKalman(20.0, 1e-3, test="innovation", backend=be)
    ref = "GLT snapshot (reference)"
    res: dict = {}
    print(f"\nblock paths, {N} samples of cone6 parity (dof 3); ns per sample, median of {repeats}; ratio to the GLT")
    print(f"{'detector':<32} {'in control':>11} {'ratio':>6} {'1 sigma bias, 2nd half':>23} {'ratio':>6} "
          f"{'10 sigma, 2nd half':>19} {'ratio':>6}")
    for label, P in (("in_control", quiet), ("bias_1sigma_second_half", faulty), ("bias_10sigma_second_half", large)):
        times: dict[str, list[float]] = {k: [] for k in dets}
        for d in dets.values():
            d.block(P[:2000], V6, 3)                        # designs and whiteners cached, as in a campaign
        for _ in range(repeats):
            for k, d in dets.items():
                t0 = time.perf_counter()
                d.block(P, V6, 3)
                times[k].append(time.perf_counter() - t0)
        res[label] = {k: {"ns_per_sample": float(np.median(v)) / N * 1e9,
                          "ratio_to_glt": float(np.median(np.array(v) / np.array(times[ref])))} for k, v in times.items()}
        res[label]["CUSUM bank, ARL0 1e5, numpy"]["alarms"] = int((dets["CUSUM bank, ARL0 1e5, numpy"].block(P, V6, 3)[0] > 1).sum())
    # the per-sample path of the CUSUM bank over the same samples (update() in a loop), on a tenth of the block
    bank = CusumBank(1.0, 1e5)
    n_step = max(N // 10, 1000)
    ts = []
    for _ in range(3):
        bank.configure(V6, 3)
        t0 = time.perf_counter()
        for p in quiet[:n_step]:
            bank.update(p)
        ts.append(time.perf_counter() - t0)
    res["cusum_update_loop_ns_per_sample"] = float(np.median(ts)) / n_step * 1e9
    for k in dets:
        a, b, c = res["in_control"][k], res["bias_1sigma_second_half"][k], res["bias_10sigma_second_half"][k]
        print(f"{k:<32} {a['ns_per_sample']:11.1f} {a['ratio_to_glt']:6.2f} {b['ns_per_sample']:23.1f} {b['ratio_to_glt']:6.2f} "
              f"{c['ns_per_sample']:19.1f} {c['ratio_to_glt']:6.2f}")
    print(f"{'CUSUM update() loop':<32} {res['cusum_update_loop_ns_per_sample']:11.1f} "
          f"{res['cusum_update_loop_ns_per_sample'] / res['in_control'][ref]['ns_per_sample']:6.2f}")
    return res


def design_figures() -> dict:
    """Every detector figure next to its theory (cone6, unit-noise parity, seeded)."""
    rng = np.random.default_rng(2)
    out: dict = {}
    rows = []
    # CUSUM delay: ARL0 1e5, 1 sigma bias on each sensor in turn from sample 100
    bank = CusumBank(1.0, 1e5)
    _U, d, thr, _ = bank.design(V6, 3)
    delays_a = np.nan_to_num(bias_delays(bank, V6, 3, 1200, rng), nan=301.0)   # 301: none within the run
    info = d[0] ** 2 / 2                                      # Kullback-Leibler information per sample
    k = d[0] / 2
    h = thr[0] / d[0]                                         # the member's threshold in units of X
    lorden = float(np.log(1e5) / info)
    siegmund = siegmund_arl(k, h)                             # zero-start ARL of the faulty sensor's member
    brook = markov_arl(h, lambda x: norm.cdf(x - k), states=400)
    out["cusum_delay_samples"] = {"measured_mean": float(delays_a.mean()),
                                  "measured_sem": float(delays_a.std(ddof=1) / np.sqrt(len(delays_a))),
                                  "trials": len(delays_a), "lorden_ln_arl0_over_I": lorden,
                                  "siegmund_member_zero_start": siegmund, "brook_evans_member_zero_start": brook}
    rows.append(("CUSUM delay, 1 sigma bias, ARL0 1e5, samples", f"{delays_a.mean():.2f} +/- {out['cusum_delay_samples']['measured_sem']:.2f}",
                 f"ln(ARL0)/I {lorden:.2f}; member from 0: Siegmund {siegmund:.2f}, Brook & Evans {brook:.2f}"))
    # CUSUM in-control run length of the bank, design 300
    bank = CusumBank(1.0, 300.0)
    _U, d3, thr3, _ = bank.design(V6, 3)
    P = rng.standard_normal((1_000_000, 3))
    s, _, _ = bank.block(P, V6, 3)
    n_al = int((s > 1.0).sum())
    member = markov_arl(thr3[0] / d3[0], lambda x: norm.cdf(x + d3[0] / 2), states=400)
    out["cusum_in_control_run_length"] = {"design_arl0": 300.0, "measured": len(P) / max(n_al, 1), "alarms": n_al,
                                          "brook_evans_members_independent": member / 12}
    rows.append(("CUSUM bank run length in control, samples", f"{len(P) / max(n_al, 1):.0f}",
                 f"design ARL0 300 (bound); Brook & Evans, 12 independent members: {member / 12:.0f}"))
    # false-alarm rates per sample: GLT snapshot and the Kalman tests (marginal, after the filter's start)
    P = rng.standard_normal((1_000_000, 3))
    for name, det, p_fa in (("GLT snapshot", GltSnapshot(1e-3), 1e-3),
                            ("Kalman estimate test, tau 20", ParityKalman(20.0, 1e-2), 1e-2),
                            ("Kalman innovation test, tau 20", ParityKalman(20.0, 1e-2, test="innovation"), 1e-2)):
        st, th, _ = det.block(P, V6, 3)
        x = int((st[200:] > th).sum())
        n = len(st) - 200
        lo, hi = clopper_pearson(x, n)
        out[f"false_alarm_rate {name}"] = {"design": p_fa, "measured": x / n, "ci99": [lo, hi]}
        rows.append((f"{name} false-alarm rate per sample", f"{x / n:.2e} [{lo:.2e}, {hi:.2e}]",
                     f"design {p_fa:g} (chi-square, dof 3)"))
    print("\ndesign figures against theory (cone6, unit-noise parity, seeded)")
    for a, b, c in rows:
        print(f"{a:<48} {b:>26}   {c}")
    return out


if __name__ == "__main__":
    main()
