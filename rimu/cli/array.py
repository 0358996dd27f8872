"""``rimu array DATA.npz``: an array of k triads as one instrument: relative gyro calibration from the motion
(gain, bias, sampling offset), the accelerometers' positions, gains and biases, the parity rms in motion after
each step per triad, and the term that limits the agreement now (docs/array.md).

DATA.npz holds ``t`` (N,) [s], ``gyro`` (N, k, 3) [rad/s] and optionally ``accel`` (N, k, 3) [m/s^2], each
triad in its own axes; optionally ``rotations`` (k, 3, 3) (triad axes -> body, default identity),
``positions_m`` (k, 3) nominal positions, and ``names`` (k,).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ._common import positive_float
from ._inputs import add_log_options, open_array


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("array", help="self-calibration of an array of triads from motion, with its report",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="NPZ file with t, gyro[, accel, rotations, positions_m, names], or a multi-IMU log")
    p.add_argument("-o", "--output", default=None, help="JSON file for the fitted parameters (SI, body frame)")
    p.add_argument("--report", default=None, metavar="DIR", help="folder for array_report.md and array_report.png")
    p.add_argument("--json", default=None, metavar="FILE", help="machine-readable summary")
    p.add_argument("--lowpass-hz", type=positive_float, default=None, help="low-pass every triad first (vehicles)")
    p.add_argument("--motion-threshold-deg-s", type=positive_float, default=30.0,
                   help="samples faster than this count as 'in motion' for the parity figures")
    add_log_options(p)
    p.set_defaults(func=run)


def _load(path: str):
    from ..array import ArrayLayout
    from ..errors import ShapeError
    from ..io.guard import load_array

    d = load_array(path, "NPZ file")
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
    _plausible(path, gyro, accel)
    return ArrayLayout(rot, pos, names), np.asarray(d["t"], dtype=float), gyro, accel


#: no MEMS gyro measures beyond +-4000 deg/s, no accelerometer of an array beyond +-400 g
_GYRO_MAX_RAD_S = 4000.0 * np.pi / 180.0
_ACCEL_MAX_MS2 = 400 * 9.80665


def _plausible(path: str, gyro: np.ndarray, accel: np.ndarray | None) -> None:
    """Units: rates beyond any MEMS gyro's range are deg/s under the rad/s label (or counts); accelerations
    likewise."""
    from ..errors import PlausibilityError

    for name, y, top, unit, likely in (("gyro", gyro, _GYRO_MAX_RAD_S, "rad/s", "deg/s or counts"),
                                       ("accel", accel, _ACCEL_MAX_MS2, "m/s^2", "counts")):
        if y is None:
            continue
        peak = float(np.nanmax(np.abs(y))) if np.isfinite(y).any() else 0.0
        if peak > top:
            raise PlausibilityError(f"{path}: {name} reaches {peak:.4g} {unit}, beyond the range of any MEMS "
                                    f"{name} ({top:.4g} {unit}): the values look like {likely}; convert them to "
                                    f"{unit}")


def _check_options(args: argparse.Namespace, t: np.ndarray, gyro: np.ndarray) -> None:
    """--lowpass-hz below the Nyquist frequency of the data; --motion-threshold-deg-s below the rates reached."""
    from ..errors import OptionError, ShapeError

    if len(t) < 10 or not np.all(np.diff(t) > 0):
        raise ShapeError(f"{args.data}: t must hold at least 10 increasing times, s")
    fs = 1.0 / float(np.median(np.diff(t)))
    if args.lowpass_hz is not None and args.lowpass_hz >= fs / 2:
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
    from ..atomic import write_text
    from ..errors import RimuError
    from ._common import json_dump

    try:
        layout, t, gyro, accel = open_array(args.data, args) or _load(args.data)
        _check_options(args, t, gyro)
        rep = array_report(layout, t, gyro, accel, motion_threshold_deg_s=args.motion_threshold_deg_s,
                           lowpass_hz=args.lowpass_hz)
    except RimuError as exc:
        where = "" if str(args.data) in str(exc) else f"{args.data}: "
        print(f"rimu array: error: {where}{exc}", file=sys.stderr)
        return 2
    if args.output:
        doc = {"gyro": rep.gyro_fit.to_dict() if rep.gyro_fit else None,
               "accel": rep.position_fit.to_dict() if rep.position_fit else None}
        write_text(args.output, json.dumps(doc, indent=1))
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "array_report.md", rep.to_markdown())
        try:
            rep.plot(out / "array_report.png")
        except ImportError as exc:
            print(f"rimu array: no plot: {exc}", file=sys.stderr)
    if args.json:
        json_dump(rep.to_dict(), args.json)
    g = list(rep.gyro_steps.values())
    line = (f"array of {layout.k} triads: gyro parity rms in motion {g[0].mean():.4g} -> {g[-1].mean():.4g} deg/s")
    if rep.accel_steps:
        a = list(rep.accel_steps.values())
        line += f", accelerometers {a[0].mean():.4g} -> {a[-1].mean():.4g} m/s^2"
    print(line + f"; limited now by {rep.limiting_term}")
    return 0
