"""``rimu campaign``: a fault-injection campaign (fault type x sensor x size x seed) with detection and false-alarm
probabilities, isolation rates and delays, with 99% confidence intervals; a table, JSON and a plot of the
detection probability against fault size with the noncentral chi-square theory on top.

Runs on a local process pool by default (``--workers``), or on a dask.distributed cluster with
``--scheduler tcp://HOST:8786`` (the same code, deterministic seeds per task: the numbers do not depend on
where the tasks ran).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (
    Deprecated,
    add_fdi_options,
    add_json_option,
    add_report_option,
    check_samples,
    fdi_settings,
    nonnegative_int,
    positive_float,
    positive_int,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="fault-injection campaign: Pd, Pfa, isolation, delay with CIs",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--geometry", default="cone6")
    p.add_argument("--instrument", default="gyro", choices=["gyro", "accel"])
    p.add_argument("--faults", default="bias", help="comma-separated fault types (bias, ramp, stuck, scale, noise, spikes, dropout, zero, "
                   "saturation, nonfinite) or 'all'")
    p.add_argument("--sensors", default=None, help="comma-separated sensor indices (default all)")
    p.add_argument("--sizes", default="4,6,8,10,12", help="fault sizes, sigma, comma-separated")
    p.add_argument("--repetitions", type=positive_int, default=5, help="seeds per (fault, sensor, size)")
    p.add_argument("--detector", default="glt", choices=["glt", "glt_window", "cusum", "kalman", "baseline"])
    p.add_argument("--window", type=positive_int, default=5)
    add_fdi_options(p)
    p.add_argument("--arl0", type=positive_float, default=1e5)
    p.add_argument("--duration", type=positive_float, default=10.0, help="s per task")
    p.add_argument("--fault-start", type=positive_float, default=5.0, help="s, inside --duration")
    p.add_argument("--open-loop-only", action="store_true", help="skip the closed-loop manager run (faster)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="base seed")
    p.add_argument("--workers", type=nonnegative_int, default=None, help="local processes (0: in this process)")
    p.add_argument("--scheduler", default=None, help="dask.distributed scheduler address")
    add_json_option(p, "the results (spec, summary, every task)")
    add_report_option(p, "the Pd-vs-size plot (campaign.png)")
    p.add_argument("--plot", action=Deprecated, new="--report DIR (writes DIR/campaign.png)", metavar="PNG")
    p.set_defaults(func=run)


def _list(opt: str, text: str, kind, lo: float | None = None) -> list:
    from ..errors import OptionError

    try:
        vals = [kind(v.strip()) for v in text.split(",") if v.strip()]
    except ValueError:
        raise OptionError(f"--{opt} {text}: expected comma-separated {'integers' if kind is int else 'numbers'}") from None
    if not vals:
        raise OptionError(f"--{opt} is empty")
    if lo is not None and any(not v >= lo for v in vals):
        raise OptionError(f"--{opt} {text}: every value must be >= {lo:g}")
    return vals


def run(args: argparse.Namespace) -> int:
    from ..errors import OptionError
    from ..experiments.campaign import CampaignSpec, run_campaign
    from ..experiments.faults import FAULTS
    from ..geometry import preset

    fdi_settings(args)  # --p-fa and --confirm not given: the one default
    if args.scheduler:  # the extra, before any work
        try:
            import distributed  # noqa: F401
        except ImportError as exc:
            raise ImportError("--scheduler needs the 'distributed' extra: pip install 'rimu[distributed]'",
                              name="distributed") from exc
    faults = sorted(FAULTS) if args.faults == "all" else [f.strip() for f in args.faults.split(",") if f.strip()]
    unknown = [f for f in faults if f not in FAULTS]
    if unknown or not faults:
        raise OptionError(f"--faults {args.faults}: unknown fault types {unknown}; known: {', '.join(sorted(FAULTS))} "
                          "or 'all'")
    check_samples(args.duration * 100.0, f"--duration {args.duration:g} s at 100 Hz", limit=5e6, least=10)
    if args.repetitions > 10_000 or (args.workers or 0) > 1024:
        raise OptionError(f"--repetitions {args.repetitions} / --workers {args.workers}: at most 10000 repetitions "
                          "and 1024 workers")
    if args.fault_start >= args.duration:
        raise OptionError(f"--fault-start {args.fault_start:g} s must lie inside the run (--duration {args.duration:g} s)")
    n = preset(args.geometry).n
    sensors = None if args.sensors is None else _list("sensors", args.sensors, int, 0)
    if sensors and max(sensors) >= n:
        raise OptionError(f"--sensors {args.sensors}: {args.geometry} has sensors 0..{n - 1}")
    spec = CampaignSpec(geometry=args.geometry, instrument=args.instrument, faults=faults, sensors=sensors,
                        sizes=_list("sizes", args.sizes, float, 0.0), repetitions=args.repetitions,
                        detector=args.detector, window=args.window, p_fa=args.p_fa, arl0=args.arl0,
                        confirm=args.confirm, duration=args.duration, fault_start=args.fault_start,
                        closed_loop=not args.open_loop_only, base_seed=args.seed)
    from ..experiments.campaign import campaign_unit
    from ..fdi import isolability

    truth, pipe, _ = campaign_unit(spec)
    print(isolability(pipe.table, truth[spec.instrument].geometry.names, spec.geometry).summary())
    res = run_campaign(spec, workers=args.workers, scheduler=args.scheduler, progress=True)
    print(res.table())
    if args.json:
        if args.json == "-":
            print(res.to_json())
        else:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            res.to_json(args.json)
            print(f"  JSON: {args.json}")
    png = Path(args.plot) if args.plot else (Path(args.report) / "campaign.png" if args.report else None)
    if png is not None:
        png.parent.mkdir(parents=True, exist_ok=True)
        out = res.plot(png)
        print(f"  plot: {out}" if out else "  (matplotlib not installed: no plot; pip install 'rimu[plots]')")
    return 0
