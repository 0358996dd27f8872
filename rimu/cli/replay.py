"""``rimu replay DATA --calibration cal.json [--inject SPEC ...]``: replay recorded or simulated data through the
runtime pipeline with fault detection and isolation, optionally with injected faults.

Prints the events (isolations, transients, re-admissions, state changes) and the final state per instrument;
``--report DIR`` writes the replay report (``replay_report.html`` and ``.pdf``, rimu's one report layout, and the
plot ``replay.png``): the parity statistic against its threshold with the alarms, the estimate, its validity, the
sensors in use with the isolations, on one time axis, ``--json FILE`` the events (time in s and sample index) and final states.

Injection: ``TYPE:INSTRUMENT:SENSOR:START[:SIZE[:DURATION]]``, SIZE in SI or as ``10sigma``; types: bias, ramp,
stuck, scale, noise, spikes, dropout, zero, saturation, nonfinite. Example: ``--inject bias:gyro:y2:15:10sigma``.
``--motion-fit SECONDS`` fits motion-aware thresholds for the gyros on the first SECONDS of the data (taken as
fault-free): the test then allows for the residual scale, misalignment, time offset and vibration of the unit in
motion (docs/many-sensors.md). A range limit in the calibration (``range_raw``) makes clipped samples count as
saturated: routed around, never isolated.
DATA is a session file in rimu's format (``.npz``, or ``.csv`` with its ``.json`` sidecar; docs/session-format.md),
as ``rimu simulate`` writes it; the segments are replayed back to back. Every effect of the calibration is
compensated (docs/runtime.md). Where segments carry known inputs (static positions, rate steps), the runtime
error is reported per instrument (``segment_error_rms``: rms over segments of the segment-mean estimate's
error against the known input; ``sample_error_rms``; SI) with the number of alarms and isolations, and
written to ``OUT/summary.json``: how a calibration is validated on a held-out session.
``--estimates FILE.csv`` writes the estimates of every sample (the columns the exported C filter writes;
floats in Python's shortest round-trip form).

``--selfcal`` replays with the in-flight self-calibration (:mod:`rimu.fdi.selfcal`, docs/selfcal.md): the runtime
tracks the drift of every sensor's bias (and scale, and the temperature coefficients when the data have a
temperature) from the parity, compensates with the tracked terms, and its window GLT's thresholds carry the
tracker's covariance (``--detector glt_window``, of ``--window`` samples; without it the detector's window is the
tracker's, ``--selfcal-window`` s). The drift rate comes from the calibration's noise model
(``--selfcal-drift-factor``, ``--selfcal-horizon``) or ``--selfcal-bias-rw``. The summary, ``--json``, ``--report``
(``selfcal-<instrument>.png``) and ``--estimates`` (columns ``{k}_{term}_{sensor}`` and ``..._sigma``, SI) show the
tracked terms over time with their 1-sigma.

The replay streams: the file is read twice in chunks (:func:`rimu.session.iter_blocks`), once for the format
and plausibility checks, the time span and the sample rate, once through the runtime; the summary figures are
accumulated and the estimates written chunk by chunk, so a replay of 1e8 samples runs in the memory of one
chunk. The ``--report`` plot holds a decimated series (every d-th sample, at most 40 000 points per series).
Faults other than bias, ramp, dropout and zero need their whole window: with one of them the file is read as
one chunk (a note says so).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from ._common import (
    Deprecated,
    add_accept_implausible,
    add_fdi_options,
    add_json_option,
    add_readmit_options,
    add_report_option,
    nonnegative_int,
    positive_float,
    positive_int,
    readmit_after,
)
from ._inputs import add_log_options
from .selfcal import add_tracker_options, loop_summary, terms_figure

DETECTORS = ["glt", "glt_window", "cusum", "kalman", "baseline"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="replay data through pipeline + FDI, optionally injecting faults",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="session file (.npz, or .csv/.json with sidecar), or a log (rimu import --help)")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--inject", action="append", default=[], metavar="SPEC", help="fault to inject (repeatable)")
    p.add_argument("--detector", default="glt", choices=DETECTORS)
    p.add_argument("--window", type=positive_int, default=5, help="samples of the window GLT")
    add_fdi_options(p)
    p.add_argument("--arl0", type=positive_float, default=1e5, help="mean samples between false alarms (cusum, baseline)")
    add_readmit_options(p, "rimu export-c")
    p.add_argument("--noise", type=positive_float, default=None, help="per-sample noise (SI) if the calibration has none")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of random fault types")
    p.add_argument("--motion-fit", type=positive_float, default=None, metavar="SECONDS",
                   help="gyros: fit motion-aware thresholds (rimu.fdi.motion: scale, misalignment, time offset, "
                        "vibration) on the first SECONDS of the data, taken as fault-free, and test with them "
                        "(docs/many-sensors.md)")
    p.add_argument("--motion-margin", type=positive_float, default=3.0, help="factor on the fitted motion variances")
    p.add_argument("--common-cause", action="store_true",
                   help="invalid samples of several sub-units at once (triads clipping together) are a common cause: "
                        "routed around, never isolated (rimu.fdi.common_cause; not in the exported C)")
    p.add_argument("--instrument", action="append", default=None, metavar="NAME",
                   help="replay only this instrument of the calibration (repeatable; default: every one)")
    p.add_argument("--px4", action="store_true",
                   help="gyros of a unit of triads: also run the PX4 EKF2-selector-style rule (|rate - median of the "
                        "other triads| - 7 deg/s integrated to 15 deg; rimu.fdi.Px4GyroSelector) on the same samples "
                        "and print the triads it flags and when")
    p.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="folder for summary.json: the runtime error against the segments' known inputs, alarms and "
                        "isolations per instrument (docs/runtime.md)")
    add_report_option(p, "the report (replay_report.html, .pdf) and its plot (replay.png)")
    add_json_option(p, "the events (time in s and sample index) and final states")
    p.add_argument("--estimates", default=None, metavar="FILE.csv",
                   help="write per sample t, then per instrument {k}_x/_y/_z (SI, master-body frame), {k}_validity "
                        "(rimu.fusion.Validity code) and {k}_isolated (0-based indices of the isolated sensors joined "
                        "by ';'): the columns the exported C filter writes")
    p.add_argument("--selfcal", action="store_true",
                   help="track the calibration's drift in flight and compensate with it (docs/selfcal.md); the "
                        "tracker's settings: --selfcal-*")
    add_tracker_options(p, "selfcal-")
    p.add_argument("--selfcal-cusum", action="store_true",
                   help="with --selfcal: a CUSUM bank beside the window GLT that carries the tracker's covariance "
                        "(half the false-alarm budget each; finds a step sooner, docs/selfcal.md)")
    p.add_argument("--out", action=Deprecated, new="--report DIR and --json FILE", convert=_old_out, metavar="DIR")
    add_accept_implausible(p)
    add_log_options(p)
    p.set_defaults(func=run, output_is_dir=True)  # -o names a folder (summary.json), checked as one


def _old_out(ns: argparse.Namespace, value: str) -> None:
    """``--out DIR`` (old): DIR/replay.png and DIR/replay.json."""
    ns.report = value
    ns.json = str(Path(value) / "replay.json")
    ns.output = value


#: samples per chunk of the streaming replay; replays longer than this show a progress bar (one step per chunk)
_CHUNK = 5_000
#: points per series the --report plot keeps (every d-th sample, d doubling as the replay grows)
_PLOT_POINTS = 20_000
#: fault types that act on each sample alone: injected chunk by chunk, they give the samples of one pass over
#: the whole file. The others (a median over the fault window, the sample before it, random draws in sequence)
#: need the whole window: with one of them the replay reads the file as one chunk.
_POINTWISE_FAULTS = frozenset({"bias", "ramp", "dropout", "zero"})


class _Median:
    """Exact median of a stream of time steps, kept as (distinct value, count) pairs: memory grows with the
    number of distinct steps, not the number of samples. Beyond ``cap`` distinct values (heavily jittered time
    stamps) the steps are rounded to 1e-9 of the running median, which is then exact to that precision."""

    def __init__(self, cap: int = 100_000) -> None:
        self.keys = np.zeros(0)
        self.counts = np.zeros(0, np.int64)
        self.cap = cap
        self.res = 0.0

    def add(self, v: np.ndarray) -> None:
        if not v.size:
            return
        if self.res:
            v = np.round(v / self.res) * self.res
        u, c = np.unique(v, return_counts=True)
        self.keys, inv = np.unique(np.concatenate([self.keys, u]), return_inverse=True)
        self.counts = np.bincount(inv, weights=np.concatenate([self.counts, c])).astype(np.int64)
        if len(self.keys) > self.cap and not self.res:
            self.res = abs(self.median()) * 1e-9 or 1e-12
            keys, counts = self.keys, self.counts
            self.keys, self.counts = np.zeros(0), np.zeros(0, np.int64)
            self.keys, inv = np.unique(np.round(keys / self.res) * self.res, return_inverse=True)
            self.counts = np.bincount(inv, weights=counts).astype(np.int64)

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def median(self) -> float:
        """``np.median`` of every value added (NaN when none)."""
        n = self.n
        if n == 0:
            return float("nan")
        cum = np.cumsum(self.counts)
        a = self.keys[np.searchsorted(cum, (n - 1) // 2, side="right")]
        b = self.keys[np.searchsorted(cum, n // 2, side="right")]
        return float(a) if a == b else float((a + b) / 2)


class _SegmentStats:
    """What the plausibility checks need of one segment, accumulated over the stream."""

    def __init__(self, angle: bool) -> None:
        self.n = 0
        self.angle = angle
        self.t0 = self.t_last = 0.0
        self.first: dict[str, np.ndarray] = {}
        self.last: dict[str, np.ndarray] = {}
        self.sum: dict[str, np.ndarray] = {}
        self.count: dict[str, np.ndarray] = {}  # finite values per column (invalid samples are NaN)
        self.lo: dict[str, np.ndarray] = {}
        self.hi: dict[str, np.ndarray] = {}
        self.trap: dict[str, np.ndarray] = {}  # sum of 0.5 (y[k] + y[k+1]) dt_k (angle segments)
        self.steps: list[np.ndarray] = []  # time steps held until the segment has 3 samples

    def add(self, t: np.ndarray, raw: dict[str, np.ndarray], within: _Median) -> None:
        d = np.diff(t) if self.n == 0 else np.diff(np.concatenate([[self.t_last], t]))
        if self.n + len(t) < 3:
            self.steps.append(d)
        else:
            within.add(np.concatenate(self.steps + [d]))
            self.steps = []
        for k, y in raw.items():
            ok = np.isfinite(y)
            if self.n == 0:
                self.first[k] = np.full(y.shape[1], np.nan)
                self.sum[k] = np.zeros(y.shape[1])
                self.count[k] = np.zeros(y.shape[1], np.int64)
                self.lo[k], self.hi[k] = np.full(y.shape[1], np.nan), np.full(y.shape[1], np.nan)
                self.trap[k] = np.zeros(y.shape[1])
            miss = np.isnan(self.first[k]) & ok.any(axis=0)  # the first usable value of each column
            if miss.any():
                self.first[k][miss] = y[ok.argmax(axis=0), np.arange(y.shape[1])][miss]
            self.sum[k] += np.where(ok, y, 0.0).sum(axis=0)
            self.count[k] += ok.sum(axis=0)
            with np.errstate(invalid="ignore"):
                np.fmin(self.lo[k], np.fmin.reduce(y, axis=0), out=self.lo[k])
                np.fmax(self.hi[k], np.fmax.reduce(y, axis=0), out=self.hi[k])
            if self.angle:  # an invalid sample adds nothing to the integral (its intervals are left out)
                yy = y if self.n == 0 else np.vstack([self.last[k], y])
                self.trap[k] += np.nan_to_num(0.5 * (yy[1:] + yy[:-1]) * d[:, None]).sum(axis=0)
            self.last[k] = y[-1].copy()
        if self.n == 0:
            self.t0 = float(t[0])
        self.n += len(t)
        self.t_last = float(t[-1])

    def rows(self, k: str) -> tuple[np.ndarray, np.ndarray]:
        """Four samples (t, raw) with this segment's first sample, column minima and maxima, and its mean (or,
        for an angle segment, its trapezoidal integral over time): what rimu.session.checks reads of a segment."""
        T = self.t_last - self.t0
        t = self.t0 + T * np.array([0.0, 1 / 3, 2 / 3, 1.0])
        r0, r1, r2 = self.first[k], self.lo[k], self.hi[k]
        if self.angle:
            r3 = 2.0 * (3.0 * self.trap[k] / T - 0.5 * r0 - r1 - r2)
        else:
            r3 = 4.0 * self.sum[k] / np.maximum(self.count[k], 1) - r0 - r1 - r2
        r3 = np.where(r1 == r2, r0, r3)  # a constant column stays constant
        return t, np.vstack([r0, r1, r2, r3])


class _Scan:
    """One streaming pass over a session file: every format check of the reader, the plausibility checks of
    rimu.session.checks on per-segment statistics, the sample count, time span and sample rate, and the
    session's segments (their known inputs) without their samples."""

    def __init__(self, path: Path, checks: str) -> None:
        from ..session import iter_blocks

        self.path = path
        self.n = 0
        self.t_first = self.t_last = 0.0
        self.in_order = True  # the samples are in the sidecar's segment order
        steps, within = _Median(), _Median()
        stats: list[_SegmentStats] = []
        side: dict = {}
        last_t, last_seg = None, -1
        self.has_temp = False
        for blk in iter_blocks(path, _CHUNK, invalid=True):
            seg = blk.meta["segment"]
            if not stats:
                side = blk.meta["sidecar"]
                stats = [_SegmentStats(str(d.get("kind")) == "angle") for d in side["segments"]]
                self.t_first = float(blk.t[0])
                self.has_temp = blk.temperature is not None
            steps.add(np.diff(blk.t if last_t is None else np.concatenate([[last_t], blk.t])))
            cut = np.flatnonzero(np.diff(seg)) + 1
            for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(seg)]])):
                i = int(seg[a])
                if i < last_seg:
                    self.in_order = False
                last_seg = i
                stats[i].add(blk.t[a:b], {k: y[a:b] for k, y in blk.raw.items()}, within)
            self.n += len(blk)
            last_t = float(blk.t[-1])
        self.t_last = last_t if last_t is not None else 0.0
        self.side = side
        self.stats = stats
        self.fs = 1.0 / steps.median() if self.n > 1 else 1.0
        self.session = self._reduced(side, stats)
        self._check(within, checks)

    def _reduced(self, side: dict, stats: list[_SegmentStats]):  # type: ignore[no-untyped-def]
        """The session with four samples per segment (see :meth:`_SegmentStats.rows`); its segments carry the
        known inputs, their first sample time and the sidecar's validation."""
        from ..session import session_from_sidecar, sidecar_geometries

        geoms = sidecar_geometries(side, str(self.path))
        t, idx, raw = [], [], {k: [] for k in geoms}
        for i, st in enumerate(stats):
            if st.n == 0:
                continue  # session_from_sidecar names the segment without samples
            for k in geoms:
                tk, rk = (np.full(1, st.t0), st.first[k][None]) if st.n < 4 else st.rows(k)
                raw[k].append(rk)
            t.append(tk)
            idx.append(np.full(len(tk), i))
        temp = np.zeros(sum(len(x) for x in t)) if self.has_temp else None
        return session_from_sidecar(side, np.concatenate(t), np.concatenate(idx), {k: np.vstack(v) for k, v in raw.items()},
                      temp, str(self.path))

    def _check(self, within: _Median, mode: str) -> None:
        """rimu.session.checks on the reduced session (units: segment means and angle integrals; constant
        columns: first values, minima, maxima), and the sample-rate check on the exact median time step within
        segments; acted on as load_session does."""
        from dataclasses import replace

        from ..session import Segment, Session
        from ..session.checks import check_session, enforce

        if mode == "off":
            return
        src = str(self.path)
        small = sum(s.n_samples for s in self.session.segments)
        found = []
        for f in check_session(self.session, src):
            if f.check == "sample_rate":
                continue
            if f.check == "constant":
                f = replace(f, message=f.message.replace(f"in all {small} samples", f"in all {self.n} samples"))
            found.append(f)
        dt = within.median()
        if within.n and dt > 0:
            s = self.session
            probe = Session([Segment("steps", "static_unknown", np.array([0.0, dt, 2 * dt]),
                                     {k: np.zeros((3, g.n)) for k, g in s.geometries.items()})],
                            s.geometries, s.sample_rate, s.latitude, s.gravity, s.raw_unit, s.meta)
            found += [f for f in check_session(probe, src) if f.check == "sample_rate"]
        enforce(found, mode)


class _Plot:
    """The series of the --report plot, decimated online: every d-th sample, d doubling whenever more than
    twice ``_PLOT_POINTS`` are held (so between ``_PLOT_POINTS`` and twice that many points per series)."""

    def __init__(self) -> None:
        self.stride, self.seen = 1, 0
        self.parts: dict[str, list[np.ndarray]] = {f: [] for f in ("t", "statistic", "threshold", "x", "state",
                                                                   "validity", "n_active")}
        self.events: list = []
        #: times and statistics of the alarm samples (every one, up to _PLOT_POINTS: decimation would drop them)
        self.alarm_t: list[np.ndarray] = []
        self.alarm_s: list[np.ndarray] = []
        self.names: list[str] = []

    def add(self, r) -> None:  # type: ignore[no-untyped-def]
        sel = slice((-self.seen) % self.stride, None, self.stride)
        self.seen += len(r.t)
        self.names = list(r.names)
        for f, v in self.parts.items():
            v.append(np.asarray(getattr(r, f))[sel])
        a = np.flatnonzero(np.asarray(r.alarm, bool))
        if a.size and sum(len(x) for x in self.alarm_t) < _PLOT_POINTS:
            self.alarm_t.append(np.asarray(r.t)[a])
            self.alarm_s.append(np.asarray(r.statistic)[a])
        self.events += [e for e in r.events if e.kind in ("isolated", "invalid_isolated", "readmitted")][:1000]
        if sum(len(p) for p in self.parts["t"]) > 2 * _PLOT_POINTS:
            for f, v in self.parts.items():
                self.parts[f] = [np.concatenate(v)[::2]]
            self.stride *= 2

    def series(self):  # type: ignore[no-untyped-def]
        from types import SimpleNamespace

        cat = (lambda v: np.concatenate(v) if v else np.zeros(0))  # noqa: E731
        return SimpleNamespace(events=self.events, names=self.names, alarm_t=cat(self.alarm_t),
                               alarm_s=cat(self.alarm_s), **{f: np.concatenate(v) for f, v in self.parts.items()})


class _Errors:
    """segment_error_rms and sample_error_rms of rimu.fusion.validation.segment_errors, accumulated over the
    stream: per segment with a known input the sum of the sample errors (its mean is the segment-mean estimate's
    error, without the cancellation of two means of ~1 g), and the sum of the squared sample errors."""

    def __init__(self, session, instrument: str) -> None:  # type: ignore[no-untyped-def]
        self.session, self.k = session, instrument
        self.sd: dict[int, np.ndarray] = {}
        self.n: dict[int, int] = {}
        self.sq, self.count = 0.0, 0

    def add(self, x: np.ndarray, t: np.ndarray, seg: np.ndarray) -> None:
        from dataclasses import replace
        from types import SimpleNamespace

        from ..fusion.validation import known_inputs

        cut = np.flatnonzero(np.diff(seg)) + 1
        s = self.session
        for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(seg)]])):
            i = int(seg[a])
            full = s.segments[i]
            part = replace(full, t=np.concatenate([full.t[:1], t[a:b]]), raw={}, temperature=None)
            u = known_inputs(SimpleNamespace(segments=[part], latitude=s.latitude, gravity=s.gravity), self.k)[0]
            if u is None:
                continue
            u = u[1:]
            d = x[a:b] - u
            d = d[np.isfinite(d).all(axis=1)]  # samples without an estimate (unobservable) have no error
            self.sq += float(np.sum(d * d))
            self.count += d.size
            if i not in self.n:
                self.sd[i], self.n[i] = np.zeros(3), 0
            self.sd[i] += d.sum(axis=0)
            self.n[i] += len(d)

    def result(self):  # type: ignore[no-untyped-def]
        """:class:`rimu.fusion.validation.InstrumentErrors`, or None when no segment has a known input."""
        from ..fusion.validation import InstrumentErrors

        if not self.n:
            return None
        order = sorted(self.n)
        E = np.array([self.sd[i] / self.n[i] for i in order])
        return InstrumentErrors(self.k, float(np.sqrt(np.mean(E * E))), float(np.sqrt(self.sq / self.count)),
                                [self.session.segments[i].label for i in order], E)


class _Tee:
    """stdout that also keeps every line (the console's notes and cautions go into the report word for word)."""

    def __init__(self, out, lines: list[str]) -> None:  # type: ignore[no-untyped-def]
        self.out, self.lines, self.part = out, lines, ""

    def write(self, text: str) -> int:
        self.part += text
        *done, self.part = self.part.split("\n")
        self.lines += done
        return self.out.write(text)

    def flush(self) -> None:
        self.out.flush()

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        return getattr(self.out, name)


def run(args: argparse.Namespace) -> int:
    import contextlib
    import sys

    console: list[str] = []
    with contextlib.redirect_stdout(_Tee(sys.stdout, console)) if args.report else contextlib.nullcontext():
        return _run(args, console)


def _run(args: argparse.Namespace, console: list[str]) -> int:
    import contextlib

    from ..calibration import Calibration
    from ..epoch import EpochBlock
    from ..errors import CalibrationFileError, GeometryMismatchError, OptionError, RimuError, SessionFormatError
    from ..experiments.faults import inject, parse_injection
    from ..export.estimates import Estimates, estimate_columns, write_estimates
    from ..fdi import Runtime
    from ..fdi.detectors import make_detector
    from ..fdi.unit import stored_motion_detectors
    from ..fusion import Pipeline
    from ..progress import bar
    from ..session import iter_blocks
    from ..units import fmt  # the field's units, as rimu calibrate prints them
    from ._common import check_outputs, fdi_settings, noise_at_rate

    # the one default otherwise; refused as rimu monitor refuses (a setting the exported C cannot hold names its option)
    settings = fdi_settings(args, common_cause=True if args.common_cause else None, readmit_after=readmit_after(args))
    if args.no_readmit:
        settings = type(settings)(**{**settings.as_dict(), "readmit_after": None})
    if args.estimates:  # a CSV without a sidecar: checked alone, then against the other outputs and the inputs
        from ..errors import OutputPathError

        check_outputs(argparse.Namespace(estimates=args.estimates), files=("estimates",), dirs=(), inputs=())
        est_path = Path(args.estimates).resolve()
        for what, v in (("--json", args.json), ("the data file", args.data), ("--calibration", args.calibration)):
            if v and v != "-" and Path(v).resolve() == est_path:
                raise OutputPathError(f"--estimates {args.estimates} would overwrite {what} {v}; give another name")
    from ._inputs import session_file

    path = _epochs_recording_session(args.data, args.calibration)
    if path is None:
        path = session_file(args.data, "warn" if args.accept_implausible else "strict", args=args)
    try:  # pass 1: every format and plausibility check, the sample count, time span and rate; constant memory
        scan = _Scan(path, "warn" if args.accept_implausible else "strict")
    except RimuError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, AttributeError, UnicodeDecodeError) as exc:
        raise SessionFormatError(f"{path}: malformed session file ({type(exc).__name__}: {exc}); see "
                                 "docs/session-format.md") from exc
    session = scan.session
    if not scan.in_order:
        print("  note: the samples are not in the order of the sidecar's segments; they are replayed in file order")
    # the calibration must be of this unit: its geometry fingerprint against the data's (a dodecahedron6
    # calibration on cone6 data would otherwise isolate healthy sensors)
    try:
        cal = Calibration.load(args.calibration, geometries=session.geometries)
    except GeometryMismatchError as exc:
        if path == Path(args.data):
            raise
        # a log read as parallel triads against a unit set up with its board's geometry (rimu setup)
        n = next(iter(session.geometries.values())).n
        raise GeometryMismatchError(f"{exc}. {args.data} was read as {n} sensors on parallel axes; for a unit set "
                                    "up with rimu setup, replay the session it wrote (rimu setup LOG ... --session S.npz; rimu replay S.npz --calibration "
                                    f"{args.calibration})") from None
    insts = [k for k in cal.instruments if k in session.geometries]
    if args.instrument:
        unknown = sorted(set(args.instrument) - set(insts))
        if unknown:
            raise OptionError(f"--instrument {', '.join(unknown)}: not an instrument of both the calibration and the "
                              f"data ({', '.join(insts) or 'none'})")
        insts = [k for k in insts if k in args.instrument]
    if not insts:
        raise CalibrationFileError(f"the calibration ({', '.join(cal.instruments)}) and the data "
                                   f"({', '.join(session.instruments)}) have no instrument in common: nothing to replay")
    t0, t_end = scan.t_first, scan.t_last
    stated = {}  # --noise for the instruments whose calibration states none: a new calibration, the file's untouched
    for k in insts:
        if cal[k].noise_sigma is None:
            if args.noise is None:
                raise CalibrationFileError(f"the {k} calibration states no noise; pass --noise SIGMA (SI per sample)")
            stated[k] = dataclasses.replace(cal[k], noise_sigma=np.full(cal[k].geometry.n, float(args.noise)))
    if stated:
        cal = type(cal)({k: stated.get(k, cal[k]) for k in cal.instruments}, cal.raw_unit, cal.method, cal.created,
                        dict(cal.metadata))
    # the noise is stated for the epochs it was measured on (rimu setup's averages): at the data's rate
    cal = noise_at_rate(cal, scan.fs, "the data's")
    injections = [parse_injection(s) for s in args.inject]
    for inj in injections:  # a fault outside the data would be "injected" without touching a sample
        if not t0 <= inj.start < t_end:
            raise OptionError(f"--inject {inj.fault}:{inj.instrument}:{inj.sensor}:{inj.start:g}: starts at "
                              f"{inj.start:g} s, outside the data (t = {t0:g} .. {t_end:g} s)")
    chunk = _CHUNK
    if injections:  # names, sensors and sizes checked before the replay starts
        inject(EpochBlock(np.array([t0]), {k: np.zeros((1, g.n)) for k, g in session.geometries.items()}),
               injections, cal, seed=args.seed)
        for inj in injections:
            print(f"  injected {inj.fault} on {inj.instrument} {inj.sensor} at {inj.start:g} s, size "
                  f"{inj.size:g}{' sigma' if inj.in_sigma else ' SI'}")
        whole = sorted({inj.fault for inj in injections} - _POINTWISE_FAULTS)
        if whole and scan.n > chunk:
            chunk = scan.n
            print(f"  note: {', '.join(whole)} faults need their whole window: this replay holds the session in "
                  "memory (bias, ramp, dropout and zero stream in constant memory)")
    fs = scan.fs
    if args.detector in ("kalman", "glt_window") and args.p_fa > 1e-4:
        print(f"  note: --p-fa is per sample; the {args.detector} statistic is correlated over several samples, so "
              "alarms come in episodes that confirmation does not filter; consider --p-fa 1e-5")
    sub = Calibration({k: cal[k] for k in insts}, cal.raw_unit, cal.method, cal.created, dict(cal.metadata))
    unit = Pipeline(sub, temperature=scan.has_temp)
    if unit.compensation:
        print("  compensated effects: " + "; ".join(
            f"{k}: {', '.join(t.effect.name for t in c.terms)}" for k, c in unit.compensation.items()))

    def blocks(pipe=None):  # type: ignore[no-untyped-def]
        """pass 2 (and the motion fit): the file again, chunk by chunk, faults injected (and, given a pipeline,
        effects compensated: the motion fit's fault-free start)"""
        for blk in iter_blocks(path, chunk, invalid=True):  # empty and NaN cells: invalid samples
            if injections:
                blk = inject(blk, injections, cal, seed=args.seed)
            yield blk if pipe is None else pipe.compensate(blk)

    trackers = {}
    if args.selfcal_cusum and not args.selfcal:
        raise OptionError("--selfcal-cusum only applies with --selfcal")
    if args.selfcal:
        from ..fdi.selfcal import SelfCalTracker
        from .selfcal import tracker_settings

        if args.detector not in ("glt", "glt_window") or args.motion_fit is not None:
            raise OptionError("--selfcal runs the window GLT whose thresholds carry the tracker's covariance: use it "
                              f"with --detector glt or glt_window and without --motion-fit (got --detector "
                              f"{args.detector}{' --motion-fit' if args.motion_fit is not None else ''})")
        if args.selfcal_window * fs > scan.n:
            raise OptionError(f"--selfcal-window {args.selfcal_window:g} s is longer than the data ({scan.n} samples at "
                              f"{fs:g} Hz): the tracker would never absorb a window")
        trackers = {k: SelfCalTracker(cal[k], tracker_settings(args, cal[k], k, scan.has_temp, "selfcal-"))
                    for k in insts}
    # the detector of each instrument; the managers, their isolators and the self-calibration loops are the
    # runtime's (rimu.fdi.Runtime: the rule rimu monitor and the exported C share)
    detectors = {}
    stored = stored_motion_detectors(sub, args.p_fa, fs) if args.detector == "glt" and not trackers else {}
    for k in insts:
        if k in trackers:  # the window GLT with the tracker's covariance: --window samples, else the tracker's
            from ..fdi.selfcal import TrackedGltWindow

            if args.detector == "glt_window":
                detectors[k] = TrackedGltWindow(args.window, args.p_fa, cusum=args.selfcal_cusum)
            elif args.selfcal_cusum:  # the runtime's window (the tracker's), with the CUSUM bank
                detectors[k] = TrackedGltWindow(max(1, int(round(trackers[k].settings.window_s * fs))), args.p_fa,
                                                cusum=True)
        elif args.motion_fit is not None and k == "gyro":
            detectors[k] = _motion_detector(cal[k], _first_seconds(blocks(Pipeline(sub, temperature=scan.has_temp)),
                                                                   t0 + args.motion_fit),
                                            args.motion_fit, args.motion_margin, args.p_fa, fs)
        elif k in stored:
            detectors[k] = stored[k]
            _say_stored(k, stored[k])
        elif args.detector != "glt":
            detectors[k] = make_detector(args.detector, unit[k].table.sigma, window=args.window, p_fa=args.p_fa,
                                         arl0=args.arl0)
    # the managers closed loop with the compensation of further effects (rimu.fdi.Runtime: the decisions of the
    # exported C filter, sample by sample)
    um = Runtime(unit, settings.replace(confirm=1 if args.detector == "cusum" else None), detectors=detectors,
                 selfcal=trackers, selfcal_history=True, sample_rate=fs)
    alarms = dict.fromkeys(insts, 0)
    events: dict[str, list] = {k: [] for k in insts}
    finite = dict.fromkeys(insts, True)
    last_state: dict[str, str | None] = dict.fromkeys(insts)
    errors = {k: _Errors(session, k) for k in insts}
    plots = {k: _Plot() for k in insts} if args.report else {}
    at_rest = {k: [0, 0] for k in insts}  # alarms and samples in the segments at rest (kind static*)
    per_seg = {k: np.zeros((len(session.segments), 2), np.int64) for k in insts}  # alarms, samples per segment
    rest_kind = np.array([str(seg.kind).startswith("static") for seg in session.segments])
    px4 = _Px4(cal["gyro"]) if args.px4 and "gyro" in insts else None
    n_chunks = -(-scan.n // chunk)
    with contextlib.ExitStack() as stack:  # pass 2: the replay, one chunk in memory at a time
        est = None
        if args.estimates:
            from ..atomic import atomic_path

            est = stack.enter_context(stack.enter_context(atomic_path(args.estimates)).open("w"))
            est.write(",".join(estimate_columns(insts) + [c for r in um.selfcal_records.values()
                                                             for c in r.columns()]) + "\n")
        for blk in bar(blocks(), total=n_chunks, desc="replay", unit="chunk", enabled=None if n_chunks > 1 else False):
            results = um.run(blk)
            for k in insts:
                r = results[k]
                alarms[k] += int(np.count_nonzero(r.alarm))
                rest = rest_kind[blk.meta["segment"]]
                at_rest[k][0] += int(np.count_nonzero(np.asarray(r.alarm)[rest]))
                at_rest[k][1] += int(rest.sum())
                np.add.at(per_seg[k], (blk.meta["segment"], 0), np.asarray(r.alarm, np.int64))
                np.add.at(per_seg[k], (blk.meta["segment"], 1), 1)
                events[k] += r.events
                # a number wherever there is an estimate; NaN exactly where there is none (unobservable)
                finite[k] = finite[k] and bool(np.array_equal(np.isfinite(r.x).all(axis=1), r.validity != 2))
                last_state[k] = r.state_names()[-1]
                errors[k].add(np.asarray(r.x), blk.t, blk.meta["segment"])
                if plots:
                    plots[k].add(r)
            extra = um.selfcal_columns(blk.t)
            if est is not None:
                e = Estimates.from_replay(blk.t, results)
                e.extra = extra or None
                write_estimates(est, e, header=False)
            if px4 is not None:
                px4.add(blk)
    summary: dict = {}
    for k in insts:
        mgr = um.managers[k]
        print(f"\n  {k}: {scan.n} samples, detector {getattr(mgr.detector, 'name', args.detector)}; final state {mgr.state.value}"
              + (f", isolated {', '.join(mgr.health.isolated)}" if mgr.health.isolated else ""))
        shown = [e for e in events[k] if e.kind != "transient"]
        n_tr = sum(1 for e in events[k] if e.kind == "transient")
        for e in shown[:50]:
            print(f"    t = {e.t:8.3f} s (sample {e.sample:>7d})  {e.kind:22s} {e.sensor or '':4s} {e.message}")
        if len(shown) > 50:
            print(f"    ... {len(shown) - 50} more")
        print(f"    transient alarm episodes (not confirmed): {n_tr}; outputs finite: {finite[k]}")
        entry = {"samples": scan.n, "alarms": alarms[k],
                 "isolations": sum(1 for e in events[k] if e.kind in ("isolated", "invalid_isolated")),
                 "final_state": mgr.state.value}
        err = errors[k].result()
        if err is not None:
            entry.update(err.to_dict())
            print(f"    runtime error: segment_error_rms {fmt(err.segment_error_rms, k)} over "
                  f"{len(err.segments)} segments, sample_error_rms {fmt(err.sample_error_rms, k)}")
        print(f"    alarms {entry['alarms']}, isolations {entry['isolations']}")
        if at_rest[k][1]:
            a, n = at_rest[k]
            entry["rest_alarms"], entry["rest_samples"] = a, n
            entry["segments"] = [{"label": seg.label, "kind": seg.kind, "t_start_s": st.t0, "t_end_s": st.t_last,
                                  "alarms": int(per_seg[k][i, 0]), "samples": int(per_seg[k][i, 1])}
                                 for i, (seg, st) in enumerate(zip(session.segments, scan.stats))]
            print(f"    alarm rate at rest (the session's static segments): {fmt(a / n, 'ratio', '%', digits=3)} of {n} "
                  f"samples (design: --p-fa {fmt(args.p_fa, 'ratio', '%', digits=3)})")
        if k in um.selfcal:
            entry["selfcal"] = loop_summary(k, um.selfcal[k])
        summary[k] = entry
    px4_doc = px4.report() if px4 is not None else None
    if args.estimates:
        print(f"\n  estimates: {args.estimates} ({scan.n} rows)")
    if args.json:
        from ._common import json_dump

        keep = ("alarms", "isolations", "rest_alarms", "rest_samples", "segments", "selfcal")
        # final_state: the manager's state at the end, as printed and as summary.json has it, with the sensors
        # isolated then; last_sample_state: the last sample's label (an alarm's suspects left out of that sample's
        # set read as fault_isolated there though nothing is isolated; it was given as final_state)
        doc = {k: {"events": [e.to_dict() for e in events[k]], "final_state": um.managers[k].state.value,
                   "isolated_at_end": list(um.managers[k].health.isolated), "last_sample_state": last_state[k],
                   **{f: v for f, v in summary[k].items() if f in keep}} for k in insts}
        if px4_doc is not None:
            doc["px4"] = px4_doc
        print(f"\n  events: {json_dump(doc, args.json)}")
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        series = {k: p.series() for k, p in plots.items()}
        page = _report(series, summary, events, args, console, fmt)
        if page is not None:  # the tracked terms: sections of the same page (and PDF), after the replay's figure
            for k, rec in um.selfcal_records.items():
                page.heading(f"Self-calibration: {k}")
                page.figure(terms_figure(k, rec.loop.tracker, rec.series or [rec.last]),
                            f"{k}: the terms the in-flight self-calibration tracked over the replay "
                                          "(docs/selfcal.md), each sensor with its 1-sigma band, in the field's units.")
        if page is None:
            print("  (matplotlib not installed: no plot; pip install 'rimu[plots]')")
        else:
            png = page.save_figure(0, out / "replay.png", dpi=90)
            html, pdf = page.write(out, "replay_report")
            print(f"  plot:   {png}\n  report: {html} and {pdf}")
            for j, k in enumerate(um.selfcal_records, start=1):  # figure 0 is the replay's, then one per tracked instrument
                print(f"  plot:   {page.save_figure(j, out / f'selfcal-{k}.png', dpi=90)}")
    if args.output:
        import json

        from ..atomic import write_text

        out = Path(args.output)
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "summary.json", json.dumps(summary if px4_doc is None else {**summary, "px4": px4_doc}, indent=1))
        print(f"  summary: {out / 'summary.json'}")
    n_iso = sum(v["isolations"] for v in summary.values())
    errs = ", ".join(f"{k} segment_error_rms {fmt(v['segment_error_rms'], k, digits=3)}"
                     for k, v in summary.items() if "segment_error_rms" in v)
    print(f"replayed {scan.n} samples: {n_iso} isolation(s)" + (f"; {errs}" if errs else ""))
    return 0


class _Px4:
    """The PX4 EKF2-selector-style rule (:class:`rimu.fdi.Px4GyroSelector`) beside the runtime: each triad's gyro
    rates with the calibration's bias removed, in MB, gathered over the replay and judged at its end."""

    def __init__(self, cal) -> None:  # type: ignore[no-untyped-def]
        from ..errors import ShapeError

        subs = cal.geometry.subunits
        if len(subs) < 2 or any(len(su.members) != 3 for su in subs):
            raise ShapeError("--px4 compares triads: the gyros must be two or more triads (sub-units of 3 sensors)")
        self.cal = cal
        self.names = [su.name for su in subs]
        self.t: list[np.ndarray] = []
        self.W: list[np.ndarray] = []

    def add(self, blk) -> None:  # type: ignore[no-untyped-def]
        y = np.where(blk.valid["gyro"], blk.raw["gyro"], np.nan) if "gyro" in blk.valid else blk.raw["gyro"]
        z = (y - self.cal.bias) / np.asarray(self.cal.scale)
        self.W.append(np.stack([z[:, list(su.members)] @ su.mat_sb_mb for su in self.cal.geometry.subunits], axis=1))
        self.t.append(np.asarray(blk.t, float))

    def report(self) -> dict:
        from ..fdi import Px4GyroSelector
        from ..units import fmt

        t, W = np.concatenate(self.t), np.concatenate(self.W)
        # no timeout: the session holds clipped samples as invalid, where PX4 would read the clipped value
        res = Px4GyroSelector(timeout_s=np.inf).run(t, W, np.isfinite(W).all(axis=2))
        flags = [{"triad": self.names[i], "t": float(res.t_flag[i]), "reason": res.reason[i]}
                 for i in np.argsort(res.t_flag) if np.isfinite(res.t_flag[i])]
        print("\n  PX4-style rule (|rate - median of the others| - 7 deg/s, integrated to 15 deg), same samples, "
              "invalid ones skipped: "
              + ("; ".join(f"{f['triad']} flagged at {fmt(f['t'], 'time', 's', digits=4)} ({f['reason']})" for f in flags)
                 if flags else "no triad flagged"))
        return {"flags": flags}


def _say_stored(k: str, det) -> None:  # type: ignore[no-untyped-def]
    """The motion-aware test of the terms ``rimu setup --motion-fit`` stored in the calibration, said once."""
    from ..fdi.motion import envelope_text

    print(f"  {k}: motion terms of the calibration (rimu setup --motion-fit, {det.fit_samples} epochs)"
          + ("" if det.envelope is None else
             f"; the thresholds assume {envelope_text(det.envelope)}: an alarm beyond is model_exceeded (output "
             "DEGRADED), nothing isolated"))


def _first_seconds(blocks, t_stop: float):  # type: ignore[no-untyped-def]
    """The samples before ``t_stop`` of a stream of blocks, as one block (the motion fit's span)."""
    from ..epoch import EpochBlock

    parts = []
    for blk in blocks:
        parts.append(blk)
        if blk.t[-1] >= t_stop:
            break
    blocks.close()
    ks = list(parts[0].raw)
    return EpochBlock(np.concatenate([b.t for b in parts]), {k: np.vstack([b.raw[k] for b in parts]) for k in ks},
                      {k: np.vstack([b.valid[k] for b in parts]) for k in parts[0].valid})


def _motion_detector(cal, block, seconds: float, margin: float, p_fa: float, fs: float):  # type: ignore[no-untyped-def]
    """Motion-aware GLT with the motion terms fitted on the first ``seconds`` of the gyro data (every sensor valid)."""
    from ..errors import ShapeError
    from ..fdi.motion import check_fit_span, fit_motion_detector

    span = float(block.t[-1] - block.t[0])
    if seconds > span:  # clamped to the data, said
        print(f"  note: --motion-fit {seconds:g} s is longer than the data ({span:.4g} s): the motion terms are "
              "fitted on all of it, and a fault anywhere in it would be absorbed (the check below looks for one)")
        seconds = span + 1.0 / fs
    sel = block.t < block.t[0] + seconds
    valid = None if block.valid.get("gyro") is None else block.valid["gyro"][sel]
    try:
        det = fit_motion_detector(cal, block.raw["gyro"][sel], valid, fs, margin=margin, p_fa=p_fa)
        check_fit_span(cal, det, block.t[sel], block.raw["gyro"][sel], valid, f"--motion-fit {seconds:g}")
    except ShapeError as exc:
        raise ShapeError(f"--motion-fit {seconds:g}: {exc}") from None
    model = det.model
    print(f"  gyro: motion terms fitted on {det.fit_samples} samples (first {seconds:g} s, margin {margin:g}): "
          f"scale {1e2 * float(np.median(model.scale_rel)):.2f} %, misalignment "
          f"{1e3 * float(np.median(model.misalignment_rad)):.2f} mrad, time offset "
          f"{1e3 * float(np.median(model.time_offset_s)):.2f} ms (medians)")
    if det.envelope is not None:
        from ..fdi.motion import envelope_text

        print(f"  gyro thresholds assume the motion of the fit span: {envelope_text(det.envelope)}; an alarm beyond "
              "is reported as model_exceeded (output DEGRADED) and isolates nothing")
    return det


def _report(results: dict, summary: dict, events: dict, args: argparse.Namespace, console: list[str],
            fmt):  # type: ignore[no-untyped-def]
    """The replay report in rimu's one layout (:class:`rimu.report.Report`): the console's notes and cautions,
    the summary per instrument in the field's units, and per instrument one column of panels on one time axis, as
    a flight-review page shows a flight: the parity statistic against its threshold with every alarm sample, the
    estimate, its validity, the sensors in the estimate with every isolation and readmission. None without
    matplotlib."""
    from ..plotting import pyplot

    plt = pyplot(optional=True)
    if plt is None:
        return None
    from ..fdi.manager import HealthState
    from ..fusion.validity import Validity
    from ..report import Report
    from ..units import field_unit

    page = Report(f"rimu replay: {Path(args.data).name} with {Path(args.calibration).name}")
    page.cautions([ln.strip() for ln in console if ln.strip().startswith(("note:", "caution", "warning"))])
    rows = []
    for k, e in summary.items():
        rows.append([k, e["samples"], e["alarms"], e["isolations"], e["final_state"],
                     fmt(e.get("segment_error_rms"), k), fmt(e.get("sample_error_rms"), k)])
    page.table(["instrument", "samples", "alarm samples", "isolations", "final state", "segment_error_rms",
                "sample_error_rms"], rows, "against the known inputs of the segments (docs/runtime.md)")
    names = {i: h.value for i, h in enumerate(HealthState)}
    page.text("States the unit went through: " + "; ".join(
        f"{k}: {', '.join(names[int(v)] for v in np.unique(r.state))}" for k, r in results.items()))
    shown = [(k, e) for k in events for e in events[k] if e.kind != "transient"][:200]
    if shown:
        page.heading("Events")
        page.table(["instrument", "t [s]", "sample", "event", "sensor", "message"],
                   [[k, f"{e.t:.3f}", e.sample, e.kind, e.sensor or "", e.message] for k, e in shown])
    k_n = len(results)
    fig, axes = plt.subplots(4, k_n, figsize=(6.2 * k_n, 10), sharex="col", squeeze=False)
    for c, (k, r) in enumerate(results.items()):
        iso = [e for e in r.events if e.kind in ("isolated", "invalid_isolated", "readmitted")]
        ax = axes[0, c]
        ln, = ax.semilogy(r.t, np.maximum(r.statistic, 1e-3), lw=0.5, label="parity statistic")
        ln.set_gid("data")
        ax.semilogy(r.t, np.where(np.isfinite(r.threshold), r.threshold, np.nan), "k--", lw=1, label="threshold")
        if r.alarm_t.size:
            ax.semilogy(r.alarm_t, np.maximum(r.alarm_s, 1e-3), "r.", ms=2, label="alarm samples")
        ax.set_title(f"{k}: parity statistic and alarms", fontsize=10)
        ax.set_ylabel("statistic [-]")
        ax = axes[1, c]
        x = np.asarray(r.x, float)
        unit, f = field_unit(k, float(np.nanmax(np.abs(x))) if np.isfinite(x).any() else None)
        for a, col in zip(range(3), ("C3", "C2", "C0")):
            ax.plot(r.t, x[:, a] * f, color=col, lw=0.5, label="xyz"[a])
        ax.set_title(f"{k}: estimate (master-body frame)", fontsize=10)
        ax.set_ylabel(("angular rate" if k == "gyro" else "specific force") + f" [{unit}]")
        ax = axes[2, c]
        ln, = ax.step(r.t, r.validity, where="post", color="C1", lw=1)
        ln.set_gid("data")
        ax.set_yticks([v.value for v in Validity], [v.name.lower() for v in Validity], fontsize=7)
        ax.set_ylim(-0.3, len(Validity) - 0.7)
        ax.set_title(f"{k}: validity of the estimate", fontsize=10)
        ax = axes[3, c]
        ln, = ax.step(r.t, r.n_active, where="post", color="C0", lw=1, label="sensors in the estimate")
        ln.set_gid("data")
        for e in iso:
            ax.axvline(e.t, color="C3" if e.kind != "readmitted" else "C2", lw=0.8, ls=":")
        n_max = max(len(r.names), int(np.max(r.n_active)) if r.n_active.size else 0)
        for e in iso[:30]:
            ax.annotate(f"{'readmit' if e.kind == 'readmitted' else 'isolate'} {e.sensor}", (e.t, n_max),
                        fontsize=7, rotation=90, va="top", ha="right")
        ax.set_ylim(-0.2, n_max + 0.5)
        ax.set_ylabel("sensors [count]")
        ax.set_xlabel("time [s]")
        ax.set_title(f"{k}: sensors in use and isolations", fontsize=10)
        for ax in axes[:, c]:
            ax.grid(alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    page.heading("Parity, validity, alarms and isolations on one time axis")
    page.figure(fig, "Per instrument: the parity test statistic against its threshold (red: alarm samples), the "
                     "estimate, its validity and the sensors in it (dotted: isolation in red, readmission in green).")
    return page


def _epochs_recording_session(data: str, calibration: str) -> Path | None:
    """A recording of ``rimu monitor -o`` (``# rimu epochs v1`` CSV, no sidecar) as a one-segment session file in
    a scratch folder, the geometries taken from the calibration, invalid samples as NaN (so replay decides on
    them as monitor did); None for any other input."""
    import atexit
    import shutil
    import tempfile

    from ..calibration.result import Calibration
    from ..epoch import EpochBlock
    from ..errors import SessionFormatError
    from ..io.recorded import CSV_MAGIC, CsvSource
    from ..session import Segment, Session, save_session

    p = Path(data)
    if p.suffix.lower() != ".csv" or not p.is_file() or p.with_suffix(".json").exists():
        return None
    with open(p, "rb") as fh:
        if fh.readline().rstrip(b"\r\n").decode("utf-8", "replace") != CSV_MAGIC:
            return None
    cal = Calibration.load(calibration)
    epochs = list(CsvSource(path=p))
    if len(epochs) < 2:
        raise SessionFormatError(f"{p}: fewer than 2 epochs in the recording; nothing to replay")
    block = EpochBlock.from_epochs(epochs)
    raw = {}
    for k in cal.instruments:
        if k in block.raw:
            y = np.array(block.raw[k], dtype=float)
            v = block.valid.get(k) if block.valid else None
            if v is not None:
                y[~np.asarray(v, dtype=bool)] = np.nan
            raw[k] = y
    if not raw:
        raise SessionFormatError(f"{p}: the recording and the calibration {calibration} share no instrument")
    rate = 1.0 / float(np.median(np.diff(block.t)))
    seg = Segment("recording", "motion", np.asarray(block.t, float), raw, block.temperature)
    session = Session([seg], {k: cal[k].geometry for k in raw}, rate, meta={"recording": str(p)})
    tmp = tempfile.mkdtemp(prefix="rimu-rec-")
    atexit.register(shutil.rmtree, tmp, True)
    out = Path(save_session(session, Path(tmp) / (p.stem + ".npz")))
    from ..atomic import flush_outputs

    flush_outputs()  # a scratch input, read back at once: not held back with the command's outputs
    return out

