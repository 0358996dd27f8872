"""Report: the array's parity rms in motion before and after each calibration step, per triad, with a plot.

Steps (gyros): raw -> relative gain and bias -> + sampling offsets; (accelerometers): raw -> lever arms at the
nominal positions removed -> + gains and biases -> + estimated positions -> + the angular acceleration taken per epoch
from the accelerometers themselves (``AA_STEP``; three triads at least, not on one line; its parity is scaled to
compare like for like with the plain model's, :func:`rimu.array.accel_angular_acceleration`). After the gyro steps the nested F-test
ranking (:func:`rimu.array.rank_candidates`) names the term that now limits the agreement.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import IdentifiabilityError, ShapeError
from ..units import RAD_TO_DEG, fmt
from .guards import MOTION_BAND_SHARE, band_share, choose_lowpass, motion_band, worse
from .layout import ArrayLayout
from .positions import PositionFit, aa_from_accelerometers_refusal, angular_acceleration_check, fit_positions
from .relative import RelativeFit, fit_relative_gyro
from .remainder import RemainderAnalysis, remainder_analysis

__all__ = ["ArrayReport", "array_report", "lowpass"]


def lowpass(t: np.ndarray, x: np.ndarray, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` (N, ...) along time, at the median sampling rate of ``t``.

    The rigid-body array model holds below the board's vibration modes; a recording from a vehicle (rotor
    vibration) is best compared there. A linear time-invariant filter applied to every triad alike commutes with
    gains, biases and time offsets, so it does not change what the relative calibration estimates.

    Raises
    ------
    ShapeError
        ``cutoff_hz`` not below the Nyquist frequency.
    """
    from scipy.signal import butter, sosfiltfilt

    fs = 1.0 / float(np.median(np.diff(t)))
    if not 0 < cutoff_hz < fs / 2:
        raise ShapeError(f"cutoff_hz must be in (0, {fs / 2:.4g}) Hz (the Nyquist frequency), got {cutoff_hz}")
    return sosfiltfilt(butter(order, cutoff_hz, fs=fs, output="sos"), np.asarray(x, dtype=float), axis=0)


@dataclass
class ArrayReport:
    """Per-step parity rms in motion (gyro in deg/s, accelerometer in m/s^2), per triad, and the fits."""

    names: tuple[str, ...]
    gyro_steps: dict[str, np.ndarray]
    accel_steps: dict[str, np.ndarray] = field(default_factory=dict)
    limiting_term: str = ""
    gyro_fit: "RelativeFit | None" = None
    position_fit: "PositionFit | None" = None
    notes: list[str] = field(default_factory=list)
    #: steps not applied because they made the agreement worse: step name -> the reason with the figures
    refused: dict[str, str] = field(default_factory=dict)
    #: what is left of the gyro disagreement: deterministic or not (:func:`rimu.array.remainder_analysis`)
    remainder: "RemainderAnalysis | None" = None
    #: the accelerometer steps fitted on the first part of the motion and judged on the rest (m/s^2, per triad)
    accel_held_out: dict[str, np.ndarray] = field(default_factory=dict)
    #: what is left of the accelerometers on the held-out part (:func:`rimu.array.angular_acceleration_check`)
    accel_remainder: "dict | None" = None

    def to_dict(self) -> dict:
        return {"triads": list(self.names),
                "gyro_parity_rms_deg_s": {k: v.tolist() for k, v in self.gyro_steps.items()},
                "accel_parity_rms_m_s2": {k: v.tolist() for k, v in self.accel_steps.items()},
                "accel_parity_rms_held_out_m_s2": {k: v.tolist() for k, v in self.accel_held_out.items()},
                "accel_remainder": self.accel_remainder,
                "limiting_term": self.limiting_term, "refused": dict(self.refused),
                "candidates": [c.to_dict() for c in (self.gyro_fit.candidates if self.gyro_fit else [])],
                "notes": self.notes, "remainder": None if self.remainder is None else self.remainder.to_dict()}

    def to_markdown(self) -> str:
        out = ["# Array report: parity rms in motion per step", ""]
        for title, steps, unit in (("Gyros", self.gyro_steps, "deg/s"), ("Accelerometers", self.accel_steps, "m/s^2"),
                                   ("Accelerometers, held out (fitted on the first half of the motion, judged on "
                                    "the second)", self.accel_held_out, "m/s^2")):
            if not steps:
                continue
            out += [f"## {title} [{unit}]", "", "| step | " + " | ".join(self.names) + " | mean |",
                    "|---|" + "---|" * (len(self.names) + 1)]
            for name, v in steps.items():
                out.append(f"| {name} | " + " | ".join(f"{x:.4g}" for x in v) + f" | {v.mean():.4g} |")
            out.append("")
            if AA_STEP in steps:
                k = len(self.names)
                out += [f"Every row is the rms per triad axis of the parity, scaled alike: on white noise sigma each "
                        f"is sigma sqrt((k - 1)/k) (k = {k}). The plain model (specific force per epoch) leaves "
                        f"3k - 3 = {3 * k - 3} parity dof per epoch; the last row's (specific force and angular "
                        f"acceleration per epoch, rimu.array.accel_angular_acceleration) leaves 3k - 6 = {3 * k - 6}, "
                        "each component scaled by sqrt(((k - 1)/k) / (1 - h)), h its leverage.", ""]
        if self.gyro_fit is not None:
            out += ["## What limits the gyro agreement now", "", f"**{self.limiting_term}**", "",
                    "| candidate | parameters | F | log10 p | share of residual |", "|---|---|---|---|---|"]
            for c in self.gyro_fit.candidates:
                out.append(f"| {c.name} | {c.n_params} | {c.f_stat:.3g} | {c.log10_p:.1f} | {c.explained:.3f} |")
            out.append("")
        if self.remainder is not None:
            out += [self.remainder.to_markdown()]
        if self.accel_remainder is not None:
            out += ["## What remains of the accelerometers (held out)", "", accel_verdict(self.accel_remainder), ""]
        out += [f"- {n}" for n in self.notes]
        out += [f"- **not applied**: {r}" for r in self.refused.values()]
        return "\n".join(out) + "\n"

    def figure(self):  # type: ignore[no-untyped-def]
        """The bar chart per triad and step (a matplotlib Figure; the ``plots`` extra): linear axes from zero,
        every axis with its unit, the legend beside the bars."""
        from ..plotting import pyplot

        plt = pyplot()
        panels = [(s, u, t) for s, u, t in ((self.gyro_steps, "deg/s", "gyro"), (self.accel_steps, "m/s^2", "accel"))
                  if s]
        w = max(7.5, 0.35 * len(self.names) + 4.5)
        fig, axes = plt.subplots(len(panels), 1, figsize=(w, 3.0 * len(panels) + 0.6), squeeze=False)
        for ax, (steps, unit, title) in zip(axes[:, 0], panels):
            x = np.arange(len(self.names))
            wbar = 0.8 / len(steps)
            for i, (name, v) in enumerate(steps.items()):
                # a long step name wrapped to the legend's width beside the axes (it ran out of the figure)
                ax.bar(x + i * wbar - 0.4 + wbar / 2, v, wbar, label=textwrap.fill(name, 26))
            ax.set_ylim(0, None)
            ax.set_xticks(x, self.names, rotation=90 if len(self.names) > 12 else 0)
            ax.set_xlabel("triad [name]")
            ax.set_ylabel(f"parity rms [{unit}]")
            ax.set_title(f"{title}: each triad against the array, in motion", fontsize=10)
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        if self.limiting_term:
            fig.suptitle(f"gyro agreement now limited by: {self.limiting_term}", fontsize=10)
        h = 3.0 * len(panels) + 0.6
        fig.subplots_adjust(left=0.9 / w, right=1 - 2.2 / w, top=1 - 0.75 / h, bottom=0.75 / h, hspace=0.7)
        return fig

    def plot(self, path: "str | Path") -> Path:
        """The bar chart of :meth:`figure` as PNG. Needs the ``plots`` extra (matplotlib)."""
        from ..plotting import save_figure

        return save_figure(self.figure(), path)


def _held_out(layout: ArrayLayout, t: np.ndarray, gyro: np.ndarray, terms: tuple[str, ...],
              motion_threshold_deg_s: float, part: float = 0.7) -> tuple[np.ndarray, np.ndarray] | None:
    """(parity rms before, after) in deg/s on the last 30 % of the recording, of a gyro fit on the first 70 %."""
    n = int(part * len(t))
    try:
        f = fit_relative_gyro(layout, t[:n], gyro[:n], terms=terms, candidates=(),
                              motion_threshold_deg_s=motion_threshold_deg_s)
    except (IdentifiabilityError, ShapeError):
        return None
    z = layout.to_body(np.asarray(gyro[n:], dtype=float))
    u = f.apply(t[n:], gyro[n:])
    omega = u.mean(axis=1)

    def rms(x: np.ndarray) -> np.ndarray:
        moving = np.linalg.norm(omega, axis=1) > np.radians(motion_threshold_deg_s)
        if moving.sum() < 10:
            moving = np.ones(len(omega), bool)
        y = x[moving] - x[moving].mean(axis=1, keepdims=True)
        return np.sqrt(np.mean(y**2, axis=(0, 2))) * RAD_TO_DEG

    return rms(z), rms(u)


def _never_worse(steps: dict[str, np.ndarray], unit: str, what: str,
                 held_out: "dict[str, tuple[np.ndarray, np.ndarray]] | None" = None
                 ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The steps applied (each no worse than the last applied one, on the fitted data and, where given, on the
    held-out part) and the refused ones with the reason."""
    applied: dict[str, np.ndarray] = {}
    refused: dict[str, str] = {}
    last = None
    for name, v in steps.items():
        if last is not None and worse(applied[last], v):
            refused[name] = (f"{what} step '{name}' not applied: it raises the parity rms in motion from "
                             f"{applied[last].mean():.4g} to {v.mean():.4g} {unit} on the data it was fitted on")
            continue
        ho = (held_out or {}).get(name)
        if last is not None and ho is not None and worse(*ho):
            refused[name] = (f"{what} step '{name}' not applied: fitted on the first 70 % of the recording it raises "
                             f"the parity rms on the last 30 % from {ho[0].mean():.4g} to {ho[1].mean():.4g} {unit}")
            continue
        applied[name] = v
        last = name
    return applied, refused


def array_report(
    layout: ArrayLayout, t: np.ndarray, gyro: np.ndarray, accel: "np.ndarray | None" = None,
    nominal_positions_m: "np.ndarray | None" = None, motion_threshold_deg_s: float = 30.0,
    lowpass_hz: "float | str | None" = None, held_out: bool = True,
) -> ArrayReport:
    """Run the steps and collect the parity rms in motion after each, per triad.

    Parameters as :func:`fit_relative_gyro` and :func:`fit_positions`; ``accel`` may be None (gyros only).
    ``lowpass_hz`` filters every triad alike first (:func:`lowpass`); ``"auto"`` chooses the cut-off from the
    vibration spectrum (:func:`rimu.array.guards.choose_lowpass`). A step the motion cannot identify is
    skipped with a note naming the missing excitation. A step that raises the parity rms in motion above its
    input's, on the data or (gyros, ``held_out``) fitted on the first 70 % and checked on the rest, is not
    applied: :attr:`ArrayReport.refused` says why, and the steps shown are the ones applied.
    """
    notes: list[str] = []
    gyro_unfiltered = gyro  # the remainder is judged on the rates as sampled (a low-passed series is never white)
    if isinstance(lowpass_hz, str):
        if lowpass_hz != "auto":
            raise ShapeError(f"lowpass_hz must be a number of Hz, 'auto' or None, got {lowpass_hz!r}")
        lowpass_hz, why = choose_lowpass(t, gyro, accel)
        notes.append(why)
        if lowpass_hz is not None:
            gyro = lowpass(t, gyro, lowpass_hz)
            accel = None if accel is None else lowpass(t, accel, lowpass_hz)
    elif lowpass_hz is not None:
        gyro = lowpass(t, gyro, lowpass_hz)
        accel = None if accel is None else lowpass(t, accel, lowpass_hz)
        notes.append(f"every triad low-passed at {lowpass_hz:g} Hz (zero phase) before the fits")
    cut_motion = None  # a cut-off below the motion's band: the lever arms are filtered away, positions mean nothing
    if lowpass_hz is not None and accel is not None:
        band, band_aa = motion_band(t, gyro_unfiltered)
        if lowpass_hz < band:
            kept, kept_aa = band_share(t, gyro_unfiltered, lowpass_hz)
            cut_motion = (f"accelerometer step '+ positions' not applied: the low-pass at {lowpass_hz:.3g} Hz lies below "
                          f"the motion's band ({100 * MOTION_BAND_SHARE:g} % of the rate's power below {band:.3g} Hz, of "
                          f"the angular acceleration's below {band_aa:.3g} Hz) and passes {100 * kept:.2g} % of the "
                          f"rate's power and {100 * kept_aa:.2g} % of the angular acceleration's: the lever arms are "
                          f"filtered away and fitted positions mean nothing; give a cut-off above {band:.3g} Hz or "
                          "--lowpass-hz none")
    base = fit_relative_gyro(layout, t, gyro, motion_threshold_deg_s=motion_threshold_deg_s)
    steps = {"raw": base.parity_rms_rad_s["before"] * RAD_TO_DEG,
             "relative gain+bias": base.parity_rms_rad_s["after"] * RAD_TO_DEG}
    fit = base
    ho: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    try:
        fit = fit_relative_gyro(layout, t, gyro, terms=("scale_misalignment", "bias", "sampling_offset"),
                                motion_threshold_deg_s=motion_threshold_deg_s)
        steps["+ sampling offsets"] = fit.parity_rms_rad_s["after"] * RAD_TO_DEG
    except IdentifiabilityError as exc:
        notes.append(f"sampling offsets skipped: {exc}")
    if held_out:
        for name, terms in (("relative gain+bias", ("scale_misalignment", "bias")),
                            ("+ sampling offsets", ("scale_misalignment", "bias", "sampling_offset"))):
            if name in steps:
                r = _held_out(layout, t, gyro, terms, motion_threshold_deg_s)
                if r is not None:
                    ho[name] = r
    if not fit.converged:
        notes.append(f"the gyro fit stopped after {fit.iterations} iterations before converging")
    steps, refused = _never_worse(steps, "deg/s", "gyro", ho)
    if "+ sampling offsets" not in steps:
        fit = base
    rep = ArrayReport(layout.names, steps, limiting_term=fit.limiting_term(), gyro_fit=fit, notes=notes,
                      refused=refused)
    try:  # the remainder after the applied gyro steps, on the rates as sampled: deterministic, or not
        rfit = fit
        if gyro_unfiltered is not gyro:  # the steps were fitted low-passed: the same terms on the rates as sampled
            rfit = fit_relative_gyro(layout, t, gyro_unfiltered, terms=fit.terms, candidates=(),
                                     motion_threshold_deg_s=motion_threshold_deg_s)
        rep.remainder = remainder_analysis(t, rfit.apply(t, gyro_unfiltered), motion_threshold_deg_s)
    except (ShapeError, IdentifiabilityError) as exc:
        notes.append(f"no analysis of the remainder: {exc}")
    if accel is not None:
        best = None
        for mode, label in (("absolute", "+ gain+bias"), ("relative", "+ relative gain+bias"), ("none", "+ bias")):
            cand = _accel_candidate(layout, t, accel, fit, gyro, nominal_positions_m, motion_threshold_deg_s, mode,
                                    notes)
            if cand is None:
                continue
            pf, align = cand
            a_steps, a_refused = _never_worse(_accel_steps(layout, pf, fit, align, nominal_positions_m, label),
                                              "m/s^2", "accelerometer")
            if best is None or list(a_steps.values())[-1].mean() < list(best[1].values())[-1].mean():
                best = (pf, a_steps, a_refused, mode)
            if not a_refused:
                break
            notes.append(f"accelerometer gain={mode!r}: " + "; ".join(a_refused.values()))
        if best is None:
            return rep
        pf, a_steps, a_refused, mode = best
        if cut_motion is not None:
            for name in ("+ positions", AA_STEP):
                a_steps.pop(name, None)
            a_refused["+ positions"] = cut_motion
        rep.accel_steps = a_steps
        rep.refused.update(a_refused)
        why = aa_from_accelerometers_refusal(pf.positions_m)
        if why is not None and cut_motion is None:
            rep.refused[AA_STEP] = f"accelerometer step '{AA_STEP}' not identifiable: {why}"
        if any(k != "raw" for k in a_steps) and cut_motion is None:
            rep.position_fit = pf
        if pf.lever_arm_invalid:
            notes.append(f"{pf.lever_arm_invalid} of {pf.moving_epochs} epochs in motion have no angular acceleration "
                         "(a clipped or missing gyro sample within the central difference's stencil): left out of "
                         "the accelerometer lever-arm step, not bridged")
        if held_out and cut_motion is None:
            ho = _accel_held_out(layout, t, gyro, accel, fit, pf, nominal_positions_m, motion_threshold_deg_s, notes)
            if ho is not None:
                ho_steps, rep.accel_remainder = ho
                label = {"absolute": "+ gain+bias", "relative": "+ relative gain+bias", "none": "+ bias"}[mode]
                steps_ho = _accel_steps(layout, pf, fit, pf.sampling_offset_s is not None
                                        and np.any(pf.sampling_offset_s != 0), nominal_positions_m, label, ho_steps)
                rep.accel_held_out = {k: v for k, v in steps_ho.items() if k == "raw" or k in a_steps}
                _aa_held_out_rule(rep.accel_steps, rep.accel_held_out, rep.refused)
                notes.extend(_held_out_raises(rep.accel_held_out, "m/s^2"))
                h = [v.mean() for v in rep.accel_held_out.values()]
                line = (f"accelerometers held out: {fmt(h[0], 'specific_force', 'm/s^2')} -> "
                        f"{fmt(h[-1], 'specific_force', 'm/s^2')} ({h[0] / h[-1]:.3g}x) after the steps applied")
                notes.append(line)
                if rep.accel_remainder is not None:
                    notes.append(f"accelerometers, what remains (held out): {accel_verdict(rep.accel_remainder)}")
    return rep


#: the last accelerometer step: the angular acceleration taken per epoch from the accelerometers themselves, not
#: from the gyros' derivative (:func:`rimu.array.accel_angular_acceleration`; its parity scaled to compare like for
#: like with the steps before it)
AA_STEP = "+ angular acceleration from the accelerometers (per epoch; Skog et al. 2016)"


def _aa_held_out_rule(steps: dict, held_out: dict, refused: dict) -> None:
    """The never-worse rule on the held-out half for :data:`AA_STEP`: where, fitted on the first half of the motion,
    it raises the parity on the second above the last step applied before it, it is taken out of ``steps`` and
    ``held_out`` and ``refused`` says why (the dicts are the caller's, updated in place)."""
    if AA_STEP not in held_out:
        return
    prev = [v for k, v in held_out.items() if k != AA_STEP][-1]
    if worse(prev, held_out[AA_STEP]):
        refused[AA_STEP] = (f"accelerometer step '{AA_STEP}' not applied: fitted on the first half of the motion it "
                            f"raises the parity rms on the second from {prev.mean():.4g} to "
                            f"{held_out[AA_STEP].mean():.4g} m/s^2")
        del held_out[AA_STEP]
        steps.pop(AA_STEP, None)


def _held_out_raises(held_out: dict, unit: str) -> list[str]:
    """Notes for the intermediate steps that raise the held-out parity above the step before them (by more than
    :func:`rimu.array.guards.worse`'s tolerance) though the steps after them, which build on them, are kept: reported,
    not applied silently."""
    out, names = [], list(held_out)
    for a, b in zip(names[:-1], names[1:]):
        if worse(held_out[a], held_out[b]):
            out.append(f"accelerometer step '{b}' raises the held-out parity rms from {held_out[a].mean():.4g} to "
                       f"{held_out[b].mean():.4g} {unit}; kept because the steps after it build on it (the chain: "
                       f"{held_out[names[0]].mean():.4g} -> {held_out[names[-1]].mean():.4g} {unit})")
    return out


def _split_motion(omega: np.ndarray, motion_threshold_deg_s: float) -> int:
    """The index that splits the epochs in motion into two halves."""
    moving = np.linalg.norm(np.nan_to_num(omega), axis=1) > np.radians(motion_threshold_deg_s)
    c = np.cumsum(moving)
    return int(np.searchsorted(c, c[-1] // 2))


def _accel_held_out(layout, t, gyro, accel, fit, pf, nominal_positions_m, motion_threshold_deg_s, notes):
    """The accelerometer steps refitted (gyros and accelerometers, the same terms and modes) on the first half of the
    motion and judged on the second: the parity dict of :meth:`PositionFit.parity_on`, or None."""
    k0 = _split_motion(fit.layout.to_body(np.asarray(gyro, dtype=float)).mean(axis=1), motion_threshold_deg_s)
    try:
        g1 = fit_relative_gyro(layout, t[:k0], gyro[:k0], terms=fit.terms, candidates=(),
                               motion_threshold_deg_s=motion_threshold_deg_s)
        p1 = fit_positions(layout, t[:k0], accel[:k0], g1, gyro[:k0], nominal_positions_m=nominal_positions_m,
                           motion_threshold_deg_s=motion_threshold_deg_s, gain=pf.gain_mode,
                           align=bool(np.any(pf.sampling_offset_s != 0)), offsets=pf.accel_offset_s is not None,
                           derivative_order=pf.derivative_order)
        u = g1.apply(t[k0:], gyro[k0:])
        a = 1 / g1.sigma_rad_s**2
        omega = np.einsum("k,nki->ni", a / a.sum(), u)
        steps, moving, invalid = p1.parity_on(t[k0:], accel[k0:], omega, motion_threshold_deg_s)
    except (IdentifiabilityError, ShapeError) as exc:
        notes.append(f"no held-out accelerometer figures: {exc}")
        return None
    try:
        c0 = (p1.layout.positions_m if p1.nominal_m is None else np.asarray(p1.nominal_m)).mean(axis=0)
        rem = angular_acceleration_check(t[k0:], p1.apply(t[k0:], accel[k0:]), omega, p1.positions_m - c0,
                                         p1.derivative_order, motion_threshold_deg_s)
    except ShapeError:
        rem = None
    notes.append(f"accelerometers held out: fitted on the first {t[k0 - 1] - t[0]:.4g} s (half of the motion), judged "
                 f"on the remaining {t[-1] - t[k0]:.4g} s ({moving - invalid} epochs in motion, {invalid} more without "
                 "an angular acceleration left out)")
    return steps, rem


def accel_verdict(rem: dict) -> str:
    """One sentence on what is left of the accelerometers after the lever arms with the gyros' angular
    acceleration (:func:`rimu.array.angular_acceleration_check`): the angular acceleration is named only when it
    explains at least 10 % of it, and whether the gyro samples hold it."""
    share = rem["share"]
    ho = rem["held_out"]
    d, g = rem["difference_rad_s2"], rem["gyro_rad_s2"]
    head = (f"with the gyros' angular acceleration {rem['parity_gyro_m_s2']:.4g} m/s^2 remain "
            f"({rem['epochs']} epochs in motion); with the accelerometers' own, per sample, "
            f"{rem['parity_accel_m_s2']:.4g} m/s^2")
    if share < 0.10:
        return head + f": an angular acceleration explains {100 * share:.3g} % of it; what is left is unexplained"
    held = ""
    if np.isfinite(ho["fir_rad_s2"]):
        better = ho["fir_rad_s2"] < 0.9 * ho["central_difference_rad_s2"]
        held = (f"; a linear filter of the gyro rate over +-2 samples, fitted on half the epochs, leaves "
                f"{ho['fir_rad_s2']:.4g} rad/s^2 of it on the other half against {ho['central_difference_rad_s2']:.4g} "
                "for the central difference: " + ("a better derivative would recover part of it" if better else
                                                   "the gyro samples do not hold it (motion the sampling does not "
                                                   "resolve)"))
    return (head + f": limiting is the angular acceleration from the gyros ({100 * share:.3g} % of what is left): "
            f"the accelerometers' differs from the gyros' central difference by {min(d):.4g}-{max(d):.4g} rad/s^2 "
            f"rms per axis (the gyros' is {min(g):.4g}-{max(g):.4g})" + held)


def _accel_candidate(layout, t, accel, fit, gyro, nominal_positions_m, motion_threshold_deg_s, mode, notes):
    """One accelerometer fit (gain ``mode``), on the gyros' time or, where their sampling offsets do not fit the
    accelerometers, on its own; None when the motion cannot identify it."""
    align = True
    try:
        cand = fit_positions(layout, t, accel, fit, gyro, nominal_positions_m=nominal_positions_m,
                             motion_threshold_deg_s=motion_threshold_deg_s, gain=mode, align=align)
    except IdentifiabilityError as exc:
        notes.append(f"accelerometer gain={mode!r} skipped: {exc}")
        return None
    if align and cand.parity_rms_m_s2["aligned_all"].mean() > cand.parity_rms_m_s2["raw_all"].mean():
        align = False
        # what was seen, not a guess about the hardware: a single-chip IMU (one die, one sampling instant for
        # both) shows it too when the gyro offsets hold something else (the paths' different filter delays)
        seen = (f"the gyros' sampling offsets do not fit the accelerometers (moved by them, the accelerometer "
                f"parity rises from {fmt(cand.parity_rms_m_s2['raw_all'].mean(), 'accel', 'm/s^2', digits=6)} to "
                f"{fmt(cand.parity_rms_m_s2['aligned_all'].mean(), 'accel', 'm/s^2', digits=6)}: the accelerometers are not sampled "
                "at the gyros' instants, or the gyro paths delay differently from the accelerometer paths)")
        try:
            cand = fit_positions(layout, t, accel, fit, gyro, nominal_positions_m=nominal_positions_m,
                                 motion_threshold_deg_s=motion_threshold_deg_s, gain=mode, align=False,
                                 offsets=True)
            note = f"{seen}: the accelerometers' own offsets were estimated"
        except IdentifiabilityError as exc:
            note = f"{seen}, and their own cannot be estimated ({exc}): accelerometers left on their own time"
            cand = fit_positions(layout, t, accel, fit, gyro, nominal_positions_m=nominal_positions_m,
                                 motion_threshold_deg_s=motion_threshold_deg_s, gain=mode, align=False)
        if note not in notes:
            notes.append(note)
    return cand, align


def _accel_steps(layout, pf, fit, align, nominal_positions_m, label, parity=None) -> dict[str, np.ndarray]:
    p = pf.parity_rms_m_s2 if parity is None else parity
    steps = {"raw": p["raw"]}
    if align and np.any(fit.sampling_offset_s != 0):
        steps["+ gyro sampling offsets"] = p["aligned"]
    nominal = layout.positions_m if nominal_positions_m is None else np.asarray(nominal_positions_m)
    if np.ptp(nominal, axis=0).max() > 0:
        steps["+ nominal lever arms"] = p["raw_nominal_lever_arms"]
    steps[label] = p["gain_bias_nominal_lever_arms"]
    steps["+ positions"] = p["positions"]
    if np.all(np.isfinite(p.get("accel_angular_acceleration", np.nan))):
        steps[AA_STEP] = p["accel_angular_acceleration"]
    return steps
