"""``rimu calibrate``: calibrate a session file with one of the papers' estimators and write the calibration file."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import Deprecated, add_accept_implausible, add_json_option, add_report_option

METHODS = ("cho", "oliveira", "zhang", "lsq")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="estimate scale factor, misalignment and bias from a session file",
                       description="Calibrate a session (rimu session format: .csv + .json sidecar, or .npz; "
                                   "see docs/session-format.md) and print a coefficient table with uncertainties.")
    p.add_argument("session", help="session file (.csv, .json sidecar, or .npz)")
    p.add_argument("--method", choices=METHODS, default="cho",
                   help="cho: Cho & Park 2005; oliveira: de Oliveira et al. 2012 (tetrad); zhang: Zhang et al. "
                        "2010 (triads, no attitude needed); lsq: generic least squares on the effect model")
    p.add_argument("--effects", default=None, help="lsq only: comma-separated effects (default scale,bias)")
    p.add_argument("--instruments", default=None, help="comma-separated subset of gyro,accel")
    p.add_argument("--wavelet", action="store_true", help="oliveira only: db4/8-level wavelet denoising")
    p.add_argument("-o", "--output", default="calibration.json", help="calibration file to write")
    add_report_option(p, "the residual plot per segment (residuals.png)")
    add_json_option(p, "the coefficients, their standard deviations (SI) and chi2/dof")
    p.add_argument("--plot", action=Deprecated, new="--report DIR (writes DIR/residuals.png)", metavar="PNG")
    add_accept_implausible(p)
    p.set_defaults(func=run)


def estimator(method: str, instruments=None, effects: str | None = None, wavelet: bool = False):
    """The estimator object of a method name."""
    from ..calibration import ChoPark, LeastSquares, Oliveira, Zhang
    from ..calibration.model import ErrorModel

    if method == "cho":
        return ChoPark(instruments=instruments)
    if method == "oliveira":
        return Oliveira(wavelet=wavelet)
    if method == "zhang":
        return Zhang()
    model = ErrorModel.from_names(effects) if effects else None
    return LeastSquares(model=model, instruments=instruments)


def _instruments(text: str | None, session) -> list[str] | None:
    from ..errors import OptionError

    if not text:
        return None
    inst = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in inst if k not in session.instruments]
    if unknown or not inst:
        raise OptionError(f"--instruments {text}: {unknown or 'empty'} not in this session; it has "
                          f"{','.join(session.instruments)}")
    return inst


def run(args: argparse.Namespace) -> int:
    from ..errors import OptionError
    from ..session import load_session

    if args.effects and args.method != "lsq":
        raise OptionError(f"--effects applies to --method lsq only, not {args.method}")
    if args.wavelet and args.method != "oliveira":
        raise OptionError(f"--wavelet applies to --method oliveira only, not {args.method}")
    session = load_session(args.session, checks="warn" if args.accept_implausible else "strict")
    inst = _instruments(args.instruments, session)
    res = estimator(args.method, inst, args.effects, args.wavelet).fit(session)
    print(res.table())
    out = res.to_calibration().save(Path(args.output))
    print(f"\ncalibration written to {out}")
    if args.json:
        from ._common import json_dump

        doc = {"method": res.method, "session": str(args.session), "calibration": str(out),
               "chi2_dof": res.chi2_dof, "notes": list(res.notes),
               "instruments": {k: {"values_si": res.values(k), "std_si": res.std(k)} for k in res.instruments}}
        print(f"summary written to {json_dump(doc, args.json)}")
    png = Path(args.plot) if args.plot else (Path(args.report) / "residuals.png" if args.report else None)
    if png is not None:
        from ..calibration.plots import plot_residuals

        png.parent.mkdir(parents=True, exist_ok=True)
        plot_residuals(res, path=png)
        print(f"residual plot written to {png}")
    return 0
