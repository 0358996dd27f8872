"""``rimu simulate``: write a simulated calibration session in rimu's session format (CSV + JSON sidecar, or NPZ)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a turntable procedure and write the raw data",
                       description="Simulate a redundant IMU on a turntable (Cho & Park Table 1/2, de Oliveira "
                                   "Table 1, Zhang's scheme) and write the samples and what the rig knows.")
    p.add_argument("--procedure", default="cho_park",
                   choices=["cho_park", "cho_park_table1", "cho_park_table2", "oliveira_table1", "zhang"])
    p.add_argument("--geometry", default=None, help="geometry preset for gyros and accelerometers "
                   "(default: cone6; tetrad4 gyros + triad3 accelerometers for oliveira_table1; triad3 for zhang)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None,
                   help="s per static position and rate step (cho_park procedures; default 60)")
    p.add_argument("--sample-rate", type=float, default=100.0, help="Hz")
    p.add_argument("--arw", type=float, default=3.0, help="gyro angle random walk, deg/sqrt(h)")
    p.add_argument("--vrw", type=float, default=200.0, help="accelerometer noise density, micro-g/sqrt(Hz)")
    p.add_argument("--latitude", type=float, default=36.37, help="deg")
    p.add_argument("-o", "--output", default="session.npz",
                   help="output file: .npz, or .csv (a .json sidecar is written beside it); see docs/session-format.md")
    p.add_argument("--truth", default=None, help="also write the true coefficients as a calibration file")
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
    from ..session import save_session
    from ..sim import PROCEDURES, Simulator

    sim = Simulator(geometries_for(args.procedure, args.geometry), arw_deg_sqrt_h=args.arw, vrw_ug_sqrt_hz=args.vrw,
                    sample_rate=args.sample_rate, latitude_deg=args.latitude, seed=args.seed)
    kw = {"duration": args.duration} if (args.duration and args.procedure.startswith("cho_park")) else {}
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
