#!/usr/bin/env python3
"""Array of triads (rimu.array): maximum-likelihood runtime estimate and self-calibration, each next to a
reference timed in the same run.

* ``ml_motion`` (Gauss-Newton on every sample at once, Skog et al. 2016) vs the noise-weighted gyro mean (one
  einsum over the same block, the cheapest fusion of the gyros): throughput ratio, and the ML rate and angular
  acceleration error over the Cramer-Rao bound on a Monte Carlo run.
* ``fit_relative_gyro`` (gain, bias, sampling offset, ranking) vs one ``numpy.linalg.lstsq`` per triad of its
  difference from the array mean on ``[w (x) I, I]`` (a single pass, no offsets): time ratio and parity rms.
* ``fit_positions`` for 8 and 32 triads (seconds per run).

Prints a table and one JSON line. Medians over repeats; ratios are what to compare across machines.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import interleaved_times, median_time, ratio_stats

from rimu.array import ArrayLayout, accel_model, crb, fit_positions, fit_relative_gyro, ml_motion
from rimu.sim.array import random_array_truth, simulate_array
from rimu.units import RAD_TO_DEG


def bench_ml(rows: int, cols: int) -> dict:
    lay = ArrayLayout.planar_grid(rows, cols, pitch_m=0.01, two_sided=True)
    rng = np.random.default_rng(0)
    M = 20000
    truth = np.array([3.0, -2.0, 4.0, 40.0, -25.0, 60.0, 1.0, -2.0, 9.81])
    sg, sa = 2e-3, 0.09
    theta = np.repeat(truth[None], M, axis=0)
    fa = accel_model(theta, lay.positions_m) + rng.normal(0, sa, (M, lay.k, 3))
    fg = theta[:, None, :3] + rng.normal(0, sg, (M, lay.k, 3))
    wts = np.full(lay.k, 1 / sg**2)
    times = interleaved_times({"ml": lambda: ml_motion(lay, fa, fg, sa, sg),
                               "ref": lambda: np.einsum("k,nki->ni", wts / wts.sum(), fg)}, 5)  # in turn
    t_ml, t_ref = statistics.median(times["ml"]), statistics.median(times["ref"])
    r_ml = ratio_stats(times, "ml", "ref")
    est = ml_motion(lay, fa, fg, sa, sg)
    x = np.column_stack([est.omega, est.omega_dot])
    P = crb(truth[None, :3], lay.positions_m, sg, sa)[0]
    ratio = np.var(x, axis=0) / np.diag(P)[:6]
    return {"triads": lay.k, "samples": M, "ml_samples_per_s": M / t_ml, "mean_samples_per_s": M / t_ref,
            "time_ratio": r_ml["median"], "time_ratio_range": [r_ml["min"], r_ml["max"]], "var_over_crb_rate": ratio[:3].tolist(),
            "var_over_crb_angacc": ratio[3:].tolist()}


def bench_cal(rows: int, cols: int, duration: float) -> dict:
    lay = ArrayLayout.planar_grid(rows, cols, pitch_m=0.01, two_sided=True)
    tr = random_array_truth(lay, seed=1, centre_gyro_common_mode=True)
    rec = simulate_array(tr, duration_s=duration, seed=1)
    terms = ("scale_misalignment", "bias", "sampling_offset")
    fit = fit_relative_gyro(lay, rec.t, rec.gyro, terms=terms)
    z = lay.to_body(rec.gyro)

    def naive():
        """The reference: every triad against the mean of all (scale-misalignment and bias), one lstsq each."""
        w = z.mean(axis=1)
        X = np.zeros((len(w), 3, 12))
        for i in range(3):
            X[:, i, 3 * i:3 * i + 3] = w
            X[:, i, 9 + i] = 1.0
        A = X.reshape(-1, 12)
        return A, w, [np.linalg.lstsq(A, (z[:, j] - w).ravel(), rcond=None)[0] for j in range(lay.k)]

    times = interleaved_times({"fit": lambda: fit_relative_gyro(lay, rec.t, rec.gyro, terms=terms), "naive": naive},
                              3)  # in turn: a load change hits both
    t_fit, t_naive = statistics.median(times["fit"]), statistics.median(times["naive"])
    r_fit = ratio_stats(times, "fit", "naive")
    A, w, sols = naive()
    res = np.array([(z[:, j] - w).ravel() - A @ sol for j, sol in enumerate(sols)])
    naive_rms = float(np.sqrt(np.mean(res**2)) * RAD_TO_DEG)
    t_pos = median_time(lambda: fit_positions(lay, rec.t, rec.accel, fit, rec.gyro), 1)
    return {"triads": lay.k, "samples": len(rec.t), "fit_s": t_fit, "naive_lstsq_s": t_naive,
            "time_ratio": r_fit["median"], "time_ratio_range": [r_fit["min"], r_fit["max"]],
            "parity_rms_deg_s": {"raw": float(fit.parity_rms_rad_s["before"].mean() * RAD_TO_DEG),
                                 "naive_gain_bias": naive_rms,
                                 "rimu": float(fit.parity_rms_rad_s["after"].mean() * RAD_TO_DEG)},
            "noise_deg_s": float(np.sqrt(np.mean(tr.gyro_noise_rad_s**2)) * RAD_TO_DEG),
            "positions_fit_s": t_pos}


def main() -> dict:
    ml = [bench_ml(2, 2), bench_ml(4, 4)]
    cal = [bench_cal(2, 2, 4.0), bench_cal(4, 4, 2.0)]
    print("ML runtime estimate (20 000 samples per block)")
    print("| triads | ml_motion [samples/s] | weighted gyro mean [samples/s] | time ratio | var/CRB rate | "
          "var/CRB angular acceleration |")
    print("|---|---|---|---|---|---|")
    for r in ml:
        print(f"| {r['triads']} | {r['ml_samples_per_s']:,.0f} | {r['mean_samples_per_s']:,.0f} | "
              f"{r['time_ratio']:.0f} | {' '.join(f'{x:.3f}' for x in r['var_over_crb_rate'])} | "
              f"{' '.join(f'{x:.3f}' for x in r['var_over_crb_angacc'])} |")
    print()
    print("Self-calibration from hand-held motion (1 kHz)")
    print("| triads | samples | fit_relative_gyro [s] | naive lstsq [s] | ratio | parity rms raw / naive / rimu "
          "[deg/s] | noise [deg/s] | fit_positions [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for r in cal:
        p = r["parity_rms_deg_s"]
        print(f"| {r['triads']} | {r['samples']} | {r['fit_s']:.3f} | {r['naive_lstsq_s']:.3f} | "
              f"{r['time_ratio']:.1f} | {p['raw']:.3f} / {p['naive_gain_bias']:.3f} / {p['rimu']:.4f} | "
              f"{r['noise_deg_s']:.4f} | {r['positions_fit_s']:.2f} |")
    doc = {"ml": ml, "calibration": cal}
    print(json.dumps(doc))
    return doc


if __name__ == "__main__":
    main()
