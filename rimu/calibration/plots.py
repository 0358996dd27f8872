"""Pictures of a calibration: residuals per segment and sensor.

For every instrument, two panels: the residual mean of each segment and sensor in units of its standard error
(``sigma / sqrt(N)``: a model that fits leaves values of order 1; a missing effect or a wrong known input
shows as a segment far outside), and the residual rms in units of the noise level sigma (1 for white noise).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plot_residuals", "residual_table"]


def residual_table(result: Any, instrument: str) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """(segments, sensors, mean/standard error, rms/sigma) of a :class:`CalibrationResult`'s residuals."""
    r = result.instruments[instrument]
    sensors = [s.name for s in r.sensors]
    segs: list[str] = []
    for s in r.sensors:
        for lab in s.residuals:
            if lab not in segs:
                segs.append(lab)
    z = np.full((len(segs), len(sensors)), np.nan)
    q = np.full_like(z, np.nan)
    for j, s in enumerate(r.sensors):
        for i, lab in enumerate(segs):
            e = s.residuals.get(lab)
            if e is None or len(e) == 0:
                continue
            z[i, j] = e.mean() / (s.sigma / np.sqrt(len(e)))
            q[i, j] = np.sqrt(np.mean(e**2)) / s.sigma
    return segs, sensors, z, q


def plot_residuals(result: Any, path: str | None = None):
    """Plot :func:`residual_table` for every instrument; returns the matplotlib Figure (saved to ``path``)."""
    from ..plotting import pyplot

    plt = pyplot()

    insts = []
    for k in result.instruments:  # an instrument no segment's known input constrains (hand-held) has no panel
        q = residual_table(result, k)[3]
        if q.size and np.nanmax(np.nan_to_num(q)) > 1e-3:
            insts.append(k)
    insts = insts or list(result.instruments)
    fig, axes = plt.subplots(len(insts), 2, figsize=(13, 3.6 * len(insts)), squeeze=False)
    for row, inst in zip(axes, insts):
        segs, sensors, z, q = residual_table(result, inst)
        x = np.arange(len(segs))
        for j, name in enumerate(sensors):
            row[0].plot(x, z[:, j], "o-", ms=3, lw=0.8, label=name)
            row[1].plot(x, q[:, j], "o-", ms=3, lw=0.8, label=name)
        for a, title in ((row[0], "residual mean / standard error"), (row[1], "residual rms / sigma")):
            a.set_xticks(x)
            a.set_xticklabels(segs, rotation=90, fontsize=7)
            a.set_title(f"{inst}: {title}", fontsize=10)
            a.grid(alpha=0.3)
        row[0].set_ylabel("mean / std. error [-]")
        row[1].set_ylabel("rms / noise sigma [-]")
        row[0].axhspan(-3, 3, color="tab:green", alpha=0.1)
        row[1].axhline(1.0, color="k", lw=0.8, ls="--")
        row[1].legend(fontsize=7, ncol=3)
    fig.suptitle(f"{result.method}: residuals per segment (chi2/dof " +
                 ", ".join(f"{k} {v:.2f}" for k, v in result.chi2_dof.items()) + ")")
    fig.tight_layout()
    if path:
        from ..atomic import atomic_path

        with atomic_path(path) as _tmp:  # whole or not at all
            fig.savefig(_tmp, dpi=110)
    return fig
