"""The calibration report of every estimator (``rimu calibrate --report DIR``), in rimu's one report layout
(:class:`rimu.report.Report`: ``calibration.html`` and ``calibration.pdf``).

What it holds, in order: the console's cautions; the parameter table with 1-sigma in the field's units; the
residuals per segment (mean in units of its standard error, rms in units of the noise) for the instruments a
segment's known input constrains; for hand-held fits, the gravity norm per pose and the rotation misfit per
motion with their thresholds, and the motions left out; the weakly determined combinations; and, when given, the
comparison with a reference calibration of the same unit (scale in ppm, bias in the field's unit).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..report import Report
from ..units import G0, field_unit, fmt, raw_unit_for, scale_unit
from .estimate import bias_magnitudes, field_value
from .plots import residual_table

__all__ = ["calibration_report"]


def calibration_report(result: Any, session: Any = None, reference: Any = None, title: str | None = None,
                       cautions: list[str] | None = None) -> Report:
    """The :class:`~rimu.report.Report` of a :class:`~rimu.calibration.estimate.CalibrationResult`.

    ``reference``: a :class:`~rimu.calibration.Calibration` of the same unit to compare with (e.g. the MPU-6050
    authors' result); ``cautions``: further console lines to show with the result's notes.
    """
    from ..plotting import pyplot

    plt = pyplot()
    rep = Report(title or f"rimu calibration: {result.method}")
    rep.cautions([f"note: {n}" for n in result.notes] + list(cautions or []))
    rep.heading("Parameters (1-sigma)")
    for inst, r in result.instruments.items():
        rows = []
        mag = bias_magnitudes(r)
        for s in r.sensors:
            for i, (n, sp) in enumerate(zip(s.theta_names, s.theta_specs)):
                v, sd, unit = field_value(n, s.theta[i], float(np.sqrt(max(s.theta_cov[i, i], 0.0))), sp.report_unit,
                                          sp.to_report, mag.get(sp.report_unit))
                if n.endswith(".scale"):
                    rows.append([n, f"{v:.8g}", f"{sd:.3g} ppm", scale_unit(inst, raw_unit_for(result.raw_unit, inst))])
                else:
                    rows.append([n, f"{v:.5g}", f"{sd:.3g}", unit])
        rep.table(["parameter", "value", "1-sigma", "unit"], rows, f"{inst}: chi2/dof {r.chi2_dof:.3g}")
    _segment_residuals(rep, result, plt)
    _handheld(rep, result, session, plt)
    ex = getattr(result, "extra", {}) or {}
    weak = [(k.split("_")[1], w) for k in ("weak_accel", "weak_gyro") for w in ex.get(k, [])]
    if weak:
        rep.heading("Weakly determined combinations")
        rep.table(["instrument", "combination (relative sd)"], [list(w) for w in weak])
    if reference is not None:
        _compare(rep, result, reference)
    return rep


def _segment_residuals(rep: Report, result: Any, plt: Any) -> None:
    panels = []
    for inst in result.instruments:
        segs, sensors, z, q = residual_table(result, inst)
        if segs and np.any(np.isfinite(q)) and np.nanmax(np.nan_to_num(q)) > 1e-3:  # residuals, not a fill of ~0
            panels.append((inst, segs, sensors, z, q))
    if not panels:
        return
    rep.heading("Residuals per segment")
    fig, axes = plt.subplots(len(panels), 2, figsize=(11, 3.4 * len(panels)), squeeze=False)
    for row, (inst, segs, sensors, z, q) in zip(axes, panels):
        x = np.arange(len(segs))
        for j, name in enumerate(sensors):
            row[0].plot(x, z[:, j], "o-", ms=3, lw=0.8, label=name)
            row[1].plot(x, q[:, j], "o-", ms=3, lw=0.8, label=name)
        row[0].axhspan(-3, 3, color="tab:green", alpha=0.12, label="+-3 (threshold)")
        row[1].axhline(1.0, color="k", lw=0.8, ls="--", label="noise level")
        row[0].set_ylabel("mean / std. error [-]")
        row[1].set_ylabel("rms / noise sigma [-]")
        step = max(1, len(segs) // 40)  # at most about 40 segment names: each tick label is drawn three times
        for a, what in ((row[0], "segment mean residual"), (row[1], "segment rms residual")):
            a.set_xticks(x[::step], segs[::step], rotation=90, fontsize=7)
            a.set_title(f"{inst}: {what}", fontsize=10)
            a.grid(alpha=0.3)
        row[1].legend(fontsize=7, ncol=1 + len(sensors) // 9, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    h = 3.4 * len(panels)
    right = 0.86 - 0.06 * (max(len(p[2]) for p in panels) // 9)
    fig.subplots_adjust(left=0.07, right=right, bottom=0.9 / h, top=1 - 0.35 / h, hspace=0.55, wspace=0.25)
    rep.figure(fig, "Each segment's residual: the mean against its standard error (outside +-3: the model misses "
                    "something constant over the segment), the rms against the noise level (1 = noise).")


def _handheld(rep: Report, result: Any, session: Any, plt: Any) -> None:
    ex = getattr(result, "extra", {}) or {}
    nr = np.asarray(ex.get("norm_residual_accel", []), dtype=float)
    rr = np.asarray(ex.get("rotation_residual_deg", []), dtype=float)
    if nr.size == 0 and rr.size == 0:
        return
    rep.heading("Hand-held fit: poses and motions")
    panels = []
    if nr.size:
        sig = np.asarray(ex.get("norm_sigma_accel", np.full(nr.size, np.nan)), dtype=float)
        poses = [s.label for s in getattr(session, "segments", []) if s.kind in ("static", "static_unknown")]
        poses = poses if len(poses) == nr.size else [f"pose {k + 1}" for k in range(nr.size)]
        panels.append(("pose", poses, nr / (1e-3 * G0), 2 * sig / (1e-3 * G0), "gravity norm - g [mg]",
                       "accelerometers: gravity norm per pose"))
        rep.table(["pose", "norm - g", "1-sigma"], [[p, fmt(v, "specific_force"), fmt(s, "specific_force")]
                                                    for p, v, s in zip(poses, nr, sig)])
    if rr.size:
        motions = list(ex.get("motion_labels", [f"motion {k + 1}" for k in range(rr.size)]))
        s = float(ex.get("rotation_sigma_deg", np.nan))
        panels.append(("motion", motions, rr, np.full(rr.size, 3 * s), "gravity-direction misfit [deg]",
                       "gyros: rotation misfit per motion"))
        rep.table(["motion", "misfit [deg]"], [[m, f"{v:.3g}"] for m, v in zip(motions, rr)],
                  f"scatter {s:.3g} deg per component")
    clipped = ex.get("clipped_motions") or []
    if clipped:
        rep.text(f"Left out of the gyro fit (the gyros clip in them): {', '.join(map(str, clipped))}.")
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 3.6), squeeze=False)
    for ax, (what, labels, v, thr, ylabel, title) in zip(axes[0], panels):
        x = np.arange(len(labels))
        ax.bar(x, v, color="C0", label="residual")
        if np.all(np.isfinite(thr)):
            ax.step(np.r_[x - 0.5, x[-1] + 0.5], np.r_[thr, thr[-1]], where="post", color="C3", lw=1,
                    label="2 sigma" if what == "pose" else "3 x scatter")
            if what == "pose":
                ax.step(np.r_[x - 0.5, x[-1] + 0.5], -np.r_[thr, thr[-1]], where="post", color="C3", lw=1)
        ax.set_xticks(x, labels, rotation=90, fontsize=7)
        ax.set_xlabel(f"{what} [label]")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    rep.figure(fig, "The gravity norm of each pose after calibration minus g, against twice its standard deviation; "
                    "the misfit between the integrated rotation and the change of the gravity direction per motion.")


def _compare(rep: Report, result: Any, reference: Any) -> None:
    cal = result.to_calibration()
    rows = []
    for inst in cal.instruments:
        if inst not in reference.instruments:
            continue
        a, b = cal[inst], reference[inst]
        if a.geometry.n != b.geometry.n:
            continue
        quantity = "rate" if inst == "gyro" else "specific_force"
        d = np.asarray(a.bias, float) - np.asarray(b.bias, float)
        unit = field_unit(quantity, float(np.nanmax(np.abs(d))) if d.size else None)[0]  # one unit per instrument
        for i, name in enumerate(a.geometry.names):
            rows.append([inst, name, f"{(a.scale[i] / b.scale[i] - 1) * 1e6:.4g}", fmt(float(d[i]), quantity, unit)])
    if rows:
        rep.heading("Against the reference calibration")
        rep.table(["instrument", "sensor", "scale difference [ppm]", "bias difference"], rows)
