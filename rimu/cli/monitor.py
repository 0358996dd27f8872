"""``rimu monitor``: a live (or recorded) source through compensation and FDI, with a status line.

Sources (one of)::

    --can virtual:rimu --layout cone6_rimu        python-can interface:channel and a layout (file or shipped name)
    --can socketcan:can0 --layout my_imu.json
    --serial /dev/ttyUSB0 --baud 921600           rimu's serial framing (docs/io.md)
    --replay log.asc --layout cone6_rimu          a python-can log (ASC, BLF, CSV, candump .log)
    --csv rec.csv | --npz run.npz | --ulog flight.ulg
    --simulate                                    a simulated cone6 device on a virtual CAN bus (no hardware)

Each epoch goes through the unit's runtime (:class:`rimu.fdi.Runtime`: compensation of every effect, Cho & Park
Eq. 20 projection, the GLT on the parity vector, the set test, confirmation, Eq. 21 isolation, re-admission,
validity): the decisions of ``rimu replay`` and of the exported C filter on the same samples. A status line
shows the epoch rate, frame counters and the health of each instrument; ``-o`` records the epochs as CSV,
``--estimates`` writes the estimates and decisions per epoch. Ctrl-C ends cleanly with a summary (epochs,
accounting identity, rejections by reason, isolations).

``--selfcal`` runs the in-flight self-calibration live (docs/selfcal.md), through the same runtime as ``rimu replay
--selfcal`` and the exported C of ``rimu export-c --selfcal`` (the same ``--selfcal-*`` options): each instrument's
compensated outputs are corrected by the tracked terms before its manager, whose window GLT carries the tracker's
covariance; ``--estimates`` then ends every row with the tracked terms and their 1-sigma (SI), and the summary
shows the terms at the end. The windows are counted at the stream's rate.

The stream's rate, where the runtime depends on it (a unit set up on averages, whose noise is stated for their
period: ``rimu setup --average``; the unit file's motion-aware tests; ``--selfcal``), is ``--sample-rate``, else the
simulated device's, the layout's or the transport's declared rate, else measured on the first 50 epochs (said on one
line). The noise is then converted to that rate as ``rimu replay`` converts it to the data's (white noise: sigma
sqrt(T_noise / T)); motion terms fitted at another rate refuse, as in ``rimu replay``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from ..units import fmt


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("monitor", help="live source -> compensation -> FDI, with a status line",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--can", metavar="INTERFACE:CHANNEL", help="python-can interface and channel")
    src.add_argument("--serial", metavar="PORT", help="serial port or pyserial URL")
    src.add_argument("--replay", metavar="LOG", help="python-can log file, or an IMU log (rimu import --help)")
    src.add_argument("--csv", metavar="FILE", help="rimu CSV recording")
    src.add_argument("--npz", metavar="FILE", help="NPZ file of rimu simulate")
    src.add_argument("--ulog", metavar="FILE", help="PX4 ULog flight log (extra 'ulog')")
    src.add_argument("--simulate", action="store_true", help="simulated cone6 device on a virtual CAN bus")
    p.add_argument("--layout", default="cone6_rimu", help="CAN layout file or shipped name (default cone6_rimu)")
    from ._common import Deprecated, add_fdi_options, add_json_option, add_readmit_options, positive_float, positive_int

    p.add_argument("--baud", type=positive_int, default=921600, help="serial baud rate")
    p.add_argument("--serial-format", default=None, metavar="NAME",
                   help="--serial only: a device's own stream instead of rimu's framing (a source of rimu.io's "
                        "registry, e.g. mimu4444)")
    p.add_argument("--common-cause", action="store_true",
                   help="invalid samples of several sub-units at once (triads clipping together) are a common cause: "
                        "routed around, never isolated (rimu.fdi.common_cause)")
    p.add_argument("--calibration", help="calibration file (rimu.calibration JSON); --simulate uses the truth")
    p.add_argument("--geometry", default=None, help="geometry preset of gyros and accelerometers "
                   "(default: the layout's, or cone6)")
    add_fdi_options(p)
    add_readmit_options(p, "rimu replay and rimu export-c")
    p.add_argument("--estimates", default=None, metavar="FILE.csv",
                   help="write per epoch the estimates and decisions, the columns of rimu replay --estimates and of "
                        "the exported C filter")
    p.add_argument("-o", "--output", dest="record", metavar="CSV", help="record every epoch to this CSV file")
    p.add_argument("--record", action=Deprecated, new="-o/--output CSV", metavar="CSV")
    p.add_argument("--side-log", metavar="JSONL", help="keep rejected raw data in this file")
    p.add_argument("--realtime", action="store_true", help="pace replays and the simulated device in real time")
    p.add_argument("--duration", type=positive_float, default=None, help="stop after this many seconds of data")
    p.add_argument("--idle-timeout", type=positive_float, default=2.0, help="stop a live source after this long silent")
    p.add_argument("--status-interval", type=positive_float, default=0.5, help="s between status lines")
    p.add_argument("--fault", default="gyro:y2:10:10",
                   help="--simulate only: INSTRUMENT:SENSOR:T_S:SIGMAS step bias, or 'none'")
    p.add_argument("--sim-duration", type=positive_float, default=20.0, help="--simulate only: s of simulated data")
    add_json_option(p, "the final summary", allow_bare=True)
    p.add_argument("--sample-rate", type=positive_float, default=None,
                   help="the stream's rate, Hz (default: the simulated device's, the layout's or the transport's, "
                        "else measured on the first epochs): the noise of a unit set up on averages, the motion "
                        "terms and --selfcal's windows are taken at it")
    from .selfcal import add_tracker_options

    s = p.add_argument_group("in-flight self-calibration (docs/selfcal.md; the options of rimu replay --selfcal)")
    s.add_argument("--selfcal", action="store_true",
                   help="track the calibration's drift live and compensate with it, as rimu replay --selfcal")
    s.add_argument("--selfcal-temperature", action="store_true",
                   help="the epochs carry the unit's temperature: track the temperature coefficients")
    add_tracker_options(s, "selfcal-")
    p.set_defaults(func=run)


def _geometries(args: argparse.Namespace, layout: Any | None) -> dict:
    from ..geometry import preset

    if args.geometry:
        return {"gyro": preset(args.geometry), "accel": preset(args.geometry)}
    if layout is not None and layout.geometry:
        return {k: preset(v) for k, v in layout.geometry.items()}
    return {"gyro": preset("cone6"), "accel": preset("cone6")}


def _open(args: argparse.Namespace) -> tuple[Any, Any, dict]:
    """The source, the calibration, and things to clean up."""
    from ..calibration import Calibration
    from ..errors import CalibrationFileError
    from ..io import SideLog
    from ..io.layout import load_layout
    from ._inputs import log_source

    side = SideLog(args.side_log, max_items=0) if args.side_log else None
    extra: dict = {}
    layout = None
    if args.simulate:
        import can

        from ..io.can import CanSource
        from ..io.device import CanDevice
        from ..sim import Simulator, rotation

        sim = Simulator(seed=0)
        run = sim.run([rotation("manoeuvre", [0.0, 0.5236, 0.0], duration=args.sim_duration)])
        fault = None
        if args.fault != "none":
            try:
                inst, name, t_f, sig = args.fault.split(":")
                i = sim.geometries[inst].index(name)
                size = float(sig) * sim.noise_sigma(inst) / run.truth[inst].scale[i]
                float(t_f)
            except (ValueError, KeyError, IndexError):
                from ..errors import OptionError

                raise OptionError(f"--fault {args.fault}: expected INSTRUMENT:SENSOR:T_S:SIGMAS with instrument gyro or "
                                  f"accel and a sensor of cone6 ({', '.join(sim.geometries['gyro'].names)}), e.g. "
                                  "gyro:y2:10:10, or 'none'") from None

            def fault(block, inst=inst, i=i, t_f=float(t_f), size=size):
                from ..epoch import EpochBlock

                raw = {k: y.copy() for k, y in block.raw.items()}
                raw[inst][block.t >= t_f, i] += size
                return EpochBlock(block.t, raw, dict(block.valid), block.temperature)
            print(f"rimu monitor: simulated cone6 unit, {args.fault.replace(':', ' ')}-sigma step fault "
                  "(instrument sensor t sigmas)")
        channel = f"rimu-sim-{uuid.uuid4().hex[:8]}"
        rx = can.Bus(interface="virtual", channel=channel)
        tx = can.Bus(interface="virtual", channel=channel)
        # faster than real time, frame times are wall-clock receive times: a stall of the sending thread must
        # not close epochs early, so the time window is widened (the counter window still applies)
        src = CanSource(args.layout, bus=rx, idle_timeout=args.idle_timeout, side_log=side,
                        timeout=None if args.realtime else 1.0)
        extra["thread"] = CanDevice(args.layout, fault=fault).start(tx, run.block, realtime=args.realtime)
        extra["tx"] = tx
        extra["n_expected"] = len(run.block)
        extra["rate"] = sim.sample_rate
        return src, run.truth, extra
    if args.can:
        from ..io.can import CanSource

        iface, _, channel = args.can.partition(":")
        layout = load_layout(args.layout)
        try:
            src = CanSource(layout, interface=iface, channel=channel or "0", idle_timeout=args.idle_timeout,
                            side_log=side)
        except (ImportError, OSError):
            raise
        except Exception as exc:  # python-can's own errors (unknown interface, bus not up) are not OSErrors
            from ..errors import TransportError

            raise TransportError(f"--can {args.can}: cannot open the CAN bus ({exc}); check the interface name "
                                 "(socketcan, virtual, pcan, ...) and that the channel exists") from exc
    elif args.serial:
        from ..io.serial import SerialSource

        if args.serial_format:
            from ..io.registry import source_class

            src = source_class(args.serial_format)(args.serial, args.baud, idle_timeout=args.idle_timeout,
                                                   side_log=side)
        else:
            src = SerialSource(args.serial, args.baud, idle_timeout=args.idle_timeout, side_log=side)
    elif args.replay and (src := log_source(args.replay)) is not None:  # an IMU log (rimu import --help)
        pass
    elif args.replay:
        from ..io.can import CanReplaySource

        layout = load_layout(args.layout)
        src = CanReplaySource(args.replay, layout, realtime=args.realtime, side_log=side)
    elif args.csv:
        from ..io.recorded import CsvSource

        src = CsvSource(args.csv)
    elif args.npz:
        from ..io.recorded import NpzSource

        src = NpzSource(args.npz)
    else:
        from ..io.ulog import ULogSource

        src = ULogSource(args.ulog)
    if not args.calibration:
        raise CalibrationFileError("this source needs --calibration FILE (a rimu calibration of the unit)")
    geos = _geometries(args, layout)
    if args.ulog:
        geos = {k: src.geometry(k) for k in src.instances}
    elif hasattr(src, "recording") or args.serial_format:  # an IMU log or a device stream: the unit's geometry is the
        geos = None                                            # calibration's (rimu setup fits axes)
    return src, Calibration.load(args.calibration, geometries=geos), extra


class _Monitor:
    """The runtime (:class:`rimu.fdi.Runtime`: the decisions of ``rimu replay`` and of the exported C) on a live
    stream: its new events per epoch, and the estimates file."""

    def __init__(self, pipe: Any, settings: Any, estimates: str | None, detectors: dict | None = None,
                 selfcal: dict | None = None, rate: float | None = None) -> None:
        from ..fdi import Runtime

        # the runtime's default managers (rimu.fdi.Runtime: the rule rimu replay and the exported C share): the
        # unit file's motion-aware tests (rimu setup --motion-fit) or the tracker's window GLT where given, the
        # terms after every window kept for the estimates and the summary
        self.rt = Runtime(pipe, settings, detectors=detectors, selfcal=selfcal, selfcal_history=True,
                          sample_rate=rate)
        self.seen = {k: 0 for k in self.rt.managers}
        #: alarm samples per instrument (the detector's test exceeded its threshold; confirmed or not)
        self.alarms = dict.fromkeys(self.rt.managers, 0)
        self.events: list[dict] = []
        self.isolations: list[dict] = []
        self.est = estimates
        self.rows: list[tuple] = []
        self.fh: Any = None
        self.n_rows = 0

    def step(self, ep: Any, n: int) -> list[dict]:
        if n == 0 and ep.temperature is None and any(
                b.startswith("tc") for loop in self.rt.selfcal.values() for b in loop.tracker.blocks):
            from ..errors import MissingInputError

            raise MissingInputError("--selfcal-temperature: the source's epochs carry no temperature; drop the option")
        res = self.rt.step(ep)
        for k, r in res.items():
            self.alarms[k] += bool(r.alarm)
        new = []
        for k, m in self.rt.managers.items():
            evs = m.events[self.seen[k]:]
            self.seen[k] = len(m.events)
            for e in evs:
                d = {"t": e.t, "sample": n, "instrument": k, "kind": e.kind, "sensor": e.sensor, "message": e.message}
                new.append(d)
                self.events.append(d)
                if e.kind in ("isolated", "invalid_isolated"):
                    self.isolations.append(d)
        terms: dict = {}
        if self.rt.selfcal_records:  # the terms of the last window that ended before this epoch
            import numpy as np

            terms = self.rt.selfcal_columns(np.array([float(ep.t)]))
        if self.est is not None:
            self.rows.append((float(ep.t), {k: (r.x.copy(), int(r.validity), self.rt.managers[k].isolated)
                                            for k, r in res.items()}, terms))
            if len(self.rows) >= 1000:
                self.flush()
        return new

    def open(self, stack: Any) -> None:
        if self.est is None:
            return
        from ..atomic import atomic_path
        from ..export.estimates import estimate_columns

        self.fh = stack.enter_context(stack.enter_context(atomic_path(self.est)).open("w"))
        self.fh.write(",".join(estimate_columns({k: m.n for k, m in self.rt.managers.items()})
                               + [c for r in self.rt.selfcal_records.values() for c in r.columns()]) + "\n")

    def flush(self) -> None:
        if self.fh is None or not self.rows:
            return
        import numpy as np

        from ..export.estimates import Estimates, write_estimates

        ks = list(self.rt.managers)
        cols = list(self.rows[0][2])
        est = Estimates(np.array([t for t, _, _ in self.rows]),
                        {k: np.array([d[k][0] for _, d, _ in self.rows]) for k in ks},
                        {k: np.array([d[k][1] for _, d, _ in self.rows]) for k in ks},
                        {k: np.array([d[k][2] for _, d, _ in self.rows]) for k in ks},
                        {c: np.concatenate([e[c] for _, _, e in self.rows]) for c in cols} or None)
        write_estimates(self.fh, est, header=False)
        self.n_rows += len(self.rows)
        self.rows = []


def _status(t: float, rate: float, src: Any, mon: _Monitor) -> str:
    a = src.accounting
    parts = [f"t {fmt(t, 'time', 's', decimals=2, width=9)}", fmt(rate, "frequency", "Hz", decimals=1, width=6),
             f"{a.unit}s {a.received} ok {a.accepted} rej {a.rejected_total}"]
    for k, m in mon.rt.managers.items():
        r = m.result
        h = m.health
        parts.append(f"{k} {int(r.active.sum()) if r.observable else 0}/{m.n} ok {h.state.value} FD "
                     f"{fmt(h.statistic, 'ratio', '', decimals=1, width=6)}/{fmt(h.threshold, 'ratio', '', decimals=1)}"
                     + (f" isolated {','.join(h.isolated)}" if h.isolated else ""))
    return " | ".join(parts)


def _install_sigint(handler: Any) -> Any:
    """Install a SIGINT handler (main thread only; elsewhere Ctrl-C keeps raising KeyboardInterrupt)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGINT, handler)


def _restore_sigint(old: Any) -> None:
    import signal

    if old is not None:
        signal.signal(signal.SIGINT, old)


def run(args: argparse.Namespace) -> int:
    import contextlib
    import itertools

    from ..fusion import Pipeline
    from ..io.accounting import Outages
    from ..io.recorded import CsvRecorder
    from ._common import fdi_settings, noise_at_rate, readmit_after

    settings = fdi_settings(args, readmit_after=readmit_after(args), common_cause=True if args.common_cause else None)
    if args.no_readmit:
        settings = type(settings)(**{**settings.as_dict(), "readmit_after": None})
    if args.selfcal_temperature and not args.selfcal:
        from ..errors import OptionError

        raise OptionError("--selfcal-temperature only applies with --selfcal")
    src, cal, extra = _open(args)
    try:
        # the stream's rate (declared, else measured on its first epochs) where anything depends on it: the noise
        # of a unit set up on averages, the unit file's motion-aware tests, the tracker's windows
        rate, head, epochs = _rate(args, cal, src, extra)
        if rate is not None:
            cal = noise_at_rate(cal, rate, "the stream's", prefix="rimu monitor: ")
        pipe = Pipeline(cal)
        if args.selfcal:
            mon = _Monitor(pipe, settings, args.estimates, selfcal=_trackers(args, cal, rate), rate=rate)
        else:
            mon = _Monitor(pipe, settings, args.estimates, _stored_detectors(cal, settings, rate), rate=rate)
    except BaseException:
        src.close()
        if extra.get("tx") is not None:
            extra["thread"].stop.set()
            extra["tx"].shutdown()
        raise
    stack = contextlib.ExitStack()
    mon.open(stack)
    rec = CsvRecorder(args.record) if args.record else None
    outages = Outages()
    tty = sys.stdout.isatty()
    n = 0
    t0 = t_last = None
    w0 = time.monotonic()
    w_status = w0
    n_status = 0
    interrupted = False
    stop_requested = []

    def _on_sigint(signum: int, frame: Any) -> None:
        # the first Ctrl-C asks the source to stop (the loop ends at the next epoch or receive timeout, with
        # every lock released); an exception raised at an arbitrary point could leave a transport's lock held
        # and hang the shutdown. A second Ctrl-C interrupts at once.
        if stop_requested:
            raise KeyboardInterrupt
        stop_requested.append(True)
        src.stop()

    old_handler = _install_sigint(_on_sigint)
    try:
        for ep in itertools.chain(head, epochs):
            if stop_requested:
                break
            if t0 is None:
                t0 = ep.t
            t_last = ep.t
            n += 1
            outages.update(ep)
            for ev in mon.step(ep, n - 1):  # events carry the epoch index as well as the time
                if ev["kind"] == "transient":
                    continue
                print(("\n" if tty else "") + f"  t = {fmt(ev['t'], 'time', 's', decimals=2)} (epoch {n - 1}): {ev['instrument']} "
                      f"{ev['kind']} {ev['sensor'] or ''} {ev['message']}", flush=True)
            if rec is not None:
                rec.write(ep)
            now = time.monotonic()
            if now - w_status >= args.status_interval:
                rate = (n - n_status) / (now - w_status)
                line = _status(ep.t, rate, src, mon)
                print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
                w_status, n_status = now, n
            if args.duration is not None and ep.t - t0 >= args.duration:
                break
            if n == extra.get("n_expected"):   # --simulate: the whole simulated run has arrived
                break
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        stack.close()  # a half-written estimates file is removed
        raise
    finally:
        _restore_sigint(old_handler)
        interrupted = interrupted or bool(stop_requested)
        src.close()
        if rec is not None:
            rec.close()
        th = extra.get("thread")
        if th is not None:
            th.stop.set()
            th.join(2)
        if extra.get("tx") is not None:
            extra["tx"].shutdown()
    if n:  # the last status line, so that the final state is always shown
        now = time.monotonic()
        rate = (n - n_status) / max(now - w_status, 1e-9)
        line = _status(t_last, rate, src, mon)
        print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
    mon.flush()
    stack.close()
    a = src.accounting
    wall = time.monotonic() - w0
    if n == 0 and not interrupted:
        from ..errors import TransportError

        raise TransportError(f"no epoch came out of the source ({a.summary()}); check that --layout matches the data "
                             "and that the source sends" + (f" within --idle-timeout {args.idle_timeout:g} s"
                                                           if (args.can or args.serial) else ""))
    summary = {"epochs": n, "data_span_s": (t_last - t0) if n else 0.0, "wall_s": wall,
               "interrupted": interrupted, "accounting": a.as_dict(), "outages": outages.as_dict(),
               "alarms": mon.alarms, "isolations": mon.isolations, "events": mon.events[:10000], "record": args.record,
               "estimates": args.estimates,
               "final_state": {k: m.health.state.value for k, m in mon.rt.managers.items()}}
    if tty:
        print()
    print(f"rimu monitor: {'interrupted, ' if interrupted else ''}{n} epochs"
          + (f" over {fmt(summary['data_span_s'], 'time', 's', decimals=2)} of data" if n else "")
          + f" in {fmt(wall, 'time', 's', decimals=1)}")
    print(f"  {a.summary()}")
    print(f"  outages (epochs without any valid sensor of an instrument): {outages.summary() or 'none'}")
    print(f"  accounting identity received = accepted + rejected + pending: "
          f"{'holds' if a.identity_holds() else 'BROKEN'}")
    for ev in mon.isolations:
        print(f"  isolated: {ev['instrument']} {ev['sensor']} at t = {fmt(ev['t'], 'time', 's', decimals=2)} "
              f"(epoch {ev.get('sample')})")
    if not mon.isolations:
        print("  no sensor isolated")
    for k, m in mon.rt.managers.items():
        print(f"  {k}: final state {m.health.state.value}" + (f", isolated {', '.join(m.health.isolated)}"
                                                            if m.health.isolated else ""))
    if mon.rt.selfcal:
        from .selfcal import loop_summary

        summary["selfcal"] = {}
        for k, loop in mon.rt.selfcal.items():
            print(f"  {k}:")
            summary["selfcal"][k] = loop_summary(k, loop)
    if args.estimates:
        print(f"  estimates: {Path(args.estimates)} ({mon.n_rows} rows)")
    if args.record:
        print(f"  recording: {Path(args.record)}" if n else "  no recording written (no epoch)")
    if args.json == "-":
        print(json.dumps(summary))
    elif args.json:
        from ._common import json_dump

        print(f"  summary: {json_dump(summary, args.json)}")
    return 0 if a.identity_holds() else 1


__all__ = ["register", "run"]


#: epochs the stream's rate is measured on when nothing declares it
_RATE_EPOCHS = 50


def _rate(args: argparse.Namespace, cal: Any, src: Any, extra: dict) -> tuple[float | None, list, Any]:
    """The stream's rate (Hz) where the runtime depends on it (a noise stated for another period, the unit file's
    motion terms, --selfcal), else None; the epochs read to measure it, and the rest of the stream.

    Declared: ``--sample-rate``, the simulated device's, the layout's, the transport's (``sample_rate_hz``);
    otherwise measured on the first epochs (1 / their median time step; ``rimu replay`` takes the data's median
    time step). Said on one line; a stream that ends before two epochs refuses, rather than run thresholds wrong
    by the square root of the averaging."""
    from ..errors import OptionError

    epochs = iter(src)
    need = args.selfcal or bool(cal.metadata.get("motion_terms")) or any(
        cal[k].noise_period_s is not None for k in cal.instruments)
    layout = getattr(src, "layout", None)
    declared = [(args.sample_rate, "--sample-rate"), (extra.get("rate"), "the simulated device's rate"),
                (getattr(layout, "sample_rate_hz", None), "the layout's rate"),
                (getattr(src, "sample_rate_hz", None), "the transport's declared rate")]
    rate, how = next(((float(r), h) for r, h in declared if r), (None, ""))
    if not need:
        return rate, [], epochs
    head: list = []
    if rate is None:
        for ep in epochs:
            head.append(ep)
            if len(head) >= _RATE_EPOCHS:
                break
        if not head:  # nothing came: the loop says so (no epoch came out of the source)
            return None, head, epochs
        import numpy as np

        dt = np.diff([float(ep.t) for ep in head])
        step = float(np.median(dt)) if dt.size else float("nan")
        if not step > 0:
            raise OptionError(f"the stream's rate cannot be measured ({len(head)} epoch(s) before it ended or stalled) "
                              "and this unit depends on it (a noise stated for averages, motion terms or --selfcal): "
                              "give --sample-rate HZ")
        rate, how = 1.0 / step, f"measured on its first {len(head)} epochs"
    print(f"rimu monitor: the stream's rate {fmt(rate, 'frequency', 'Hz', digits=4)} ({how})")
    return rate, head, epochs


def _trackers(args: argparse.Namespace, cal: Any, rate: float) -> dict:
    """The trackers of every instrument (rimu replay --selfcal's, from the same options)."""
    from ..errors import OptionError
    from ..fdi.selfcal import SelfCalTracker
    from .selfcal import tracker_settings

    if args.selfcal_window * rate < 1:
        raise OptionError(f"--selfcal-window {args.selfcal_window:g} s is shorter than one sample at {rate:g} Hz")
    trackers = {k: SelfCalTracker(cal[k], tracker_settings(args, cal[k], k, args.selfcal_temperature, "selfcal-"))
                for k in cal.instruments}
    print(f"rimu monitor: self-calibration of {', '.join(trackers)} at {rate:g} Hz (windows of "
          f"{args.selfcal_window:g} s; docs/selfcal.md)")
    return trackers


def _stored_detectors(cal: Any, settings: Any, rate: float | None) -> dict:
    """The motion-aware tests stored in the unit file by ``rimu setup --motion-fit``
    (:func:`rimu.fdi.unit.stored_motion_detectors`, checked against the stream's rate), said once."""
    from ..fdi.motion import envelope_text
    from ..fdi.unit import stored_motion_detectors

    out = stored_motion_detectors(cal, settings.p_fa, rate)
    for k, det in out.items():
        print(f"rimu monitor: {k}: motion-aware test of the unit file at {det.sample_rate:.4g} Hz"
              + ("" if det.envelope is None else f" ({envelope_text(det.envelope)})"))
    return out
