"""``rimu setup LOG -o cal.json --session unit.npz``: set up a unit of triads that nobody calibrated as a whole
(IMUs strapped to a vehicle, an autopilot's two or three IMUs) from a span of its own log, taken as fault-free.

Clock offsets of every IMU against the first (where the IMUs have their own clocks), axis alignment of every
triad (unless the log says its IMUs are already in one body frame), gyro and accelerometer bias differences and
per-sensor noise from the triads' disagreement are fitted on ``--fit-window START:END`` (s from the start of the
log; default the whole log) by :func:`rimu.calibration.multi_imu.setup_multi_imu`. Writes the calibration
(``-o``: the nominal one of the log's own mounting, rotations fitted) and, with ``--session``, the whole log on
one time base (averaged over ``--average`` s; time from the start of the log) as a session file that ``rimu replay
--calibration`` monitors.
LOG is anything ``rimu import`` reads, or its recording file.
"""

from __future__ import annotations

import argparse
from typing import Any

from ._common import add_accept_implausible, add_json_option, nonnegative_float, positive_float
from ._inputs import add_log_options


def _window(text: str) -> tuple[Any, Any]:
    """``START:END``, each in s from the start of the log or as a percentage of its span (``:50%``: the first
    half); an empty bound is open."""
    import math

    def bound(x: str, open_: float) -> Any:
        x = x.strip()
        if not x:
            return open_
        if x.endswith("%"):
            v = float(x[:-1])
            if not 0.0 <= v <= 100.0:
                raise ValueError
            return ("%", v / 100.0)
        v = float(x)
        if math.isnan(v):
            raise ValueError
        return v

    try:
        a_txt, b_txt = text.split(":")
        a, b = bound(a_txt, -math.inf), bound(b_txt, math.inf)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not START:END in seconds or percent of the log (e.g. 0:30, "
                                         ":50%)") from None
    if not isinstance(a, tuple) and not isinstance(b, tuple) and not a < b:
        raise argparse.ArgumentTypeError(f"{text!r}: START must be before END")
    if isinstance(a, tuple) and isinstance(b, tuple) and not a[1] < b[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: START must be before END")
    return a, b


def _track(text: str) -> Any:
    """``auto`` or a non-negative time in s."""
    return "auto" if text.strip().lower() == "auto" else nonnegative_float(text)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("setup", help="clock and axis alignment, bias differences and noise of a multi-IMU unit "
                       "from its own log -> calibration (+ session for rimu replay)", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="multi-IMU log (any format rimu import reads) or rimu recording")
    p.add_argument("-o", "--output", required=True, help="calibration file to write")
    p.add_argument("--session", default=None, metavar="FILE.npz", help="write the unit's samples on one time base")
    p.add_argument("--fit-window", type=_window, default=None, metavar="START:END",
                   help="fit on this span, s from the start of the log or %% of its span (e.g. :50%%: the first "
                        "half; default: the whole log)")
    p.add_argument("--average", type=nonnegative_float, default=0.1,
                   help="block-average length, s (0: none; default %(default)s)")
    p.add_argument("--parallel", action="store_true",
                   help="keep the triads on the axes the log states (no rotation fitted): for a static recording in "
                        "one pose, where the rotations cannot be found (gravity in one direction only); the gyros "
                        "at rest do not depend on the rotations, the bias differences are fitted either way")
    p.add_argument("--motion-fit", action="store_true",
                   help="also fit the gyros' motion terms (rimu.fdi.fit_motion_detector: residual scale, misalignment, "
                        "time offset, vibration per rate and angular acceleration, and the envelope of motion they hold "
                        "for) on the fit window, and store them in the calibration: rimu replay and rimu monitor then "
                        "test with them")
    p.add_argument("--motion-margin", type=positive_float, default=10.0,
                   help="factor on the fitted motion variances (default %(default)s)")
    p.add_argument("--motion-window", type=positive_float, default=0.1, metavar="SECONDS",
                   help="the motion-aware test decides on the mean of its last SECONDS of samples (at least one; "
                        "default %(default)s s: at the full rate of a fast-sampled unit the sensitivity of 0.1 s "
                        "averages, deciding at every sample)")
    p.add_argument("--bias-track", type=_track, default="auto", metavar="SECONDS|auto",
                   help="time constant of the motion-aware test's tracker of the triads' relative bias drift at rest: "
                        "'auto' (default) measures it on the fit window's poses at rest, tau = N/K of the residuals' "
                        "white noise density N and bias random walk K (the Allan variance's minimum over sqrt(3)); "
                        "or SECONDS (0: none)")
    add_json_option(p, "clock offsets (s), rotation angles (deg), spans at rest (s) per triad")
    add_log_options(p)
    add_accept_implausible(p)
    p.set_defaults(func=run, extra_outputs=("session",))  # --session is written (rimu.cli._common.output_options)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..calibration.multi_imu import setup_multi_imu
    from ..errors import SessionFormatError
    from ..session import save_session
    from ._common import json_dump
    from ._inputs import open_recording

    rec = open_recording(args.log, args, "warn" if args.accept_implausible else "strict")
    if len(rec.units) < 2:
        raise SessionFormatError(f"{args.log}: {len(rec.units)} IMU; a unit of triads needs two or more")
    t0 = float(rec.units[0].t[0])  # the window counts from the start of the log (the first IMU's first stamp)
    span = max(float(u.t[-1] - u.t[0]) for u in rec.units if len(u.t))
    win = None
    if args.fit_window is not None:
        win = tuple(t0 + (w[1] * span if isinstance(w, tuple) else w) for w in args.fit_window)
        if not win[0] < win[1]:
            from ..errors import OptionError

            raise OptionError(f"--fit-window: the span {win[0] - t0:.4g} .. {win[1] - t0:.4g} s is empty")
    if args.average and args.average > span / 10:
        from ..errors import OptionError

        raise OptionError(f"--average {args.average:g} s: the log spans {span:.4g} s; give at most {span / 10:.4g} s "
                          "(ten averaged epochs)")
    su = setup_multi_imu(rec, average_s=args.average or None, fit_window_s=win,
                         align_axes=False if args.parallel else None)
    print(su.report())
    if args.motion_fit:
        _fit_motion(su, args.motion_margin, args.motion_window, args.bias_track or None)
    out = su.calibration.save(args.output)
    print(f"calibration written to {out}")
    b = su.block
    insts = [k for k in su.calibration.instruments if k in b.raw]
    spans = _rest_spans(su, t0)
    if args.session:
        s = _session(su, insts, rec.names, t0, str(args.log))
        n_rest = sum(len(g.t) for g in s.segments if g.kind == "static_unknown")
        print(f"session written to {save_session(s, args.session)}: {len(b.t)} epochs at {s.sample_rate:.4g} Hz "
              f"({len(spans)} spans at rest, {n_rest} epochs; invalid samples kept as empty values)")
    if args.json:
        doc = {"imus": rec.names, "offsets_s": None if su.timing is None else list(su.timing.offsets_s),
               "rotation_deg": [float(np.degrees(np.arccos(np.clip((np.trace(a.mat_unit_ref) - 1) / 2, -1, 1))))
                                for a in su.alignments],
               "fit_window_s": [w - t0 for w in su.fit_window_s], "n_average": su.n_average, "delivering": su.delivering,
               "rest_spans_s": spans, "spans_s": {k: v for k, v in su.spans.items() if k != "noise_scale"},
               "sample_rate_hz": 1.0 / float(np.median(np.diff(b.t)))}
        print(f"summary written to {json_dump(doc, args.json)}")
    return 0


def _rest_spans(su, t0: float) -> list[list[float]]:  # type: ignore[no-untyped-def]
    """The spans at rest of the whole log (``su.still``), ``[start, end]`` in s from the start of the log."""
    import numpy as np

    st = np.asarray(su.still, bool)
    t = su.block.t[: len(st)]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], st.astype(np.int8), [0]])))
    return [[float(t[a] - t0), float(t[b - 1] - t0)] for a, b in zip(edges[::2], edges[1::2])]


def _session(su, insts: list[str], names: list[str], t0: float, source: str):  # type: ignore[no-untyped-def]
    """The whole log on one time base as a session: one segment per span at rest (kind ``static_unknown``) or in
    motion (``motion``), every epoch kept, an invalid sample (clipped, placeholder, a gap) as an empty value
    (NaN: invalid when replayed), so the replay sees the log's invalidity where it was."""
    import numpy as np

    from ..session import Segment, Session

    b = su.block
    n = len(b.t)
    st = np.zeros(n, bool)
    st[: len(su.still)] = su.still[:n]
    raw = {k: np.where(b.valid[k], b.raw[k], np.nan) for k in insts}
    cut = np.concatenate([[0], np.flatnonzero(np.diff(st.astype(np.int8))) + 1, [n]])
    segs = []
    for i, (a, e) in enumerate(zip(cut[:-1], cut[1:])):
        rest = bool(st[a])
        segs.append(Segment(f"{'rest' if rest else 'move'}{i}", "static_unknown" if rest else "motion", b.t[a:e] - t0,
                            {k: v[a:e] for k, v in raw.items()},
                            None if b.temperature is None else b.temperature[a:e], meta={"imus": names}))
    return Session(segs, {k: su.calibration[k].geometry for k in insts}, 1.0 / float(np.median(np.diff(b.t))),
                   raw_unit="SI", meta={"raw_units": {"gyro": "rad/s", "accel": "m/s^2"}, "source": source, "t0_s": t0})


def _fit_accel_motion(su, gyro_det, win, fs: float, margin: float, window_s: float) -> None:  # type: ignore[no-untyped-def]
    """The accelerometers' motion terms on the same window, with the gyros' rate (from their rest level) as the
    unit's motion: their lever-arm terms grow with it; stored beside the gyros'. Where the setup took the
    accelerometers' relative gains from the poses at rest, no scale or misalignment term (fitted on the motion's
    large specific force, margin 10, they would claim at rest, under gravity, errors the poses showed absent)."""
    import numpy as np

    from ..errors import ShapeError
    from ..fdi.motion import fit_motion_detector, motion_detector_to_dict
    from ..fusion import InstrumentPipeline

    b = su.block
    gp = InstrumentPipeline(su.calibration["gyro"]).process(b.raw["gyro"][win], b.valid["gyro"][win])
    rate = np.asarray(gp.x, dtype=float) - gyro_det.rest_level
    try:
        det = fit_motion_detector(su.calibration["accel"], b.raw["accel"][win], b.valid["accel"][win], fs,
                                  margin=margin, window=max(1, round(window_s * fs)),
                                  still=np.asarray(su.still, bool)[win], rate=rate,
                                  extra_var=su.pose_sigma["accel"] ** 2 if "accel" in su.pose_sigma else 0.0,
                                  terms=("time_offset", "rate", "accel") if su.spans.get("accel_gains_from_rest")
                                  else ("scale", "misalignment", "time_offset", "rate", "accel"))
    except ShapeError as exc:
        raise ShapeError(f"--motion-fit (accelerometers): {exc}") from None
    su.calibration.metadata["motion_terms"]["accel"] = motion_detector_to_dict(det)
    m = det.model
    print(f"accel motion terms (fit window, {det.fit_samples} epochs, margin {margin:g}, the test on the mean of "
          f"{det.window} epoch(s)): scale {1e2 * float(np.median(m.scale_rel)):.3g} %, misalignment "
          f"{1e3 * float(np.median(m.misalignment_rad)):.3g} mrad, vibration {float(np.median(np.sqrt(m.rate_var))):.3g} "
          f"m/s^2 per rad/s and {float(np.median(np.sqrt(m.accel_var))):.3g} m/s^2 per rad/s^2 (medians); they hold "
          f"for |rate| up to {np.degrees(det.envelope[0]):.4g} deg/s and |angular acceleration| up to "
          f"{np.degrees(det.envelope[1]):.4g} deg/s^2 of the gyros (beyond: model_exceeded, nothing isolated)")


def _fit_motion(su, margin: float, window_s: float, track_s: Any) -> None:  # type: ignore[no-untyped-def]
    """The gyros' motion terms on the fit window (taken as fault-free), stored in the calibration's metadata
    (``motion_terms``), with what they assume printed."""
    import numpy as np

    from ..errors import ShapeError
    from ..fdi.motion import envelope_text, fit_motion_detector, motion_detector_to_dict

    if "gyro" not in su.calibration.instruments:
        raise ShapeError("--motion-fit: the unit has no gyros")
    b = su.block
    lo, hi = su.fit_window_s
    win = (b.t >= lo) & (b.t <= hi)
    fs = 1.0 / float(np.median(np.diff(b.t)))
    try:
        det = fit_motion_detector(su.calibration["gyro"], b.raw["gyro"][win], b.valid["gyro"][win], fs, margin=margin,
                                  window=max(1, round(window_s * fs)), bias_track_s=track_s,
                                  still=np.asarray(su.still, bool)[win])
    except ShapeError as exc:
        raise ShapeError(f"--motion-fit: {exc}") from None
    su.calibration.metadata["motion_terms"] = {"gyro": motion_detector_to_dict(det)}
    if det.bias_drift is not None:
        print("gyro " + (det.bias_drift if isinstance(det.bias_drift, str) else det.bias_drift.describe()))
    if "accel" in su.calibration.instruments and "accel" in b.raw:
        _fit_accel_motion(su, det, win, fs, margin, window_s)
    m = det.model
    print(f"gyro motion terms (fit window, {det.fit_samples} epochs, margin {margin:g}; the test decides on the mean "
          f"of {det.window} epoch(s), window gain {float(np.median(det.window_gain)):.3g} (median)): scale "
          f"{1e2 * float(np.median(m.scale_rel)):.3g} %, misalignment {1e3 * float(np.median(m.misalignment_rad)):.3g} "
          f"mrad, time offset {1e3 * float(np.median(m.time_offset_s)):.3g} ms (medians); they hold for "
          f"{envelope_text(det.envelope)} (beyond: model_exceeded, nothing isolated)")
    if det.moving_samples < 50:
        print(f"gyro: no motion in the fit window ({det.moving_samples} epochs): no motion term fitted; the test is "
              "the plain GLT of the noise at rest, which holds at rest only")
