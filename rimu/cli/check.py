"""``rimu check SESSION --calibration cal.json``: parity-based calibration quality (de Oliveira 2012, Eq. 21-25).

For every pair of rate sequences with opposite commanded rates, the mean parity vector of the commanded-rate
part with the nominal and with the calibrated geometry; a quality index per direction of excitation and an
overall verdict, without a reference. Prints a table, and writes a plot and a JSON report with ``--out``.

SESSION is a session file in rimu's format (docs/session-format.md): ``.npz``, or ``.csv`` with its ``.json``
sidecar, as written by ``rimu simulate`` or ``rimu.session.save_session``.
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
    p.add_argument("session", help="session file (.npz, or .csv/.json with sidecar; docs/session-format.md)")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--instrument", default=None, help="gyro or accel (default: every one with 4+ sensors)")
    p.add_argument("--p-fa", type=float, default=1e-3, help="false-alarm probability of the whole check")
    p.add_argument("--noise", type=float, default=None, help="per-sample noise (SI) if the calibration has none")
    p.add_argument("--out", default=None, help="folder for the plot and the JSON report")
    p.set_defaults(func=run)


def read_session(path: str | Path) -> tuple[Any, Any]:
    """(Session, EpochBlock) of a session file in rimu's format (``.npz``, or ``.csv`` / ``.json`` with its
    sidecar; :func:`rimu.session.load_session`), the samples of every segment back to back."""
    from ..epoch import EpochBlock
    from ..session import load_session

    session = load_session(path)
    segs = session.segments
    temps = [s.temperature for s in segs]
    block = EpochBlock(np.concatenate([s.t for s in segs]),
                       {k: np.vstack([s.raw[k] for s in segs]) for k in session.instruments},
                       temperature=None if any(x is None for x in temps) else np.concatenate(temps))
    return session, block


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..fdi.quality import parity_quality

    session, _ = read_session(args.session)
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
