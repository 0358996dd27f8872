"""``rimu detect``: turn a raw hand-held recording (text or CSV: time and raw columns, no labels) into a session
of still poses and the motions between them, ready for ``rimu calibrate --method handheld``.

Thresholds adapt to the data (per axis, from the initial still period when there is one; the multiple of it
chosen as imu_tk does, see :func:`rimu.calibration.detect.detect_poses`); minimum durations are options. The
report (``--report DIR``) holds the signal with the detected poses and motions shaded.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ._common import bounded_float, nonnegative_float, positive_float
from ._inputs import add_log_options, open_raw


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("detect", help="find the still poses and motions of a raw hand-held recording",
                       description="Read a raw log (text/CSV: an optional 'name,value' metadata block, an optional "
                                   "header, a time or sample column and raw columns), detect still poses and the "
                                   "motions between them, and write a session file.")
    p.add_argument("raw", help="raw recording (.csv, .txt, ...)")
    p.add_argument("-o", "--output", required=True, help="session file to write (.csv with .json sidecar, or .npz)")
    p.add_argument("--rate", type=positive_float, default=None, help="sample rate, Hz (default: the file's 'Fs' row or its times)")
    p.add_argument("--accel", default=None, help="accelerometer columns: comma-separated names or 0-based indices")
    p.add_argument("--gyro", default=None, help="gyro columns: comma-separated names or 0-based indices")
    p.add_argument("--time", default=None, help="time (s) or sample-index column (name or index)")
    p.add_argument("--init-still", type=positive_float, default=None,
                   help="seconds of rest at the start, the noise floor of the thresholds (default: the file's "
                        "'Initialization time' row, else the quietest 10%% of the record)")
    p.add_argument("--window", type=positive_float, default=0.5, help="moving-variance window, s (default %(default)s)")
    p.add_argument("--factor", default="auto",
                   help="threshold as a multiple of the noise floor, or 'auto' (imu_tk's search; default)")
    p.add_argument("--min-static", type=positive_float, default=1.0, help="shortest pose kept, s (default %(default)s)")
    p.add_argument("--min-motion", type=positive_float, default=0.2,
                   help="shorter motions between two poses are bumps, merged into the pose, s (default %(default)s)")
    p.add_argument("--margin", type=nonnegative_float, default=None,
                   help="trimmed from both ends of each pose, s (default: window/2; less than half of --min-static)")
    p.add_argument("--gravity", type=bounded_float(9.76, 9.84, "m/s^2", "local gravity anywhere on Earth's surface"),
                   default=None, help="local gravity, m/s^2 (default 9.80665)")
    p.add_argument("--geometry", default=None, metavar="NAME|FILE.json",
                   help="the unit's geometry for both instruments when the file has more than three columns each: a "
                        "preset name (e.g. mimu4444, triads with k parallel triads as triads:K) or a geometry JSON "
                        "file (Geometry.to_dict); default: one triad")
    p.add_argument("--report", metavar="DIR", help="write detection.png and detection.md here")
    p.add_argument("--json", metavar="FILE", help="write a machine-readable summary here")
    p.add_argument("--imu", default=None, help="the IMU of a multi-IMU log to read (default: the first)")
    add_log_options(p)
    p.set_defaults(func=run)


def _cols(text: str | None):
    return None if text is None else [c.strip() for c in text.split(",") if c.strip()]


def geometry_option(text: str) -> object:
    """``NAME`` (a preset), ``triads:K`` (k parallel triads) or a geometry JSON file."""
    import json as _json

    from ..errors import GeometryError
    from ..geometry import Geometry, preset

    if text.endswith(".json"):
        try:
            return Geometry.from_dict(_json.loads(Path(text).read_text()))
        except (OSError, ValueError) as exc:
            raise GeometryError(f"cannot read the geometry file {text!r} ({exc})") from None
    name, _, k = text.partition(":")
    if k:
        if not k.isdigit() or int(k) < 1:
            raise GeometryError(f"--geometry {text!r}: give the number of triads as triads:K, K a positive integer")
        return preset(name, rotations=int(k))
    return preset(name)


def _factor(text: str) -> float | str:
    from ..errors import OptionError

    if text == "auto":
        return text
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (1.0 < v <= 1e6):
        raise OptionError(f"--factor {text}: give 'auto' or a multiple of the noise floor above 1 (at most 1e6)")
    return v


def _check_spans(args: argparse.Namespace, span: float) -> None:
    """The durations given as options against the record's length, s."""
    from ..errors import OptionError

    for opt, v, most in (("--window", args.window, span / 4), ("--min-static", args.min_static, span / 2),
                         ("--min-motion", args.min_motion, span / 2), ("--init-still", args.init_still, span / 2)):
        if v is not None and v > most:
            rate = f"--rate {args.rate:g} Hz" if args.rate else "the sample rate of the file"
            raise OptionError(f"{opt} {v:g} s: the record {args.raw} lasts {span:.4g} s at {rate}; give at most "
                              f"{most:.4g} s")


def run(args: argparse.Namespace) -> int:
    from ..calibration.detect import detect_session, plot_detection
    from ..session import save_session
    from ..units import G0

    if args.factor != "auto":
        _factor(args.factor)  # refused before reading
    log = open_raw(args.raw, args.rate, _cols(args.accel), _cols(args.gyro), args.time, args, args.imu)
    _check_spans(args, len(log.t) / log.sample_rate)
    init = args.init_still
    if init is None:
        for k, v in log.meta.items():
            if "init" in str(k).lower() and isinstance(v, float) and v > 0:
                init = v
    factor = _factor(args.factor)
    if args.margin is not None and 2 * args.margin >= args.min_static:
        from ..errors import OptionError

        raise OptionError(f"--margin {args.margin:g} s: trimmed from both ends, it must leave some of the shortest pose "
                          f"(--min-static {args.min_static:g} s): give less than {args.min_static / 2:g} s")
    geometries = None
    if args.geometry:
        geo = geometry_option(args.geometry)
        geometries = {k: geo for k in log.raw}
        bad = {k: y.shape[1] for k, y in log.raw.items() if y.shape[1] != geo.n}
        if bad:
            from ..errors import GeometryError

            raise GeometryError(f"--geometry {args.geometry} has {geo.n} sensors; the file's {bad} columns differ")
    session, det = detect_session(log.t, log.raw, log.sample_rate, geometries, gravity=args.gravity or G0,
                                  window_s=args.window, factor=factor, init_still_s=init,
                                  min_static_s=args.min_static, min_motion_s=args.min_motion, margin_s=args.margin)
    poses = [s for s in session.segments if s.kind == "static_unknown"]
    motions = [s for s in session.segments if s.kind == "motion"]
    fs = log.sample_rate
    chosen = det.settings.get("factor_chosen", det.threshold)
    print(f"{args.raw}: {len(log.t)} samples at {fs:g} Hz, columns accel {log.columns['accel']}"
          + (f", gyro {log.columns['gyro']}" if "gyro" in log.columns else ""))
    print(f"threshold: {chosen:.4g} x the per-axis noise floor ("
          + (f"initial still period {init:g} s" if init else "quietest 10% of the record") + ")")
    for s in session.segments:
        a, b = s.meta["detected"]
        print(f"  {s.label:>5s} {s.kind:15s} {a / fs:8.2f} - {b / fs:8.2f} s ({(b - a) / fs:5.2f} s)")
    summary = {"raw": str(args.raw), "sample_rate": fs, "n_samples": len(log.t), "poses": len(poses),
               "motions": len(motions), "threshold_factor": chosen, "init_still_s": init,
               "dropped_short": det.dropped_short,
               "segments": [{"label": s.label, "kind": s.kind, "start": s.meta["detected"][0],
                             "end": s.meta["detected"][1]} for s in session.segments]}
    if args.report:
        d = Path(args.report)
        d.mkdir(parents=True, exist_ok=True)
        fig = plot_detection(det, log.raw["accel"], fs, path=str(d / "detection.png"))
        fig.clf()
        lines = [f"# Detection of {args.raw}", "",
                 f"{len(poses)} poses, {len(motions)} motions; threshold {chosen:.4g} x the noise floor.", "",
                 "![detection](detection.png)", "", "| segment | kind | start (s) | end (s) |", "|---|---|---|---|"]
        lines += [f"| {s['label']} | {s['kind']} | {s['start'] / fs:.2f} | {s['end'] / fs:.2f} |"
                  for s in summary["segments"]]
        (d / "detection.md").write_text("\n".join(lines) + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))
    out = save_session(session, args.output)
    print(f"session written to {out}: {len(poses)} poses, {len(motions)} motions")
    return 0
