"""Monte Carlo helpers: errors of a calibration against a truth, normalised by the reported uncertainties.

A Monte Carlo campaign repeats simulate -> fit over seeds; the simulator is passed in as a callable (this
module never imports :mod:`rimu.sim`, so the library keeps its one-way imports), and progress is shown with
tqdm on a terminal when it is installed (extra ``progress``), else not at all.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .result import Calibration, InstrumentCalibration

__all__ = ["MonteCarlo", "MonteCarloResult", "calibration_errors", "normalised_errors", "physical_vector", "progress"]


def physical_vector(cal: InstrumentCalibration, names: Sequence[str]) -> np.ndarray:
    """Values of the named physical parameters (``"x1.scale"``, ``"x1.mis_y"``, ``"x1.bias"``) in SI."""
    g = cal.geometry
    out = np.empty(len(names))
    for k, n in enumerate(names):
        s, p = n.split(".", 1)
        i = g.index(s)
        if p == "scale":
            out[k] = cal.scale[i]
        elif p == "bias":
            out[k] = cal.bias[i]
        else:
            E, mn = g.off_axis_basis(i)
            if p not in mn:
                found = False
                for eff in cal.effects.values():
                    if n in eff:
                        out[k] = eff[n]
                        found = True
                if not found:
                    raise KeyError(f"unknown parameter {n!r}")
                continue
            out[k] = float(E[list(mn).index(p)] @ cal.misalignment[i])
    return out


def calibration_errors(est: InstrumentCalibration, truth: InstrumentCalibration) -> tuple[list[str], np.ndarray]:
    """(names, estimate - truth) over the estimate's ``param_names`` (SI)."""
    names = list(est.param_names)
    return names, physical_vector(est, names) - physical_vector(truth, names)


def normalised_errors(est: InstrumentCalibration, truth: InstrumentCalibration) -> tuple[list[str], np.ndarray]:
    """(names, (estimate - truth) / reported standard deviation). Parameters with zero variance (fixed by a
    frame convention) are left out."""
    if est.covariance is None:
        raise ValueError("the calibration carries no covariance")
    names, err = calibration_errors(est, truth)
    sd = np.sqrt(np.clip(np.diag(est.covariance), 0.0, None))
    keep = sd > 0
    return [n for n, k in zip(names, keep) if k], err[keep] / sd[keep]


def progress(it: Iterable[Any], total: int | None = None, desc: str = "", enabled: bool = True) -> Iterable[Any]:
    """A tqdm bar on a terminal when tqdm is installed (extra ``progress``), else nothing
    (:func:`rimu.progress.bar`)."""
    from ..progress import bar

    return bar(it, total=total, desc=desc, enabled=None if enabled else False)


@dataclass
class MonteCarloResult:
    """Errors over seeds. ``errors[inst]`` is (runs, p) in SI; ``predicted_std[inst]`` the mean reported std."""

    names: dict[str, list[str]]
    errors: dict[str, np.ndarray]
    normalised: dict[str, np.ndarray]
    predicted_std: dict[str, np.ndarray]
    extra: list[dict[str, Any]] = field(default_factory=list)

    def empirical_std(self, instrument: str) -> np.ndarray:
        return self.errors[instrument].std(axis=0, ddof=1)

    def rms_normalised(self, instrument: str) -> np.ndarray:
        return np.sqrt(np.mean(self.normalised[instrument] ** 2, axis=0))


class MonteCarlo:
    """Repeat ``simulate(seed) -> (session, truth Calibration)`` and ``fit(session) -> CalibrationResult``.

    Parameters
    ----------
    simulate : callable
        seed -> (Session, Calibration truth).
    fit : callable
        Session -> CalibrationResult (or anything with ``to_calibration()``).
    instruments : sequence of str
    progress : bool
    """

    def __init__(self, simulate: Callable[[int], tuple[Any, Calibration]], fit: Callable[[Any], Any],
                 instruments: Sequence[str] = ("gyro", "accel"), show_progress: bool = True) -> None:
        self.simulate = simulate
        self.fit = fit
        self.instruments = tuple(instruments)
        self.show_progress = show_progress

    def run(self, seeds: Iterable[int]) -> MonteCarloResult:
        seeds = list(seeds)
        errs: dict[str, list[np.ndarray]] = {k: [] for k in self.instruments}
        nerr: dict[str, list[np.ndarray]] = {k: [] for k in self.instruments}
        sds: dict[str, list[np.ndarray]] = {k: [] for k in self.instruments}
        names: dict[str, list[str]] = {}
        extra = []
        for seed in progress(seeds, len(seeds), "monte carlo", self.show_progress):
            session, truth = self.simulate(seed)
            res = self.fit(session)
            cal = res.to_calibration()
            for k in self.instruments:
                nm, e = calibration_errors(cal[k], truth[k])
                names[k] = nm
                sd = np.sqrt(np.clip(np.diag(cal[k].covariance), 0, None))
                errs[k].append(e)
                sds[k].append(sd)
                with np.errstate(divide="ignore", invalid="ignore"):
                    nerr[k].append(np.where(sd > 0, e / np.where(sd > 0, sd, 1.0), 0.0))
            extra.append(getattr(res, "extra", {}))
        return MonteCarloResult(names, {k: np.array(v) for k, v in errs.items()},
                                {k: np.array(v) for k, v in nerr.items()},
                                {k: np.mean(v, axis=0) for k, v in sds.items()}, extra)
