"""``rimu demo``: rimu's main job end to end on simulated data, no hardware needed.

1. simulate the cone6 unit of Cho & Park 2005 on a 2-axis turntable (Table 1 + Table 2, Table 3 as truth);
2. calibrate it (least squares on the effect model) and save the calibration file;
3. run a 30 s manoeuvre through the runtime pipeline, sample by sample, with the faults of Cho & Park's
   Fig. 6 injected (gyro y2 at 15 s, accelerometer x1 at 20 s);
4. detect and isolate them with the generalized likelihood test on the parity vector (Eq. 21 isolation);
5. print a short report and write a plot.
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
    p.add_argument("--out", default="rimu-demo", help="folder for the calibration file, report and plot")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--segment-duration", type=float, default=20.0, help="s per calibration segment")
    p.add_argument("--p-fa", type=float, default=1e-3, help="per-sample false-alarm probability of the test")
    p.add_argument("--confirm", type=int, default=5, help="consecutive alarms on one sensor to isolate it")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..calibration.lsq import fit_lsq
    from ..fdi import glt_snapshot
    from ..fusion import Pipeline
    from ..geometry import cone6
    from ..sim import Simulator, cho_park_procedure, rotation
    from ..units import DS_TO_RS, G0, MS2_TO_UG, RAD_TO_ARCSEC, RS_TO_DS, RS_TO_DH

    t_start = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    geo = cone6()
    sim = Simulator({"gyro": geo, "accel": geo}, seed=args.seed)
    report: dict = {"geometry": geo.name, "seed": args.seed}

    # 1-2. calibration run and fit --------------------------------------------------------------------
    print("rimu demo: cone6 redundant IMU (Cho & Park 2005), simulated on a 2-axis turntable")
    cal_run = sim.run(cho_park_procedure(duration=args.segment_duration))
    print(f"  calibration session: {len(cal_run.session)} segments (Table 1 + Table 2), "
          f"{len(cal_run.block)} samples at {sim.sample_rate:g} Hz")
    fits = {k: fit_lsq(cal_run.session, instrument=k) for k in ("gyro", "accel")}
    cal = Calibration({k: f.to_calibration() for k, f in fits.items()}, method="lsq (scale_misalignment + bias)")
    path = cal.save(out / "calibration.json")
    cal = Calibration.load(path, geometries={"gyro": geo, "accel": geo})
    print(f"  calibrated, saved and reloaded (checksum verified): {path}")
    print("\n  sensor | gyro dSF ppm (3s) | gyro mis arcsec | gyro bias deg/h | acc dSF ppm | acc bias ug")
    truth = cal_run.truth
    norm_errs = []
    for i, nm in enumerate(geo.names):
        row = []
        for k in ("gyro", "accel"):
            f = fits[k].sensors[i]
            tr = truth[k]
            e_sf = (cal[k].scale[i] / tr.scale[i] - 1) / 1e-6
            s_sf = f.std("scale") / cal[k].scale[i] / 1e-6
            e_b = cal[k].bias[i] - tr.bias[i]
            s_b = f.std("bias")
            norm_errs += [e_sf / s_sf, e_b / s_b]
            if k == "gyro":
                mis_err = np.degrees(np.arccos(np.clip(cal[k].misalignment[i] @ tr.misalignment[i], -1, 1))) * 3600
                row.append(f"{e_sf:+8.0f} ({3 * s_sf:5.0f})")
                row.append(f"{mis_err:8.1f}")
                row.append(f"{e_b * RS_TO_DH:+9.0f} ({3 * s_b * RS_TO_DH:4.0f})")
            else:
                row.append(f"{e_sf:+8.0f} ({3 * s_sf:4.0f})")
                row.append(f"{e_b * MS2_TO_UG:+7.0f} ({3 * s_b * MS2_TO_UG:4.0f})")
        print(f"  {nm:>6} | " + " | ".join(row))
    ne = np.array(norm_errs)
    report["calibration"] = {"normalised_error_rms": float(np.sqrt(np.mean(ne**2))),
                             "max_abs_normalised_error": float(np.abs(ne).max()),
                             "chi2_dof": {k: f.chi2_dof for k, f in fits.items()}}
    print(f"  errors / reported sigma: rms {report['calibration']['normalised_error_rms']:.2f}, "
          f"max {report['calibration']['max_abs_normalised_error']:.2f} (honest uncertainties give rms ~ 1)")

    # 3. the manoeuvre with faults ------------------------------------------------------------------------
    man = sim.run([rotation("manoeuvre", [0, 30 * DS_TO_RS, 0], duration=30.0)])
    Y = {k: man.block.raw[k].copy() for k in ("gyro", "accel")}
    t = man.block.t
    faults = {"gyro": (geo.index("y2"), 15.0, 10.0 * sim.noise_sigma("gyro")),
              "accel": (geo.index("x1"), 20.0, 10.0 * sim.noise_sigma("accel"))}
    for k, (i, t_f, size) in faults.items():
        Y[k][t >= t_f, i] += size / truth[k].scale[i]  # a step bias of 10 sigma in the sensor's raw output
    print(f"\n  manoeuvre: 30 deg/s about MB y for 30 s; faults injected (10 sigma step bias): "
          f"gyro y2 at 15 s, accelerometer x1 at 20 s")

    # 4. runtime pipeline, sample by sample, with GLT detection and Eq. 21 isolation -----------------------
    pipe = Pipeline(cal)
    N = len(t)
    xs = {k: np.zeros((N, 3)) for k in Y}
    stats = {k: np.zeros(N) for k in Y}
    thresholds = {k: np.zeros(N) for k in Y}
    events = []
    streak = {k: (-1, 0) for k in Y}
    for n in range(N):
        for k, ip in pipe.instruments.items():
            r = ip.step(Y[k][n])
            xs[k][n] = r.x
            d = glt_snapshot(r.parity, ip.table.Vz[r.entry], r.dof, args.p_fa, r.active)
            stats[k][n], thresholds[k][n] = d.statistic, d.threshold
            last, count = streak[k]
            if d.detected and d.isolated >= 0:
                count = count + 1 if d.isolated == last else 1
                streak[k] = (d.isolated, count)
                if count >= args.confirm:
                    ip.isolate(d.isolated)
                    events.append({"instrument": k, "sensor": geo.names[d.isolated], "t": float(t[n]),
                                   "delay_s": float(t[n] - faults[k][1])})
                    streak[k] = (-1, 0)
            else:
                streak[k] = (-1, 0)
    for e in events:
        print(f"  t = {e['t']:6.2f} s  {e['instrument']:5s} {e['sensor']} isolated "
              f"(fault at {faults[e['instrument']][1]:.0f} s, delay {e['delay_s'] * 1000:.0f} ms)")
    report["events"] = events

    # 5. accuracy before/after isolation -----------------------------------------------------------------
    print("\n  MB-frame error std before / after isolation, and the ratio (H_r^T H_r)^-1 predicts:")
    report["std"] = {}
    for k, (i, t_f, _) in faults.items():
        err = xs[k] - man.truth_inputs[k]
        unit, conv = ("deg/s", RS_TO_DS) if k == "gyro" else ("mg", 1e3 / G0)
        iso_t = next((e["t"] for e in events if e["instrument"] == k), None)
        before = err[(t > 1.0) & (t < t_f)]
        after = err[t > iso_t + 0.1] if iso_t is not None else err[:0]
        P_full = pipe[k].table.P[pipe[k].table.lookup(pipe[k].table.full_code)]
        P_red = pipe[k].table.P[pipe[k].table.lookup(pipe[k].table.full_code & ~(1 << i))]
        pred = np.sqrt(np.diag(P_red) / np.diag(P_full))
        meas = after.std(axis=0) / before.std(axis=0) if len(after) else np.full(3, np.nan)
        report["std"][k] = {"before": (before.std(axis=0) * conv).tolist(), "after": (after.std(axis=0) * conv).tolist(),
                            "ratio_measured": meas.tolist(), "ratio_predicted": pred.tolist(),
                            "mean_after": (after.mean(axis=0) * conv).tolist()}
        for a, ax in enumerate("xyz"):
            print(f"  {k:5s} {ax}: {before[:, a].std() * conv:7.4f} -> {after[:, a].std() * conv:7.4f} {unit}"
                  f"   ratio {meas[a]:.3f} (predicted {pred[a]:.3f})")
    report["elapsed_s"] = time.perf_counter() - t_start
    (out / "report.json").write_text(json.dumps(report, indent=1))
    png = _plot(out, t, xs, man.truth_inputs, stats, thresholds, events, faults)
    print(f"\n  report: {out / 'report.json'}" + (f"\n  plot:   {png}" if png else "  (matplotlib not installed: no plot)"))
    print(f"  done in {report['elapsed_s']:.1f} s")
    ok = {(e["instrument"], e["sensor"]) for e in events} == {("gyro", "y2"), ("accel", "x1")}
    if not ok:
        print("  WARNING: the isolated sensors are not the faulty ones")
    return 0 if ok else 1


def _plot(out: Path, t, xs, truth, stats, thresholds, events, faults) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
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
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png
