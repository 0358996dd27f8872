"""``rimu check SESSION --calibration cal.json``: parity-based calibration quality (de Oliveira 2012, Eq. 21-25).

For every pair of rate sequences with opposite commanded rates, the mean parity vector of the commanded-rate
part with the nominal and with the calibrated geometry; a quality index per direction of excitation and an
overall verdict, without a reference. Prints a table, and writes a plot and a JSON report with ``--out``.

SESSION is, until the calibration session file format lands, the NPZ written by ``rimu simulate``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="parity-based calibration quality check of a calibration on its session",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", help="session file (NPZ from 'rimu simulate')")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--instrument", default=None, help="gyro or accel (default: every one with 4+ sensors)")
    p.add_argument("--p-fa", type=float, default=1e-3, help="false-alarm probability of the whole check")
    p.add_argument("--noise", type=float, default=None, help="per-sample noise (SI) if the calibration has none")
    p.add_argument("--out", default=None, help="folder for the plot and the JSON report")
    p.set_defaults(func=run)


def read_simulated_npz(path: str | Path) -> tuple[Any, Any]:
    """(Session, EpochBlock) from the NPZ of ``rimu simulate``. Small and isolated on purpose: it goes when the
    session file format of the calibration work lands."""
    from ..epoch import EpochBlock
    from ..errors import SessionFormatError
    from ..geometry import Geometry
    from ..session import Segment, Session

    try:
        z = np.load(path, allow_pickle=False)
        meta = json.loads(str(z["meta"]))
        t, seg = z["t"], z["segment"]
        raw = {k[4:]: z[k] for k in z.files if k.startswith("raw_")}
    except (OSError, KeyError, ValueError) as exc:
        raise SessionFormatError(f"{path} is not a session NPZ written by 'rimu simulate' ({exc})") from exc
    geos = {k: Geometry.from_dict(d) for k, d in meta["geometries"].items()}
    segments = []
    for i, sm in enumerate(meta["segments"]):
        m = seg == i
        kw = {"specific_force_mb": sm.get("specific_force_mb_ms2"), "rate_mb": sm.get("rate_mb_rads"),
              "angle_mb": sm.get("angle_mb_rad"), "mat_ln_mb": sm.get("mat_ln_mb")}
        segments.append(Segment(sm["label"], sm["kind"], t[m], {k: v[m] for k, v in raw.items()},
                                **{k: (None if v is None else np.asarray(v)) for k, v in kw.items()}))
    session = Session(segments, geos, float(meta["sample_rate_hz"]), meta.get("latitude_rad"),
                      raw_unit=meta.get("raw_unit", "count"), meta={"simulator": meta.get("simulator")})
    return session, EpochBlock(t, dict(raw))


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..fdi.quality import parity_quality

    session, _ = read_simulated_npz(args.session)
    cal = Calibration.load(args.calibration, geometries=session.geometries)
    insts = [args.instrument] if args.instrument else [k for k in cal.instruments
                                                      if k in session.geometries and cal[k].geometry.n >= 4]
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    doc, ok = {}, True
    for k in insts:
        c = cal[k]
        if c.noise_sigma is None:
            if args.noise is None:
                from ..errors import CalibrationFileError

                raise CalibrationFileError(f"the {k} calibration states no noise; pass --noise SIGMA (SI per sample)")
            c.noise_sigma = np.full(c.geometry.n, float(args.noise))
        rep = parity_quality(session, c, args.p_fa)
        print(rep.summary())
        print()
        doc[k] = rep.to_dict()
        ok &= rep.good
        if out:
            png = rep.plot(out / f"check-{k}.png")
            if png:
                print(f"  plot: {png}")
    if out:
        (out / "check.json").write_text(json.dumps(doc, indent=1))
        print(f"  report: {out / 'check.json'}")
    return 0 if ok else 3
