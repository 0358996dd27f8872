"""The diagnosis as a Markdown report with figures (and a minimal HTML page around the same text)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..atomic import atomic_files
from ..report import Report, collect_problems
from . import plots
from .api import Comparison, Diagnosis, Iteration, format_p

__all__ = ["render_markdown", "write_report"]


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    return out


def render_markdown(diagnosis: Diagnosis, directory: Path, comparisons: Sequence[Comparison] = (),
                    title: str = "rimu diagnosis", figures: bool = True) -> str:
    """Markdown text of the report; figures are written to ``directory`` and linked relatively."""
    md = [f"# {title}", ""]
    s = diagnosis.session
    md += [f"Session: {len(s)} segments, instruments {', '.join(s.instruments)}, "
           f"{s.sample_rate:g} Hz, latitude {'unknown' if s.latitude is None else f'{s.latitude * 57.29577951308232:.2f} deg'}. "
           f"Significance alpha = {diagnosis.settings['alpha']:g} (family-wise, Holm over candidates).", ""]
    if diagnosis.nothing_missing:
        md += ["**Nothing is missing**: no candidate effect explains the residual beyond noise.", ""]
    for k, why in diagnosis.errors.items():
        md += [f"> {k}: not diagnosed: {why}", ""]
    for inst, d in diagnosis.instruments.items():
        md += [f"## {inst}: model `{d.model.label}`", ""]
        md += [f"chi2/dof {d.fit.chi2_dof:.4g}, BIC {d.fit.bic:.1f}, {len(d.fit.segment_labels)} segments used"
               + (f", {len(d.fit.skipped)} skipped ({'; '.join(sorted(set(d.fit.skipped.values())))})" if d.fit.skipped else ""), ""]
        md += ["### Residual statistics", ""]
        unit, fac = d.fit.display()
        md += _table(["sensor", f"rms [{unit}]", f"noise sigma [{d.fit.raw_unit}]", "chi2/dof", "z(chi2)", "lag-1 rho",
                      "Ljung-Box p", "white"],
                     [(x.name, f"{x.rms_raw * f:.4g}", f"{x.sigma:.4g}{'' if x.sigma_known else ' (est.)'}",
                       f"{x.chi2_dof:.4f}", f"{x.chi2_z:+.1f}", f"{x.lag1:+.3f}", f"{x.ljung_box_p:.2g}",
                       "yes" if x.white else "no") for x, f in zip(d.stats, fac)])
        md += [""]
        fl = d.failures
        md += ["### Where the model fails", ""]
        if not (fl["sensors"] or fl["segments"] or fl["not_white"]):
            md += ["Nowhere: every sensor's chi2/dof and every segment's mean residual are within noise.", ""]
        else:
            if fl["sensors"]:
                md += [f"- sensors with residual above noise: {', '.join(fl['sensors'])}"]
            if fl["not_white"]:
                md += [f"- residual not white (Ljung-Box): {', '.join(fl['not_white'])}"]
            if fl["segments"]:
                worst = sorted(fl["segments"].items(), key=lambda kv: -max(abs(z) for _, z in kv[1]))
                md += [f"- {len(worst)} segments with a mean residual beyond +-{fl['segment_threshold_z']:.1f} "
                       "standard errors; worst: " + ", ".join(
                           f"{lab} ({', '.join(f'{n} {z:+.0f}' for n, z in v[:3])})" for lab, v in worst[:8])]
            md += [""]
        if figures:
            fd = directory / "figures"
            f1 = plots.plot_residual_time(d.fit, fd / f"{inst}_residual_time.png")
            f2 = plots.plot_segment_map(d, fd / f"{inst}_segments.png")
            f3 = plots.plot_input(d.fit, fd / f"{inst}_input.png")
            f4 = plots.plot_temperature(d.fit, fd / f"{inst}_temperature.png")
            md += [f"![residual over time]({f1.relative_to(directory)})", "",
                   f"![segments]({f2.relative_to(directory)})", ""]
            if f3:
                md += [f"![input]({f3.relative_to(directory)})", ""]
            if f4:
                md += [f"![temperature]({f4.relative_to(directory)})", ""]
        md += ["### Which effect is missing", ""]
        md += [line.strip() for line in d.lines() if line.strip()[:2].rstrip(".").isdigit() or "nothing is missing" in line]
        md += [""]
        rows = []
        for c in d.tests:
            if not (c.testable and c.sensors):
                continue
            verdict = ("**yes**" if c.significant and c.name not in d.secondary else
                       f"shadow of {d.secondary[c.name]}" if c.name in d.secondary else "no")
            rows.append((c.name, verdict, format_p(c.log10_p_holm), f"{c.dbic:+.1f}",
                         ", ".join(f"{x.sensor} {100 * x.explained_excess:.0f}%" for x in c.sensors if x.significant) or "-",
                         c.description))
        md += _table(["candidate", "missing", "p (Holm)", "dBIC", "sensors (share of excess residual)", "what it is"], rows)
        md += [""]
        if figures:
            for f in d.findings[:3]:
                c = f.best
                p = plots.plot_candidate(d.fit, c, directory / "figures" / f"{inst}_candidate_{c.name}.png")
                md += [f"![{c.name}]({p.relative_to(directory)})", ""]
            p = plots.plot_regressors(d.fit, d.tests, directory / "figures" / f"{inst}_regressors.png")
            if p:
                md += [f"Residual of {d.fit.sensors[0].name} against every candidate's regressor:", "",
                       f"![regressors]({p.relative_to(directory)})", ""]
        nt = d.not_testable
        if nt:
            md += ["### Not testable with this data", ""]
            md += [f"- **{c.name}**: {c.reason}." + (f" To test it: {c.advice}." if c.advice else "") for c in nt]
            md += [""]
        na = d.not_applicable
        if na:
            md += [f"Not candidates for {inst}s: " + "; ".join(
                f"{c.name} ({c.reason})" if c.name == "earth_rate" else c.name for c in na) + ".", ""]
    if comparisons:
        md += ["## Add it and watch the error fall", ""]
        for n, c in enumerate(comparisons, start=1):
            md += [f"### {c.instrument}: + {', '.join(c.added)}", "",
                   f"chi2/dof {c.chi2_before:.4g} -> **{c.chi2_after:.4g}**, dBIC {c.dbic:+.1f}, dAIC {c.daic:+.1f}", ""]
            unit, rb, ra = c.rms()
            md += _table(["sensor", f"rms before [{unit}]", f"rms after [{unit}]", "change"],
                         [(s.name, f"{b:.4g}", f"{a:.4g}", f"{100 * (a - b) / b:+.1f}%")
                          for s, b, a in zip(c.before.sensors, rb, ra)])
            md += ["", "New parameters (1-sigma):", ""]
            md += _table(["sensor", "parameter", "value", "1-sigma", "unit", "z"],
                         [(r["sensor"], r["parameter"], f"{r['value']:.4g}", f"{r['std']:.2g}", r["report_unit"],
                           f"{r['z']:+.1f}" if r['z'] is not None else "-") for r in c.new_parameters()])
            md += [""]
            if figures:
                p = plots.plot_comparison(c, directory / "figures" / f"compare_{n}_{c.instrument}.png")
                md += [f"![before/after]({p.relative_to(directory)})", ""]
    return "\n".join(md)


def write_report(diagnosis: Diagnosis | Iteration, directory: str | Path, comparisons: Sequence[Comparison] = (),
                 title: str = "rimu diagnosis", html_page: bool = True, figures: bool = True) -> Path:
    """Write ``report.md`` (and ``report.html``), the figures and ``diagnosis.json`` into ``directory``.

    Pass an :class:`Iteration` to report the starting diagnosis, every refit and the final state.
    ``figures=False`` writes the text only. Returns the Markdown path.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with collect_problems() as problems:
        text, data = _render(diagnosis, directory, comparisons, title, figures)
    md = directory / "report.md"
    rep = Report(title)
    rep.cautions(cautions(diagnosis))
    rep.markdown(text, directory)
    rep.problems.extend(problems)
    with atomic_files() as tx:  # the files appear together, whole
        tx.path(md).write_text(text)
        tx.path(directory / "diagnosis.json").write_text(json.dumps(data, indent=1, default=float))
        if html_page:
            tx.path(directory / "report.html").write_text(rep.html())
            rep.write_pdf(tx.path(directory / "report.pdf"))
    return md


def _render(diagnosis: Diagnosis | Iteration, directory: Path, comparisons: Sequence[Comparison], title: str,
            figures: bool) -> tuple[str, dict]:
    if isinstance(diagnosis, Iteration):
        first = diagnosis.rounds[0][0] if diagnosis.rounds else diagnosis.final
        comps = [c for _, cs in diagnosis.rounds for c in cs.values()]
        text = render_markdown(first, directory, comps, title, figures)
        if diagnosis.rounds:
            final_dir = directory / "final"
            text += "\n\n" + render_markdown(diagnosis.final, final_dir, (), "Final model", figures).replace(
                "](figures/", "](final/figures/")
        data = {"start": first.to_dict(), "comparisons": [c.to_dict() for c in comps], "final": diagnosis.final.to_dict()}
    else:
        text = render_markdown(diagnosis, directory, comparisons, title, figures)
        data = {"diagnosis": diagnosis.to_dict(), "comparisons": [c.to_dict() for c in comparisons]}
    return text, data


def cautions(diagnosis: Diagnosis | Iteration) -> list[str]:
    """The console's cautions and notes, word for word (the report shows them above everything else)."""
    keys = ("caution", "note:", "not applied", "not testable", "warning")
    return [ln.strip() for ln in diagnosis.summary().splitlines() if any(k in ln for k in keys)]
