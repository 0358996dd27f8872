"""``rimu monitor``: a live (or recorded) source through compensation and FDI, with a status line.

Sources (one of)::

    --can virtual:rimu --layout cone6_rimu        python-can interface:channel and a layout (file or shipped name)
    --can socketcan:can0 --layout my_imu.json
    --serial /dev/ttyUSB0 --baud 921600           rimu's serial framing (docs/io.md)
    --replay log.asc --layout cone6_rimu          a python-can log (ASC, BLF, CSV, candump .log)
    --csv rec.csv | --npz run.npz | --ulog flight.ulg
    --simulate                                    a simulated cone6 device on a virtual CAN bus (no hardware)

Each epoch goes through the runtime pipeline (Cho & Park Eq. 20 compensation and projection) and the GLT on
the parity vector; a sensor flagged ``--confirm`` times in a row is isolated (Eq. 21). A status line shows the
epoch rate, frame counters and the health of each instrument; ``--record`` writes the epochs as CSV. Ctrl-C
ends cleanly with a summary (epochs, accounting identity, rejections by reason, isolations).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import uuid
from pathlib import Path
from typing import Any


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
    from ._common import Deprecated, add_json_option, positive_float, positive_int, probability

    p.add_argument("--baud", type=positive_int, default=921600, help="serial baud rate")
    p.add_argument("--calibration", help="calibration file (rimu.calibration JSON); --simulate uses the truth")
    p.add_argument("--geometry", default=None, help="geometry preset of gyros and accelerometers "
                   "(default: the layout's, or cone6)")
    p.add_argument("--p-fa", type=probability, default=1e-3, help="per-sample false-alarm probability of the GLT")
    p.add_argument("--confirm", type=positive_int, default=5, help="consecutive alarms on one sensor to isolate it")
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
    elif hasattr(src, "recording"):  # an IMU log: the unit's geometry is the calibration's (rimu setup fits axes)
        geos = None
    return src, Calibration.load(args.calibration, geometries=geos), extra


class _Fdi:
    """GLT on the normalised parity vector + confirmation + isolation (as rimu demo does)."""

    def __init__(self, pipe: Any, p_fa: float, confirm: int) -> None:
        from ..fdi import glt_snapshot

        self.glt = glt_snapshot
        self.pipe, self.p_fa, self.confirm = pipe, p_fa, confirm
        self.streak = {k: (-1, 0) for k in pipe.instruments}
        self.stat = {k: 0.0 for k in pipe.instruments}
        self.thr = {k: float("inf") for k in pipe.instruments}
        self.events: list[dict] = []

    def step(self, t: float, res: dict) -> list[dict]:
        new = []
        for k, r in res.items():
            ip = self.pipe[k]
            d = self.glt(r.parity, ip.table.Vz[r.entry], r.dof, self.p_fa, r.active)
            self.stat[k], self.thr[k] = d.statistic, d.threshold
            last, count = self.streak[k]
            if d.detected and d.isolated >= 0:
                count = count + 1 if d.isolated == last else 1
                self.streak[k] = (d.isolated, count)
                if count >= self.confirm:
                    ip.isolate(d.isolated)
                    ev = {"t": t, "instrument": k, "sensor": ip.calibration.geometry.names[d.isolated]}
                    self.events.append(ev)
                    new.append(ev)
                    self.streak[k] = (-1, 0)
            else:
                self.streak[k] = (-1, 0)
        return new


def _status(t: float, rate: float, src: Any, pipe: Any, fdi: _Fdi) -> str:
    a = src.accounting
    parts = [f"t {t:9.2f} s", f"{rate:6.1f} Hz", f"{a.unit}s {a.received} ok {a.accepted} rej {a.rejected_total}"]
    for k, ip in pipe.instruments.items():
        iso = [ip.calibration.geometry.names[i] for i in range(ip.n) if ip.isolated[i]]
        inv = int(ip.result.invalid.sum())
        parts.append(f"{k} {ip.n - len(iso) - inv}/{ip.n} ok FD {fdi.stat[k]:6.1f}/{fdi.thr[k]:.1f}"
                     + (f" isolated {','.join(iso)}" if iso else ""))
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
    from ..fusion import Pipeline
    from ..io.accounting import Outages
    from ..io.recorded import CsvRecorder

    src, cal, extra = _open(args)
    pipe = Pipeline(cal)
    fdi = _Fdi(pipe, args.p_fa, args.confirm)
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
        for ep in src:
            if stop_requested:
                break
            if t0 is None:
                t0 = ep.t
            t_last = ep.t
            n += 1
            outages.update(ep)
            for ev in fdi.step(ep.t, pipe.step(ep)):
                ev["sample"] = n - 1  # events carry the epoch index as well as the time
                print(("\n" if tty else "") + f"  t = {ev['t']:.2f} s (epoch {n - 1}): {ev['instrument']} "
                      f"{ev['sensor']} isolated", flush=True)
            if rec is not None:
                rec.write(ep)
            now = time.monotonic()
            if now - w_status >= args.status_interval:
                rate = (n - n_status) / (now - w_status)
                line = _status(ep.t, rate, src, pipe, fdi)
                print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
                w_status, n_status = now, n
            if args.duration is not None and ep.t - t0 >= args.duration:
                break
            if n == extra.get("n_expected"):   # --simulate: the whole simulated run has arrived
                break
    except KeyboardInterrupt:
        interrupted = True
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
        line = _status(t_last, rate, src, pipe, fdi)
        print(("\r" + line) if tty else line, end="" if tty else "\n", flush=True)
    a = src.accounting
    wall = time.monotonic() - w0
    if n == 0 and not interrupted:
        from ..errors import TransportError

        raise TransportError(f"no epoch came out of the source ({a.summary()}); check that --layout matches the data "
                             "and that the source sends" + (f" within --idle-timeout {args.idle_timeout:g} s"
                                                           if (args.can or args.serial) else ""))
    summary = {"epochs": n, "data_span_s": (t_last - t0) if n else 0.0, "wall_s": wall,
               "interrupted": interrupted, "accounting": a.as_dict(), "outages": outages.as_dict(),
               "isolations": fdi.events,
               "record": args.record}
    if tty:
        print()
    print(f"rimu monitor: {'interrupted, ' if interrupted else ''}{n} epochs"
          + (f" over {summary['data_span_s']:.2f} s of data" if n else "") + f" in {wall:.1f} s")
    print(f"  {a.summary()}")
    print(f"  outages (epochs without any valid sensor of an instrument): {outages.summary() or 'none'}")
    print(f"  accounting identity received = accepted + rejected + pending: "
          f"{'holds' if a.identity_holds() else 'BROKEN'}")
    for ev in fdi.events:
        print(f"  isolated: {ev['instrument']} {ev['sensor']} at t = {ev['t']:.2f} s (epoch {ev.get('sample')})")
    if not fdi.events:
        print("  no sensor isolated")
    if args.record:
        print(f"  recording: {Path(args.record)}" if n else "  no recording written (no epoch)")
    if args.json == "-":
        print(json.dumps(summary))
    elif args.json:
        from ._common import json_dump

        print(f"  summary: {json_dump(summary, args.json)}")
    return 0 if a.identity_holds() else 1


__all__ = ["register", "run"]
