"""``rimu replay DATA --calibration cal.json [--inject SPEC ...]``: replay recorded or simulated data through the
runtime pipeline with fault detection and isolation, optionally with injected faults.

Prints the events (isolations, transients, re-admissions, state changes) and the final state per instrument;
with ``--out`` writes a plot of the parity statistic against its threshold, the estimates and the states over
time, and a JSON file of the events.

Injection: ``TYPE:INSTRUMENT:SENSOR:START[:SIZE[:DURATION]]``, SIZE in SI or as ``10sigma``; types: bias, ramp,
stuck, scale, noise, spikes, dropout, zero, saturation, nonfinite. Example: ``--inject bias:gyro:y2:15:10sigma``.
DATA is a session file in rimu's format (``.npz``, or ``.csv`` with its ``.json`` sidecar; docs/session-format.md),
as ``rimu simulate`` writes it; the segments are replayed back to back. Every effect of the calibration is
compensated (docs/runtime.md). Where segments carry known inputs (static positions, rate steps), the runtime
error is reported per instrument (``segment_error_rms``: rms over segments of the segment-mean estimate's
error against the known input; ``sample_error_rms``; SI) with the number of alarms and isolations, and
written to ``OUT/summary.json``: how a calibration is validated on a held-out session.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="replay data through pipeline + FDI, optionally injecting faults",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="session file (.npz, or .csv/.json with sidecar)")
    p.add_argument("--calibration", required=True, help="calibration JSON file")
    p.add_argument("--inject", action="append", default=[], metavar="SPEC", help="fault to inject (repeatable)")
    p.add_argument("--detector", default="glt", choices=["glt", "glt_window", "cusum", "kalman", "baseline"])
    p.add_argument("--window", type=int, default=5, help="samples of the window GLT")
    p.add_argument("--p-fa", type=float, default=1e-3, help="per-sample false-alarm probability")
    p.add_argument("--arl0", type=float, default=1e5, help="mean samples between false alarms (cusum, baseline)")
    p.add_argument("--confirm", type=int, default=3, help="consecutive alarms before isolation")
    p.add_argument("--readmit-after", type=int, default=None, help="clean samples before re-admission")
    p.add_argument("--noise", type=float, default=None, help="per-sample noise (SI) if the calibration has none")
    p.add_argument("--seed", type=int, default=0, help="seed of random fault types")
    p.add_argument("-o", "--output", "--out", dest="out", default=None,
                   help="folder for summary.json, the plot and the events JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..fdi import RedundancyManager
    from ..fdi.campaign import CampaignSpec, make_detector
    from ..fdi.faults import inject, parse_injection
    from ..fusion import Pipeline
    from ..fusion.validation import segment_errors, session_block
    from .check import read_session

    session, _ = read_session(args.data)
    block, seg_index = session_block(session)
    cal = Calibration.load(args.calibration)
    insts = [k for k in cal.instruments if k in block.raw]
    for k in insts:
        if cal[k].noise_sigma is None:
            if args.noise is None:
                from ..errors import CalibrationFileError

                raise CalibrationFileError(f"the {k} calibration states no noise; pass --noise SIGMA (SI per sample)")
            cal[k].noise_sigma = np.full(cal[k].geometry.n, float(args.noise))
    injections = [parse_injection(s) for s in args.inject]
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
        mgr = RedundancyManager(pipe, make_detector(spec, pipe.table.sigma), p_fa=args.p_fa,
                                confirm=1 if args.detector == "cusum" else args.confirm,
                                readmit_after=args.readmit_after, sample_rate=fs)
        res = mgr.run(block.raw[k], block.valid.get(k), block.t)
        results[k] = res
        print(f"\n  {k}: {len(block)} samples, detector {args.detector}; final state {mgr.state.value}"
              + (f", isolated {', '.join(mgr.health.isolated)}" if mgr.health.isolated else ""))
        shown = [e for e in res.events if e.kind != "transient"]
        n_tr = sum(1 for e in res.events if e.kind == "transient")
        for e in shown[:50]:
            print(f"    t = {e.t:8.3f} s  {e.kind:22s} {e.sensor or '':4s} {e.message}")
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
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        doc = {k: {"events": [e.to_dict() for e in r.events], "final_state": r.state_names()[-1] if len(r.t) else None}
               for k, r in results.items()}
        (out / "replay.json").write_text(json.dumps(doc, indent=1))
        (out / "summary.json").write_text(json.dumps(summary, indent=1))
        png = _plot(out / "replay.png", results)
        print(f"\n  events: {out / 'replay.json'}" + (f"\n  plot:   {png}" if png else ""))
        print(f"  summary: {out / 'summary.json'}")
    n_iso = sum(v["isolations"] for v in summary.values())
    errs = ", ".join(f"{k} segment_error_rms {v['segment_error_rms']:.3g} {v['unit']}"
                     for k, v in summary.items() if "segment_error_rms" in v)
    print(f"replayed {len(block)} samples: {n_iso} isolation(s)" + (f"; {errs}" if errs else ""))
    return 0


def _plot(path: Path, results: dict) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
