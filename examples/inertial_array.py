"""An array of 32 MEMS triads as one instrument, on simulated hand-held motion with known truth.

1. simulate 32 raw (uncalibrated) gyro + accelerometer triads on a two-sided board under hand-held motion;
2. relative gyro calibration from the motion: gains, biases, sampling offsets; the ranking of missing terms;
3. accelerometer positions, gains and biases from the same motion (Carlsson et al. 2021);
4. the array at runtime: maximum-likelihood angular rate and angular acceleration (Skog et al. 2016) against
   the Cramer-Rao bound;
5. the report: parity rms in motion after each step, per triad, with a plot.

Run: python examples/inertial_array.py [REPORT_DIR]
(not "array.py": a script of that name would shadow the standard library module of the same name)
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from rimu.array import ArrayLayout, array_report, crb, fit_positions, fit_relative_gyro, ml_motion
from rimu.sim.array import random_array_truth, simulate_array
from rimu.units import RAD_TO_DEG


def main(report_dir: str | None = None) -> None:
    lay = ArrayLayout.planar_grid(4, 4, pitch_m=0.01, two_sided=True)        # 32 triads, 3 x 3 cm board
    rng = np.random.default_rng(1)
    true_pos = lay.positions_m + rng.normal(0, 3e-4, lay.positions_m.shape)  # placed 0.3 mm off nominal
    truth = random_array_truth(lay.with_positions(true_pos), seed=1, centre_gyro_common_mode=True,
                               aa_sensitivity_sigma_s=1e-4)                   # a hidden angular-acceleration term
    rec = simulate_array(truth, duration_s=2.0, seed=1)
    w_rms = np.degrees(np.sqrt(np.mean(rec.omega**2)))
    print(f"1. {lay.k} triads, {len(rec.t)} samples at 1 kHz, {w_rms:.0f} deg/s rms per axis, "
          f"{np.sqrt(np.mean(rec.omega_dot**2)):.0f} rad/s^2 rms angular acceleration")

    gf = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", "sampling_offset"))
    print("2. relative gyro calibration (first 4 triads):")
    print("\n".join(gf.table().splitlines()[:5]))
    print(f"   parity rms in motion {gf.parity_rms_rad_s['before'].mean() * RAD_TO_DEG:.3f} -> "
          f"{gf.parity_rms_rad_s['after'].mean() * RAD_TO_DEG:.4f} deg/s; now limited by: {gf.limiting_term()}")
    gf2 = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", "sampling_offset",
                                                         "aa_sensitivity"))
    print(f"   with it: {gf2.parity_rms_rad_s['after'].mean() * RAD_TO_DEG:.4f} deg/s; "
          f"now limited by: {gf2.limiting_term()}")

    pf = fit_positions(lay, rec.t, rec.accel, gf2, rec.gyro)
    err = np.abs(pf.positions_m - true_pos).max() * 1e3
    print(f"3. positions: max |estimate - truth| {err:.3f} mm (sd {pf.position_std_m().max() * 1e3:.3f} mm; "
          f"the nominal ones were {np.abs(lay.positions_m - true_pos).max() * 1e3:.2f} mm off)")

    u_g = gf2.apply(rec.t, rec.gyro)
    u_a = pf.apply(rec.t, rec.accel)
    m = ml_motion(pf.layout, u_a, u_g, pf.sigma_m_s2, gf2.sigma_rad_s)
    inner = slice(20, -20)
    e = (m.omega - rec.omega)[inner]
    bound = crb(rec.omega[inner], pf.positions_m, gf2.sigma_rad_s, pf.sigma_m_s2)
    print(f"4. ML angular rate error {np.degrees(e.std(axis=0)).round(4)} deg/s per axis; Cramer-Rao bound "
          f"{np.degrees(np.sqrt(bound[:, [0, 1, 2], [0, 1, 2]].mean(axis=0))).round(4)} deg/s")

    rep = array_report(lay, rec.t, rec.gyro, rec.accel)
    print("5. report: gyro parity rms per step [deg/s]:",
          {k: round(float(v.mean()), 4) for k, v in rep.gyro_steps.items()},
          f"limiting term: {rep.limiting_term}")
    if report_dir:
        out = Path(report_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "array_report.md").write_text(rep.to_markdown())
        rep.plot(out / "array_report.png")
        print(f"   written: {out / 'array_report.md'}, {out / 'array_report.png'}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
