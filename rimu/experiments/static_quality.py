"""Parity check of a calibration on the segments at rest: the accelerometers' counterpart of de Oliveira's
rate-pair check (:mod:`rimu.experiments.quality`).

The +w / -w rate pairs of de Oliveira et al. 2012 (Eq. 21-25) excite the gyros; accelerometers see the same
gravity in both sequences of a pair, so their ``g_w`` is zero and that check cannot fail for them. At rest the
accelerometers measure gravity in every attitude, and the parity of the compensated outputs needs no known
input at all: with ``z = SF * mean(y) - B`` (Cho & Park 2005, Eq. 20 without ``M^-1``) and ``v_c`` the parity
rows of the calibrated axes ``M H`` (de Oliveira Eq. 22), a correct calibration gives ``q = v_c z`` = noise of the
means only, whatever the attitude. A scale, misalignment or bias error left in the calibration shows as
``v_c (A_true - A_cal) f + v_c (b_true - b_cal)``.

Each static segment is tested with ``q^T C^-1 q`` against ``chi2(n - 3)`` at ``p_fa / segments`` (Bonferroni),
``C = v_c diag(sigma^2 / N) v_c^T`` plus the calibration's own covariance propagated at the segment's specific
force (:class:`rimu.fdi.calaware.CalibrationCovariance`). The statistic is the one of :mod:`rimu.experiments.quality`, so
the report reads the same way; the misfit is given in micro-g.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from ..calibration.result import InstrumentCalibration
from ..errors import SessionFormatError
from ..geometry import null_space_rows
from ..session import Session
from ..units import MS2_TO_UG
from .quality import ParityCheckReport, covariance_model, vector_text

__all__ = ["SegmentQuality", "StaticQualityReport", "static_parity_quality"]


@dataclass
class SegmentQuality:
    """One segment at rest."""

    label: str
    specific_force_mb: np.ndarray
    parity: np.ndarray
    statistic: float
    threshold: float
    misfit_ug: float

    @property
    def bad(self) -> bool:
        return self.statistic > self.threshold

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "specific_force_mb_m_s2": self.specific_force_mb.tolist(),
                "parity": self.parity.tolist(), "statistic": self.statistic, "threshold": self.threshold,
                "bad": self.bad, "misfit_ug": self.misfit_ug}


@dataclass
class StaticQualityReport(ParityCheckReport, rows="segments"):
    """Per-segment statistics and the verdict (attributes as :class:`rimu.experiments.quality.QualityReport`, with
    ``segments``, one a segment at rest, in place of its pairs)."""

    segments: list[SegmentQuality]
    p_fa: float
    uses_calibration_covariance: bool
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        from ..units import G0, UG_TO_MS2, field_unit, fmt

        # one unit for the misfit column (rimu.units.fmt): ug, or mg and m/s^2 for larger misfits
        unit = field_unit("specific_force", UG_TO_MS2 * max([s.misfit_ug for s in self.segments] or [0.0]))[0]
        head = [f"parity calibration check at rest ({self.instrument}): v_c (SF y - B), chi2({self.dof}) per segment",
                f"{'segment':>10} {'f (MB), g':>24} | {'|v_c z|':>14} | {'chi2':>9} {'limit':>7}"]
        rows = [f"{s.label:>10} {vector_text(s.specific_force_mb / G0):>24} | "
                f"{fmt(s.misfit_ug * UG_TO_MS2, 'specific_force', unit, digits=4, width=8):>14} | "
                f"{s.statistic:9.1f} {s.threshold:7.1f}" for s in self.segments]
        w = max(self.segments, key=lambda s: s.statistic)
        return self._summary(head, rows, f"largest misfit in segment {w.label!r}, about "
                                         f"{fmt(w.misfit_ug * UG_TO_MS2, 'specific_force', digits=3)}")

    @property
    def dof(self) -> int:
        return int(self.segments[0].parity.shape[0]) if self.segments else 0

    def to_dict(self) -> dict[str, Any]:
        return self._to_dict("segments", kind="static")

    def plot(self, path: str | Path) -> Path | None:
        """Bar chart of the misfit per segment (red: above its threshold)."""
        def draw(ax: Any, k: np.ndarray, colours: list[str]) -> None:
            ax.bar(k, [s.misfit_ug for s in self.segments], color=colours)

        return self._plot(path, [s.label for s in self.segments], "|v_c (SF y - B)| [ug]",
                          f"{self.instrument} parity check at rest: {self.verdict}", draw)


def static_parity_quality(session: Session, calibration: InstrumentCalibration, p_fa: float = 1e-3) -> StaticQualityReport:
    """The parity check of a calibration on the session's segments at rest (module docstring).

    Raises
    ------
    SessionFormatError
        Fewer than four sensors (no parity space), no ``noise_sigma``, or no segment at rest.
    """
    cal = calibration
    g = cal.geometry
    if g.n < 4:
        raise SessionFormatError(f"a parity check needs at least four sensors; {g.name} has {g.n} (no parity space)")
    if cal.noise_sigma is None:
        raise SessionFormatError("the calibration states no noise_sigma; the check needs the noise of each sensor")
    if not 0 < p_fa < 1:
        raise ValueError(f"p_fa must be in (0, 1), got {p_fa}")
    segs = [s for s in session.segments if s.kind in ("static", "static_unknown") and s.n_samples >= 2]
    if not segs:
        raise SessionFormatError("the session has no segment at rest (kind 'static' or 'static_unknown')")
    A = cal.axes_mb()
    vc = null_space_rows(A)
    Ap = np.linalg.pinv(A)
    covm, notes = covariance_model(cal)
    r = vc.shape[0]
    thr = float(chi2.isf(p_fa / len(segs), r))
    out = []
    for s in segs:
        y = s.raw[cal.instrument]
        z = cal.compensate(y.mean(axis=0))
        q = vc @ z
        f = Ap @ z
        C = (vc * (cal.noise_sigma**2 / y.shape[0])) @ vc.T
        if covm is not None:
            ut = np.concatenate([f, [1.0]])
            L = vc @ np.einsum("c,cnp->np", ut, covm.D)
            C = C + L @ covm.Sigma @ L.T
        stat = float(q @ np.linalg.solve(C, q))
        out.append(SegmentQuality(s.label, f, q, stat, thr, float(np.linalg.norm(q) * MS2_TO_UG)))
    return StaticQualityReport(cal.instrument, out, p_fa, covm is not None, notes)
