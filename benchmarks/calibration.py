"""Calibration benchmark: rimu's Cho & Park cone6 calibration timed beside imucal's Ferraris calibration of a
triad on data of equal size, in the same run; and the accuracy of rimu and imucal on the same simulated
Ferraris-style triad data (six static positions, one full turn about each axis).

    python benchmarks/calibration.py [--repeats 5]

imucal is optional (it is not a rimu dependency): install it to compare (``pip install imucal``); without it
the script says so and reports rimu alone. Prints a table and a JSON line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time

from rimu.calibration import ChoPark, LeastSquares
from rimu.geometry import triad3
from rimu.sim import Simulator, cho_park_procedure, rotation, static
from rimu.units import DEG_TO_RAD, G0, MS2_TO_UG, RS_TO_DH

try:  # optional reference
    from imucal import FerrarisCalibration, FerrarisSignalRegions

    HAVE_IMUCAL = True
except ImportError:  # pragma: no cover
    HAVE_IMUCAL = False

SECTIONS = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot", "z_rot")
UPS = {"x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0), "z_p": (0, 0, 1), "z_a": (0, 0, -1)}
AXES = {"x_rot": (1, 0, 0), "y_rot": (0, 1, 0), "z_rot": (0, 0, 1)}


def ferraris_procedure(static_s: float, turn_rate_deg: float = 36.0):
    """Six static positions and one full positive turn about each MB axis (reported as an angle)."""
    steps = [static(k, up, static_s) for k, up in UPS.items()]
    for k, ax in AXES.items():
        steps.append(rotation(k, np.array(ax) * turn_rate_deg * DEG_TO_RAD, 360.0 / turn_rate_deg, report="angle"))
    return steps


def imucal_fit(session, fs: float):
    """imucal's Ferraris calibration of the session's sections; returns (SF acc, axes acc, bias acc, SF gyro,
    axes gyro, bias gyro) in rimu's conventions (SI per raw unit, unit rows, SI bias)."""
    seg = {s.label: s for s in session.segments}
    regions = FerrarisSignalRegions(
        *[seg[k].raw["accel"] for k in SECTIONS[:6]], *[seg[k].raw["gyro"] for k in SECTIONS[:6]],
        *[seg[k].raw["accel"] for k in SECTIONS[6:]], *[seg[k].raw["gyro"] for k in SECTIONS[6:]])
    cal = FerrarisCalibration(grav=G0, expected_angle=360.0).compute(regions, fs, "count", "count")
    ka, kg = np.diag(cal.K_a), np.diag(cal.K_g)
    return (1 / ka, cal.R_a / np.linalg.norm(cal.R_a, axis=1)[:, None], np.asarray(cal.b_a) / ka,
            DEG_TO_RAD / kg, cal.R_g / np.linalg.norm(cal.R_g, axis=1)[:, None], np.asarray(cal.b_g) * DEG_TO_RAD / kg)


def errors(truth, sf_a, ax_a, b_a, sf_g, ax_g, b_g) -> dict[str, float]:
    """rms errors: scale (ppm), axis direction (arcsec), bias (ug, deg/h)."""
    def ang(A, B):
        return np.degrees(np.arccos(np.clip(np.sum(A * B, axis=1), -1, 1))) * 3600

    ta, tg = truth["accel"], truth["gyro"]
    def rms(x):
        return float(np.sqrt(np.mean(np.square(x))))

    return {
        "acc_scale_ppm": rms((sf_a / ta.scale - 1) * 1e6), "acc_axis_arcsec": rms(ang(ax_a, ta.axes_mb())),
        "acc_bias_ug": rms((b_a - ta.bias) * MS2_TO_UG),
        "gyro_scale_ppm": rms((sf_g / tg.scale - 1) * 1e6), "gyro_axis_arcsec": rms(ang(ax_g, tg.axes_mb())),
        "gyro_bias_dh": rms((b_g - tg.bias) * RS_TO_DH),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--accuracy-runs", type=int, default=20)
    ap.add_argument("--memory-factor", type=int, default=16, help="length of the memory test session, x 60 s")
    args = ap.parse_args()
    out: dict = {"benchmark": "calibration", "imucal": HAVE_IMUCAL}

    # 1. timing: cone6, Tables 1 + 2, 100 Hz, 60 s per segment
    run = Simulator(seed=1).run(cho_park_procedure(duration=60.0))
    n_samples = sum(s.n_samples for s in run.session.segments)
    t_rimu = median_time(lambda: ChoPark().fit(run.session).to_calibration(), args.repeats)
    # equal-size triad data for imucal: nine sections sharing the same number of samples
    g = triad3()
    per = n_samples // 9
    fer = Simulator({"gyro": g, "accel": g}, latitude_deg=None, seed=2).run(ferraris_procedure(per / 100.0, 360.0 / (per / 100.0)))
    n_fer = sum(s.n_samples for s in fer.session.segments)
    t_imucal = None
    if HAVE_IMUCAL:
        t_imucal = median_time(lambda: imucal_fit(fer.session, 100.0), args.repeats)
    t_lsq = median_time(lambda: LeastSquares().fit(fer.session).to_calibration(), args.repeats)
    print(f"timing (median of {args.repeats})")
    print(f"  rimu ChoPark, cone6 Tables 1+2 ({n_samples} samples x 12 channels): {t_rimu * 1e3:8.1f} ms")
    if t_imucal is not None:
        print(f"  imucal Ferraris, triad ({n_fer} samples x 6 channels):              {t_imucal * 1e3:8.1f} ms  "
              f"(rimu / imucal = {t_rimu / t_imucal:.2f})")
    else:
        print("  imucal is not importable here: install it (pip install imucal) for the reference timing")
    print(f"  rimu LeastSquares on the same triad data:                            {t_lsq * 1e3:8.1f} ms")
    out["timing_ms"] = {"rimu_chopark_cone6": t_rimu * 1e3, "imucal_ferraris_triad": None if t_imucal is None else
                        t_imucal * 1e3, "rimu_lsq_triad": t_lsq * 1e3, "samples_cone6": n_samples,
                        "samples_triad": n_fer}

    # 2. accuracy on the same simulated Ferraris-style triad data (20 s statics, 10 s turns)
    acc: dict[str, list] = {"rimu": [], "imucal": []}
    for r in range(args.accuracy_runs):
        sim = Simulator({"gyro": g, "accel": g}, latitude_deg=None, arw_deg_sqrt_h=0.3, vrw_ug_sqrt_hz=100.0,
                        seed=100 + r)
        fr = sim.run(ferraris_procedure(20.0))
        cal = LeastSquares().fit(fr.session).to_calibration()
        acc["rimu"].append(errors(fr.truth, cal["accel"].scale, cal["accel"].axes_mb(), cal["accel"].bias,
                                  cal["gyro"].scale, cal["gyro"].axes_mb(), cal["gyro"].bias))
        if HAVE_IMUCAL:
            acc["imucal"].append(errors(fr.truth, *imucal_fit(fr.session, 100.0)))
    print(f"\naccuracy on the same simulated triad data ({args.accuracy_runs} runs; rms over axes and runs)")
    keys = list(acc["rimu"][0])
    print(f"  {'':<18}" + "".join(f"{k:>18}" for k in keys))
    summary = {}
    for who in ("rimu", "imucal"):
        if not acc[who]:
            continue
        vals = {k: float(np.sqrt(np.mean([a[k] ** 2 for a in acc[who]]))) for k in keys}
        summary[who] = vals
        print(f"  {who:<18}" + "".join(f"{vals[k]:>18.4g}" for k in keys))
    if not HAVE_IMUCAL:
        print("  imucal: not importable here, no reference accuracy")
    out["accuracy"] = summary

    # 3. the real Ferraris recording shared with imucal (../shared/data), both from data in memory
    folder = next((c for c in (Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "imucal_ferraris_session",
                               Path("/work/shared/data/imucal_ferraris_session")) if c.exists()), None)
    if folder is not None:
        from rimu.session import load_ferraris

        sess = load_ferraris(folder)
        tr = []
        for _ in range(args.repeats):
            fresh = load_ferraris(folder)  # a session never fitted before: no cache helps
            t0 = time.perf_counter()
            LeastSquares().fit(fresh).to_calibration()
            tr.append(time.perf_counter() - t0)
        real = {"rimu_lsq_ms": statistics.median(tr) * 1e3,
                "samples": sum(x.n_samples for x in sess.segments)}
        if HAVE_IMUCAL:
            import pandas as pd
            from imucal import FerrarisCalibration, ferraris_regions_from_section_list

            data = pd.read_csv(folder / "example_ferraris_session.csv", header=0, index_col=0)
            sections = pd.read_json(folder / "example_ferraris_session_list.json").T
            real["imucal_ms"] = median_time(lambda: FerrarisCalibration().compute(
                ferraris_regions_from_section_list(data, sections), sampling_rate_hz=102.4, from_acc_unit="m/s^2",
                from_gyr_unit="deg/s"), args.repeats) * 1e3
            real["ratio_rimu_over_imucal"] = real["rimu_lsq_ms"] / real["imucal_ms"]
        print(f"\nreal Ferraris recording ({real['samples']} samples, median of {args.repeats}): rimu LeastSquares "
              f"{real['rimu_lsq_ms']:.2f} ms" + (f", imucal {real['imucal_ms']:.2f} ms, ratio "
                                                 f"{real['ratio_rimu_over_imucal']:.2f}" if HAVE_IMUCAL else ""))
        out["real_ferraris"] = real
    else:
        print("\nreal Ferraris recording: ../shared/data/imucal_ferraris_session is absent here")

    # 4. memory: peak allocation of a fit on a 16x-long session (beyond the session's own samples)
    import tracemalloc

    big = Simulator(seed=3).run(cho_park_procedure(duration=60.0 * args.memory_factor)).session
    data_mb = sum(s.raw["gyro"].nbytes + s.raw["accel"].nbytes + s.t.nbytes for s in big.segments) / 1e6
    mem = {"session_data_mb": data_mb, "factor": args.memory_factor}
    for name, est in (("chopark", ChoPark), ("lsq", LeastSquares)):
        tracemalloc.start()
        est().fit(big).to_calibration()
        mem[f"{name}_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
    print(f"memory, {args.memory_factor}x-long cone6 session ({data_mb:.0f} MB of samples): peak extra allocation "
          f"ChoPark {mem['chopark_peak_mb']:.1f} MB, LeastSquares {mem['lsq_peak_mb']:.1f} MB (target < 200 MB)")
    out["memory"] = mem
    print(json.dumps(out))


if __name__ == "__main__":
    main()
