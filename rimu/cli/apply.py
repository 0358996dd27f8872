"""``rimu apply LOG --calibration cal.json -o OUT.npz``: a raw log in, the calibrated SI log out (rimu's recording
file; :meth:`rimu.calibration.Calibration.apply`: each triad's scale, misalignment and bias, its vector in the
calibration's body frame, rad/s and m/s^2).

A calibration made from raw counts (``raw_unit`` count, as ``rimu detect`` + ``rimu calibrate`` of a text log
make it) applies to a text log read as counts, the way ``rimu detect`` reads it; a calibration of SI outputs
(``rimu setup``) to any log rimu reads, on the first IMU's time base. Counts are never taken as SI: a binary log
(read in SI) with a calibration of counts is refused.
"""

from __future__ import annotations

import argparse

from ._common import add_accept_implausible, add_json_option
from ._inputs import add_log_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("apply", help="apply a calibration to a raw log: calibrated SI recording out",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="raw log (any format rimu import reads)")
    p.add_argument("--calibration", required=True, help="calibration file")
    p.add_argument("-o", "--output", required=True, help="calibrated recording to write (.npz)")
    add_json_option(p, "samples and mean rate per output triad")
    add_log_options(p)
    add_accept_implausible(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..calibration import Calibration
    from ..errors import NotApplicableError
    from ..io.formats import find_format
    from ..io.formats.rimu_recording import save_recording
    from ..io.multiimu import ImuStream, MultiImuRecording
    from ._common import json_dump
    from ._inputs import log_options, open_raw, open_recording

    cal = Calibration.load(args.calibration)
    insts = list(cal.instruments)
    counts = str(cal.raw_unit).lower() not in ("si", "rad/s", "m/s^2")
    fmt = log_options(args).get("format") or find_format(args.log)
    if counts:
        if fmt not in ("text", "mpu6050"):
            raise NotApplicableError(f"{args.calibration} is a calibration of raw {cal.raw_unit}s and {args.log} is a "
                                     f"{fmt} log read in SI; apply it to the raw text log it was made for, or "
                                     "calibrate the SI data (rimu setup)")
        log = open_raw(args.log, None, None, None, None)
        t, raw = log.t, {k: log.raw[k] for k in insts if k in log.raw}
    else:
        rec = open_recording(args.log, args, "warn" if args.accept_implausible else "strict")
        b = rec.to_block()
        ok = np.all([b.valid[k].all(axis=1) for k in insts if k in b.valid], axis=0)
        t, raw = b.t[ok], {k: b.raw[k][ok] for k in insts if k in b.raw}
    out = cal.apply(raw)
    geo = cal[insts[0]].geometry
    subs = geo.subunits if all(len(s.members) == 3 for s in geo.subunits) and geo.subunits else []
    names = [s.name for s in subs] if subs and out[insts[0]].shape[1] == 3 * len(subs) else ["unit"]
    units = [ImuStream(n, t, *(out[k][:, 3 * j:3 * j + 3] if k in out else None for k in ("gyro", "accel")))
             for j, n in enumerate(names)]
    rec_out = MultiImuRecording(units, {"format": "rimu", "source": str(args.log), "calibration": str(args.calibration),
                                        "units_from": {"gyro": "calibration (rad/s)", "accel": "calibration (m/s^2)"}})
    path = save_recording(rec_out, args.output)
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float("nan")
    from ..units import field_unit, fmt

    def mean3(k: str, v: np.ndarray) -> str:  # one field unit for the three axes (rimu.units.fmt)
        unit = field_unit(k, float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else None)[0]
        return f"{k} mean [{', '.join(fmt(x, k, unit).rsplit(' ', 1)[0] for x in v)}] {unit}"

    for u in units:
        means = ", ".join(mean3(k, np.nanmean(getattr(u, k), axis=0)) for k in ("gyro", "accel")
                          if getattr(u, k) is not None)
        print(f"{u.name}: {len(u)} samples at {rate:.4g} Hz; {means}")
    print(f"calibrated recording written to {path}")
    if args.json:
        doc = {"output": str(path), "triads": [{"name": u.name, "samples": len(u), "mean_rate_hz": rate} for u in units]}
        print(f"summary written to {json_dump(doc, args.json)}")
    return 0
