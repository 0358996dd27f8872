"""``rimu calibrate``: calibrate a session file with one of the papers' estimators and write the calibration file."""

from __future__ import annotations

import argparse
from pathlib import Path

METHODS = ("cho", "oliveira", "zhang", "lsq", "handheld")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="estimate scale factor, misalignment and bias from a session file",
                       description="Calibrate a session (rimu session format: .csv + .json sidecar, or .npz; "
                                   "see docs/session-format.md) and print a coefficient table with uncertainties.")
    p.add_argument("session", help="session file (.csv, .json sidecar, or .npz)")
    p.add_argument("--method", choices=METHODS, default="cho",
                   help="cho: Cho & Park 2005; oliveira: de Oliveira et al. 2012 (tetrad); zhang: Zhang et al. "
                        "2010 (triads, no attitude needed); lsq: generic least squares on the effect model; handheld: "
                        "poses of unknown attitude and hand rotations between them (rimu detect's sessions)")
    p.add_argument("--effects", default=None, help="lsq only: comma-separated effects (default scale,bias)")
    p.add_argument("--instruments", default=None, help="comma-separated subset of gyro,accel")
    p.add_argument("--wavelet", action="store_true", help="oliveira only: db4/8-level wavelet denoising")
    p.add_argument("-o", "--output", default="calibration.json", help="calibration file to write")
    p.add_argument("--plot", default=None, help="write a residual plot per segment (PNG)")
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
    if method == "handheld":
        from ..calibration.handheld import HandHeld

        return HandHeld(instruments=instruments)
    model = ErrorModel.from_names(effects) if effects else None
    return LeastSquares(model=model, instruments=instruments)


def run(args: argparse.Namespace) -> int:
    from ..session import load_session

    session = load_session(args.session)
    inst = args.instruments.split(",") if args.instruments else None
    res = estimator(args.method, inst, args.effects, args.wavelet).fit(session)
    print(res.table())
    out = res.to_calibration().save(Path(args.output))
    print(f"\ncalibration written to {out}")
    if args.plot:
        from ..calibration.plots import plot_residuals

        plot_residuals(res, path=args.plot)
        print(f"residual plot written to {args.plot}")
    return 0
