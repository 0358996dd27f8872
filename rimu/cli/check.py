"""``rimu check SESSION --calibration cal.json``: parity-based calibration quality (de Oliveira 2012, Eq. 21-25).

For every pair of rate sequences with opposite commanded rates, the mean parity vector of the commanded-rate
part with the nominal and with the calibrated geometry; a quality index per direction of excitation and an
overall verdict, without a reference. Accelerometers see the same gravity in both sequences of a pair, so they
are checked at rest instead (rimu.experiments.static_quality: the parity of the compensated outputs of every static
segment). A triad has no parity space: the check says "not applicable" for it.

Prints a table per instrument; ``--report DIR`` writes the plots, ``--json FILE`` the figures. Exit status 0 when
every applicable check passes, 1 when one fails, 2 when none applies (a triad, no rate pairs, no segment at rest).

SESSION is a session file in rimu's format (docs/session-format.md): ``.npz``, or ``.csv`` with its ``.json``
sidecar, as written by ``rimu simulate`` or ``rimu.session.save_session``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ._common import (
    add_accept_implausible,
    add_json_option,
    add_old_out,
    add_report_option,
    positive_float,
    probability,
)
from ._inputs import add_log_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="parity-based calibration quality check of a calibration on its session",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", help="session file (.npz, or .csv/.json with sidecar; docs/session-format.md)")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--instrument", default=None, choices=["gyro", "accel"],
                   help="check only this instrument (default: every one the calibration and the session share)")
    p.add_argument("--p-fa", type=probability, default=1e-3, help="false-alarm probability of the whole check")
    p.add_argument("--noise", type=positive_float, default=None, help="per-sample noise (SI) if the calibration has none")
    add_report_option(p, "the plots (check-<instrument>.png)")
    add_json_option(p, "the figures of every check")
    add_old_out(p, "check")
    add_accept_implausible(p)
    add_log_options(p)
    p.set_defaults(func=run)


def read_session(path: str | Path, checks: str = "strict", args: Any = None) -> tuple[Any, Any]:
    """(Session, EpochBlock) of a session file in rimu's format (``.npz``, or ``.csv`` / ``.json`` with its
    sidecar; :func:`rimu.session.load_session`), the samples of every segment back to back."""
    from ..epoch import EpochBlock
    from ._inputs import open_session

    session = open_session(path, checks, args=args)
    segs = session.segments
    temps = [s.temperature for s in segs]
    block = EpochBlock(np.concatenate([s.t for s in segs]),
                       {k: np.vstack([s.raw[k] for s in segs]) for k in session.instruments},
                       temperature=None if any(x is None for x in temps) else np.concatenate(temps))
    return session, block


def _not_applicable(session: Any, cal: Any, k: str) -> str | None:
    """Why the check does not apply to instrument k, or None."""
    g = cal[k].geometry
    if g.n < 4:
        return (f"{k}: not applicable: {g.name} has {g.n} sensors, so there is no parity space (a parity check needs "
                "4 or more sensors; check a triad against a reference instead)")
    if k == "gyro":
        from ..calibration.parity_check import opposite_rate_pairs

        if not opposite_rate_pairs(session):
            return (f"{k}: not applicable: the session has no pair of consecutive rate segments with opposite "
                    "commanded rates (+w/-w, as Cho & Park Table 2 or de Oliveira Table 1)")
    elif not any(s.kind in ("static", "static_unknown") for s in session.segments):
        return f"{k}: not applicable: the session has no segment at rest (kind 'static' or 'static_unknown')"
    return None


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..errors import CalibrationFileError, OptionError
    from ..experiments.quality import parity_quality
    from ..experiments.static_quality import static_parity_quality

    session, _ = read_session(args.session, "warn" if args.accept_implausible else "strict", args)
    cal = Calibration.load(args.calibration, geometries=session.geometries)
    shared = [k for k in cal.instruments if k in session.geometries]
    if args.instrument:
        if args.instrument not in shared:
            raise OptionError(f"--instrument {args.instrument}: not in both the calibration ({', '.join(cal.instruments)})"
                              f" and the session ({', '.join(session.instruments)})")
        shared = [args.instrument]
    if not shared:
        raise CalibrationFileError(f"the calibration ({', '.join(cal.instruments)}) and the session "
                                   f"({', '.join(session.instruments)}) have no instrument in common")
    out = Path(args.report) if args.report else None
    doc: dict[str, Any] = {}
    ok, checked, skipped = True, [], []
    for k in shared:
        why = _not_applicable(session, cal, k)
        if why:
            skipped.append(why)
            doc[k] = {"instrument": k, "verdict": "not applicable", "reason": why}
            continue
        c = cal[k]
        if c.noise_sigma is None:
            if args.noise is None:
                raise CalibrationFileError(f"the {k} calibration states no noise; pass --noise SIGMA (SI per sample)")
            c.noise_sigma = np.full(c.geometry.n, float(args.noise))
        rep = parity_quality(session, c, args.p_fa) if k == "gyro" else static_parity_quality(session, c, args.p_fa)
        print(rep.summary())
        print()
        doc[k] = rep.to_dict()
        ok &= rep.good
        checked.append(k)
        if out:
            out.mkdir(parents=True, exist_ok=True)
            png = rep.plot(out / f"check-{k}.png")
            if png:
                print(f"  plot: {png}")
    if args.json:
        from ._common import json_dump

        print(f"  report: {json_dump(doc, args.json)}")
    if not checked:
        from ..errors import NotApplicableError

        raise NotApplicableError("nothing to check: " + "; ".join(skipped))
    for why in skipped:
        print(why)
    print(f"rimu check: {'GOOD' if ok else 'BAD'} ({', '.join(checked)} checked"
          + (f"; {len(skipped)} not applicable" if skipped else "") + ")")
    return 0 if ok else 1
