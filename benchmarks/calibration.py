"""Calibration benchmark: every rimu estimator (Cho & Park, de Oliveira, Zhang, hand-held, generic least squares)
timed beside imucal's Ferraris calibration of a triad on data of equal size and channel count, in the same run
(interleaved); the accuracy of rimu and imucal on the same simulated Ferraris-style triad data (six static
positions, one full turn about each axis); every estimator tried on imucal's real Ferraris recording (time, or the
estimator's refusal and why).

Equal size: imucal's input is 144000 samples x 6 channels (a gyro and an accelerometer triad, nine Ferraris
sections). Cho & Park (Tables 1 + 2), Zhang (nine positions and six CW/CCW pairs in the paper's 100 s : 180 s
proportions), hand-held (30 poses, long holds) and LeastSquares (imucal's own data) get triad sessions of the same
144000 x 6. de Oliveira needs at least four gyros: a tetrad of gyros with a triad of accelerometers (7 channels) over
its Table 1 sequences with the same number of sample-channels; its ratio is also given per sample-channel.

rimu runs with numba loaded (its ``fast`` extra, as in any process running rimu's compiled runtime): its statistics
and base fit take their compiled kernels then; the real recording's comparison also times rimu with numpy alone
(``backend="numpy"``). From files, rimu's Ferraris loader parses with pandas, which imucal's side loads in this
process (without pandas loaded it takes numpy's reader).

Every fit reads its session afresh: an estimator's per-segment statistics (rimu.session.stats) live for one
``fit``, so no round is helped by an earlier one (the warm-up call only imports).

    python benchmarks/calibration.py [--repeats 15]

imucal is optional (it is not a rimu dependency): install it to compare (``pip install imucal``); without it
the script says so and reports rimu alone. Prints a table and a JSON line.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import interleaved_times, load, ratio_stats

from rimu.calibration import ChoPark, LeastSquares, Oliveira, Zhang
from rimu.calibration.handheld import HandHeld
from rimu.errors import RimuError
from rimu.geometry import tetrad4, triad3
from rimu.sim import Simulator, cho_park_procedure, oliveira_table1, rotation, static, zhang_scheme
from rimu.sim.handheld import handheld_run
from rimu.units import DEG_TO_RAD, G0, MS2_TO_UG, RS_TO_DH

try:  # rimu's fast extra (numba), loaded as in any process that runs rimu's compiled runtime: rimu's statistics and
    # base fit take their compiled kernels once numba is loaded (a short session never imports it by itself; the
    # real recording's section also times rimu with numpy alone, backend="numpy")
    import numba  # noqa: F401

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

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


def imucal_regions(session):
    """The session's sections as imucal's FerrarisSignalRegions, each array in the layout imucal's own loader
    (``ferraris_regions_from_section_list``, from a pandas frame) makes: column-ordered (Fortran) copies, on which
    its column means run about 12x faster than on row-ordered views."""
    seg = {s.label: s for s in session.segments}
    return FerrarisSignalRegions(
        *[np.asfortranarray(seg[k].raw["accel"]) for k in SECTIONS[:6]],
        *[np.asfortranarray(seg[k].raw["gyro"]) for k in SECTIONS[:6]],
        *[np.asfortranarray(seg[k].raw["accel"]) for k in SECTIONS[6:]],
        *[np.asfortranarray(seg[k].raw["gyro"]) for k in SECTIONS[6:]])


def imucal_fit(session, fs: float, regions=None):
    """imucal's Ferraris calibration of the session's sections (or of ``regions`` made from it); returns (SF acc,
    axes acc, bias acc, SF gyro, axes gyro, bias gyro) in rimu's conventions (SI per raw unit, unit rows, SI bias)."""
    regions = imucal_regions(session) if regions is None else regions
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
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--accuracy-runs", type=int, default=20)
    ap.add_argument("--memory-factor", type=int, default=16, help="length of the memory test session, x 60 s")
    args = ap.parse_args()
    out: dict = {"benchmark": "calibration", "imucal": HAVE_IMUCAL}

    # 1. timing: every estimator beside imucal on data of equal size (144000 samples x 6 channels), interleaved
    g = triad3()
    n_target = 144000
    per = n_target // 9
    fer = Simulator({"gyro": g, "accel": g}, latitude_deg=None, seed=2).run(ferraris_procedure(per / 100.0, 360.0 / (per / 100.0)))
    cp = Simulator({"gyro": g, "accel": g}, seed=1).run(cho_park_procedure(duration=60.0))  # 24 x 60 s
    zs = 1440.0 / (9 + 12 * 1.8)  # Zhang's 100 s statics : 180 s rotations, scaled to 1440 s
    zh = Simulator({"gyro": g, "accel": g}, seed=3).run(zhang_scheme(static_duration=round(zs, 2),
                                                                     rotation_duration=round(1.8 * zs, 2)))
    hh = handheld_run(n_poses=30, static_s=46.3, seed=1000)
    # de Oliveira: 7 channels, 16 sequences of two whole turns, 864000 sample-channels in all
    ol_s = 6 * n_target / 7 / 16 / 100.0
    ol = Simulator({"gyro": tetrad4(), "accel": g}, latitude_deg=-23.2, seed=4).run(
        oliveira_table1(rate=2 * 2 * np.pi / ol_s, turns=2))
    fer_regions = imucal_regions(fer.session) if HAVE_IMUCAL else None  # prepared outside the timing, as
    # rimu's sessions are: both sides start from data in memory in the layout their own loaders make
    cases = {  # name: (label, session, fit); imucal first
        # imucal's own call alone: the conversion of its result to rimu's conventions (imucal_fit) is the
        # comparison's, not imucal's, and stays outside its time
        "imucal_ferraris": ("imucal Ferraris, triad", fer.session, (lambda: FerrarisCalibration(
            grav=G0, expected_angle=360.0).compute(fer_regions, 100.0, "count", "count")) if HAVE_IMUCAL else None),
        "chopark": ("rimu ChoPark, triad, Tables 1+2", cp.session, lambda: ChoPark().fit(cp.session).to_calibration()),
        "oliveira": ("rimu Oliveira, gyro tetrad, Table 1", ol.session,
                     lambda: Oliveira().fit(ol.session).to_calibration()),
        "zhang": ("rimu Zhang, triad, 9 positions + 6 pairs", zh.session, lambda: Zhang().fit(zh.session).to_calibration()),
        "handheld": ("rimu HandHeld, triad, 30 poses", hh.session, lambda: HandHeld().fit(hh.session).to_calibration()),
        "lsq": ("rimu LeastSquares, imucal's triad data", fer.session,
                lambda: LeastSquares().fit(fer.session).to_calibration()),
    }
    size = {k: (sum(x.n_samples for x in c[1].segments), sum(geo.n for geo in c[1].geometries.values()))
            for k, c in cases.items()}
    fns = {k: c[2] for k, c in cases.items() if c[2] is not None}
    for f in fns.values():  # one warm-up call each (imports; no statistics outlive a fit)
        f()
    times = interleaved_times(fns, args.repeats, time.thread_time)  # each estimator once per round, in turn
    med = {k: statistics.median(v) for k, v in times.items()}
    t_imucal = med.get("imucal_ferraris")
    print(f"timing (thread CPU time, median of {args.repeats} interleaved rounds; ratio = median [min, max] of the "
          f"per-round ratios; {load()}; imucal's input: {size['imucal_ferraris'][0]} samples x "
          f"{size['imucal_ferraris'][1]} channels, column-ordered as its loader makes them, sections prepared, "
          "FerrarisCalibration().compute alone; rimu's: a simulated session in memory, "
          "estimator().fit(session).to_calibration()" + (", numba loaded)" if HAVE_NUMBA else ", numpy alone)"))
    print(f"  {'estimator':42s} {'samples x ch':>15s} {'ms':>9s} {'/ imucal':>20s} {'per sample-ch':>14s}")
    ratio, ratio_sc, ratio_range = {}, {}, {}
    for k, (label, _, _) in cases.items():
        if k not in med:
            print(f"  {label:42s} imucal is not importable here: install it (pip install imucal)")
            continue
        n, c = size[k]
        line = f"  {label:42s} {f'{n} x {c}':>15s} {med[k] * 1e3:9.2f}"
        if t_imucal is not None and k != "imucal_ferraris":
            rs = ratio_stats(times, k, "imucal_ferraris")
            ratio[k], ratio_range[k] = rs["median"], rs
            n0, c0 = size["imucal_ferraris"]
            ratio_sc[k] = ratio[k] * (n0 * c0) / (n * c)
            line += f" {rs['median']:6.2f} [{rs['min']:.2f}, {rs['max']:.2f}] {ratio_sc[k]:14.2f}"
        print(line)
    out["timing_ms"] = {k: v * 1e3 for k, v in med.items()}
    out["ratio_to_imucal"] = ratio
    out["ratio_to_imucal_range"] = ratio_range
    out["timing_includes"] = {"imucal": "FerrarisCalibration().compute on FerrarisSignalRegions prepared beforehand "
                                        "(column-ordered arrays, as its loader makes); its result as imucal returns "
                                        "it (the conversion to rimu's conventions is not timed)",
                              "rimu": "estimator().fit(session).to_calibration() on a session in memory"
                                      + (" (numba loaded: compiled kernels)" if HAVE_NUMBA else " (numpy alone)")}
    out["ratio_to_imucal_per_sample_channel"] = ratio_sc
    out["size_samples_channels"] = size

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
        real: dict = {"samples": sum(x.n_samples for x in sess.segments), "estimators": {}}
        print(f"\nreal Ferraris recording ({real['samples']} samples; median of {args.repeats}; each fit on a freshly "
              "loaded session, loaded outside the timing, so no cache helps):")
        for name, est in (("chopark", ChoPark), ("oliveira", Oliveira), ("zhang", Zhang), ("handheld", HandHeld),
                          ("lsq", LeastSquares)):
            try:
                est().fit(load_ferraris(folder)).to_calibration()
            except RimuError as exc:  # the estimator's own refusal: the data do not identify its model
                real["estimators"][name] = {"refused": f"{type(exc).__name__}: {exc}"}
                print(f"  {est.__name__:12s} refused: {type(exc).__name__}: {exc}")
                continue
            fresh = [load_ferraris(folder) for _ in range(args.repeats + 1)]
            it = iter(fresh)
            ts = interleaved_times({name: lambda est=est, it=it: est().fit(next(it)).to_calibration()},
                                   args.repeats, time.thread_time)[name]
            real["estimators"][name] = {"ms": statistics.median(ts) * 1e3}
        # rimu's LeastSquares against imucal, both from prepared data and both from the files, interleaved
        rounds = max(args.repeats, 60)  # (a round is some 30 ms: more rounds for a steadier median on loaded cores)
        sessions = iter([load_ferraris(folder) for _ in range(2 * rounds + 4)])  # loaded outside the timing
        kernels = "with its compiled kernels (numba loaded)" if HAVE_NUMBA else "numpy alone (numba not installed)"
        fns = {"rimu_prepared": lambda: LeastSquares().fit(next(sessions)).to_calibration(),
               "rimu_prepared_numpy": lambda: LeastSquares(backend="numpy").fit(next(sessions)).to_calibration(),
               "rimu_files": lambda: LeastSquares().fit(load_ferraris(folder)).to_calibration()}
        includes = {"rimu_prepared": f"LeastSquares().fit(session).to_calibration() on a session loaded beforehand, "
                                     f"{kernels}",
                    "rimu_prepared_numpy": "the same, backend='numpy' (no compiled kernel)",
                    "rimu_files": "load_ferraris(folder) (CSV parsed by pandas, loaded in this process as it is by "
                                  "imucal's side, else numpy; section list JSON) + the same fit"}
        if HAVE_IMUCAL:
            import pandas as pd
            from imucal import ferraris_regions_from_section_list

            csv_path, json_path = folder / "example_ferraris_session.csv", folder / "example_ferraris_session_list.json"

            def imucal_files():
                data = pd.read_csv(csv_path, header=0, index_col=0)
                sections = pd.read_json(json_path).T
                regions = ferraris_regions_from_section_list(data, sections)
                return FerrarisCalibration().compute(regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2",
                                                     from_gyr_unit="deg/s")

            # its own loader's arrays, made afresh for every call as rimu's sessions are (both sides then read
            # data that no earlier call left in the caches)
            pool = iter([ferraris_regions_from_section_list(pd.read_csv(csv_path, header=0, index_col=0),
                                                            pd.read_json(json_path).T) for _ in range(rounds + 2)])
            fns["imucal_prepared"] = lambda: FerrarisCalibration().compute(
                next(pool), sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s")
            fns["imucal_files"] = imucal_files
            includes["imucal_prepared"] = ("FerrarisCalibration().compute on FerrarisSignalRegions its loader made "
                                           "beforehand, fresh for every call as rimu's sessions are")
            includes["imucal_files"] = "pandas read_csv + read_json + ferraris_regions_from_section_list + compute"
        for f in fns.values():
            f()
        # each comparison interleaves its own candidates only: a round of the prepared pair is not run right after
        # a file-parsing call that leaves the caches cold for whichever candidate comes next (the pairs were one
        # rotation of five; rimu's prepared fit then ran 0.70 ms against 0.44 ms alone, imucal's barely moved)
        ts = {}
        for group in (("rimu_prepared", "rimu_prepared_numpy", "imucal_prepared"), ("rimu_files", "imucal_files")):
            ts.update(interleaved_times({k: fns[k] for k in group if k in fns}, rounds, time.thread_time))
        real["ms"] = {k: statistics.median(v) * 1e3 for k, v in ts.items()}
        real["includes"] = includes
        real["rimu_lsq_ms"] = real["ms"]["rimu_prepared"]
        print(f"  LeastSquares against imucal (thread CPU time, median of {rounds} rounds, each comparison's own "
              f"candidates interleaved; "
              f"ratio = median [min, max] of per-round ratios; {load()}):")
        for k in fns:
            print(f"    {k:20s} {real['ms'][k]:7.2f} ms  ({includes[k]})")
        if HAVE_IMUCAL:
            real["ratio_prepared"] = ratio_stats(ts, "rimu_prepared", "imucal_prepared")
            real["ratio_prepared_numpy"] = ratio_stats(ts, "rimu_prepared_numpy", "imucal_prepared")
            real["ratio_files"] = ratio_stats(ts, "rimu_files", "imucal_files")
            for w, tgt in (("prepared", 2.0), ("prepared_numpy", 2.0), ("files", 1.0)):
                r = real[f"ratio_{w}"]
                print(f"    rimu / imucal from {w:14s}: {r['median']:.2f} [{r['min']:.2f}, {r['max']:.2f}]  "
                      f"target <= {tgt}")
            for v in real["estimators"].values():
                if "ms" in v:
                    v["ratio_to_imucal_prepared"] = v["ms"] / real["ms"]["imucal_prepared"]
        for name, v in real["estimators"].items():
            if "ms" in v:
                print(f"  {name:12s} {v['ms']:.2f} ms (fit of a session loaded beforehand)")
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
