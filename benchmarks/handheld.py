"""Hand-held calibration over seeded simulated recordings: normalised errors (covariance honesty), static-norm
residual against the floor of the true coefficients, gravity-direction misfit, and the time of a fit against the
reference (an independent full-model accelerometer fit, Tedaldi's parametrisation, scipy least_squares); on the
equal-size case of the calibration benchmark (30 poses, 144233 samples x 6 channels) the fit with its held-out checks
timed interleaved with the same fit without them and with the reference, and the time of each stage.

Run: python benchmarks/handheld.py [N_SEEDS] [N_POSES]
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rimu.calibration.handheld as hh_mod
from rimu.calibration.handheld import HandHeld, gauge_fixed
from rimu.calibration.lsq import physical_from_beta
from rimu.calibration.model import ErrorModel
from rimu.sim.handheld import handheld_run
from rimu.units import G0


def reference_fit(Y: np.ndarray) -> float:
    def res(p):
        T = np.array([[1, -p[0], p[1]], [0, 1, -p[2]], [0, 0, 1]])
        return np.linalg.norm((Y + p[6:9]) @ (T @ np.diag(p[3:6])).T, axis=1) - G0

    p0 = np.r_[0, 0, 0, np.full(3, G0 / 16384), -Y.mean(axis=0)]
    sol = least_squares(res, p0, method="lm", x_scale=np.r_[1e-3, 1e-3, 1e-3, np.full(3, 1e-6), np.full(3, 100)])
    return float(np.sqrt(np.mean(sol.fun**2)))


def equal_size(rounds: int = 15) -> dict:
    """The calibration benchmark's hand-held case (30 poses of 46.3 s at 100 Hz, seed 1000: 144233 samples x 6
    channels), thread CPU time, interleaved: HandHeld().fit (both held-out checks), HandHeld(held_out=False).fit
    and the reference accelerometer fit (from the pose means, computed outside its timing); then the stages of the
    fit with checks, timed by timers put around handheld's module functions for separate rounds."""
    run = handheld_run(n_poses=30, static_s=46.3, seed=1000)
    s = run.session
    Y = np.array([g.raw["accel"].mean(axis=0) for g in s.segments if g.kind == "static_unknown"])
    cands = {"fit": lambda: HandHeld().fit(s), "fit_no_checks": lambda: HandHeld(held_out=False).fit(s),
             "reference": lambda: reference_fit(Y)}
    for f in cands.values():  # warm: numba's cache loaded, first-call costs out of the timing
        f()
    t = {k: [] for k in cands}
    for _ in range(rounds):
        for k, f in cands.items():
            t0 = time.thread_time()
            f()
            t[k].append(time.thread_time() - t0)
    a = {k: np.array(v) for k, v in t.items()}
    out = {"samples": int(sum(g.n_samples for g in s.segments)), "rounds": rounds,
           "ms": {k: float(np.median(v) * 1e3) for k, v in a.items()}}
    for num, den in (("fit", "fit_no_checks"), ("fit", "reference")):
        q = a[num] / a[den]
        out[f"{num}/{den}"] = [float(np.median(q)), float(q.min()), float(q.max())]
    stages = ("fit_accel", "held_out_accel", "fit_gyro", "held_out_gyro")
    acc: dict[str, list[float]] = {k: [] for k in stages}
    saved = {k: getattr(hh_mod, k) for k in stages}
    spent: dict[str, float] = {}
    depth = [0]

    def timed(name, f):
        def g(*args, **kw):  # outermost calls only: a check's own refits count as the check's
            depth[0] += 1
            t0 = time.thread_time()
            try:
                return f(*args, **kw)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    spent[name] = spent.get(name, 0.0) + time.thread_time() - t0
        return g

    tot = []
    try:
        for k in stages:
            setattr(hh_mod, k, timed(k, saved[k]))
        for _ in range(rounds):
            spent.clear()
            t0 = time.thread_time()
            HandHeld().fit(s)
            tot.append(time.thread_time() - t0 - sum(spent.values()))
            for k in stages:
                acc[k].append(spent.get(k, 0.0))
    finally:
        for k in stages:
            setattr(hh_mod, k, saved[k])
    names = {"fit_accel": "accel fit (the one applied)", "held_out_accel": "accel held-out check (2 fits, 60 leave-one-out problems)",
             "fit_gyro": "gyro fit (the one applied)", "held_out_gyro": "gyro held-out check (1 fit, 8 fold fits)"}
    out["stages_ms"] = {names[k]: float(np.median(v) * 1e3) for k, v in acc.items()}
    out["stages_ms"]["the rest (one pass over the samples, noise, gravity directions, result)"] = float(
        np.median(tot) * 1e3)
    out["load_average"] = [round(x, 2) for x in os.getloadavg()]
    return out


def main(n_seeds: int = 20, n_poses: int = 30) -> dict:
    base = ErrorModel.base()
    z = {"accel": [], "gyro": []}
    floor_ratio, rot, t_fit, t_ref, ref_ratio = [], [], [], [], []
    for seed in range(n_seeds):
        run = handheld_run(n_poses=n_poses, static_s=3.0, seed=1000 + seed)
        t0 = time.thread_time()
        res = HandHeld().fit(run.session)
        t_fit.append(time.thread_time() - t0)
        Y = np.array([s.raw["accel"].mean(axis=0) for s in run.session.segments if s.kind == "static_unknown"])
        t0 = time.thread_time()
        ref = reference_fit(Y)
        t_ref.append(time.thread_time() - t0)
        eq = HandHeld(pose_weights="equal", instruments=["accel"]).fit(run.session)
        ref_ratio.append(eq.extra["norm_rms_accel"] / ref)
        cal = run.truth["accel"]
        A = cal.axes_mb()
        truth_r = [np.linalg.norm(np.linalg.solve(A, cal.compensate(y))) - G0 for y in Y]
        floor_ratio.append(res.extra["norm_rms_accel"] / float(np.sqrt(np.mean(np.square(truth_r)))))
        rot.append(res.extra["rotation_rms_deg"])
        for inst, r in res.instruments.items():
            W, c = gauge_fixed(run.truth["accel"], (0, 1, 2), run.truth[inst])
            for f in r.sensors:
                i = f.ctx.index
                th, _, _ = physical_from_beta(base, f.ctx, np.concatenate([W[i], [c[i]]]))
                sd = np.sqrt(np.clip(np.diag(f.theta_cov), 0, None))
                ok = sd > 0
                z[inst].append((f.theta - th)[ok] / sd[ok])
    out = {"seeds": n_seeds, "poses": n_poses}
    print(f"hand-held calibration, {n_seeds} seeded recordings of {n_poses} poses (MEMS triad, tremor and sway)")
    print(f"{'quantity':48s} {'value':>10s}")
    for inst in ("accel", "gyro"):
        zz = np.concatenate(z[inst])
        out[f"nees_rms_{inst}"] = float(np.sqrt(np.mean(zz**2)))
        out[f"max_abs_z_{inst}"] = float(np.abs(zz).max())
        print(f"{'normalised error rms, ' + inst:48s} {out[f'nees_rms_{inst}']:10.3f}")
        print(f"{'largest |normalised error|, ' + inst:48s} {out[f'max_abs_z_{inst}']:10.2f}")
    out["norm_rms_over_truth_floor_median"] = float(np.median(floor_ratio))
    out["equal_weight_rms_over_reference_median"] = float(np.median(ref_ratio))
    out["rotation_misfit_deg_median"] = float(np.median(rot))
    out["fit_s_median"] = float(np.median(t_fit))
    out["reference_accel_fit_s_median"] = float(np.median(t_ref))
    out["fit_over_reference_time"] = out["fit_s_median"] / out["reference_accel_fit_s_median"]
    print(f"{'static-norm rms / rms of the true coefficients':48s} {out['norm_rms_over_truth_floor_median']:10.3f}")
    print(f"{'equal-weight rms / independent fit rms':48s} {out['equal_weight_rms_over_reference_median']:10.4f}")
    print(f"{'gravity-direction misfit per motion (deg)':48s} {out['rotation_misfit_deg_median']:10.4f}")
    print(f"{'HandHeld fit, accel + gyro (thread CPU s, median)':48s} {out['fit_s_median']:10.3f}")
    print(f"{'reference accel-only fit (thread CPU s, median)':48s} {out['reference_accel_fit_s_median']:10.4f}")
    eq = equal_size()
    out["equal_size"] = eq
    print(f"\nequal-size case of the calibration benchmark ({eq['samples']} samples x 6 channels, 30 poses): thread "
          f"CPU time, median of {eq['rounds']} interleaved rounds; ratio = median [min, max] of per-round ratios; "
          f"load average {' '.join(str(x) for x in eq['load_average'])} on {os.cpu_count()} cores")
    ms = eq["ms"]
    print(f"  {'HandHeld().fit, with both held-out checks':56s} {ms['fit']:8.2f} ms")
    print(f"  {'HandHeld(held_out=False).fit':56s} {ms['fit_no_checks']:8.2f} ms   with / without checks "
          "{:.2f} [{:.2f}, {:.2f}]".format(*eq["fit/fit_no_checks"]))
    print(f"  {'reference accel-only fit (scipy, from the pose means)':56s} {ms['reference']:8.2f} ms   "
          "fit / reference {:.1f} [{:.1f}, {:.1f}]".format(*eq["fit/reference"]))
    print("  stages of the fit with checks (timers around handheld's functions, separate rounds):")
    for k, v in eq["stages_ms"].items():
        print(f"    {k:72s} {v:8.2f} ms")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
