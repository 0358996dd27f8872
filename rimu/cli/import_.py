"""``rimu import LOG [--format NAME] [--mapping FILE] -o REC.npz [--json FILE]``: any recorded log to rimu's
recording file.

The format is found from the content and the name (``--format`` to force one); ``.xz``, ``.gz``, ``.bz2`` and
``.zst`` are read as such. Each IMU keeps its own time stamps; units are converted to SI (from what the file
states, else from what is declared: ``--mapping``, ``--gyro-unit``, ``--accel-unit``) and checked at the door
(gravity at rest, plausible rates; ``--accept-implausible`` turns a refusal into a warning). Formats with a
streaming reader are imported piece by piece: a long log never has to fit in memory. ``--json`` summarises per
IMU its name, sample count, mean rate in Hz, the units it was converted from, the axes' frame where the log states
it (``frame``; null where it does not) and the rejected records by reason.
"""

from __future__ import annotations

import argparse

from ._common import add_accept_implausible, add_json_option


def register(sub: argparse._SubParsersAction) -> None:
    from ..io.formats import FALLBACK, FORMATS

    p = sub.add_parser("import", help="read a recorded log (DataFlash, ULog, ROS bag, Xsens DOT, CSV, ...) into "
                       "rimu's recording file", description=__doc__ + "\nFormats: " + ", ".join(
                           list(FORMATS) + list(FALLBACK)) + ".",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="log file or folder (compressed or not)")
    p.add_argument("-o", "--output", required=True, help="recording file to write (.npz)")
    add_json_option(p, "per IMU: name, samples, mean rate (Hz), units converted from, axes' frame, rejected records")
    from ._inputs import add_log_options

    add_log_options(p)
    add_accept_implausible(p)
    p.set_defaults(func=run)


def summary(head_meta: dict, names: list[str], counts: dict[str, int], spans: dict[str, tuple[float, float]]
            ) -> dict:
    """The ``--json`` document."""
    imus = []
    rej = head_meta.get("rejected") or {}
    for n in names:
        a, b = spans.get(n, (float("nan"), float("nan")))
        c = counts[n]
        imus.append({"name": n, "samples": c, "mean_rate_hz": (c - 1) / (b - a) if c > 1 and b > a else None,
                     "duration_s": b - a if c else 0.0, "units_from": head_meta.get("units_from", {}),
                     "frame": (head_meta.get("frames") or {}).get(n, head_meta.get("frame")),
                     "rejected": rej.get(n, {})})
    return {"format": head_meta.get("format"), "source": head_meta.get("source"), "imus": imus,
            "file_counts": {k: head_meta[k] for k in ("records", "garbage_bytes", "truncated") if k in head_meta}}


def run(args: argparse.Namespace) -> int:
    from ..io.formats import format_module, iter_log
    from ..io.formats.rimu_recording import RecordingWriter
    from ..session.checks import enforce
    from ._common import json_dump
    from ._inputs import check_recording, log_options

    opts = log_options(args)
    checks = "warn" if args.accept_implausible else "strict"
    w = RecordingWriter(args.output)
    counts: dict[str, int] = {}
    spans: dict[str, tuple[float, float]] = {}
    meta: dict = {}
    checked = False
    try:
        for piece in iter_log(args.log, **opts):
            if not checked and any(len(u) > 200 for u in piece.units):
                enforce(check_recording(piece, str(args.log)), checks)
                checked = True
            w.add(piece)
            for u in piece.units:
                counts[u.name] = counts.get(u.name, 0) + len(u)
                if len(u):
                    a, b = spans.get(u.name, (float(u.t[0]), float(u.t[-1])))
                    spans[u.name] = (min(a, float(u.t[0])), max(b, float(u.t[-1])))
            meta = piece.meta
        if not counts:
            from ..errors import SessionFormatError

            raise SessionFormatError(f"{args.log}: no IMU samples in the log")
        meta.setdefault("format", format_module(opts["format"]).NAME if "format" in opts else None)
        out = w.close(meta)
    except BaseException:
        w.abort()
        raise
    doc = summary(meta, w.names, counts, spans)
    for imu in doc["imus"]:
        rate = imu["mean_rate_hz"]
        rej = ", ".join(f"{k} {v}" for k, v in imu["rejected"].items() if v) or "none"
        print(f"{imu['name']}: {imu['samples']} samples, {imu['duration_s']:.3f} s, "
              + (f"{rate:.4g} Hz" if rate else "rate n/a") + f"; rejected: {rej}")
    uf = meta.get("units_from") or {}
    if uf:
        print("units (SI: rad/s, m/s^2, s) converted from: " + "; ".join(f"{k} {v}" for k, v in uf.items()))
    frames = {imu["frame"] for imu in doc["imus"] if imu["frame"]}
    if len(frames) == 1:
        print(f"axes: {frames.pop()}")
    elif frames:
        print("axes: " + "; ".join(f"{imu['name']} {imu['frame']}" for imu in doc["imus"] if imu["frame"]))
    print(f"{meta.get('format')} log {args.log}: {len(w.names)} IMUs -> {out}")
    if args.json:
        print(f"summary written to {json_dump(doc, args.json)}")
    return 0
