"""Parity space of every active set, and what a geometry can detect and isolate.

For the calibrated axes A (rows a_i) and noise sigma_i, the normalised parity rows ``Vz = V_w W`` of
each active set are computed by :class:`rimu.fusion.ProjectionTable` when the set occurs (de Oliveira et al. 2012,
Eq. 6-11, on the whitened rows). A bias ``b`` (SI) on sensor j moves the normalised parity vector by
``b Vz[:, j]``; this module derives from those columns:

* the detectability of one fault (``|v_j| > 0``), of two simultaneous faults (columns i, j linearly
  independent) and the isolability of one (no two columns collinear, which needs ``dof >= 2``);
* the correlation ``rho_jk = v_j . v_k / (|v_j| |v_k|)`` between parity columns, which bounds wrong
  isolation: with ``m = b |v_j|`` the GLT picks k instead of j with probability (pairwise, exact)

      P(|X_k| > |X_j|) = Phi(-a) Phi(c) + Phi(a) Phi(-c),  a = m sqrt((1 - |rho|) / 2), c = m sqrt((1 + |rho|) / 2)

  because ``X_k - X_j`` and ``X_k + X_j`` are independent normals; the sum over k is an upper bound
  (Bonferroni) and the largest term a lower bound of the wrong-isolation probability;
* the detection probability of the chi-square test (Daly, Gai & Harrison 1979): ``FD ~ chi2(dof, lambda)``
  with ``lambda = N b^2 |v_j|^2`` for a bias held over an N-sample window.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..fusion import ProjectionTable
from ..fusion.projection import bits_mask

__all__ = [
    "IsolabilityReport",
    "SetReport",
    "isolability",
    "column_correlations",
    "pairwise_wrong_isolation",
    "wrong_isolation_bounds",
    "detection_probability",
]

_TOL = 1e-9


def column_correlations(Vz: np.ndarray) -> np.ndarray:
    """Correlation ``rho_jk`` between the parity columns of one active set, (n, n); 0 for inactive columns.

    >>> from rimu.geometry import cone6
    >>> rho = column_correlations(cone6().parity_matrix())
    >>> round(float(abs(rho[0, 4])), 4), round(float(abs(rho[0, 3])), 4)
    (0.6667, 0.3333)
    """
    V = np.asarray(Vz, dtype=float)
    n2 = np.einsum("ij,ij->j", V, V)
    norms = np.sqrt(n2)
    ok = norms > _TOL
    rho = np.zeros((V.shape[1], V.shape[1]))
    sub = V[:, ok]
    rho[np.ix_(ok, ok)] = (sub.T @ sub) / np.outer(norms[ok], norms[ok])
    return rho


def pairwise_wrong_isolation(m: float | np.ndarray, rho: float | np.ndarray) -> np.ndarray:
    """P(|X_k| > |X_j|) for unit-variance normals with correlation rho and means (m rho, m) (see module doc).

    ``m`` is the fault's parity signal in sigma (``b |v_j|``). Exact for the pair.

    >>> round(float(pairwise_wrong_isolation(0.0, 0.5)), 3)  # no signal: a coin toss
    0.5
    """
    from scipy.stats import norm  # analysis only: not imported with the runtime (~40 MB)
    m = np.asarray(m, dtype=float)
    r = np.clip(np.abs(np.asarray(rho, dtype=float)), 0.0, 1.0)
    a = m * np.sqrt((1.0 - r) / 2.0)
    c = m * np.sqrt((1.0 + r) / 2.0)
    return norm.cdf(-a) * norm.cdf(c) + norm.cdf(a) * norm.cdf(-c)


def wrong_isolation_bounds(Vz: np.ndarray, j: int, size: float, window: int = 1) -> tuple[float, float]:
    """Lower and upper bound of the GLT's wrong-isolation probability for a bias on sensor ``j``.

    Parameters
    ----------
    Vz : ndarray (r, n)
        Normalised parity rows of the active set (``ProjectionTable.Vz[entry]``).
    j : int
    size : float
        Bias in the units Vz is normalised with (SI; or in sigma when Vz is for unit noise).
    window : int
        Samples averaged (the window GLT): the signal grows as sqrt(window).

    Returns
    -------
    (lower, upper) : the largest pairwise term and the Bonferroni sum over the other active sensors.
    """
    V = np.asarray(Vz, dtype=float)
    rho = column_correlations(V)
    nv = np.linalg.norm(V, axis=0)
    nj = float(nv[j])
    others = np.flatnonzero((np.arange(len(nv)) != j) & (nv > _TOL))
    if not others.size or nj <= _TOL:
        return 0.0, 0.0
    p = pairwise_wrong_isolation(abs(size) * nj * np.sqrt(window), rho[j, others])
    return float(p.max()), float(min(1.0, p.sum()))


def detection_probability(p_fa: float, dof: int, noncentrality: float | np.ndarray) -> np.ndarray:
    """Detection probability of the chi-square test: ``P(chi2(dof, lambda) > chi2_{1-p_fa}(dof))``.

    Daly, Gai & Harrison 1979 (generalized likelihood test on the parity vector).

    >>> round(float(detection_probability(1e-3, 3, 0.0)), 6)
    0.001
    """
    from scipy.stats import chi2, ncx2  # analysis only: not imported with the runtime (~40 MB)
    thr = chi2.isf(p_fa, dof)
    lam = np.asarray(noncentrality, dtype=float)
    return np.where(lam > 0, ncx2.sf(thr, dof, np.maximum(lam, 1e-300)), chi2.sf(thr, dof))


@dataclass
class SetReport:
    """Fault detection and isolation capability of one active set."""

    active: list[str]
    dof: int
    detect_one: bool
    isolate_one: bool
    detect_two: bool
    column_norms: dict[str, float]
    max_abs_correlation: float
    worst_pair: tuple[str, str] | None
    wrong_isolation_10sigma: tuple[float, float] | None

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["worst_pair"] = list(self.worst_pair) if self.worst_pair else None
        d["wrong_isolation_10sigma"] = list(self.wrong_isolation_10sigma) if self.wrong_isolation_10sigma else None
        return d


@dataclass
class IsolabilityReport:
    """What a geometry (with its calibration and noise) can detect and isolate, per active set.

    Attributes
    ----------
    geometry : str
    names : list of str
    full : SetReport
        The set with every sensor.
    after_one : dict[str, SetReport]
        The sets with one sensor excluded (after a first isolation).
    correlations : ndarray (n, n)
        Parity-column correlations of the full set.
    """

    geometry: str
    names: list[str]
    full: SetReport
    after_one: dict[str, SetReport] = field(default_factory=dict)
    correlations: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def faults_isolable(self) -> int:
        """How many successive faults can be isolated, one after the other (0, 1, 2, ...)."""
        if not self.full.isolate_one:
            return 0
        if self.after_one and all(r.isolate_one for r in self.after_one.values()):
            return 2
        return 1

    def summary(self) -> str:
        """A readable report."""
        f = self.full
        lines = [f"{self.geometry}: {len(self.names)} sensors, parity dimension {f.dof}"]
        lines.append(f"  detect one fault: {'yes' if f.detect_one else 'no'}; "
                     f"isolate one: {'yes' if f.isolate_one else 'NO (isolation impossible)'}; "
                     f"detect two at once: {'yes' if f.detect_two else 'no'}")
        lines.append(f"  successive faults that can be isolated: {self.faults_isolable}")
        if f.worst_pair:
            lines.append(f"  largest parity-column correlation |rho| = {f.max_abs_correlation:.3f} "
                         f"({f.worst_pair[0]}, {f.worst_pair[1]})")
        if f.wrong_isolation_10sigma:
            lo, hi = f.wrong_isolation_10sigma
            lines.append(f"  wrong isolation of a 10 sigma bias (snapshot GLT): {100 * lo:.3f} % .. {100 * hi:.3f} %")
        norms = ", ".join(f"{k} {v:.3f}" for k, v in f.column_norms.items())
        lines.append(f"  |v_j| sigma_j (fraction of a bias seen by parity): {norms}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {"geometry": self.geometry, "names": self.names, "full": self.full.to_dict(),
                "after_one": {k: v.to_dict() for k, v in self.after_one.items()},
                "faults_isolable": self.faults_isolable, "correlations": self.correlations.tolist()}


def _set_report(table: ProjectionTable, e: int, names: Sequence[str]) -> SetReport:
    n = table.n
    active = bits_mask(int(table.codes[e]), n)
    dof = int(table.dof[e])
    V = table.Vz[e, :dof]
    sig = table.sigma
    norms = np.linalg.norm(V, axis=0) * sig  # |v_wj|: dimensionless
    idx = [i for i in range(n) if active[i]]
    detect_one = dof >= 1 and bool(np.all(norms[idx] > _TOL))
    rho = column_correlations(V) if dof else np.zeros((n, n))
    # every pair at once (a unit of 96 axes has 4560 pairs per set): the first pair of largest |rho|, and
    # whether each pair's two columns are independent (smallest singular value of [v_i v_j] above 1e-9)
    ia = np.asarray(idx)
    iu, ju = np.triu_indices(len(ia), 1)
    pi, pj = ia[iu], ia[ju]
    max_rho, worst = 0.0, None
    if len(pi):
        ar = np.abs(rho[pi, pj])
        kmax = int(np.argmax(ar))
        if ar[kmax] > 0.0:
            max_rho, worst = float(ar[kmax]), (names[pi[kmax]], names[pj[kmax]])
    isolate_one = detect_one and dof >= 2 and max_rho < 1 - 1e-6
    detect_two = False
    if dof >= 2:
        gram = V.T @ V
        a, b, c = gram[pi, pi], gram[pj, pj], gram[pi, pj]
        lam_min = 0.5 * (a + b) - np.sqrt(0.25 * (a - b) ** 2 + c * c)
        detect_two = bool(np.all(np.sqrt(np.clip(lam_min, 0.0, None)) > 1e-9))
    wrong = None
    if isolate_one:
        # wrong_isolation_bounds of a 10 sigma bias on each active sensor, every (j, k) pair in one call
        nv = np.linalg.norm(V, axis=0)[ia]
        P = pairwise_wrong_isolation((10.0 * sig[ia] * nv)[:, None], rho[np.ix_(ia, ia)])
        P[np.eye(len(ia), dtype=bool) | ~(nv > _TOL)[None, :]] = 0.0
        wrong = (float(P.max(axis=1).max()), float(np.minimum(1.0, P.sum(axis=1)).max()))
    return SetReport([names[i] for i in idx], dof, detect_one, isolate_one, detect_two,
                     {names[i]: float(norms[i]) for i in idx}, float(max_rho), worst, wrong)


def isolability(table: ProjectionTable, names: Sequence[str] | None = None, geometry: str = "custom") -> IsolabilityReport:
    """The fault-isolability report of a projection table (its full set and every one-sensor exclusion).

    Parameters
    ----------
    table : ProjectionTable
        ``InstrumentPipeline.table``, or ``ProjectionTable(geometry.H)`` for the nominal geometry.
    names : sequence of str, optional
        Sensor names (default s1..sn).
    geometry : str
        Name used in the report.

    Examples
    --------
    >>> from rimu.geometry import tetrad4, cone6
    >>> isolability(ProjectionTable(tetrad4().H)).full.isolate_one
    False
    >>> r = isolability(ProjectionTable(cone6().H), cone6().names, "cone6")
    >>> r.full.detect_two, r.faults_isolable
    (True, 2)
    """
    n = table.n
    names = list(names) if names is not None else [f"s{i + 1}" for i in range(n)]
    e0 = table.lookup(table.full_code)
    full = _set_report(table, e0, names)
    after = {}
    for i in range(n):
        e = table.lookup(table.full_code & ~(1 << i))
        if e >= 0 and table.observable[e]:
            after[names[i]] = _set_report(table, e, names)
    return IsolabilityReport(geometry, names, full, after, column_correlations(table.Vz[e0, :full.dof]))
