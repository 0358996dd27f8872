"""``rimu array DATA.npz``: an array of k triads as one instrument: relative gyro calibration from the motion
(gain, bias, sampling offset), the accelerometers' positions, gains and biases, the parity rms in motion after
each step per triad, and the term that limits the agreement now (docs/array.md). A step that raises the parity
rms is not applied and the output says so; the low-pass cut-off is chosen from the vibration spectrum.

DATA.npz holds ``t`` (N,) [s], ``gyro`` (N, k, 3) [rad/s, or --gyro-unit] and optionally ``accel`` (N, k, 3)
[m/s^2, or --accel-unit], each triad in its own axes (values far from these units are refused: rates beyond any
full scale, an accelerometer norm far from one gravity); optionally ``rotations`` (k, 3, 3) (triad axes -> body, default identity),
``positions_m`` (k, 3) nominal positions, and ``names`` (k,).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..units import DEG_TO_RAD
from ._common import add_accept_implausible, positive_float
from ._inputs import add_log_options, open_array


def _own_npz(path: str) -> bool:
    """Whether ``path`` is an NPZ of rimu array's own shape (``t`` and ``gyro`` arrays)."""
    if not str(path).endswith(".npz"):
        return False
    try:
        with np.load(path, allow_pickle=False) as z:
            return "t" in z.files and "gyro" in z.files
    except Exception:  # an .npz numpy cannot open: rimu array's own (guarded) reader says what is wrong with it
        return True


def _factor(instrument: str, unit: "str | None") -> float:
    """Factor to SI of a declared unit of the arrays: a name (deg/s, g, mg, ...) or SI per unit; SI when None."""
    from ..errors import OptionError
    from ..units import RAW_UNITS, raw_to_si

    if unit is None:
        return 1.0
    try:
        f = float(unit)
    except ValueError:
        f = raw_to_si(instrument, unit)  # type: ignore[assignment]
    if f is None or not np.isfinite(f) or f <= 0:
        names = ", ".join(RAW_UNITS[instrument])
        raise OptionError(f"--{instrument}-unit {unit}: not a unit of {instrument} outputs ({names}, or SI per unit)")
    return float(f)


def _lowpass(text: str) -> "float | str | None":
    if text.strip().lower() in ("auto", "none"):
        return None if text.strip().lower() == "none" else "auto"
    return positive_float(text)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("array", help="self-calibration of an array of triads from motion, with its report",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="NPZ file with t, gyro[, accel, rotations, positions_m, names], or a multi-IMU log")
    p.add_argument("-o", "--output", default=None, help="JSON file for the fitted parameters (SI, body frame)")
    p.add_argument("--report", default=None, metavar="DIR", help="folder for array_report.md and array_report.png")
    p.add_argument("--json", default=None, metavar="FILE", help="machine-readable summary")
    p.add_argument("--lowpass-hz", type=_lowpass, default="auto",
                   help="low-pass every triad first: a cut-off in Hz, 'auto' (default: chosen from the vibration "
                        "spectrum, where the triads stop agreeing) or 'none'")
    p.add_argument("--no-held-out", action="store_true",
                   help="do not check the gyro steps on a held-out part (the last 30 %%) of the recording")
    add_accept_implausible(p)
    p.add_argument("--motion-threshold-deg-s", type=positive_float, default=30.0,
                   help="samples faster than this count as 'in motion' for the parity figures")
    add_log_options(p)
    p.set_defaults(func=run)


def _load(path: str):
    from ..array import ArrayLayout
    from ..errors import ShapeError
    from ..io.guard import load_array

    d = load_array(path, "NPZ file")  # garbage, truncated, empty, pickled: one line naming the file
    if not isinstance(d, dict):
        raise ShapeError(f"{path}: a single array; array needs an NPZ file with t (N,) and gyro (N, k, 3) [rad/s]")
    missing = [k for k in ("t", "gyro") if k not in d]
    if missing:
        raise ShapeError(f"{path!r} lacks {', '.join(missing)}: it needs t (N,) and gyro (N, k, 3) [rad/s]")
    gyro = np.asarray(d["gyro"], dtype=float)
    if gyro.ndim != 3 or gyro.shape[2] != 3:
        raise ShapeError(f"{path}: gyro must have shape (N, k, 3), got {gyro.shape}")
    k = gyro.shape[1]
    rot = d["rotations"] if "rotations" in d else np.repeat(np.eye(3)[None], k, axis=0)
    pos = d["positions_m"] if "positions_m" in d else np.zeros((k, 3))
    names = tuple(str(x) for x in d["names"]) if "names" in d else ()
    accel = np.asarray(d["accel"], dtype=float) if "accel" in d else None
    return ArrayLayout(rot, pos, names), np.asarray(d["t"], dtype=float), gyro, accel


def _check_options(args: argparse.Namespace, t: np.ndarray, gyro: np.ndarray) -> None:
    """--lowpass-hz below the Nyquist frequency of the data; --motion-threshold-deg-s below the rates reached."""
    from ..errors import OptionError, ShapeError

    if len(t) < 10 or not np.all(np.diff(t) > 0):
        raise ShapeError(f"{args.data}: t must hold at least 10 increasing times, s")
    fs = 1.0 / float(np.median(np.diff(t)))
    if isinstance(args.lowpass_hz, float) and args.lowpass_hz >= fs / 2:
        raise OptionError(f"--lowpass-hz {args.lowpass_hz:g}: must be below the Nyquist frequency of "
                          f"{args.data} ({fs / 2:.4g} Hz)")
    rate = np.degrees(np.linalg.norm(np.nanmean(gyro, axis=1), axis=1))
    fast = int(np.sum(rate > args.motion_threshold_deg_s))
    if fast < 10:
        raise OptionError(f"--motion-threshold-deg-s {args.motion_threshold_deg_s:g}: only {fast} samples of "
                          f"{args.data} turn faster (peak {np.nanmax(rate):.4g} deg/s); give a threshold below the "
                          "peak rate")


def run(args: argparse.Namespace) -> int:
    from ..array import array_report
    from ..array.guards import check_units
    from ..errors import PlausibilityError, RimuError

    try:
        if _own_npz(args.data):  # rimu array's NPZ: its arrays in the units declared (--gyro-unit, --accel-unit; SI)
            layout, t, gyro, accel = _load(args.data)
            gyro = gyro * _factor("gyro", args.gyro_unit)
            accel = None if accel is None else accel * _factor("accel", args.accel_unit)
        else:  # a log: its reader converts to SI (the units options declare a text log's)
            layout, t, gyro, accel = open_array(args.data, args) or _load(args.data)
        _check_options(args, t, gyro)
        problems = check_units(gyro, accel)
        if problems and not args.accept_implausible:
            raise PlausibilityError(f"{args.data}: " + "; ".join(problems)
                                    + " (--accept-implausible to run anyway)")
        for p in problems:
            print(f"rimu array: warning: {p}", file=sys.stderr)
        rep = array_report(layout, t, gyro, accel, motion_threshold_deg_s=args.motion_threshold_deg_s,
                           lowpass_hz=args.lowpass_hz, held_out=not args.no_held_out)
    except RimuError as exc:
        where = "" if str(args.data) in str(exc) else f"{args.data}: "
        print(f"rimu array: error: {where}{exc}", file=sys.stderr)
        return 2
    if args.output:
        doc = {"gyro": rep.gyro_fit.to_dict() if rep.gyro_fit else None,
               "accel": rep.position_fit.to_dict() if rep.position_fit else None}
        Path(args.output).write_text(json.dumps(doc, indent=1))
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        (out / "array_report.md").write_text(rep.to_markdown())
        try:
            rep.plot(out / "array_report.png")
        except ImportError as exc:
            print(f"rimu array: no plot: {exc}", file=sys.stderr)
        else:  # the one report layout (HTML + PDF), as rimu calibrate and rimu diagnose write it
            from ..report import Report

            page = Report(f"rimu array: {layout.k} triads")
            page.cautions([f"note: {n}" for n in rep.notes] + [f"not applied: {r}" for r in rep.refused.values()])
            page.markdown(rep.to_markdown().split("\n", 1)[1].split("\n- ", 1)[0], out)
            page.figure(rep.figure(), "parity rms in motion per triad and step (the steps applied)")
            page.write(out, "array_report")
    if args.json:
        Path(args.json).write_text(json.dumps(rep.to_dict(), indent=1))
    from ..units import fmt

    g = list(rep.gyro_steps.values())
    line = (f"array of {layout.k} triads: gyro parity rms in motion {fmt(g[0].mean() * DEG_TO_RAD, 'rate', 'deg/s')} "
            f"-> {fmt(g[-1].mean() * DEG_TO_RAD, 'rate', 'deg/s')}")
    if rep.accel_steps:
        a = list(rep.accel_steps.values())
        line += f", accelerometers {fmt(a[0].mean(), 'specific_force', 'm/s^2')} -> {fmt(a[-1].mean(), 'specific_force', 'm/s^2')}"
    for n in rep.notes[:1] + [n for n in rep.notes[1:] if "not applied" in n or "angular acceleration" in n] + [
            f"not applied: {r}" for r in rep.refused.values()]:
        print(f"note: {n}")
    lim = rep.limiting_term
    print(line + (f"; what is left is {lim}" if lim.startswith("unexplained") else f"; limited now by {lim}")
          + ("" if rep.remainder is None else f"; remainder: {rep.remainder.verdict}"))
    return 0
