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

from ._common import add_accept_implausible, add_json_option, nonnegative_float
from ._inputs import add_log_options


def _window(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) if x.strip() else float("nan") for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not START:END in seconds (e.g. 0:30)") from None
    import math

    a = -math.inf if math.isnan(a) else a
    b = math.inf if math.isnan(b) else b
    if not a < b:
        raise argparse.ArgumentTypeError(f"{text!r}: START must be before END")
    return a, b


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("setup", help="clock and axis alignment, bias differences and noise of a multi-IMU unit "
                       "from its own log -> calibration (+ session for rimu replay)", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("log", help="multi-IMU log (any format rimu import reads) or rimu recording")
    p.add_argument("-o", "--output", required=True, help="calibration file to write")
    p.add_argument("--session", default=None, metavar="FILE.npz", help="write the unit's samples on one time base")
    p.add_argument("--fit-window", type=_window, default=None, metavar="START:END",
                   help="fit on this span, s from the start of the log (default: the whole log)")
    p.add_argument("--average", type=nonnegative_float, default=0.1,
                   help="block-average length, s (0: none; default %(default)s)")
    add_json_option(p, "clock offsets (s) and rotation angles (deg) per triad")
    add_log_options(p)
    add_accept_implausible(p)
    p.set_defaults(func=run, extra_outputs=("session",))  # --session is written (rimu.cli._common.output_options)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..calibration.multi_imu import setup_multi_imu
    from ..errors import SessionFormatError
    from ..session import Segment, Session, save_session
    from ._common import json_dump
    from ._inputs import open_recording

    rec = open_recording(args.log, args, "warn" if args.accept_implausible else "strict")
    if len(rec.units) < 2:
        raise SessionFormatError(f"{args.log}: {len(rec.units)} IMU; a unit of triads needs two or more")
    t0 = float(rec.units[0].t[0])  # the window counts from the start of the log (the first IMU's first stamp)
    win = None if args.fit_window is None else (args.fit_window[0] + t0, args.fit_window[1] + t0)
    span = max(float(u.t[-1] - u.t[0]) for u in rec.units if len(u.t))
    if args.average and args.average > span / 10:
        from ..errors import OptionError

        raise OptionError(f"--average {args.average:g} s: the log spans {span:.4g} s; give at most {span / 10:.4g} s "
                          "(ten averaged epochs)")
    su = setup_multi_imu(rec, average_s=args.average or None, fit_window_s=win)
    print(su.report())
    out = su.calibration.save(args.output)
    print(f"calibration written to {out}")
    b = su.block
    insts = [k for k in su.calibration.instruments if k in b.raw]
    if args.session:
        ok = np.all([b.valid[k].all(axis=1) for k in insts], axis=0)
        seg = Segment("log", "motion", b.t[ok] - t0, {k: b.raw[k][ok] for k in insts},
                      None if b.temperature is None else b.temperature[ok], meta={"imus": rec.names})
        s = Session([seg], {k: su.calibration[k].geometry for k in insts}, 1.0 / float(np.median(np.diff(b.t[ok]))),
                    raw_unit="SI", meta={"raw_units": {"gyro": "rad/s", "accel": "m/s^2"}, "source": str(args.log),
                                         "t0_s": t0})
        print(f"session written to {save_session(s, args.session)}: {int(ok.sum())} epochs at {s.sample_rate:.4g} Hz")
    if args.json:
        doc = {"imus": rec.names, "offsets_s": None if su.timing is None else list(su.timing.offsets_s),
               "rotation_deg": [float(np.degrees(np.arccos(np.clip((np.trace(a.mat_unit_ref) - 1) / 2, -1, 1))))
                                for a in su.alignments],
               "fit_window_s": [w - t0 for w in su.fit_window_s], "n_average": su.n_average, "delivering": su.delivering}
        print(f"summary written to {json_dump(doc, args.json)}")
    return 0
