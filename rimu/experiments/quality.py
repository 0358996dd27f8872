"""Parity-based calibration quality: de Oliveira et al. 2012, Eq. 21-25, as a check a user can run.

For each pair of rate sequences of a calibration session with opposite commanded rates (+w, -w about the
same MB direction; de Oliveira's Table 1 pairs 1-2, 3-4, ...), with ``g_n`` the mean raw output of sequence n:

* ``g_b = 1/2 SF (g_n + g_n+1)``: bias and Earth rate, the commanded rate removed (Eq. 21);
* ``g_w = 1/2 SF (g_n - g_n+1)``: the commanded rate only, bias and Earth rate removed (Eq. 22-23; the sign
  that removes the bias);
* ``v g_w`` with the nominal parity vector v of H (Eq. 23, 24) and ``v_c g_w`` with the parity vector of the
  calibrated axes M H (Eq. 22, 25).

With a correct calibration ``v_c`` annihilates the calibrated axes, so ``v_c g_w`` is noise only; a
misalignment or scale error left in the calibration shows as ``v_c (A_true - A_cal) w``, largest for rates
along the direction of the error. The quality index of a pair is the chi-square statistic
``q^T (C_noise + C_cal)^-1 q`` of ``q = v_c g_w`` (noise of the means, and the calibration's own stated
uncertainty propagated through w, :mod:`rimu.fdi.calaware`), and the equivalent misalignment
``|v_c g_w| / |w|`` (arcsec). The verdict is "bad" when a pair exceeds the chi-square threshold at
``p_fa / pairs`` (Bonferroni), and the report names the rate directions where the error shows.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from scipy.stats import chi2

from ..calibration.parity_check import pair_parity
from ..calibration.result import InstrumentCalibration
from ..fdi.calaware import CalibrationCovariance
from ..session import Session
from ..units import RAD_TO_ARCSEC, RAD_TO_DEG

__all__ = ["PairQuality", "QualityReport", "parity_quality", "ParityCheckReport"]

#: the mark of a row whose statistic exceeds its threshold, in both parity checks' summaries
_FLAG = "  <-- error shows here"


@dataclass
class ParityCheckReport:
    """What the parity checks of a calibration share (the rate pairs here, the segments at rest in
    :mod:`rimu.experiments.static_quality`): the verdict, the frame of the summary and of the dictionary.

    A subclass is a dataclass that adds its list of rows (each with ``bad`` and ``to_dict()``, named by ``rows=``
    in its class statement), ``p_fa``, ``uses_calibration_covariance`` and ``notes``.
    """

    instrument: str
    _rows: ClassVar[str] = ""
    if TYPE_CHECKING:
        p_fa: float
        uses_calibration_covariance: bool
        notes: list[str]

    def __init_subclass__(cls, rows: str = "", **kw: Any) -> None:
        super().__init_subclass__(**kw)
        if rows:
            cls._rows = rows

    def rows(self) -> list[Any]:
        """The pairs or segments checked."""
        return list(getattr(self, self._rows))

    @property
    def good(self) -> bool:
        return not any(r.bad for r in self.rows())

    @property
    def verdict(self) -> str:
        return "good" if self.good else "bad"

    def _summary(self, head: list[str], rows: list[str], where: str) -> str:
        """``head``, one line a row (flagged when bad), the verdict with ``where`` the error shows when bad, and
        the notes."""
        lines = head + [line + (_FLAG if r.bad else "") for r, line in zip(self.rows(), rows)]
        lines.append(f"verdict: {self.verdict.upper()}" + ("" if self.good else f"; {where}"))
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def _to_dict(self, key: str, **first: Any) -> dict[str, Any]:
        return {"instrument": self.instrument, **first, "verdict": self.verdict, "p_fa": self.p_fa,
                "uses_calibration_covariance": self.uses_calibration_covariance,
                key: [r.to_dict() for r in self.rows()], "notes": self.notes}

    def _plot(self, path: str | Path, labels: list[str], ylabel: str, title: str,
              draw: Callable[[Any, np.ndarray, list[str]], None]) -> Path | None:
        """A bar chart with one group a row (``draw(ax, positions, colours)``, red where the row is bad), or None
        without matplotlib."""
        from ..plotting import pyplot, save_figure

        plt = pyplot(optional=True)
        if plt is None:
            return None
        fig, ax = plt.subplots(figsize=(8, 4))
        k = np.arange(len(labels))
        draw(ax, k, ["r" if r.bad else "g" for r in self.rows()])
        ax.set_xticks(k)
        ax.set_xticklabels(labels, rotation=45, fontsize=7)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        fig.tight_layout()
        return save_figure(fig, path)


def vector_text(v: np.ndarray) -> str:
    """``(+0.58, -0.58, +0.58)``: a direction as the parity checks' summaries print it."""
    return "(" + ", ".join(f"{c:+.2f}" for c in v) + ")"


def covariance_model(calibration: InstrumentCalibration) -> tuple[CalibrationCovariance | None, list[str]]:
    """The calibration's stated covariance as propagated by :class:`CalibrationCovariance` (None without one)
    and the notes a parity check reports about it."""
    if calibration.covariance is not None and calibration.param_names:
        covm = CalibrationCovariance(calibration)
        if covm.ignored:
            return covm, [f"parameters not propagated: {', '.join(covm.ignored[:6])}"
                          + (" ..." if len(covm.ignored) > 6 else "")]
        return covm, []
    return None, ["no calibration covariance: the tolerance is the noise of the means only"]


@dataclass
class PairQuality:
    """One +w / -w pair."""

    labels: tuple[str, str]
    rate_mb: np.ndarray
    parity_nominal: np.ndarray
    parity_calibrated: np.ndarray
    bias_parity: np.ndarray
    statistic: float
    threshold: float
    misalignment_arcsec: float
    nominal_arcsec: float

    @property
    def direction(self) -> np.ndarray:
        return self.rate_mb / np.linalg.norm(self.rate_mb)

    @property
    def bad(self) -> bool:
        return self.statistic > self.threshold

    def to_dict(self) -> dict[str, Any]:
        return {"labels": list(self.labels), "rate_mb_dps": (self.rate_mb * RAD_TO_DEG).tolist(),
                "direction": self.direction.tolist(), "parity_nominal": self.parity_nominal.tolist(),
                "parity_calibrated": self.parity_calibrated.tolist(), "bias_parity": self.bias_parity.tolist(),
                "statistic": self.statistic, "threshold": self.threshold, "bad": self.bad,
                "misalignment_arcsec": self.misalignment_arcsec, "nominal_arcsec": self.nominal_arcsec}


@dataclass
class QualityReport(ParityCheckReport, rows="pairs"):
    """Per-pair quality indices and the overall verdict.

    Attributes
    ----------
    instrument : str
    pairs : list of PairQuality
        One a +w / -w pair of the session.
    p_fa : float
        False-alarm probability of the whole check.
    uses_calibration_covariance : bool
    notes : list of str
    """

    pairs: list[PairQuality]
    p_fa: float
    uses_calibration_covariance: bool
    notes: list[str] = field(default_factory=list)

    def worst(self) -> PairQuality:
        """The pair where the error shows most: the largest equivalent misalignment among the failing pairs
        (the largest statistic when none fails)."""
        bad = [p for p in self.pairs if p.bad]
        if bad:
            return max(bad, key=lambda p: p.misalignment_arcsec)
        return max(self.pairs, key=lambda p: p.statistic)

    def bad_directions(self) -> list[np.ndarray]:
        return [p.direction for p in self.pairs if p.bad]

    def summary(self) -> str:
        from ..units import ARCSEC_TO_RAD, field_unit, fmt

        # one angle unit for the table (rimu.units.fmt): arcsec, or deg for misfits of a degree and more
        unit = field_unit("angle", ARCSEC_TO_RAD * max([max(p.nominal_arcsec, p.misalignment_arcsec)
                                                        for p in self.pairs] or [0.0]))[0]
        head = [f"parity calibration check ({self.instrument}): de Oliveira et al. 2012, Eq. 21-25",
                f"{'pair':>10} {'rate direction (MB)':>24} | {'|v g_w|/|w|':>16} {'|v_c g_w|/|w|':>16} | "
                f"{'chi2':>9} {'limit':>7}"]
        rows = [f"{p.labels[0] + '/' + p.labels[1]:>10} {vector_text(p.direction):>24} | "
                f"{fmt(p.nominal_arcsec * ARCSEC_TO_RAD, 'angle', unit, digits=4, width=9):>16} "
                f"{fmt(p.misalignment_arcsec * ARCSEC_TO_RAD, 'angle', unit, digits=4, width=9):>16} | "
                f"{p.statistic:9.1f} {p.threshold:7.1f}" for p in self.pairs]
        w = self.worst()
        return self._summary(head, rows, f"largest misfit for rates along MB {vector_text(w.direction)}"
                             f" [{w.labels[0]}/{w.labels[1]}], about "
                             f"{fmt(w.misalignment_arcsec * ARCSEC_TO_RAD, 'angle', digits=3)}")

    def to_dict(self) -> dict[str, Any]:
        return self._to_dict("pairs")

    def plot(self, path: str | Path) -> Path | None:
        """Bar chart of the equivalent misalignment per pair, nominal and calibrated parity (their Fig. 5)."""
        def draw(ax: Any, k: np.ndarray, colours: list[str]) -> None:
            ax.bar(k - 0.2, [p.nominal_arcsec for p in self.pairs], 0.4, label="nominal parity v (Eq. 23)")
            ax.bar(k + 0.2, [p.misalignment_arcsec for p in self.pairs], 0.4, color=colours,
                   label="calibrated parity v_c (Eq. 22)")
            ax.set_yscale("symlog", linthresh=10)
            ax.legend(fontsize=8)

        return self._plot(path, [f"{p.labels[0]}/{p.labels[1]}" for p in self.pairs], "|parity of g_w| / |w| [arcsec]",
                          f"parity calibration check: {self.verdict}", draw)


def parity_quality(session: Session, calibration: InstrumentCalibration, p_fa: float = 1e-3) -> QualityReport:
    """The parity check of a calibration on its session (see the module docstring).

    Parameters
    ----------
    session : Session
        With pairs of rate segments at opposite commanded rates (de Oliveira Table 1, Cho & Park Table 2).
    calibration : InstrumentCalibration
        Needs ``noise_sigma`` (per-sample noise, SI); its covariance, if any, widens the tolerance.
    p_fa : float
        False-alarm probability of the whole check (Bonferroni over the pairs).
    """
    cal = calibration
    inst = cal.instrument
    pp = pair_parity(session, cal)              # Eq. 21-25 (rimu.calibration.parity_check)
    vc = pp.v_c
    r = vc.shape[0]
    covm, notes = covariance_model(cal)
    thr = float(chi2.isf(p_fa / len(pp.labels), r))
    out = []
    for k, labels in enumerate(pp.labels):
        w, q = pp.rate_mb[k], pp.corrected[k]
        C = (vc * pp.var_g_w[k]) @ vc.T
        if covm is not None:
            D = np.einsum("c,cnp->np", w, covm.D[:3])
            L = vc @ D
            C = C + L @ covm.Sigma @ L.T
        stat = float(q @ np.linalg.solve(C, q))
        nw = float(np.linalg.norm(w))
        out.append(PairQuality(labels, w, pp.nominal[k], q, pp.bias_parity[k], stat, thr,
                               float(np.linalg.norm(q) / nw * RAD_TO_ARCSEC),
                               float(np.linalg.norm(pp.nominal[k]) / nw * RAD_TO_ARCSEC)))
    return QualityReport(inst, out, p_fa, covm is not None, notes)
