"""Figures of the diagnosis (matplotlib, Agg backend; imported only when a figure is drawn).

Every function takes what it draws and a path, writes a PNG and returns the path.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..calibration.effects._common import input_unit
from ..plotting import pyplot
from .candidates import candidate_bases
from .residuals import input_bins

if TYPE_CHECKING:  # pragma: no cover
    from .api import Comparison, InstrumentDiagnosis
    from .candidates import CandidateTest
    from .fitting import ModelFit

__all__ = [
    "plot_candidate",
    "plot_comparison",
    "plot_input",
    "plot_regressors",
    "plot_residual_time",
    "plot_segment_map",
    "plot_temperature",
]


def _grid(n: int, plt, width: float = 10.0, height: float = 1.8):
    fig, axes = plt.subplots(n, 1, figsize=(width, max(2.5, height * n)), sharex=True, squeeze=False)
    return fig, axes[:, 0]


def _save(fig, path: str | Path, margins: tuple[float, float, float, float] | None = None, hspace: float = 0.2,
          wspace: float = 0.2) -> Path:
    """Write the figure as PNG (whole or not at all) and close it.

    ``margins`` (left, right, bottom, top) in inches place the axes at once; without them ``tight_layout``
    measures every label first, a second rendering pass over the figure's text (about a third of the time of a
    many-axes figure), kept for the figures whose labels have no known size (segment labels, legends).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if margins is None:
        fig.tight_layout()
    else:
        w, h = fig.get_size_inches()
        left, right, bottom, top = margins
        fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                            hspace=hspace, wspace=wspace)
    from ..atomic import atomic_path
    from ..report import check_figure

    check_figure(fig)  # empty axes removed; unlabelled units and clipped titles reported to the report
    with atomic_path(path) as _tmp:  # fast zlib level: PNG compression took a fifth of a figure's time
        fig.savefig(_tmp, dpi=90, format="png", pil_kwargs={"compress_level": 1})
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _few_ticks(*axes, x: bool = False, n: int = 4) -> None:
    """At most about ``n`` y ticks (and x ticks with ``x``) on each of ``axes``: on figures of many small axes
    the ticks are most of the drawing time (each is several artists), and their labels would crowd anyway."""
    from matplotlib.ticker import MaxNLocator

    for ax in axes:
        ax.yaxis.set_major_locator(MaxNLocator(n))
        if x:
            ax.xaxis.set_major_locator(MaxNLocator(n))


def _decimate(n: int, keep: int = 4000) -> slice:
    return slice(None, None, max(1, n // keep))


def plot_residual_time(fit: ModelFit, path: str | Path) -> Path:
    """Residual / noise level against time for every sensor, with each segment's mean residual drawn over the
    segment (red). The means in units of their own standard error are the segment map's
    (:func:`plot_segment_map`); a second y axis for them here would double the figure's drawing time."""
    plt = pyplot()
    fig, axes = _grid(len(fit.sensors), plt)
    for ax, s in zip(axes, fit.sensors):
        k = _decimate(s.n_obs)
        ax.plot(s.t[k], (s.r / s.sigma)[k], ".", ms=1, color="0.6")
        counts = np.maximum(np.bincount(s.seg_index), 1)
        means = np.bincount(s.seg_index, weights=s.r) / counts / s.sigma
        edges = np.flatnonzero(np.diff(s.seg_index)) + 1
        t0 = s.t[np.concatenate([[0], edges])]
        t1 = s.t[np.concatenate([edges - 1, [s.n_obs - 1]])]
        ax.hlines(means[s.seg_index[np.concatenate([[0], edges])]], t0, t1, color="C3", lw=1.5)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{s.name}\nr/sigma [-]", fontsize=8)
        _few_ticks(ax)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{fit.instrument}: residual of {fit.model.label} (red: segment means)")
    return _save(fig, path, (0.75, 0.2, 0.5, 0.45), hspace=0.12)


def plot_segment_map(d: InstrumentDiagnosis, path: str | Path) -> Path:
    """Mean residual of each sensor on each segment, in units of its standard error (where it fails)."""
    plt = pyplot()
    labels = d.fit.segment_labels
    Z = np.zeros((len(d.stats), len(labels)))
    for i, st in enumerate(d.stats):
        pos = {g.label: g.mean_z for g in st.segments}
        Z[i] = [pos.get(lab, 0.0) for lab in labels]
    lim = max(3.0, float(np.percentile(np.abs(Z), 98)))
    fig, ax = plt.subplots(figsize=(min(18, max(6.5, 2 + 0.25 * len(labels))), 1 + 0.45 * len(d.stats)))
    im = ax.imshow(Z, aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax.set_yticks(range(len(d.stats)), [s.name for s in d.stats])
    ax.set_xticks(range(len(labels)), labels, rotation=90, fontsize=6)
    fig.colorbar(im, ax=ax, label="segment mean / std. err.")
    ax.set_title(f"{d.instrument}: where the model fails (threshold +-{d.failures['segment_threshold_z']:.1f})",
                 fontsize=10)
    # margins from the longest labels (sensor names at 10 pt, segment labels turned upright at 6 pt)
    left = 0.3 + 0.085 * max(len(s.name) for s in d.stats)
    bottom = 0.3 + 0.052 * max((len(lab) for lab in labels), default=1)
    return _save(fig, path, (left, 1.45, bottom, 0.4))


def plot_input(fit: ModelFit, path: str | Path) -> Path | None:
    """Mean residual against the input along the sensing axis (magnitude and sign), one line per sensor on one
    axes (one axes instead of one per sensor: a figure's time goes mostly into its axes' decorations); None when
    the input along the axes never changes (gyros at rest): no empty axes."""
    if not any(input_bins(s, 12) for s in fit.sensors):
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    _si, field, per = input_unit(fit.contexts[0])
    for s in fit.sensors:
        b = input_bins(s, 12)
        if b:
            x, m, e, _ = (np.array(v) for v in zip(*b))
            ax.errorbar(x / per, m, yerr=e, fmt="o-", ms=3, capsize=0, label=s.name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel(f"input along the sensor's axis [{field}]")
    ax.set_ylabel("mean residual / sigma [-]")
    if 1 < len(fit.sensors) <= 12:
        ax.legend(fontsize=7, ncol=min(len(fit.sensors), 6), loc="upper center")
    ax.set_title(f"{fit.instrument}: residual against input", y=1.0)
    return _save(fig, path, (0.75, 0.2, 0.55, 0.35))


def plot_temperature(fit: ModelFit, path: str | Path) -> Path | None:
    """Mean residual against temperature (binned), per sensor; None when temperature never changed."""
    s0 = fit.sensors[0]
    if s0.temperature is None or np.ptp(s0.temperature) < 0.1:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for s in fit.sensors:
        T = s.temperature
        edges = np.linspace(T.min(), T.max(), 13)
        k = np.clip(np.searchsorted(edges, T, side="right") - 1, 0, 11)
        cnt = np.bincount(k, minlength=12)
        m = np.bincount(k, weights=s.r / s.sigma, minlength=12) / np.maximum(cnt, 1)
        ok = cnt > 0
        ax.plot(0.5 * (edges[:-1] + edges[1:])[ok], m[ok], "o-", ms=3, label=s.name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("temperature [degC]")
    ax.set_ylabel("mean residual / sigma [-]")
    ax.legend(fontsize=7, ncol=3)
    ax.set_title(f"{fit.instrument}: residual against temperature")
    return _save(fig, path)


def plot_candidate(fit: ModelFit, test: CandidateTest, path: str | Path) -> Path:
    """The plot that shows a finding: for each sensor, the segment means of the residual against the segment
    means of the part of it the candidate explains (added-variable plot; points on the diagonal = explained)."""
    plt = pyplot()
    idx = test.sensor_indices
    fig, axes = plt.subplots(1, max(1, len(idx)), figsize=(2.6 * max(1, len(idx)), 2.8), squeeze=False)
    for ax, i in zip(axes[0], idx):
        s = fit.sensors[i]
        part = test.explained(i)
        cnt = np.maximum(np.bincount(s.seg_index), 1)
        ym = np.bincount(s.seg_index, weights=s.r) / cnt / s.sigma
        xm = np.bincount(s.seg_index, weights=part) / cnt / s.sigma
        ax.plot(xm, ym, "o", ms=3, color="C3" if any(x.sensor == s.name and x.significant for x in test.sensors) else "C0")
        lo, hi = float(min(xm.min(), ym.min())), float(max(xm.max(), ym.max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.6)
        ax.set_title(s.name, fontsize=9, y=1.0)  # a fixed place: no measuring of the ticks
        ax.set_xlabel(f"{test.name} part / sigma [-]", fontsize=7)
        ax.set_ylabel("segment mean residual / sigma [-]" if i == idx[0] else "residual / sigma [-]", fontsize=7)
    fig.suptitle(f"{fit.instrument}: {test.name} against the residual (red: sensors where it is significant)")
    return _save(fig, path, (0.6, 0.15, 0.5, 0.6), wspace=0.35)


def plot_regressors(fit: ModelFit, tests: list[CandidateTest], path: str | Path, sensor: int = 0) -> Path | None:
    """Residual of one sensor against each testable candidate's regressor (its first direction outside the
    model's span), binned by the regressor's deciles: a sloped line is an effect the model lacks, a flat one at
    zero an effect the data do not show. One axes for all candidates (x = decile of each one's own regressor,
    so that lines of regressors in different units share it): a grid of one axes per candidate spent three
    quarters of the report's drawing time on axes decorations."""
    tt = [t for t in tests if sensor in t.sensor_indices][:12]
    if not tt:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    s = fit.sensors[sensor]
    z = s.r / s.sigma
    bases = candidate_bases(tt, sensor)  # every candidate's columns built once, from one shared design
    styles = ("-", "--", ":", "-.")
    for j, t in enumerate(tt):
        x = bases[t.name][:, 0]
        edges = np.quantile(x, np.linspace(0, 1, 11))
        k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 9)
        cnt = np.bincount(k, minlength=10)
        m = np.bincount(k, weights=z, minlength=10) / np.maximum(cnt, 1)
        ok = cnt > 0
        d = 1 + np.arange(10)[ok] + 0.3 * (j / max(1, len(tt) - 1) - 0.5)  # offset: error bars side by side
        ax.errorbar(d, m[ok], yerr=1 / np.sqrt(cnt[ok]), fmt="o", ls=styles[j // 10 % 4], ms=3, lw=1.2 if t.significant else 0.8,
                    color="C3" if t.significant else f"C{j % 10 if j % 10 != 3 else 9}",
                    label=t.name + (" (significant)" if t.significant else ""))
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xticks(range(1, 11))
    ax.set_xlabel("decile of the candidate's regressor [-]")
    ax.set_ylabel("mean residual / sigma [-]")
    ax.legend(fontsize=6, ncol=1, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_title(f"{fit.instrument} {s.name}: residual against each candidate's regressor", y=1.0)
    return _save(fig, path, (0.9, 2.1, 0.55, 0.35))


def plot_comparison(comp: Comparison, path: str | Path) -> Path:
    """Before and after: rms per sensor (field units) and the residual of the most improved sensor over time."""
    plt = pyplot()
    unit, rb, ra = comp.rms()
    fb, fa = rb / np.maximum(comp.before.rms_raw(), 1e-300), ra / np.maximum(comp.after.rms_raw(), 1e-300)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.4), gridspec_kw={"width_ratios": [1, 2]})
    x = np.arange(len(rb))
    a1.bar(x - 0.2, rb, 0.4, label="before")
    a1.bar(x + 0.2, ra, 0.4, label="after")
    a1.set_xticks(x, [s.name for s in comp.before.sensors])
    a1.set_ylabel(f"residual rms [{unit}]")
    a1.legend(fontsize=7)
    k = int(np.argmax(rb - ra))
    sb, sa = comp.before.sensors[k], comp.after.sensors[k]
    cnt = np.maximum(np.bincount(sb.seg_index), 1)
    tm = np.bincount(sb.seg_index, weights=sb.t) / cnt
    a2.plot(tm, np.bincount(sb.seg_index, weights=sb.r) / cnt * fb[k], "o-", ms=3, label="before")
    a2.plot(tm, np.bincount(sa.seg_index, weights=sa.r) / cnt * fa[k], "o-", ms=3, label="after")
    a2.axhline(0, color="k", lw=0.5)
    a2.set_xlabel("time [s]")
    a2.set_ylabel(f"{sb.name} segment mean residual [{unit}]")
    a2.legend(fontsize=7)
    fig.suptitle(f"{comp.instrument}: + {', '.join(comp.added)}: chi2/dof {comp.chi2_before:.3g} -> {comp.chi2_after:.3g}")
    return _save(fig, path)
