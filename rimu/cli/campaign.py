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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="fault-injection campaign: Pd, Pfa, isolation, delay with CIs",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--geometry", default="cone6")
    p.add_argument("--instrument", default="gyro", choices=["gyro", "accel"])
    p.add_argument("--faults", default="bias", help="comma-separated fault types (bias, ramp, stuck, scale, noise, spikes, dropout, zero, "
                   "saturation, nonfinite) or 'all'")
    p.add_argument("--sensors", default=None, help="comma-separated sensor indices (default all)")
    p.add_argument("--sizes", default="4,6,8,10,12", help="fault sizes, sigma, comma-separated")
    p.add_argument("--repetitions", type=int, default=5, help="seeds per (fault, sensor, size)")
    p.add_argument("--detector", default="glt", choices=["glt", "glt_window", "cusum", "kalman", "baseline"])
    p.add_argument("--window", type=int, default=5)
    p.add_argument("--p-fa", type=float, default=1e-3)
    p.add_argument("--arl0", type=float, default=1e5)
    p.add_argument("--confirm", type=int, default=3)
    p.add_argument("--duration", type=float, default=10.0, help="s per task")
    p.add_argument("--fault-start", type=float, default=5.0, help="s")
    p.add_argument("--open-loop-only", action="store_true", help="skip the closed-loop manager run (faster)")
    p.add_argument("--seed", type=int, default=0, help="base seed")
    p.add_argument("--workers", type=int, default=None, help="local processes (0: in this process)")
    p.add_argument("--scheduler", default=None, help="dask.distributed scheduler address")
    p.add_argument("--json", default=None, metavar="OUT", help="write the results as JSON")
    p.add_argument("--plot", default=None, metavar="PNG", help="write the Pd-vs-size plot")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..fdi.campaign import CampaignSpec, run_campaign
    from ..fdi.faults import FAULTS

    faults = sorted(FAULTS) if args.faults == "all" else [f.strip() for f in args.faults.split(",") if f.strip()]
    spec = CampaignSpec(geometry=args.geometry, instrument=args.instrument, faults=faults,
                        sensors=None if args.sensors is None else [int(s) for s in args.sensors.split(",")],
                        sizes=[float(s) for s in args.sizes.split(",")], repetitions=args.repetitions,
                        detector=args.detector, window=args.window, p_fa=args.p_fa, arl0=args.arl0,
                        confirm=args.confirm, duration=args.duration, fault_start=args.fault_start,
                        closed_loop=not args.open_loop_only, base_seed=args.seed)
    from ..fdi import isolability
    from ..fdi.campaign import _setup

    truth, pipe, _ = _setup(spec)
    print(isolability(pipe.table, truth[spec.instrument].geometry.names, spec.geometry).summary())
    res = run_campaign(spec, workers=args.workers, scheduler=args.scheduler, progress=True)
    print(res.table())
    if args.json:
        res.to_json(args.json)
        print(f"  JSON: {args.json}")
    if args.plot:
        png = res.plot(Path(args.plot))
        print(f"  plot: {png}" if png else "  (matplotlib not installed: no plot)")
    return 0
