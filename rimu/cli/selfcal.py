"""``rimu selfcal LOG --calibration cal.json -o cal2.json``: fit the drift and temperature model of the in-flight
tracker (:mod:`rimu.fdi.selfcal`) to a recording, from the parity of every sensor at once, and write the updated
calibration with its covariance.

LOG is a session file in rimu's format (``.npz``, or ``.csv`` with its ``.json`` sidecar; docs/session-format.md),
read in chunks and run through the same Kalman filter as in flight: every effect of the calibration is compensated
first, then per instrument the bias drift (random walk), the relative scale drift (where the motion excites it)
and, when the log has a temperature column, the temperature coefficients of the bias are tracked. Windows whose
innovation fails the chi-square gate are left out (a fault in the log is not absorbed). What the parity cannot see,
the common mode (a drift every sensor shares as a true input would), is stated and left as it was.

The output: scale ``SF / (1 + k)`` and bias ``(B + b) / (1 + k)`` at the end of the log, first- to third-order
temperature coefficients added to the ``bias_temperature``, ``bias_temperature2`` and ``bias_temperature3`` effects
(``--temperature-orders``), and the covariance of the tracked terms in place of theirs (``x1.bias``, ``x1.scale``,
``x1.bias_tc1``...).

The drift rate: from the calibration's noise model (``rimu noise``: bias instability and rate random walk, times
``--drift-factor``), or ``--bias-rw`` ((SI)^2/s). Figures are printed in the field's units (deg/h, micro-g, ppm).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ._common import (
    add_json_option,
    add_report_option,
    json_dump,
    nonnegative_float,
    positive_float,
    positive_int,
    probability,
)

_TC_DEFAULT = {"gyro": (1e-4, 1e-5, 1e-6), "accel": (1e-3, 1e-4, 1e-5)}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("selfcal", help="fit the calibration's drift and temperature terms to a recording (parity)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", metavar="LOG", help="session file (.npz, or .csv/.json with sidecar)")
    p.add_argument("--calibration", required=True, help="calibration JSON file (the fixed calibration)")
    p.add_argument("-o", "--output", required=True, help="updated calibration JSON file to write")
    p.add_argument("--instrument", action="append", choices=["gyro", "accel"], default=None,
                   help="instrument to track (repeatable; default every instrument of the calibration in the log)")
    add_tracker_options(p)
    add_json_option(p)
    add_report_option(p, "the report (selfcal_report.html, selfcal_report.pdf: the tracked terms at the end and "
                         "over the log with their 1-sigma band) and selfcal-<instrument>.png")
    p.set_defaults(func=run)


def add_tracker_options(p: argparse.ArgumentParser, prefix: str = "") -> None:
    """The tracker's settings (:class:`rimu.fdi.selfcal.SelfCalSettings`) as options, ``--{prefix}drift-factor``...
    (``rimu selfcal``: no prefix; ``rimu replay --selfcal``: ``selfcal-``)."""
    p.add_argument(f"--{prefix}drift-factor", type=positive_float, default=1.0,
                   help="bias drift rate relative to the noise model's bias instability (default %(default)s)")
    p.add_argument(f"--{prefix}horizon", type=positive_float, default=3600.0,
                   help="time scale at which the bias random walk matches the bias instability, s (default %(default)s)")
    p.add_argument(f"--{prefix}bias-rw", type=positive_float, default=None,
                   help="bias random-walk intensity, SI^2/s (instead of the noise model's)")
    p.add_argument(f"--{prefix}scale-rw", type=positive_float, default=(200e-6) ** 2 / 7200.0,
                   help="relative scale random-walk intensity, 1/s (default: 200 ppm in 2 h)")
    p.add_argument(f"--{prefix}no-scale", action="store_true", help="do not track the scale")
    p.add_argument(f"--{prefix}bias-sigma0", type=nonnegative_float, default=0.0,
                   help="1-sigma of each bias's error when tracking starts, SI (default 0: the calibration is taken "
                        "as true at the start; give its stated uncertainty to let the tracker correct it)")
    p.add_argument(f"--{prefix}scale-sigma0", type=nonnegative_float, default=0.0,
                   help="1-sigma of each relative scale's error when tracking starts, 1 (e.g. 1e-3 for 1000 ppm; "
                        "default 0)")
    p.add_argument(f"--{prefix}temperature-orders", type=positive_int, default=2, choices=[1, 2, 3],
                   help="orders of the bias temperature coefficients tracked when the data have a temperature "
                        "(default %(default)s)")
    p.add_argument(f"--{prefix}temperature-sigma", default=None,
                   help="prior 1-sigma of the coefficients, comma-separated per order, SI/K^k (default gyro "
                        "1e-4,1e-5,1e-6 rad/s/K^k; accel 1e-3,1e-4,1e-5 m/s^2/K^k)")
    p.add_argument(f"--{prefix}window", type=positive_float, default=1.0,
                   help="window of one measurement of the tracker, s (default %(default)s)")
    p.add_argument(f"--{prefix}gate", type=probability, default=1e-4,
                   help="innovation gate probability: windows beyond it are not absorbed (default %(default)s)")
    if prefix:  # in flight: the detector's alarms hold the tracker
        p.add_argument(f"--{prefix}hold", type=nonnegative_float, default=3.0,
                       help="seconds without an alarm before a window is absorbed (default %(default)s; at least the "
                            "detector's window plus its confirmations)")
        p.add_argument(f"--{prefix}guard", type=nonnegative_float, default=60.0,
                       help="memory of the held-out check, s: each group of terms corrects the outputs only while "
                            "it lowers the parity of windows it was not fitted on (default %(default)s; 0: off, "
                            "every term applied; docs/selfcal.md)")


def tracker_settings(args: argparse.Namespace, cal: Any, inst: str, has_temperature: bool, prefix: str = "") -> Any:
    """:class:`rimu.fdi.selfcal.SelfCalSettings` of instrument ``inst`` from the options of
    :func:`add_tracker_options`; one clear line when the drift rate or the noise cannot be known."""
    from ..errors import MissingNoiseError, OptionError
    from ..fdi.selfcal import SelfCalSettings, bias_random_walk

    def opt(name: str) -> Any:
        return getattr(args, (prefix + name).replace("-", "_"))

    flag = f"--{prefix}bias-rw"
    if cal.noise_sigma is None and cal.noise is None:
        raise MissingNoiseError(f"the {inst} calibration has neither noise_sigma nor a noise model: the tracker needs "
                                "the sensors' noise; identify it first (rimu noise) or set noise_sigma in the file")
    if opt("bias-rw") is not None:
        q = opt("bias-rw")
    elif cal.noise is not None:
        q = bias_random_walk(cal.noise, opt("drift-factor"), opt("horizon"))
    else:
        raise MissingNoiseError(f"the {inst} calibration has no noise model: give the bias drift rate with {flag} "
                                "(SI^2/s), or identify the noise first (rimu noise)")
    tsig = None
    orders = opt("temperature-orders")
    if has_temperature:
        if opt("temperature-sigma") is not None:
            try:
                vals = [float(x) for x in opt("temperature-sigma").split(",")]
            except ValueError:
                raise OptionError(f"--{prefix}temperature-sigma must be numbers separated by commas, got "
                                  f"{opt('temperature-sigma')!r}") from None
            if len(vals) < orders or any(not v > 0 for v in vals):
                raise OptionError(f"--{prefix}temperature-sigma needs {orders} positive values (one per "
                                  f"order), got {opt('temperature-sigma')!r}")
        else:
            vals = list(_TC_DEFAULT[inst])
        tsig = tuple(vals[:orders])
    extra = {"hold_s": opt("hold"), "guard_s": opt("guard") or None} if prefix else {}
    return SelfCalSettings(bias_rw=q, scale_rw=None if opt("no-scale") else opt("scale-rw"), bias_sigma0=opt("bias-sigma0"),
                           scale_sigma0=opt("scale-sigma0"), temperature_sigma=tsig, window_s=opt("window"), gate_p=opt("gate"), **extra)


def print_terms(inst: str, trk: Any, terms: dict[str, tuple[np.ndarray, np.ndarray]], indent: str = "  "
                ) -> list[dict[str, Any]]:
    """Print the tracked terms of every sensor in one field unit per instrument (:func:`rimu.units.fmt`; scales in
    ppm, coefficients per K^k); returns them per sensor in SI (for the JSON summaries)."""
    from ..units import field_unit, fmt

    quantity = "rate" if inst == "gyro" else "specific_force"
    # one unit per instrument for every term, the one its largest bias (or coefficient) reads best in
    big = max((float(np.nanmax(np.abs(v))) for k, (v, _) in terms.items() if k != "scale" and np.size(v)), default=0.0)
    unit, _ = field_unit(quantity, big)
    rows = []
    for i, nm in enumerate(trk.calibration.geometry.names):
        row: dict[str, Any] = {"sensor": nm}
        parts = []
        for blk_name, (v, s) in terms.items():
            if blk_name == "bias":
                parts.append(f"bias {fmt(v[i], quantity, unit)} +- {fmt(s[i], quantity, unit, digits=2)}")
            elif blk_name == "scale":
                parts.append(f"scale {fmt(v[i], 'ratio', 'ppm')} +- {fmt(s[i], 'ratio', 'ppm', digits=2)}")
            else:
                o = int(blk_name[2])
                parts.append(f"{blk_name} {fmt(v[i], quantity, unit, digits=3)}/K^{o} +- "
                             f"{fmt(s[i], quantity, unit, digits=2)}/K^{o}")
            row[blk_name] = float(v[i])
            row[blk_name + "_sigma"] = float(s[i])
        print(f"{indent}{nm:>8s}  " + ", ".join(parts))
        rows.append(row)
    return rows


def run(args: argparse.Namespace) -> int:
    from ..calibration import Calibration
    from ..errors import SessionFormatError
    from ..fdi.selfcal import SelfCalTracker
    from ..fusion import Pipeline
    from ..session import iter_blocks
    cal = Calibration.load(args.calibration)
    pipe = Pipeline(cal)
    trackers: dict[str, Any] = {}
    states: dict[str, Any] = {}
    counts: dict[str, list[int]] = {}
    history: dict[str, list[tuple[float, np.ndarray, np.ndarray]]] = {}
    n_samples, t_first, t_last, has_t = 0, None, None, None
    for blk in iter_blocks(args.data):
        if has_t is None:
            has_t = blk.temperature is not None and bool(np.isfinite(blk.temperature).any())
            insts = args.instrument or [k for k in cal.instruments if k in blk.raw]
            missing = [k for k in insts if k not in blk.raw or k not in cal.instruments]
            if missing or not insts:
                raise SessionFormatError(f"{args.data}: no {missing or 'instrument'} data that the calibration "
                                         f"{args.calibration} also has (log: {sorted(blk.raw)}, calibration: "
                                         f"{list(cal.instruments)})")
            for k in insts:
                trackers[k] = SelfCalTracker(cal[k], tracker_settings(args, cal[k], k, has_t))
                states[k] = trackers[k].initial_state(float(blk.t[0]))
                counts[k] = [0, 0]
                history[k] = []
            t_first = float(blk.t[0])
        comp = pipe.compensate(blk)
        n_samples += len(blk.t)
        t_last = float(blk.t[-1])
        fs = 1.0 / float(np.median(np.diff(blk.t))) if len(blk.t) > 1 else 1.0
        for k, trk in trackers.items():
            M = max(1, int(round(args.window * fs)))
            raw = comp.raw[k]
            ok = np.isfinite(raw) & blk.valid.get(k, np.ones(raw.shape, bool))
            z = cal[k].compensate(np.where(ok, raw, 0.0))
            T = blk.temperature if has_t else None
            for a in range(0, len(z), M):
                b = min(len(z), a + M)
                rows = ok[a:b].all(axis=1)
                if T is not None:
                    rows &= np.isfinite(T[a:b])
                if not rows.any():
                    continue
                zw = z[a:b][rows]
                u = zw @ trk.G.T
                g = trk.regressors(len(zw), u, None if T is None else T[a:b][rows])
                st = trk.predict(states[k], float(blk.t[b - 1]))
                states[k], info = trk.update(st, zw, g)
                counts[k][0 if info.accepted else 1] += 1
                if args.report:
                    tm = trk.terms(states[k])
                    history[k].append((float(blk.t[b - 1]), np.stack([tm[x][0] for x in trk.blocks]),
                                       np.stack([tm[x][1] for x in trk.blocks])))
    if not trackers:
        raise SessionFormatError(f"{args.data}: the log holds no samples")
    out = dict(cal.instruments_cal)
    summary: dict[str, Any] = {"log": str(args.data), "samples": n_samples, "duration_s": t_last - t_first,
                               "temperature": bool(has_t), "instruments": {}}
    import contextlib
    import io

    console = [f"{args.data}: {n_samples} samples over {t_last - t_first:.1f} s"
               + ("" if has_t else " (no temperature: temperature terms not tracked)")]
    print(console[0])
    sections = []
    for k, trk in trackers.items():
        out[k] = trk.calibration_at(states[k])
        terms = trk.terms(states[k])
        console.append(f"{k}: {counts[k][0]} windows absorbed, {counts[k][1]} gated out; tracked terms (common mode "
                       f"left as it was: only an external reference gives it), value +- 1 sigma:")
        print(console[-1])
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            rows = print_terms(k, trk, terms)
        print(buf.getvalue(), end="")
        sections.append((k, trk, history[k], buf.getvalue().splitlines()))
        summary["instruments"][k] = {"windows_absorbed": counts[k][0], "windows_gated": counts[k][1],
                                     "blocks": list(trk.blocks), "units": "SI (rad/s or m/s^2, relative scale, "
                                     "SI/K^k)", "sensors": rows}
    meta = dict(cal.metadata)
    meta["selfcal"] = {"log": str(args.data), "duration_s": t_last - t_first,
                       "tracked": {k: list(t.blocks) for k, t in trackers.items()}}
    written = Calibration(out, cal.raw_unit, f"{cal.method}+selfcal", metadata=meta).save(args.output)
    print(f"updated calibration written to {written}")
    if args.report:
        html, pdf, *pngs = _report(args.report, str(args.data), console, sections)
        print(f"report: {html} and {pdf}" + "".join(f"\nplot: {p}" for p in pngs))
    if args.json:
        json_dump(summary, args.json)
    return 0


def loop_summary(inst: str, loop: Any) -> dict:
    """Print the self-calibration of one instrument at the end of a run (windows absorbed, gated out, thrown away;
    the tracked terms with their 1-sigma; the held-out check) and return it as the summary's dict: what ``rimu
    replay --selfcal`` and ``rimu monitor --selfcal`` both show (``loop``: the runtime's
    :class:`rimu.fdi.selfcal.SelfCalLoop`)."""
    print(f"    self-calibration: {loop.accepted} windows absorbed, {loop.rejected} gated out, {loop.discarded} "
          "thrown away (alarms); tracked terms at the end (common mode left as it was), value +- 1 sigma:")
    rows = print_terms(inst, loop.tracker, loop.terms(), indent="    ")
    if loop.discarded > loop.accepted:  # the alarms froze the tracker more than it tracked: say what may cause it
        print(f"    note: the alarms threw away more windows ({loop.discarded}) than were absorbed ({loop.accepted}): "
              "a unit drifting faster than the tracker is told (--selfcal-bias-rw or --selfcal-drift-factor) or "
              "starting further off (--selfcal-bias-sigma0) alarms on its drift, the tracker stays frozen and "
              "healthy sensors may be isolated (docs/selfcal.md, Fault-aware)")
    g = loop.guard()
    if g["enabled"]:
        print(f"    held-out check (docs/selfcal.md): parity rms {g['heldout_rms_fixed']:.3f} sigma with the fixed "
              f"calibration, {g['heldout_rms_applied']:.3f} sigma with the terms applied"
              + ("" if g["nis_per_dof"] is None else
                 f"; innovations {g['nis_per_dof']:.2f} per dof (1: the model fits)"))
        for name, v in g["groups"].items():
            print(f"      {name}: {'applied' if v['applied'] else 'SUSPENDED'} at the end; suspended "
                  f"{v['suspended_windows']} windows ({v['suspensions']} times switched off); held-out gain "
                  f"{v['heldout_gain']:+.4g} sigma^2" + ("" if v["heldout_gain"] > 0 else
                                                         " (it would have made the parity worse)"))
    return {"windows_absorbed": loop.accepted, "windows_gated": loop.rejected, "windows_discarded": loop.discarded,
            "blocks": list(loop.tracker.blocks), "units": "SI (rad/s or m/s^2, relative scale, SI/K^k)",
            "sensors": rows, "guard": g}


def terms_figure(inst: str, trk: Any, hist: list[tuple[float, np.ndarray, np.ndarray]], max_points: int = 400) -> Any:
    """The tracked terms of every sensor over a log (``hist``: (t, values (m, n), 1-sigma (m, n)) per window, at most
    ``max_points`` of them drawn, evenly spaced), each with its 1-sigma band, one panel per term, each axis in the field unit of its values (rimu.units.field_unit;
    bracketed, as the report layout wants). Shared by ``rimu selfcal`` and ``rimu replay --selfcal``."""
    from ..plotting import pyplot
    from ..units import PPM, field_unit

    plt = pyplot()
    if len(hist) > max_points:  # a picture of the history, not every window: at most max_points, the last kept
        step = -(-len(hist) // max_points)
        hist = [*hist[:-1:step], hist[-1]]
    t = np.array([h[0] for h in hist], dtype=float)
    v = np.array([h[1] for h in hist], dtype=float)
    s = np.array([h[2] for h in hist], dtype=float)
    if not np.isfinite(t).all():
        t = np.zeros(len(t))
    fig, axes = plt.subplots(trk.m, 1, figsize=(9, 2.3 * trk.m + 0.6), sharex=True, squeeze=False)
    names = trk.calibration.geometry.names
    q = "rate" if inst == "gyro" else "specific_force"
    for b, (name, ax) in enumerate(zip(trk.blocks, axes[:, 0])):
        big = float(np.nanmax(np.abs(v[:, b]) + np.abs(s[:, b]))) if v.size else 0.0
        if name == "scale":
            fb, ub = 1.0 / PPM, "ppm"
        else:
            u, fb = field_unit(q, big)
            ub = u if name == "bias" else f"{u}/K^{name[2]}"
        for i in range(trk.n):
            line, = ax.plot(t, v[:, b, i] * fb, lw=0.8, marker="." if len(t) < 3 else None,
                            label=names[i] if trk.n <= 12 else None)
            line.set_gid("data")
            ax.fill_between(t, (v[:, b, i] - s[:, b, i]) * fb, (v[:, b, i] + s[:, b, i]) * fb,
                            color=line.get_color(), alpha=0.15, lw=0)
        ax.set_ylabel(f"{name} [{ub}]")
        ax.set_title(f"{inst}: tracked {name} (without its common mode), 1-sigma band", fontsize=10)
        ax.grid(alpha=0.3)
    if trk.n <= 12:
        axes[0, 0].legend(ncol=1, fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def _report(folder: str, log: str, console: list[str], sections: list[tuple[str, Any, list, list[str]]]) -> list:
    """The one report layout (:class:`rimu.report.Report`): ``selfcal_report.html`` and ``.pdf`` in ``folder`` with
    the console's notes, per instrument the terms at the end of the log as a table and their history as a figure
    (also written as ``selfcal-<instrument>.png``). Returns the paths written."""
    from pathlib import Path

    from ..report import Report

    rep = Report(f"rimu selfcal: {log}")
    rep.cautions(console)
    for inst, trk, hist, lines in sections:
        rep.heading(f"Self-calibration: {inst}")
        rep.table(["sensor", "tracked terms at the end of the log, value +- 1 sigma"],
                  [ln.strip().split("  ", 1) if "  " in ln.strip() else [ln.strip(), ""] for ln in lines])
        rep.figure(terms_figure(inst, trk, hist), f"{inst}: the terms tracked over the log, each sensor with its "
                                                  "1-sigma band, in the field's units (docs/selfcal.md).")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    written = [rep.save_figure(j, out / f"selfcal-{inst}.png") for j, (inst, *_r) in enumerate(sections)]
    html, pdf = rep.write(out, "selfcal_report")
    return [html, pdf, *[w for w in written if w is not None]]
