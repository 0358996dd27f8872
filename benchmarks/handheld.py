"""Hand-held calibration over seeded simulated recordings: normalised errors (covariance honesty), static-norm
residual against the floor of the true coefficients, gravity-direction misfit, and the time of a fit against the
reference (an independent full-model accelerometer fit, Tedaldi's parametrisation, scipy least_squares).

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


def main(n_seeds: int = 20, n_poses: int = 30) -> dict:
    base = ErrorModel.base()
    z = {"accel": [], "gyro": []}
    floor_ratio, rot, t_fit, t_ref, ref_ratio = [], [], [], [], []
    for seed in range(n_seeds):
        run = handheld_run(n_poses=n_poses, static_s=3.0, seed=1000 + seed)
        t0 = time.perf_counter()
        res = HandHeld().fit(run.session)
        t_fit.append(time.perf_counter() - t0)
        Y = np.array([s.raw["accel"].mean(axis=0) for s in run.session.segments if s.kind == "static_unknown"])
        t0 = time.perf_counter()
        ref = reference_fit(Y)
        t_ref.append(time.perf_counter() - t0)
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
    print(f"{'HandHeld fit, accel + gyro (s, median)':48s} {out['fit_s_median']:10.3f}")
    print(f"{'reference accel-only fit (s, median)':48s} {out['reference_accel_fit_s_median']:10.4f}")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
