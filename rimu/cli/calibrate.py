"""``rimu calibrate``: calibrate a session file with one of the papers' estimators and write the calibration file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ._common import Deprecated, add_accept_implausible, add_json_option, add_report_option
from ._inputs import add_log_options, open_session

METHODS = ("cho", "oliveira", "zhang", "lsq", "handheld")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="estimate scale factor, misalignment and bias from a session file",
                       description="Calibrate a session (rimu session format: .csv + .json sidecar, or .npz; "
                                   "see docs/session-format.md) and print a coefficient table with uncertainties.")
    p.add_argument("session", help="session file (.csv, .json sidecar, or .npz), Ferraris folder, or a log")
    p.add_argument("--method", choices=METHODS, default="cho",
                   help="cho: Cho & Park 2005; oliveira: de Oliveira et al. 2012 (tetrad); zhang: Zhang et al. "
                        "2010 (triads, no attitude needed); lsq: generic least squares on the effect model; handheld: "
                        "poses of unknown attitude and hand rotations between them (rimu detect's sessions)")
    p.add_argument("--effects", default=None, help="lsq only: comma-separated effects (default scale,bias)")
    p.add_argument("--keep-worse-effects", action="store_true",
                   help="lsq only: apply every effect of --effects even when it raises the residual on held-out "
                        "segments (by default such an effect is not applied and the output says why)")
    p.add_argument("--instruments", default=None, help="comma-separated subset of gyro,accel")
    p.add_argument("--wavelet", action="store_true", help="oliveira only: db4/8-level wavelet denoising")
    p.add_argument("-o", "--output", default="calibration.json", help="calibration file to write")
    add_report_option(p, "the calibration report (calibration.html, calibration.pdf) and residuals.png")
    p.add_argument("--reference", default=None, metavar="CAL",
                   help="a calibration of the same unit to compare with in the report (e.g. the maker's)")
    add_json_option(p, "the coefficients, their standard deviations (SI) and chi2/dof")
    p.add_argument("--plot", action=Deprecated, new="--report DIR (writes DIR/residuals.png)", metavar="PNG")
    add_accept_implausible(p)
    add_log_options(p)
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


def bias_at_zero_input(res) -> dict[str, dict[str, tuple[float, float]]]:  # type: ignore[no-untyped-def]
    """Per instrument and sensor: (std of the compensated output at zero input, marginal std of B), SI.

    The calibration stores ``B = SF * c`` (c: the raw offset, Cho & Park Eq. 20 ``SF y - B``), so the marginal
    std of B carries the scale-factor uncertainty times the raw offset, and B and SF are strongly correlated. What
    the compensated output gets wrong at rest is ``d(SF y - B)`` at ``y = B / SF``:
    ``var = (B/SF)^2 var(SF) + var(B) - 2 (B/SF) cov(SF, B)``; the prediction of ``rimu design`` (Cho & Park
    Eq. 19) is this figure.
    """
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for k, r in res.instruments.items():
        for sf in r.sensors:
            names = list(sf.theta_names)
            try:
                i, j = names.index(f"{sf.name}.scale"), names.index(f"{sf.name}.bias")
            except ValueError:
                continue
            S, B = float(sf.theta[i]), float(sf.theta[j])
            C = np.asarray(sf.theta_cov)
            c = B / S
            var = c * c * C[i, i] + C[j, j] - 2 * c * C[i, j]
            out.setdefault(k, {})[sf.name] = (float(np.sqrt(max(var, 0.0))), float(np.sqrt(max(C[j, j], 0.0))))
    return out


def _print_bias_note(zero: dict, res=None) -> None:  # type: ignore[no-untyped-def]
    for line in _bias_note_lines(zero, res):
        print(line)


def _bias_note_lines(zero: dict, res=None) -> list[str]:  # type: ignore[no-untyped-def]
    """The note on the bias std at zero input, in the unit of the bias column of ``res``'s table (the one the
    largest bias calls for: deg/h for a tactical gyro, deg/s for a MEMS one)."""
    from ..calibration.estimate import bias_magnitudes
    from ..units import field_unit

    out = []
    for k, per in zero.items():
        mag = bias_magnitudes(res.instruments[k]) if res is not None and k in res.instruments else {}
        m = mag.get("deg/h" if k == "gyro" else "ug", max((z for z, _ in per.values()), default=0.0))
        u, f = field_unit(k, m) if k in ("gyro", "accel") else ("SI", 1.0)
        ratio = max(m / z for z, m in per.values() if z > 0) if per else 1.0
        if ratio < 1.5:
            continue
        row = ", ".join(f"{n} {z * f:.3g}" for n, (z, _) in per.items())
        out.append(f"note: {k} bias std at zero input (the error of SF*y - B at rest; what 'rimu design' predicts, Cho & Park"
              f" Eq. 19), {u}: {row}. The bias column above is the marginal std of B = SF x raw offset, up to "
              f"{ratio:.3g} times larger: it also carries the scale-factor uncertainty times the raw offset, which "
              "the correlation of B with SF cancels in the compensated output")
    return out


def _held_out_effects(session, effects: str | None, instruments, keep_worse: bool = False
                      ) -> tuple[dict[str, list[str]], list[str]]:  # type: ignore[no-untyped-def]
    """lsq with effects beyond scale, misalignment and bias: each added effect (in the order given) compared with the
    model without it on held-out segments (fitted on every other segment, checked on the rest;
    rimu.diagnose.Comparison.held_out). Returns the effects not applied per instrument (those that raise the
    held-out residual; none with ``keep_worse``) and the lines that say so, with the figures."""
    from ..calibration.model import ErrorModel
    from ..diagnose.api import compare
    from ..diagnose.fitting import fit_model
    from ..errors import IdentifiabilityError

    if not effects:
        return {}, []
    model = ErrorModel.from_names(effects)
    base_names = [e.name for e in model if e.name in ("bias", "scale_misalignment")]
    extra_effects = [e for e in model if e.name not in base_names]
    if not extra_effects or set(base_names) != {"bias", "scale_misalignment"}:
        return {}, []
    how = "the residual on held-out segments (fitted on every other segment, checked on the rest)"
    dropped: dict[str, list[str]] = {}
    out = []
    for k in instruments or session.instruments:
        kept = list(base_names)
        try:
            before = fit_model(session, ErrorModel.from_names(",".join(kept)), k)
        except (IdentifiabilityError, ValueError):
            continue
        for e in extra_effects:
            if not any(e.applies_to(ctx) for ctx in before.contexts):
                continue
            try:
                c = compare(session, before, ErrorModel.from_names(",".join([*kept, e.name])))
            except (IdentifiabilityError, ValueError):
                continue
            h = c.held_out()
            if h is None:
                out.append(f"note: {k}: the effect {e.name} could not be checked on held-out segments (half of the "
                           "segments cannot identify the model); applied")
                kept.append(e.name)
                before = c.after
                continue
            b, a = float(h[1].mean()), float(h[2].mean())
            line = f"{k}: adding {e.name} takes {how} {b:.4g} -> {a:.4g} {h[0]} (mean over the sensors)"
            if not c.worse_held_out():
                out.append(f"note: {line}; applied")
                kept.append(e.name)
                before = c.after
            elif keep_worse:
                out.append(f"caution: {line}; applied as asked (--keep-worse-effects): it fits these segments, "
                           "not the instrument")
                kept.append(e.name)
                before = c.after
            else:
                dropped.setdefault(k, []).append(e.name)
                out.append(f"caution: {line}; not applied (the fit without it is kept): it fits these segments, "
                           f"not the instrument; --keep-worse-effects applies it anyway")
    return dropped, out


def _fit_lsq(session, effects: str, inst, dropped: dict[str, list[str]]):  # type: ignore[no-untyped-def]
    """The lsq fit with the effects of ``dropped`` left out of their instrument's model (one fit per instrument
    whose model differs from the one asked for)."""
    from ..calibration import LeastSquares
    from ..calibration.estimate import CalibrationResult
    from ..calibration.model import ErrorModel

    names = [e.name for e in ErrorModel.from_names(effects)]
    parts = []
    for k in inst or session.instruments:
        model = ErrorModel.from_names(",".join(n for n in names if n not in dropped.get(k, [])))
        parts.append((k, model, LeastSquares(model=model, instruments=[k]).fit(session)))
    method = (f"least squares ({ErrorModel.from_names(effects).label}; "
              + "; ".join(f"{k} without {', '.join(v)}" for k, v in dropped.items()) + ": raised the held-out residual)")
    return CalibrationResult(method, {k: r.instruments[k] for k, _, r in parts}, session.raw_unit,
                             [n for _, _, r in parts for n in r.notes],
                             {"effects_not_applied": {k: list(v) for k, v in dropped.items()}})


def run(args: argparse.Namespace) -> int:
    from ..errors import OptionError
    if args.effects and args.method != "lsq":
        raise OptionError(f"--effects applies to --method lsq only, not {args.method}")
    if args.keep_worse_effects and (args.method != "lsq" or not args.effects):
        raise OptionError("--keep-worse-effects applies to --method lsq with --effects only")
    if args.wavelet and args.method != "oliveira":
        raise OptionError(f"--wavelet applies to --method oliveira only, not {args.method}")
    session = open_session(args.session, "warn" if args.accept_implausible else "strict", args=args)
    inst = _instruments(args.instruments, session)
    ref = None
    if args.reference:  # read before any work: a bad reference writes nothing
        from ..calibration import Calibration

        ref = Calibration.load(args.reference, session.geometries)
    dropped, held = ({}, [])
    if args.method == "lsq":
        dropped, held = _held_out_effects(session, args.effects, inst, args.keep_worse_effects)
    if dropped:
        res = _fit_lsq(session, args.effects, inst, dropped)
    else:
        res = estimator(args.method, inst, args.effects, args.wavelet).fit(session)
    print(res.table())
    zero = bias_at_zero_input(res)
    _print_bias_note(zero, res)
    for line in held:
        print(line)
    res.notes.extend(line.split(": ", 1)[1] for line in held)  # the result's notes (JSON, report) say it too
    out = res.to_calibration().save(Path(args.output))
    print(f"\ncalibration written to {out}")
    if args.json:
        from ._common import json_dump

        doc = {"method": res.method, "session": str(args.session), "calibration": str(out),
               "chi2_dof": res.chi2_dof, "notes": list(res.notes),
               "instruments": {k: {"values_si": res.values(k), "std_si": res.std(k),
                                   "bias_std_at_zero_input_si": {n: z for n, (z, _) in zero.get(k, {}).items()}}
                               for k in res.instruments}}
        print(f"summary written to {json_dump(doc, args.json)}")
    if args.report:
        from ..calibration.report import calibration_report

        rep = calibration_report(res, session, ref, cautions=_bias_note_lines(zero, res))  # held: in the notes
        Path(args.report).mkdir(parents=True, exist_ok=True)
        if not args.plot and rep.save_figure(0, Path(args.report) / "residuals.png"):
            print(f"residual plot written to {Path(args.report) / 'residuals.png'}")
        html, pdf = rep.write(args.report, "calibration")
        print(f"calibration report written to {html} and {pdf}")
    png = Path(args.plot) if args.plot else None
    if png is not None:
        from ..calibration.plots import plot_residuals

        png.parent.mkdir(parents=True, exist_ok=True)
        plot_residuals(res, path=png)
        print(f"residual plot written to {png}")
    return 0
