"""``rimu simulate``: write a simulated calibration session in rimu's session format (CSV + JSON sidecar, or NPZ)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import PROCEDURES, add_procedure_options, check_samples, finite_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a turntable procedure and write the raw data",
                       description="Simulate a redundant IMU on a turntable (Cho & Park Table 1/2, de Oliveira "
                                   "Table 1, Zhang's scheme) and write the samples and what the rig knows.")
    p.add_argument("--procedure", default="cho_park", choices=PROCEDURES)
    p.add_argument("--geometry", default=None, help="geometry preset for gyros and accelerometers "
                   "(default: cone6; tetrad4 gyros + triad3 accelerometers for oliveira_table1; triad3 for zhang)")
    p.add_argument("--seed", type=int, default=0)
    add_procedure_options(p)  # noise > 0: a noise-free unit has no calibration covariance
    p.add_argument("--latitude", type=finite_float, default=36.37, help="deg, in [-90, 90]")
    p.add_argument("-o", "--output", default="session.npz",
                   help="output file: .npz, or .csv (a .json sidecar is written beside it); see docs/session-format.md")
    p.add_argument("--truth", default=None, metavar="FILE",
                   help="also write the true coefficients as a calibration file (not the session's own .json sidecar)")
    p.set_defaults(func=run)


def geometries_for(procedure: str, geometry: str | None) -> dict:
    from ..geometry import preset

    if geometry:
        return {"gyro": preset(geometry), "accel": preset(geometry)}
    if procedure == "oliveira_table1":
        return {"gyro": preset("tetrad4"), "accel": preset("triad3")}
    if procedure == "zhang":
        return {"gyro": preset("triad3"), "accel": preset("triad3")}
    return {"gyro": preset("cone6"), "accel": preset("cone6")}


def run(args: argparse.Namespace) -> int:
    from ..errors import OptionError
    from ..session import save_session
    from ..sim import PROCEDURES, Simulator

    if not -90.0 <= args.latitude <= 90.0:
        raise OptionError(f"--latitude must be in [-90, 90] deg, got {args.latitude:g}")
    if args.duration is not None and not args.procedure.startswith("cho_park"):
        raise OptionError(f"--duration sets the segment length of the cho_park procedures; {args.procedure} has its "
                          "own fixed durations: leave --duration out")
    check_samples((args.duration or 60.0) * args.sample_rate,
                  f"--duration {args.duration or 60.0:g} s at --sample-rate {args.sample_rate:g} Hz", limit=5e6)
    if Path(args.output).suffix not in (".npz", ".csv"):
        raise OptionError(f"-o {args.output}: use a .csv (a .json sidecar is written beside it) or .npz file name")
    sim = Simulator(geometries_for(args.procedure, args.geometry), arw_deg_sqrt_h=args.arw, vrw_ug_sqrt_hz=args.vrw,
                    sample_rate=args.sample_rate, latitude_deg=args.latitude, seed=args.seed)
    kw = {"duration": args.duration} if args.duration is not None else {}
    result = sim.run(PROCEDURES[args.procedure](**kw))
    s = result.session
    out = save_session(s, Path(args.output))
    side = f" + sidecar {out.with_suffix('.json')}" if out.suffix == ".csv" else ""
    print(f"simulated {args.procedure}: {len(s)} segments, {len(result.block)} samples at {s.sample_rate:g} Hz "
          f"-> {out}{side} (rimu session format, docs/session-format.md)")
    if args.truth:
        result.truth.save(args.truth)
        print(f"true coefficients -> {args.truth}")
    return 0
