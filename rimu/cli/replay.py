"""``rimu replay DATA --calibration cal.json [--inject SPEC ...]``: replay recorded or simulated data through the
runtime pipeline with fault detection and isolation, optionally with injected faults.

Prints the events (isolations, transients, re-admissions, state changes) and the final state per instrument;
``--report DIR`` writes a plot of the parity statistic against its threshold, the estimates and the states over
time, ``--json FILE`` the events (time in s and sample index) and final states.

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
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ._common import (
    Deprecated,
    add_accept_implausible,
    add_json_option,
    add_report_option,
    nonnegative_int,
    positive_float,
    positive_int,
    probability,
)

DETECTORS = ["glt", "glt_window", "cusum", "kalman", "baseline"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="replay data through pipeline + FDI, optionally injecting faults",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="session file (.npz, or .csv/.json with sidecar)")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--inject", action="append", default=[], metavar="SPEC", help="fault to inject (repeatable)")
    p.add_argument("--detector", default="glt", choices=DETECTORS)
    p.add_argument("--window", type=positive_int, default=5, help="samples of the window GLT")
    p.add_argument("--p-fa", type=probability, default=1e-3, help="per-sample false-alarm probability")
    p.add_argument("--arl0", type=positive_float, default=1e5, help="mean samples between false alarms (cusum, baseline)")
    p.add_argument("--confirm", type=positive_int, default=3, help="consecutive alarms before isolation")
    p.add_argument("--readmit-after", type=positive_int, default=None, help="clean samples before re-admission")
    p.add_argument("--noise", type=positive_float, default=None, help="per-sample noise (SI) if the calibration has none")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of random fault types")
    p.add_argument("--motion-fit", type=positive_float, default=None, metavar="SECONDS",
                   help="gyros: fit motion-aware thresholds (rimu.fdi.motion: scale, misalignment, time offset, "
                        "vibration) on the first SECONDS of the data, taken as fault-free, and test with them "
                        "(docs/many-sensors.md)")
    p.add_argument("--motion-margin", type=positive_float, default=3.0, help="factor on the fitted motion variances")
    p.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="folder for summary.json: the runtime error against the segments' known inputs, alarms and "
                        "isolations per instrument (docs/runtime.md)")
    add_report_option(p, "the plot (replay.png)")
    add_json_option(p, "the events (time in s and sample index) and final states")
    p.add_argument("--out", action=Deprecated, new="--report DIR and --json FILE", convert=_old_out, metavar="DIR")
    add_accept_implausible(p)
    p.set_defaults(func=run)


def _old_out(ns: argparse.Namespace, value: str) -> None:
    """``--out DIR`` (old): DIR/replay.png and DIR/replay.json."""
    ns.report = value
    ns.json = str(Path(value) / "replay.json")
    ns.output = value


#: replays longer than this many samples show a progress bar (in chunks of this size)
_CHUNK = 20_000


def _run(mgr, Y, valid, t, desc: str):  # type: ignore[no-untyped-def]
    """``mgr.run`` over the whole block, in chunks with a progress bar when the block is long (the manager keeps
    its state between calls, so the result is the same)."""
    from dataclasses import replace

    from ..progress import bar

    n = len(Y)
    if n <= _CHUNK:
        return mgr.run(Y, valid, t)
    parts = [mgr.run(Y[a:a + _CHUNK], None if valid is None else valid[a:a + _CHUNK], t[a:a + _CHUNK])
             for a in bar(range(0, n, _CHUNK), total=-(-n // _CHUNK), desc=desc, unit="chunk")]
    cat = {f: np.concatenate([getattr(r, f) for r in parts]) for f in
           ("t", "x", "statistic", "threshold", "alarm", "state", "n_active")}
    return replace(parts[0], events=[e for r in parts for e in r.events], **cat)


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..fdi import RedundancyManager
    from ..fdi.campaign import CampaignSpec, make_detector
    from ..fdi.faults import inject, parse_injection
    from ..fusion import Pipeline
    from ..fusion.validation import segment_errors, session_block
    from .check import read_session

    session, _ = read_session(args.data, "warn" if args.accept_implausible else "strict")
    block, seg_index = session_block(session)
    # the calibration must be of this unit: its geometry fingerprint against the data's (a dodecahedron6
    # calibration on cone6 data would otherwise isolate healthy sensors)
    cal = Calibration.load(args.calibration, geometries=session.geometries)
    insts = [k for k in cal.instruments if k in block.raw]
    if not insts:
        from ..errors import CalibrationFileError

        raise CalibrationFileError(f"the calibration ({', '.join(cal.instruments)}) and the data "
                                   f"({', '.join(session.instruments)}) have no instrument in common: nothing to replay")
    t_end = float(block.t[-1])
    for k in insts:
        if cal[k].noise_sigma is None:
            if args.noise is None:
                from ..errors import CalibrationFileError

                raise CalibrationFileError(f"the {k} calibration states no noise; pass --noise SIGMA (SI per sample)")
            cal[k].noise_sigma = np.full(cal[k].geometry.n, float(args.noise))
    injections = [parse_injection(s) for s in args.inject]
    for inj in injections:  # a fault outside the data would be "injected" without touching a sample
        if not float(block.t[0]) <= inj.start < t_end:
            from ..errors import OptionError

            raise OptionError(f"--inject {inj.fault}:{inj.instrument}:{inj.sensor}:{inj.start:g}: starts at "
                              f"{inj.start:g} s, outside the data (t = {float(block.t[0]):g} .. {t_end:g} s)")
    if injections:
        block = inject(block, injections, cal, seed=args.seed)
        for inj in injections:
            print(f"  injected {inj.fault} on {inj.instrument} {inj.sensor} at {inj.start:g} s, size "
                  f"{inj.size:g}{' sigma' if inj.in_sigma else ' SI'}")
    fs = 1.0 / float(np.median(np.diff(block.t))) if len(block) > 1 else 1.0
    if args.detector in ("kalman", "glt_window") and args.p_fa > 1e-4:
        print(f"  note: --p-fa is per sample; the {args.detector} statistic is correlated over several samples, so "
              "alarms come in episodes that confirmation does not filter; consider --p-fa 1e-5")
    unit = Pipeline(Calibration({k: cal[k] for k in insts}, cal.raw_unit, cal.method, cal.created, dict(cal.metadata)),
                    temperature=block.temperature is not None)
    block = unit.compensate(block)
    if unit.compensation:
        print("  compensated effects: " + "; ".join(
            f"{k}: {', '.join(t.effect.name for t in c.terms)}" for k, c in unit.compensation.items()))
    results = {}
    summary: dict = {}
    for k in insts:
        pipe = unit[k]
        spec = CampaignSpec(detector=args.detector, window=args.window, p_fa=args.p_fa, arl0=args.arl0)
        det = make_detector(spec, pipe.table.sigma)
        if args.motion_fit is not None and k == "gyro":
            det = _motion_detector(cal[k], block, args.motion_fit, args.motion_margin, args.p_fa, fs)
        mgr = RedundancyManager(pipe, det, p_fa=args.p_fa,
                                confirm=1 if args.detector == "cusum" else args.confirm,
                                readmit_after=args.readmit_after, sample_rate=fs)
        res = _run(mgr, block.raw[k], block.valid.get(k), block.t, f"replay {k}")
        results[k] = res
        print(f"\n  {k}: {len(block)} samples, detector {getattr(det, 'name', args.detector)}; final state {mgr.state.value}"
              + (f", isolated {', '.join(mgr.health.isolated)}" if mgr.health.isolated else ""))
        shown = [e for e in res.events if e.kind != "transient"]
        n_tr = sum(1 for e in res.events if e.kind == "transient")
        for e in shown[:50]:
            print(f"    t = {e.t:8.3f} s (sample {e.sample:>7d})  {e.kind:22s} {e.sensor or '':4s} {e.message}")
        if len(shown) > 50:
            print(f"    ... {len(shown) - 50} more")
        print(f"    transient alarm episodes (not confirmed): {n_tr}; outputs finite: {bool(np.isfinite(res.x).all())}")
        entry = {"samples": len(block), "alarms": int(np.count_nonzero(res.alarm)),
                 "isolations": sum(1 for e in res.events if e.kind in ("isolated", "invalid_isolated")),
                 "final_state": mgr.state.value}
        try:
            err = segment_errors(session, k, np.asarray(res.x), seg_index)
        except ValueError:
            err = None
        if err is not None:
            entry.update(err.to_dict())
            print(f"    runtime error: segment_error_rms {err.segment_error_rms:.4g} {entry['unit']} over "
                  f"{len(err.segments)} segments, sample_error_rms {err.sample_error_rms:.4g} {entry['unit']}")
        print(f"    alarms {entry['alarms']}, isolations {entry['isolations']}")
        summary[k] = entry
    if args.json:
        from ._common import json_dump

        doc = {k: {"events": [e.to_dict() for e in r.events], "final_state": r.state_names()[-1] if len(r.t) else None}
               for k, r in results.items()}
        print(f"\n  events: {json_dump(doc, args.json)}")
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        png = _plot(out / "replay.png", results)
        print(f"  plot:   {png}" if png else "  (matplotlib not installed: no plot; pip install 'rimu[plots]')")
    if args.output:
        import json

        from ..atomic import write_text

        out = Path(args.output)
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "summary.json", json.dumps(summary, indent=1))
        print(f"  summary: {out / 'summary.json'}")
    n_iso = sum(v["isolations"] for v in summary.values())
    errs = ", ".join(f"{k} segment_error_rms {v['segment_error_rms']:.3g} {v['unit']}"
                     for k, v in summary.items() if "segment_error_rms" in v)
    print(f"replayed {len(block)} samples: {n_iso} isolation(s)" + (f"; {errs}" if errs else ""))
    return 0


def _motion_detector(cal, block, seconds: float, margin: float, p_fa: float, fs: float):  # type: ignore[no-untyped-def]
    """Motion-aware GLT with the motion terms fitted on the first ``seconds`` of the gyro data (every sensor valid)."""
    from ..errors import ShapeError
    from ..fdi.motion import MotionAwareGlt, MotionNoiseModel, fit_motion_terms
    from ..fusion import InstrumentPipeline, Validity

    sel = block.t < block.t[0] + seconds
    pipe = InstrumentPipeline(cal)
    blk = pipe.process(block.raw["gyro"][sel], None if block.valid.get("gyro") is None else block.valid["gyro"][sel])
    full = np.asarray(blk.validity) == Validity.NOMINAL
    if full.sum() < 50:
        raise ShapeError(f"--motion-fit {seconds:g}: only {int(full.sum())} samples with every gyro valid in that "
                         "span; give a longer fault-free span (at least 50 samples)")
    res = pipe.table.sigma**2 * (blk.parity @ pipe.table.Vz[0])
    alpha = np.gradient(blk.x, 1.0 / fs, axis=0)
    model = fit_motion_terms(MotionNoiseModel(cal, sigma=pipe.table.sigma), res[full], pipe.table.G[0], blk.x[full],
                             alpha[full], margin=margin)
    print(f"  gyro: motion terms fitted on {int(full.sum())} samples (first {seconds:g} s, margin {margin:g}): "
          f"scale {1e2 * float(np.median(model.scale_rel)):.2f} %, misalignment "
          f"{1e3 * float(np.median(model.misalignment_rad)):.2f} mrad, time offset "
          f"{1e3 * float(np.median(model.time_offset_s)):.2f} ms (medians)")
    return MotionAwareGlt(model, p_fa, sample_rate=fs)


def _plot(path: Path, results: dict) -> Path | None:
    from ..plotting import pyplot

    plt = pyplot(optional=True)
    if plt is None:
        return None
    from ..fdi.manager import HealthState

    k_n = len(results)
    fig, axes = plt.subplots(3, k_n, figsize=(6 * k_n, 8), sharex=True, squeeze=False)
    for c, (k, r) in enumerate(results.items()):
        ax = axes[0, c]
        ax.semilogy(r.t, np.maximum(r.statistic, 1e-3), lw=0.5, label="statistic")
        ax.semilogy(r.t, np.where(np.isfinite(r.threshold), r.threshold, np.nan), "k--", lw=1, label="threshold")
        for e in r.events:
            if e.kind in ("isolated", "invalid_isolated", "readmitted"):
                ax.axvline(e.t, color="m" if e.kind != "readmitted" else "g", lw=0.8, ls=":")
                ax.text(e.t, ax.get_ylim()[1], f"{e.kind[:3]} {e.sensor}", fontsize=7, rotation=90, va="top")
        ax.set_title(f"{k}: parity test statistic")
        ax.legend(fontsize=7, loc="upper left")
        ax = axes[1, c]
        for a, col in zip(range(3), "rgb"):
            ax.plot(r.t, r.x[:, a], col, lw=0.5, label="xyz"[a])
        ax.set_title(f"{k}: MB-frame estimate (SI)")
        ax.legend(fontsize=7)
        ax = axes[2, c]
        ax.step(r.t, r.state, where="post")
        ax.set_yticks(range(len(HealthState)))
        ax.set_yticklabels([s.value for s in HealthState], fontsize=7)
        ax.set_xlabel("time, s")
        ax.set_title(f"{k}: state")
    fig.tight_layout()
    from ..atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path
