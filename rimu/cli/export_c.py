"""``rimu export-c``: write a calibration's runtime (compensation, projection, covariance, parity) and its fault
management (the redundancy manager's decisions, configured here and baked into the code) as C99.

``--selfcal`` adds the in-flight self-calibration (docs/selfcal.md): every instrument's tracker runs before its
manager exactly as ``rimu replay --selfcal`` runs it (the same ``--selfcal-*`` options and defaults, the window GLT
whose thresholds carry the tracker's covariance, the held-out check), and the filter writes the tracked terms and
their 1-sigma after the estimates. The windows are counted at ``--sample-rate`` (default the calibration's noise
model's rate); ``--selfcal-temperature`` tracks the temperature coefficients (the filter then reads the temperature
column; they are tracked anyway when the calibration's compensation reads it)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_readmit_options, bounded_float, positive_float, positive_int, probability, readmit_after
from .selfcal import add_tracker_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-c", help="write the runtime of a calibration as dependency-free C99",
                       description="Write rimu_unit.h/.c (the runtime: no dynamic memory, only <math.h>), a CSV "
                                   "filter program rimu_filter.c and a Makefile for one calibrated unit. See "
                                   "docs/flying.md.")
    p.add_argument("calibration", help="calibration file (rimu calibrate -o ...)")
    p.add_argument("-o", "--output", required=True, help="directory to write the C sources into")
    p.add_argument("--real", choices=("double", "float"), default=None,
                   help="floating-point type of the generated code (float for FPUs without double; default double, "
                        "float with --target cortex-m4)")
    p.add_argument("--build", action="store_true", help="also build rimu_filter with the system C compiler")
    p.add_argument("--target", choices=("host", "cortex-m4"), default="host",
                   help="cortex-m4: single precision for a Cortex-M4F, plus its QEMU harness, flight image and "
                        "Makefile.cortex-m4 (--build builds them with arm-none-eabi-gcc; docs/flight-target.md)")
    g = p.add_argument_group("fault management (baked into the code; an option not given keeps the one default of rimu.fdi.FdiSettings)")
    g.add_argument("--p-fa", type=probability, default=None,
                   help="per-sample false-alarm probability of the detection test (and of the re-admission test)")
    g.add_argument("--confirm", type=positive_int, default=None,
                   help="consecutive alarms naming the same sensor set before it is isolated")
    g.add_argument("--invalid-persist", type=positive_int, default=None,
                   help="consecutive invalid samples before a sensor is isolated")
    add_readmit_options(g, "rimu replay")
    g.add_argument("--fail-after", type=positive_int, default=None,
                   help="isolations of one sensor after which it is FAILED (not re-admitted)")
    g.add_argument("--backoff", type=bounded_float(1.0, 100.0, why="the clean period never shrinks"), default=None,
                   help="factor on the clean period at each further isolation of a sensor (>= 1)")
    g.add_argument("--clear-after", type=positive_int, default=None,
                   help="alarm-free samples after which a 'not isolable' fault report is withdrawn")
    g.add_argument("--episode-gap", type=positive_int, default=None,
                   help="alarm-free samples that end an alarm episode (default max(confirm, 5))")
    g.add_argument("--set-alpha", type=probability, default=None,
                   help="level of the consistency test of a sensor set (the isolation test)")
    g.add_argument("--max-set-size", type=int, choices=(1, 2), default=None,
                   help="largest number of sensors one isolation names")
    g.add_argument("--scatter-window", type=positive_int, default=None,
                   help="most samples of an alarm episode the set test pools (even; its thresholds are a table of "
                        "this many times n - 4 numbers in the code)")
    s = p.add_argument_group("in-flight self-calibration (docs/selfcal.md; the options of rimu replay --selfcal)")
    s.add_argument("--selfcal", action="store_true",
                   help="track the calibration's drift in flight and compensate with it, as rimu replay --selfcal")
    s.add_argument("--sample-rate", type=positive_float, default=None,
                   help="the unit's sample rate, Hz, with --selfcal (default: the calibration's noise model's)")
    s.add_argument("--selfcal-temperature", action="store_true",
                   help="the unit has a temperature channel: track the temperature coefficients (the filter reads "
                        "the temperature column)")
    s.add_argument("--selfcal-detector-window", type=positive_int, default=None,
                   help="samples of the window GLT whose thresholds carry the tracker's covariance (rimu replay "
                        "--selfcal --detector glt_window --window N; default the tracker's window, as rimu replay "
                        "--selfcal with --detector glt)")
    s.add_argument("--selfcal-cusum", action="store_true",
                   help="the window GLT with a CUSUM bank beside it that carries the tracker's covariance (rimu replay "
                        "--selfcal --selfcal-cusum; docs/selfcal.md)")
    add_tracker_options(s, "selfcal-")
    p.set_defaults(func=run, output_is_dir=True)  # -o names a folder (rimu.cli._common.check_outputs)


def fdi_settings(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The :class:`rimu.export.FdiSettings` of the options (an option not given keeps FdiSettings' default)."""
    from ..errors import OptionError
    from ..export import FdiSettings

    if args.backoff is not None and args.backoff < 1:
        raise OptionError(f"--backoff {args.backoff:g}: must be at least 1 (the clean period never shrinks)")
    given = {"p_fa": args.p_fa, "confirm": args.confirm, "invalid_persist": args.invalid_persist,
             "fail_after": args.fail_after, "backoff": args.backoff,
             "clear_after": args.clear_after, "episode_gap": args.episode_gap, "alpha": args.set_alpha,
             "max_size": args.max_set_size, "scatter_window": args.scatter_window}
    kw = {k: v for k, v in given.items() if v is not None}   # the others keep FdiSettings' defaults
    try:
        return FdiSettings(**kw, readmit_after=readmit_after(args))
    except ValueError as exc:  # a combination out of range: named by the options that set it
        text = str(exc)
        for field, opt in _OPTIONS.items():
            text = text.replace(field, opt)
        raise OptionError(text) from None


#: FdiSettings field -> option (for its messages)
_OPTIONS = {"readmit_after": "--readmit-after", "fail_after": "--fail-after", "invalid_persist": "--invalid-persist",
            "clear_after": "--clear-after", "episode_gap": "--episode-gap", "confirm": "--confirm",
            "backoff": "--backoff", "p_fa": "--p-fa", "alpha": "--set-alpha", "max_size": "--max-set-size",
            "scatter_window": "--scatter-window"}


def run(args: argparse.Namespace) -> int:
    from ..calibration.result import Calibration
    from ..errors import OptionError
    from ..export import export_c

    fdi = fdi_settings(args)
    cal = Calibration.load(args.calibration)
    out = Path(args.output)
    settings = f"fault management p_fa {fdi.p_fa:g}, confirm {fdi.confirm}"
    target = args.target == "cortex-m4"
    if args.selfcal and (target or args.real == "float"):
        raise OptionError("--selfcal is generated in double precision only: drop --real float and --target cortex-m4")
    if not args.selfcal:
        given = [o for o, v in (("--sample-rate", args.sample_rate), ("--selfcal-temperature", args.selfcal_temperature),
                                ("--selfcal-detector-window", args.selfcal_detector_window),
                                ("--selfcal-cusum", args.selfcal_cusum)) if v]
        if given:
            raise OptionError(f"{' and '.join(given)} only apply with --selfcal")
    if target:  # single precision with the Cortex-M4 harness (rimu.export.target)
        from ..export.target import write_target

        if args.real == "double":
            raise OptionError("--target cortex-m4 builds in single precision: drop --real double")
        files = write_target(cal, args.output, fdi)
        msg = f"wrote {len(files)} files to {out} (float, Cortex-M4F; {settings})"
    else:
        real = args.real or "double"
        trackers, rate = _trackers(args, cal, real) if args.selfcal else (None, None)
        files = export_c(cal, args.output, real=real, fdi=fdi, selfcal=trackers, sample_rate=rate,
                         detector_window=args.selfcal_detector_window, selfcal_cusum=args.selfcal_cusum)
        msg = f"wrote {', '.join(f.name for f in files)} to {out} ({real}; {settings}"
        if trackers:
            msg += (f"; self-calibration of {', '.join(trackers)} at {rate:g} Hz, terms "
                    + "; ".join(f"{k}: {', '.join(t.blocks)}" for k, t in trackers.items()))
        msg += ")"
    if args.build:
        why, res, built = _build(out, target)
        if why:
            print(f"{msg}; not built: {why}")
            return 1
        if res.returncode != 0:
            print(res.stderr.strip())
            print(f"{msg}; the build failed (above)")
            return 1
        msg += f"; built {built}"
    print(msg)
    return 0


def _trackers(args: argparse.Namespace, cal, real: str):  # type: ignore[no-untyped-def]
    """The trackers of every instrument (rimu replay --selfcal's, from the same options) and the sample rate."""
    from ..errors import OptionError
    from ..export.c_effects import needs_temperature
    from ..fdi.selfcal import SelfCalTracker
    from .selfcal import tracker_settings

    rate = args.sample_rate
    if rate is None:
        rates = {float(cal[k].noise.sample_rate) for k in cal.instruments if cal[k].noise is not None}
        if len(rates) != 1:
            raise OptionError("--selfcal counts the tracker's windows in samples: give the unit's --sample-rate (Hz; "
                              "the calibration has no noise model that states it)")
        rate = rates.pop()
    if args.selfcal_window * rate < 1:
        raise OptionError(f"--selfcal-window {args.selfcal_window:g} s is shorter than one sample at {rate:g} Hz")
    temp = args.selfcal_temperature or needs_temperature(cal)
    return {k: SelfCalTracker(cal[k], tracker_settings(args, cal[k], k, temp, "selfcal-")) for k in cal.instruments}, rate


def _build(out: Path, target: bool):  # type: ignore[no-untyped-def]
    """Build what was written: (why it could not be built or None, the build's result, what was built)."""
    if target:
        from ..export.target import build_target, missing_tools

        miss = missing_tools()
        if miss:
            return (f"{', '.join(miss)} not installed (Debian: apt-get install gcc-arm-none-eabi "
                    "libnewlib-arm-none-eabi qemu-system-arm make gcc)"), None, ""
        return None, build_target(out), f"rimu_target.elf, rimu_flight.elf and rimu_target_host in {out}"
    from ..export import build_filter

    cc, res = build_filter(out)
    if cc is None:
        return f"no C compiler or make found (install gcc or clang and make, then run make in {out})", None, ""
    return None, res, f"{out / 'rimu_filter'}"
