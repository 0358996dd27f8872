"""``rimu simulate``: write a simulated calibration session or stream to an NPZ file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a turntable procedure and write the raw data",
                       description="Simulate a redundant IMU on a turntable (Cho & Park Table 1/2, de Oliveira "
                                   "Table 1, Zhang's scheme) and write the samples and what the rig knows.")
    p.add_argument("--procedure", default="cho_park",
                   choices=["cho_park", "cho_park_table1", "cho_park_table2", "oliveira_table1", "zhang"])
    p.add_argument("--geometry", default=None, help="geometry preset for gyros and accelerometers "
                   "(default: cone6; tetrad4 gyros + triad3 accelerometers for oliveira_table1; triad3 for zhang)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sample-rate", type=float, default=100.0, help="Hz")
    p.add_argument("--arw", type=float, default=3.0, help="gyro angle random walk, deg/sqrt(h)")
    p.add_argument("--vrw", type=float, default=200.0, help="accelerometer noise density, micro-g/sqrt(Hz)")
    p.add_argument("--latitude", type=float, default=36.37, help="deg")
    p.add_argument("-o", "--output", default="session.npz", help="output .npz file")
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
    from ..sim import PROCEDURES, Simulator

    sim = Simulator(geometries_for(args.procedure, args.geometry), arw_deg_sqrt_h=args.arw, vrw_ug_sqrt_hz=args.vrw,
                    sample_rate=args.sample_rate, latitude_deg=args.latitude, seed=args.seed)
    result = sim.run(PROCEDURES[args.procedure]())
    s = result.session
    out = Path(args.output)
    arrays = {"t": result.block.t, "segment": result.segment_index}
    for k, y in result.block.raw.items():
        arrays[f"raw_{k}"] = y
    meta = {
        "sample_rate_hz": s.sample_rate,
        "latitude_rad": s.latitude,
        "raw_unit": s.raw_unit,
        "geometries": {k: g.to_dict() for k, g in s.geometries.items()},
        "segments": [
            {"label": seg.label, "kind": seg.kind,
             "specific_force_mb_ms2": None if seg.specific_force_mb is None else np.asarray(seg.specific_force_mb).tolist(),
             "rate_mb_rads": None if seg.rate_mb is None else np.asarray(seg.rate_mb).tolist(),
             "angle_mb_rad": None if seg.angle_mb is None else np.asarray(seg.angle_mb).tolist(),
             "mat_ln_mb": None if seg.mat_ln_mb is None else seg.mat_ln_mb.tolist()}
            for seg in s.segments
        ],
        "simulator": sim.settings(),
    }
    np.savez_compressed(out, meta=np.array(json.dumps(meta)), **arrays)
    print(f"simulated {args.procedure}: {len(s)} segments, {len(result.block)} samples at {s.sample_rate:g} Hz "
          f"-> {out}")
    return 0
