"""``rimu diagnose``: compare an error model with a calibration session, find the missing effect, add it,
and write a report.

SESSION is one of: a Ferraris-style recording folder (the CSV and its section list, as imucal's example),
or a rimu session file (``.csv`` + ``.json`` sidecar, or ``.npz``; ``docs/session-format.md``), as
``rimu simulate`` writes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ._common import add_accept_implausible, add_json_option, add_report_option, finite_float, probability
from ._inputs import add_log_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="residual diagnostics: which effect is missing from the error model",
                       description="Fit an error model to a calibration session, describe the residual, test every "
                                   "effect of the library that is not in the model, and refit with the ones you add.")
    p.add_argument("session", help="Ferraris recording folder, or a rimu session file (.csv/.json/.npz)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calibration", help="calibration JSON: its effects define the model, its noise sigma the noise level")
    g.add_argument("--model", default="bias,scale,misalignment", help="comma list of effect names (default: %(default)s)")
    p.add_argument("--add", nargs="+", default=[], metavar="EFFECT", help="effects to add and refit (before/after)")
    p.add_argument("--iterate", action="store_true", help="add the top missing effect and refit until nothing is missing")
    p.add_argument("--instrument", choices=["gyro", "accel"], action="append", help="restrict to an instrument (repeatable)")
    p.add_argument("--alpha", type=probability, default=0.01, help="family-wise significance (default: %(default)s)")
    p.add_argument("--no-earth-rate", action="store_true", help="leave the Earth rate out of the gyro input (tests earth_rate)")
    p.add_argument("--reference-temperature", type=finite_float, default=25.0, help="T_ref of temperature effects, degC")
    add_report_option(p, "report.md, report.html, figures and diagnosis.json")
    add_json_option(p, "the diagnosis ('-': on stdout instead of the text)", allow_bare=True)
    p.add_argument("--list-effects", action="store_true", help="list the effects of the library and exit")
    add_accept_implausible(p)
    add_log_options(p)
    p.set_defaults(func=run)


def load_session(path: str | Path, checks: str = "strict", args: Any = None):
    """A Session from a Ferraris recording folder, or a rimu session file (``.csv`` with its ``.json``
    sidecar, the sidecar itself, or ``.npz``; see ``docs/session-format.md``)."""
    from ._inputs import open_session

    return open_session(path, checks, args=args)


def run(args: argparse.Namespace) -> int:
    from ..calibration.model import EFFECTS, ErrorModel
    from ..diagnose import diagnose, iterate, write_report

    if args.list_effects:
        from ..calibration import effects as _  # noqa: F401

        for name, cls in sorted(EFFECTS.items()):
            if name == cls.name:
                print(f"{name:20s} {'/'.join(cls.instruments):11s} {cls.description}")
        return 0
    session = load_session(args.session, "warn" if args.accept_implausible else "strict", args)
    sigma = None
    if args.calibration:
        from ..calibration import Calibration

        cal = Calibration.load(args.calibration, session.geometries)
        model = {}
        sigma = {}
        for k in cal.instruments:
            names = ["bias", "scale_misalignment"] + list(cal[k].effects)
            model[k] = ErrorModel.from_names(names)
            if cal[k].noise_sigma is not None:
                sigma[k] = cal[k].noise_sigma / cal[k].scale
    else:
        model = ErrorModel.from_names(args.model)
    kw = dict(instruments=args.instrument, alpha=args.alpha, include_earth_rate=not args.no_earth_rate,
              reference_temperature=args.reference_temperature, sigma=sigma)
    comparisons = []
    if args.iterate:
        result = iterate(session, model, **kw)
        text = result.summary()
        data = {"rounds": [{"diagnosis": d.to_dict(), "comparisons": [c.to_dict() for c in cs.values()]}
                           for d, cs in result.rounds], "final": result.final.to_dict()}
        target = result
    else:
        d = diagnose(session, model, **kw)
        if args.add:
            comparisons = list(d.add(*args.add).values())
            if not comparisons:
                print(f"rimu diagnose: none of {args.add} applies to the instruments diagnosed or all are in the model",
                      file=sys.stderr)
        text = d.summary() + "".join("\n" + "\n".join(c.lines()) for c in comparisons)
        data = {"diagnosis": d.to_dict(), "comparisons": [c.to_dict() for c in comparisons]}
        target = d
    if args.json == "-":
        print(json.dumps(data, default=float))
    else:
        print(text)
        if args.json:
            from ._common import json_dump

            print(f"diagnosis JSON: {json_dump(data, args.json)}")
    if args.report:
        md = write_report(target, args.report, comparisons)
        print(f"report: {md}", file=sys.stderr if args.json == "-" else sys.stdout)
    return 0
