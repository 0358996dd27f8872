"""``rimu design``: predicted uncertainties of a turntable procedure (Cho & Park 2005, Eq. 19 and Fig. 3) and a
greedy D-optimal choice of static attitudes and rotation axes, compared with the papers' procedures."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ._common import (
    PROCEDURES,
    Deprecated,
    add_json_option,
    add_procedure_options,
    add_report_option,
    check_samples,
    positive_int,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("design", help="predict calibration uncertainties of a procedure; D-optimal test design",
                       description=__doc__)
    p.add_argument("--geometry", default="cone6", help="geometry preset (cone6, tetrad4, triad3, ...)")
    p.add_argument("--procedure", default="cho_park", choices=PROCEDURES)
    add_procedure_options(p)
    p.add_argument("--greedy", type=positive_int, default=10, help="number of static positions to select (rate pairs: 7)")
    add_report_option(p, "Cho & Park's Fig. 3 for this geometry (fig3.png)")
    add_json_option(p, "the predicted standard deviations (SI) and the design figures")
    p.add_argument("--plot", action=Deprecated, new="--report DIR (writes DIR/fig3.png)", metavar="PNG")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..calibration.design import (
        ProcedureInputs,
        fig3_curve,
        greedy_d_optimal,
        log_det_information,
        plot_fig3,
        predicted_std,
        procedure_inputs,
        turntable_candidates,
    )
    from ..errors import IdentifiabilityError, OptionError
    from ..geometry import preset
    from ..sim import PROCEDURES, zhang_scheme
    from ..sim.procedures import CHO_PARK_TABLE1, CHO_PARK_TABLE2
    from ..units import ARW_DSQH_TO_RSQS, G0, UG_TO_MS2, field_unit, fmt, white_noise_sigma

    geo = preset(args.geometry)
    if args.duration is not None and not args.procedure.startswith("cho_park"):
        raise OptionError(f"--duration sets the segment length of the cho_park procedures; {args.procedure} has its "
                          "own fixed durations: leave --duration out")
    args.duration = 60.0 if args.duration is None else args.duration
    check_samples(args.duration * args.sample_rate,
                  f"--duration {args.duration:g} s at --sample-rate {args.sample_rate:g} Hz", limit=1e9)
    proc = PROCEDURES[args.procedure]()
    if args.procedure.startswith("cho_park"):
        proc = PROCEDURES[args.procedure](duration=args.duration)
    inp = procedure_inputs(proc)
    n = int(round(args.duration * args.sample_rate))
    sa = white_noise_sigma(args.vrw * UG_TO_MS2, args.sample_rate)
    sg = white_noise_sigma(args.arw * ARW_DSQH_TO_RSQS, args.sample_rate)
    print(f"rimu design: {geo.name} ({geo.n} sensors), procedure {args.procedure}: {inp.n_static} static positions, "
          f"{inp.n_pairs} +/- rate pairs, {n} samples each")
    try:
        pred = predicted_std(geo, inp, sa, sg, n)
    except IdentifiabilityError as exc:  # say which parameters, then continue with the design part
        print(f"  this procedure cannot identify the model: {exc}")
        pred = None
    if pred:
        print("\npredicted standard deviations (Cho & Park Eq. 19), field units")
        a, g = pred["accel"], pred["gyro"]
        # one field unit per column, chosen by the column's largest figure (rimu.units.fmt, as every printout)
        cols = [("acc SF", "ratio", a, "scale"), ("acc mis", "angle", a, "mis"), ("acc bias", "specific_force", a, "bias"),
                ("gyro SF", "ratio", g, "scale"), ("gyro mis", "angle", g, "mis"), ("gyro bias", "rate", g, "bias")]

        def cell(d: dict, name: str, what: str) -> float:
            return max(v for k, v in d.items() if k.startswith(name + ".mis")) if what == "mis" else d[f"{name}.{what}"]

        units = [field_unit(q, max(cell(d, nm, w) for nm in geo.names))[0] for _, q, d, w in cols]
        heads = [f"{h} {u}" for (h, *_), u in zip(cols, units)]
        print(f"  {'sensor':<8} " + " ".join(f"{h:>16}" for h in heads))
        for name in geo.names:
            print(f"  {name:<8} " + " ".join(
                f"{fmt(cell(d, name, w), q, u, digits=4).rsplit(' ', 1)[0]:>16}" for (_, q, d, w), u in zip(cols, units)))
        print("  bias: the error of the compensated output at zero input. 'rimu calibrate' prints this figure in a "
              "note; its bias column is the marginal std of B = SF x raw offset, larger by the scale-factor "
              "uncertainty times the unit's raw offset, which design cannot know")
    U, A = turntable_candidates()
    k = args.greedy
    if k > len(U):
        raise OptionError(f"--greedy {k}: there are only {len(U)} candidate static positions")
    sel = greedy_d_optimal(geo, U, k, "static")
    selr = greedy_d_optimal(geo, A, 7, "rate")
    t1 = ProcedureInputs(np.array(CHO_PARK_TABLE1) * G0, np.zeros((0, 3)))
    t2 = np.array(CHO_PARK_TABLE2)
    t2 = ProcedureInputs(np.zeros((0, 3)), t2[0::2] - t2[1::2])
    z = procedure_inputs(zhang_scheme())
    print("\nD-optimal design (sum over sensors of log det of the Eq. 19 information; larger is better)")
    print(f"  static: greedy {k} positions {log_det_information(geo, ProcedureInputs(U[sel] * G0, np.zeros((0, 3))), 'static'):.2f}"
          f" | Cho & Park Table 1 (10) {log_det_information(geo, t1, 'static'):.2f}"
          f" | Zhang's 9 attitudes {log_det_information(geo, ProcedureInputs(z.forces, np.zeros((0, 3))), 'static'):.2f}")
    print(f"  rate:   greedy 7 pairs {log_det_information(geo, ProcedureInputs(np.zeros((0, 3)), 2 * A[selr]), 'rate'):.2f}"
          f" | Cho & Park Table 2 (7) {log_det_information(geo, t2, 'rate'):.2f}"
          f" | Zhang's 6 axes {log_det_information(geo, ProcedureInputs(np.zeros((0, 3)), z.rate_diffs / np.linalg.norm(z.rate_diffs, axis=1)[:, None] * 2), 'rate'):.2f}")
    print("  greedy static 'up' directions (MB): " + ", ".join(str(np.round(U[i], 2).tolist()) for i in sel))
    print("  greedy rotation axes (MB):          " + ", ".join(str(np.round(A[i], 2).tolist()) for i in selr))
    if args.json:
        from ._common import json_dump

        doc = {"geometry": geo.name, "procedure": args.procedure, "samples_per_segment": n,
               "predicted_std_si": pred, "greedy_static_up_mb": U[sel].tolist(), "greedy_rate_axes_mb": A[selr].tolist()}
        print(f"\nsummary written to {json_dump(doc, args.json)}")
    png = Path(args.plot) if args.plot else (Path(args.report) / "fig3.png" if args.report else None)
    if png is not None:
        png.parent.mkdir(parents=True, exist_ok=True)
        curve = fig3_curve(geo, np.array(CHO_PARK_TABLE1), t2.rate_diffs)
        plot_fig3(curve, str(png), f"Cho & Park Fig. 3 for {geo.name}")
        print(f"\nFig. 3 written to {png}")
    return 0
