"""``rimu demo``: rimu's main job end to end on simulated data, no hardware needed.

1. simulate the cone6 unit of Cho & Park 2005 on a 2-axis turntable (Table 1 + Table 2, Table 3 as truth);
2. calibrate it with Cho & Park's estimator and save the calibration file;
3. compare the error model with the measurements: the unit has one effect the base model lacks (a gyro
   g-sensitivity), and the diagnosis names it, adds it and shows the error fall;
4. run a 30 s manoeuvre through the runtime pipeline, sample by sample, with the faults of Cho & Park's
   Fig. 6 injected (gyro y2 at 15 s, accelerometer x1 at 20 s);
5. detect and isolate them with the redundancy manager (generalized likelihood test on the parity vector,
   confirmation, Eq. 21 isolation) and keep going on the remaining sensors;
6. print a short report and write a plot.

Between 3 and 4 the loop is closed at the runtime: a held-out session of the same unit is replayed through the
pipeline and the FDI with the base calibration and with the one refitted with the effect the diagnosis named;
the runtime error falls to the noise floor and the false isolations stop (``runtime_error.png``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate, calibrate, fuse, inject faults, isolate them; report and plot",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    from ._common import Deprecated, add_fdi_options, nonnegative_int, positive_float

    p.add_argument("--report", default="rimu-demo", metavar="DIR",
                   help="folder for the plot (demo.png), and by default the calibration file and report.json")
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="calibration file (default DIR/calibration.json)")
    p.add_argument("--json", default=None, metavar="FILE", help="the summary as JSON (default DIR/report.json)")
    p.add_argument("--out", action=Deprecated, new="--report DIR", dest="report", metavar="DIR")
    p.add_argument("--seed", type=nonnegative_int, default=7)
    p.add_argument("--segment-duration", type=positive_float, default=20.0, help="s per calibration segment")
    add_fdi_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    from ..atomic import flush_outputs
    from ..calibration import Calibration, ChoPark
    from ..calibration.effects import GSensitivity
    from ..diagnose import diagnose
    from ..epoch import EpochBlock
    from ..fdi import Runtime
    from ._common import fdi_settings

    settings = fdi_settings(args)  # --p-fa and --confirm not given: the one default
    from ..fusion import Pipeline
    from ..geometry import cone6
    from ..sim import Simulator, TruthEffect, cho_park_procedure, rotation
    from ..units import DS_TO_RS, G0, MS2_TO_UG, RS_TO_DH, SI_UNITS, field_unit, fmt
    from ._common import check_samples

    check_samples(args.segment_duration * 100.0, f"--segment-duration {args.segment_duration:g} s at 100 Hz",
                  limit=5e6, least=10)
    out = Path(args.report)
    out.mkdir(parents=True, exist_ok=True)
    geo = cone6()
    # the unit: Cho & Park's Table 3 coefficients, and one effect the base model does not have: gyro x2 is
    # sensitive to specific force, (0.10, -0.05, 0.08) (deg/s)/g, as MEMS rate gyros of the ADXRS class are
    gsens_true = np.array([0.10, -0.05, 0.08]) * DS_TO_RS / G0
    hidden = {"gyro": [TruthEffect(GSensitivity(), {geo.index("x2"): gsens_true})]}
    sim = Simulator({"gyro": geo, "accel": geo}, effects=hidden, seed=args.seed)
    report: dict = {"geometry": geo.name, "seed": args.seed}

    # 1-2. calibration run and Cho & Park's estimator -----------------------------------------------------
    print("rimu demo: cone6 redundant IMU (Cho & Park 2005), simulated on a 2-axis turntable")
    cal_run = sim.run(cho_park_procedure(duration=args.segment_duration))
    print(f"  calibration session: {len(cal_run.session)} segments (Table 1 + Table 2), "
          f"{len(cal_run.block)} samples at {sim.sample_rate:g} Hz")
    res = ChoPark().fit(cal_run.session)
    cal = res.to_calibration()
    path = cal.save(Path(args.output) if args.output else out / "calibration.json")
    flush_outputs()  # read back below: in place now (removed again if the run fails)
    cal = Calibration.load(path, geometries={"gyro": geo, "accel": geo})
    print(f"  calibrated (Cho & Park Eq. 5-17), saved and reloaded (checksum verified): {path}")
    print("\n  errors against the truth, (3 sigma) as reported by the estimator:")
    print("  sensor | gyro dSF ppm     | gyro mis arcsec | gyro bias deg/h  | acc dSF ppm   | acc bias ug")
    truth = cal_run.truth
    norm_errs: dict[str, list[float]] = {"all": [], "without_x2_gyro": []}
    for i, nm in enumerate(geo.names):
        row = []
        for k in ("gyro", "accel"):
            f = res[k].sensors[i]
            tr = truth[k]
            e_sf = (cal[k].scale[i] / tr.scale[i] - 1) / 1e-6
            s_sf = f.std("scale") / cal[k].scale[i] / 1e-6
            e_b = cal[k].bias[i] - tr.bias[i]
            s_b = f.std("bias")
            norm_errs["all"] += [e_sf / s_sf, e_b / s_b]
            if not (k == "gyro" and nm == "x2"):
                norm_errs["without_x2_gyro"] += [e_sf / s_sf, e_b / s_b]
            if k == "gyro":
                mis_err = np.degrees(np.arccos(np.clip(cal[k].misalignment[i] @ tr.misalignment[i], -1, 1))) * 3600
                row.append(f"{e_sf:+7.0f} ({3 * s_sf:5.0f})")
                row.append(f"{mis_err:15.1f}")
                row.append(f"{e_b * RS_TO_DH:+7.0f} ({3 * s_b * RS_TO_DH:5.0f})")
            else:
                row.append(f"{e_sf:+6.0f} ({3 * s_sf:4.0f})")
                row.append(f"{e_b * MS2_TO_UG:+6.0f} ({3 * s_b * MS2_TO_UG:4.0f})")
        print(f"  {nm:>6} | " + " | ".join(row))
    ne = {k: np.array(v) for k, v in norm_errs.items()}
    report["calibration"] = {
        "method": res.method,
        "normalised_error_rms": float(np.sqrt(np.mean(ne["all"] ** 2))),
        "normalised_error_rms_without_x2_gyro": float(np.sqrt(np.mean(ne["without_x2_gyro"] ** 2))),
        "max_abs_normalised_error": float(np.abs(ne["all"]).max()),
        "chi2_dof": res.chi2_dof,
    }
    c = report["calibration"]
    print(f"  errors / reported sigma: rms {c['normalised_error_rms']:.2f} over all coefficients, "
          f"{c['normalised_error_rms_without_x2_gyro']:.2f} without gyro x2 (honest uncertainties give ~1)")

    # 3. model against measurement: which effect is missing ------------------------------------------------
    print("\n  model against measurement (gyros): residuals of the base model, candidate effects tested")
    d = diagnose(cal_run.session, "bias,scale,misalignment", instruments=["gyro"])
    dg = d["gyro"]
    top = dg.top()
    best = dg.test(top) if top else None
    strongest = max(best.sensors, key=lambda s: s.explained_total) if best else None
    if best is not None:
        print(f"  missing: {top} on gyro {strongest.sensor}: explains {100 * strongest.explained_total:.0f}% of the "
              f"residual variance (p ~ 1e{strongest.log10_p:.0f})")
    comp = d.add(top)["gyro"] if top else None
    if comp is not None:
        print(f"  added {top}: chi2/dof {comp.chi2_before:.4f} -> {comp.chi2_after:.4f}, BIC {comp.dbic:+.0f}")
        for line in comp.lines()[1:]:
            if line.strip().startswith("x2: rms"):
                print(f"  {line.strip()}")
        for r in comp.new_parameters():
            if r["sensor"] == "x2":
                print(f"    x2.{r['parameter']} = {r['value']:+.1f} +- {r['std']:.1f} {r['report_unit']}")
    report["diagnosis"] = {
        "top": top, "sensor": None if strongest is None else strongest.sensor,
        "chi2_before": None if comp is None else comp.chi2_before,
        "chi2_after": None if comp is None else comp.chi2_after,
        "gsens_x2": None if comp is None else {r["parameter"]: [r["value_si"], r["std_si"]]
                                                for r in comp.new_parameters() if r["sensor"] == "x2"},
        "gsens_x2_truth_si": gsens_true.tolist(),
    }

    # 3b. close the loop at the runtime: replay a held-out session with the base and the refitted calibration --
    if top:
        report["runtime"] = _close_the_loop(sim, cal_run, cal, top, out)

    # 4. the manoeuvre with faults ------------------------------------------------------------------------
    man = sim.run([rotation("manoeuvre", [0, 30 * DS_TO_RS, 0], duration=30.0)])
    Y = {k: man.block.raw[k].copy() for k in ("gyro", "accel")}
    t = man.block.t
    faults = {"gyro": (geo.index("y2"), 15.0, 10.0 * sim.noise_sigma("gyro")),
              "accel": (geo.index("x1"), 20.0, 10.0 * sim.noise_sigma("accel"))}
    for k, (i, t_f, size) in faults.items():
        Y[k][t >= t_f, i] += size / truth[k].scale[i]  # a step bias of 10 sigma in the sensor's raw output
    print("\n  manoeuvre: 30 deg/s about MB y for 30 s; faults injected (10 sigma step bias): "
          "gyro y2 at 15 s, accelerometer x1 at 20 s")

    # 5. runtime pipeline and redundancy management (GLT, confirmation, Cho & Park Eq. 21 isolation) --------
    pipe = Pipeline(cal)
    rt = Runtime(pipe, settings)   # the runtime of rimu monitor, rimu replay and the exported C
    runs = rt.run(EpochBlock(t, Y))
    managers = rt.managers
    events = []
    for k, r in runs.items():
        for e in r.events:
            if e.kind == "isolated":
                events.append({"instrument": k, "sensor": e.sensor, "t": float(e.t),
                               "delay_s": float(e.t - faults[k][1])})
    for e in sorted(events, key=lambda e: e["t"]):
        print(f"  t = {fmt(e['t'], 'time', 's', decimals=2, width=6)}  {e['instrument']:5s} {e['sensor']} isolated "
              f"(fault at {fmt(faults[e['instrument']][1], 'time', 's')}, delay {fmt(e['delay_s'], 'time', 'ms', 3)})")
    for k, m in managers.items():
        print(f"  {k}: state {m.health.state.value}, isolated {m.health.isolated}")
    report["events"] = events
    report["states"] = {k: m.health.state.value for k, m in managers.items()}

    # 6. accuracy before/after isolation -----------------------------------------------------------------
    print("\n  MB-frame error std before / after isolation, and the ratio (H_r^T H_r)^-1 predicts:")
    report["std"] = {}
    for k, (i, t_f, _) in faults.items():
        err = runs[k].x - man.truth_inputs[k]
        iso_t = next((e["t"] for e in events if e["instrument"] == k), None)
        before = err[(t > 1.0) & (t < t_f)]
        after = err[t > iso_t + 0.1] if iso_t is not None else err[:0]
        tab = pipe[k].table
        P_full = tab.P[tab.lookup(tab.full_code)]
        P_red = tab.P[tab.lookup(tab.full_code & ~(1 << i))]
        pred = np.sqrt(np.diag(P_red) / np.diag(P_full))
        meas = after.std(axis=0) / before.std(axis=0) if len(after) else np.zeros(3)
        # SI in the JSON, with its unit; printed through the one formatter in the unit the magnitude calls for
        report["std"][k] = {"before": before.std(axis=0).tolist(),
                            "after": after.std(axis=0).tolist() if len(after) else [],
                            "unit": SI_UNITS["rate" if k == "gyro" else "specific_force"],
                            "ratio_measured": meas.tolist(), "ratio_predicted": pred.tolist()}
        unit = field_unit(k, float(before.std(axis=0).max()))[0]
        for a, ax in enumerate("xyz"):
            aft = after[:, a].std() if len(after) else float("nan")
            print(f"  {k:5s} {ax}: {fmt(before[:, a].std(), k, unit, decimals=4, width=7).split()[0]} -> "
                  f"{fmt(aft, k, unit, decimals=4, width=7)}   ratio {meas[a]:.3f} (predicted {pred[a]:.3f})")
    # 7. flight code: the same runtime and decisions as dependency-free C, checked sample by sample --------
    report["flight_code"] = _flight_code(cal, t, Y, runs, out, args)
    report["elapsed_s"] = time.perf_counter() - t_start
    from ..atomic import write_text

    json_path = Path(args.json) if args.json else out / "report.json"
    if args.json == "-":
        print(json.dumps(report, indent=1))
    else:
        write_text(json_path, json.dumps(report, indent=1))
    xs = {k: r.x for k, r in runs.items()}
    stats = {k: r.statistic for k, r in runs.items()}
    thresholds = {k: r.threshold for k, r in runs.items()}
    png = _plot(out, t, xs, man.truth_inputs, stats, thresholds, events, faults)
    print(f"\n  report: {json_path}" + (f"\n  plot:   {png}" if png else "  (matplotlib not installed: no plot)"))
    print(f"  done in {report['elapsed_s']:.1f} s")
    ok = {(e["instrument"], e["sensor"]) for e in events} == {("gyro", "y2"), ("accel", "x1")}
    if not ok:
        print("  WARNING: the isolated sensors are not the faulty ones")
    fc = report["flight_code"]
    if fc.get("built") and not (fc.get("decisions_equal") and fc.get("max_rel_diff", 1.0) < 1e-9):
        print("  WARNING: the exported C does not match the Python runtime")
        ok = False
    return 0 if ok else 1


def _flight_code(cal, t, Y, runs, out: Path, args: argparse.Namespace) -> dict:  # type: ignore[no-untyped-def]
    """Export the calibration as C99 (compensation, projection, GLT, isolation, re-admission, validity), build
    the CSV filter with the system C compiler, feed it the manoeuvre's raw samples and compare its estimates
    and decisions with the Python managers' on every sample. Skipped, with a line saying why, without a
    compiler."""
    import subprocess

    from ..export import Estimates, build_filter, export_c, read_estimates
    from ._common import fdi_settings

    d = out / "flight_code"
    export_c(cal, d, fdi=fdi_settings(args))
    cc, build = build_filter(d)
    if cc is None:
        print("\n  flight code: no C compiler (or make) here; `rimu export-c CAL -o DIR --build` needs one")
        return {"built": False}
    if build.returncode != 0:
        print(f"\n  flight code: the build failed ({build.stderr.strip().splitlines()[-1:]})")
        return {"built": False, "error": build.stderr[-2000:]}
    insts = list(cal.instruments)
    rows = np.column_stack([t] + [Y[k] for k in insts])
    text = "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"
    t0 = time.perf_counter()
    res = subprocess.run([str(d / "rimu_filter")], input=text, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        print(f"\n  flight code: the filter failed ({res.stderr.strip()[-200:]})")
        return {"built": True, "error": res.stderr[-2000:]}
    import io as _io

    c_est = read_estimates(_io.StringIO(res.stdout), cal)
    py = Estimates.from_replay(t, {k: runs[k] for k in insts})
    rel = max(float(np.nanmax(np.abs(c_est.x[k] - py.x[k]), initial=0.0)) / max(float(np.nanmax(np.abs(py.x[k]))),
                                                                                   1e-300) for k in insts)
    same_nan = all(np.array_equal(np.isnan(c_est.x[k]), np.isnan(py.x[k])) for k in insts)
    same = same_nan and all(np.array_equal(c_est.validity[k], py.validity[k])
                            and np.array_equal(c_est.isolated[k], py.isolated[k]) for k in insts)
    print(f"\n  flight code: C99 exported and built with {cc} ({d}); {len(t)} samples through the C filter: "
          f"decisions {'equal to Python on every sample' if same else 'DIFFER from Python'}, estimates within "
          f"{rel:.1e} relative")
    return {"built": True, "compiler": cc, "samples": len(t), "decisions_equal": same, "max_rel_diff": rel,
            "filter_wall_s": wall}


def _close_the_loop(sim, cal_run, cal, top: str, out: Path) -> dict:
    """Base calibration vs the one with ``top`` refitted, replayed on a held-out session (errors, FDI)."""
    from ..calibration import LeastSquares
    from ..calibration.model import ErrorModel
    from ..experiments.validate import validate
    from ..fusion.validation import plot_segment_errors
    from ..sim.typical import validation_procedure
    from ..units import MS2_TO_UG, RS_TO_DH

    gyro = LeastSquares(ErrorModel.base() + top, instruments=["gyro"]).fit(cal_run.session).to_calibration()["gyro"]
    full = type(cal)({"gyro": gyro, "accel": cal["accel"]}, cal.raw_unit, "cho_park + lsq", metadata=dict(cal.metadata))
    from ..sim import Simulator

    # the same unit (Table 3 truth, the same hidden effect and noise densities), another day: 20 s per segment
    # at 20 Hz keeps the replay short while the noise of the segment means stays below the effect
    other = Simulator(dict(sim.geometries), effects=sim.effects, seed=(sim.seed or 0) + 1, sample_rate=20.0)
    held_out = other.run(validation_procedure(30.0, duration=20.0)).session
    print(f"\n  close the loop: a held-out session of the same unit ({len(held_out)} segments: static, tilted, "
          "rotating), replayed through pipeline + FDI")
    res = {}
    for label, c in (("base calibration", cal), (f"with {top}", full)):
        v = validate(held_out, c)
        res[label] = v
        g, a = v["gyro"], v["accel"]
        print(f"  {label:>22}: gyro segment error {g.errors.segment_error_rms * RS_TO_DH:6.2f} deg/h, "
              f"accel {a.errors.segment_error_rms * MS2_TO_UG:6.1f} ug; false isolations "
              f"{g.isolations + a.isolations}, samples alarmed {g.alarms + a.alarms}")
    (b, f) = res.values()
    png = plot_segment_errors({k: v["gyro"].errors for k, v in res.items()}, out / "runtime_error.png",
                              title="gyro runtime error on the held-out session, before and after")
    if png:
        print(f"  plot:   {png}")
    return {"before": {k: v.to_dict() for k, v in b.items()}, "after": {k: v.to_dict() for k, v in f.items()},
            "gyro_error_ratio": b["gyro"].errors.segment_error_rms / f["gyro"].errors.segment_error_rms}


def _plot(out: Path, t, xs, truth, stats, thresholds, events, faults) -> Path | None:
    from ..plotting import pyplot

    plt = pyplot(optional=True)
    if plt is None:
        return None
    from ..units import G0, RS_TO_DS

    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    for col, k in enumerate(("gyro", "accel")):
        conv, unit = (RS_TO_DS, "deg/s") if k == "gyro" else (1.0 / G0, "g")
        ax = axes[0, col]
        for a, c in zip(range(3), "rgb"):
            ax.plot(t, xs[k][:, a] * conv, c, lw=0.5, label=f"{'xyz'[a]} estimate")
            ax.plot(t, truth[k][:, a] * conv, c + "--", lw=1.0)
        ax.set_title(f"{k}: MB-frame estimate (dashed: truth)")
        ax.set_ylabel(unit)
        ax.legend(loc="upper left", fontsize=7)
        ax = axes[1, col]
        ax.semilogy(t, np.maximum(stats[k], 1e-3), lw=0.5, label="FD = p^T p")
        ax.semilogy(t, thresholds[k], "k--", lw=1, label="threshold (P_FA)")
        ax.axvline(faults[k][1], color="r", lw=0.8, label="fault injected")
        for e in events:
            if e["instrument"] == k:
                ax.axvline(e["t"], color="m", lw=0.8, ls=":", label=f"{e['sensor']} isolated")
        ax.set_xlabel("time, s")
        ax.set_title(f"{k}: parity test statistic")
        ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    png = out / "demo.png"
    from ..atomic import atomic_path

    with atomic_path(png) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return png
