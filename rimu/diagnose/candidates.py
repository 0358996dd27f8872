"""Which effect is missing: nested F-tests of every candidate effect against the model's residual, corrected
for testing many candidates (Holm 1979), with per-sensor attribution, identifiability and confounding checks.

For sensor i and candidate e with columns C (N x k): the model's span is projected out,
``C_perp = (I - Q Q^T) C``; the candidate explains ``dRSS = |Qc^T r|^2`` of the residual r (Qc an orthonormal
basis of C_perp), and under "e is absent" with Gaussian white noise

    F = (dRSS / k) / ((RSS - dRSS) / (N - p - k))  ~  F(k, N - p - k)

(the nested-model F-test; for large N it equals the score/LM test dRSS / sigma^2 ~ chi2(k)). Coloured noise
(significant within-segment autocorrelation) divides F by its long-run variance inflation, so that averages
over many correlated samples are not taken for independent evidence. Across sensors
the candidate's evidence is the better of (a) the pooled statistic sum_i dRSS_i / s_i^2 ~ chi2(sum k_i)
(an effect on every sensor) and (b) the smallest per-sensor p-value, Bonferroni-corrected over sensors (an
effect on one sensor), the two combined by Bonferroni. Candidates are then ranked and corrected by Holm's
step-down procedure at family-wise level alpha. The change of the Bayesian information criterion,
``N ln(RSS_1 / RSS_0) + k ln N`` summed over sensors, is reported alongside.

Not testable: a candidate whose columns, after the model's span is removed, are (numerically) zero or
linearly dependent cannot be estimated from the session; the reason is reported with the test that would
excite it. Confounded: two significant candidates neither of which adds significantly to the other
(the encompassing test: e1 given model + e2 and e2 given model + e1) cannot be told apart from this session.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special

from ..calibration.model import Effect
from ..session import Session
from .fitting import ModelFit, SensorFit, candidate_design

__all__ = [
    "CandidateTest",
    "SensorTest",
    "canonical_correlation",
    "candidate_bases",
    "conditional_log10_p",
    "confounding",
    "holm",
    "score_candidates",
]

_LN10 = np.log(10.0)


@dataclass
class SensorTest:
    """One candidate on one sensor."""

    sensor: str
    k: int
    drss: float
    rss0: float
    dof1: int
    f: float
    log10_p: float
    dbic: float
    explained_total: float
    explained_excess: float
    significant: bool = False

    @property
    def p(self) -> float:
        return float(10.0**self.log10_p)


@dataclass
class CandidateTest:
    """A candidate effect's test over all sensors of one instrument."""

    name: str
    testable: bool
    reason: str = ""
    applicable: bool = True
    advice: str = ""
    sensors: list[SensorTest] = field(default_factory=list)
    log10_p: float = 0.0
    log10_p_holm: float = 0.0
    significant: bool = False
    dbic: float = 0.0
    description: str = ""
    # per sensor index: whitener W (U = C_perp W), U^T r, and the sensor's workspace of inner products
    _W: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _gamma: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _ws: dict[int, _Workspace] = field(default_factory=dict, repr=False)
    _coef: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _effect: Any = field(default=None, repr=False)
    _session: Any = field(default=None, repr=False)
    _fit: Any = field(default=None, repr=False)

    @property
    def sensor_indices(self) -> list[int]:
        """Indices of the sensors the candidate was tested on."""
        return list(self._W)

    def basis(self, i: int) -> np.ndarray:
        """Orthonormal basis U (N x k) of the candidate's columns outside the model's span on sensor i
        (recomputed on demand, for plots; :func:`candidate_bases` for many candidates at once)."""
        return candidate_bases([self], i)[self.name]

    def coefficients(self, i: int) -> np.ndarray:
        """The candidate's coefficients on sensor i in the fit of the model plus the candidate (raw output per
        unit of each of its columns): what adding it and refitting would estimate."""
        return self._coef[i]

    def explained(self, i: int) -> np.ndarray:
        """The part of sensor i's residual the candidate explains, per sample (raw units)."""
        return self.basis(i) @ self._gamma[i]

    @property
    def p(self) -> float:
        return float(10.0**self.log10_p)

    @property
    def p_holm(self) -> float:
        return float(10.0**self.log10_p_holm)

    def detected_sensors(self) -> list[str]:
        return [s.sensor for s in self.sensors if s.significant]

    def to_dict(self) -> dict:
        return {
            "name": self.name, "testable": self.testable, "applicable": self.applicable, "reason": self.reason,
            "advice": self.advice,
            "log10_p": self.log10_p, "log10_p_holm": self.log10_p_holm, "significant": self.significant,
            "dbic": self.dbic, "detected_sensors": self.detected_sensors(),
            "sensors": [{k: v for k, v in s.__dict__.items()} for s in self.sensors],
        }


def chi2_logsf(x: float, k: float) -> float:
    """Natural log of the chi-square(k) survival function, as ``scipy.stats.chi2.logsf`` computes it (log of
    the upper tail above the median, log1p of the lower below), from :mod:`scipy.special` (whose import is
    cheap, unlike :mod:`scipy.stats`'s)."""
    with np.errstate(divide="ignore"):
        if x > 2.0 * special.gammaincinv(k / 2.0, 0.5):
            return float(np.log(special.chdtrc(k, x)))
        return float(np.log1p(-special.chdtr(k, x)))


def f_logsf(x: float, d1: float, d2: float) -> float:
    """Natural log of the F(d1, d2) survival function, as ``scipy.stats.f.logsf`` computes it."""
    with np.errstate(divide="ignore"):
        if x > special.fdtri(d1, d2, 0.5):
            return float(np.log(special.fdtrc(d1, d2, x)))
        return float(np.log1p(-special.fdtr(d1, d2, x)))


def candidate_bases(tests: Sequence[CandidateTest], i: int) -> dict[str, np.ndarray]:
    """Orthonormal bases U = C_perp W (N x k) of several candidates' columns outside the model's span on sensor
    i, from one shared design (the columns are built once for all of them). Candidates not tested on sensor i
    are left out."""
    tests = [t for t in tests if i in t._W]
    if not tests:
        return {}
    fit, session = tests[0]._fit, tests[0]._session
    s = fit.sensors[i]
    B, slices, _ = candidate_design(session, fit, [t._effect for t in tests], i)
    # every column normalised and projected out of the model's span at once, in one contiguous N x K block
    # (per candidate, the strided column slices sent the products off BLAS: 20 ms a candidate on 144000 rows)
    B = np.ascontiguousarray(B)
    norms = np.linalg.norm(B, axis=0)
    B /= np.where(norms == 0, 1.0, norms)
    Q = np.ascontiguousarray(s.Q)
    B -= Q @ (Q.T @ B)
    # and every candidate's W in one block-diagonal matrix: one product instead of a strided one per candidate
    widths = [t._W[i].shape[1] for t in tests]
    W = np.zeros((B.shape[1], sum(widths)))
    ends = np.cumsum(widths)
    for t, e, w in zip(tests, ends, widths):
        W[slices[t.name], e - w:e] = t._W[i]
    U = B @ W
    return {t.name: U[:, e - w:e] for t, e, w in zip(tests, ends, widths)}


def _log10_chi2sf(x: float, k: int) -> float:
    """log10 of the chi-square survival function, with the asymptotic tail where scipy underflows."""
    if x <= 0:
        return 0.0
    v = chi2_logsf(x, k)
    if not np.isfinite(v):
        from math import lgamma, log

        v = -x / 2 + (k / 2 - 1) * log(x / 2) - lgamma(k / 2)
    return float(min(0.0, v / _LN10))


def _log10_fsf(f: float, d1: int, d2: int) -> float:
    """log10 of the F(d1, d2) survival function (chi-square tail of d1 F where it underflows)."""
    if f <= 0:
        return 0.0
    v = f_logsf(f, d1, d2)
    if not np.isfinite(v):
        return _log10_chi2sf(f * d1, d1)
    return float(min(0.0, v / _LN10))


def holm(log10_p: Sequence[float], alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Holm's step-down correction. Returns (adjusted log10 p-values, rejected) in the input order.

    >>> adj, rej = holm(np.log10([0.001, 0.04, 0.03]), 0.05)
    >>> np.round(10 ** adj, 3).tolist(), rej.tolist()
    ([0.003, 0.06, 0.06], [True, False, False])
    """
    lp = np.asarray(log10_p, dtype=float)
    m = lp.size
    order = np.argsort(lp)
    adj = np.empty(m)
    run = -np.inf
    for j, k in enumerate(order):
        run = max(run, lp[k] + np.log10(m - j))
        adj[k] = min(run, 0.0)
    return adj, adj <= np.log10(alpha)


@dataclass
class _Workspace:
    """Inner products of one sensor's candidate columns (normalised, N x K side by side) with themselves, with
    the model's orthonormal basis Q and with the residual: everything the tests need, in the small space."""

    BtB: np.ndarray
    QtB: np.ndarray
    Btr: np.ndarray
    slices: dict[str, slice]
    #: the columns' norms (after centring), by which they were normalised
    norms: np.ndarray

    def perp_gram(self, a: str, b: str) -> np.ndarray:
        """``C_a_perp^T C_b_perp`` with ``C_perp = (I - Q Q^T) C``."""
        sa, sb = self.slices[a], self.slices[b]
        return self.BtB[sa, sb] - self.QtB[:, sa].T @ self.QtB[:, sb]


def _workspace(B: np.ndarray, slices: dict[str, slice], s: SensorFit) -> _Workspace:
    """The candidates' columns appended to the model's design by their inner products: the Gram block
    ``B^T B``, the cross block ``Q^T B`` with the model's orthonormal basis and ``B^T r``, from two products
    over the samples; every candidate is then tested in the small space through the Schur complement
    ``B^T B - B^T Q Q^T B`` (:meth:`_Workspace.perp_gram`), never refitted."""
    G = B.T @ B
    H = B.T @ np.column_stack([s.Q, s.r])
    nr = np.sqrt(np.diag(G))
    d = np.where(nr == 0, 1.0, nr)
    p = s.Q.shape[1]
    QtB = H[:, :p].T / d
    # r is orthogonal to Q up to rounding; remove that rounding
    Btr = H[:, p] / d - QtB.T @ (s.Q.T @ s.r)
    return _Workspace(G / np.outer(d, d), QtB, Btr, slices, nr)


def _refit_workspace(B: np.ndarray, slices: dict[str, slice], s: SensorFit) -> _Workspace:
    """The reference (``method="refit"``): the same inner products from columns whose projection on the
    model's design is removed explicitly, by a least-squares fit of each column on the design."""
    nr = np.linalg.norm(B, axis=0)
    Bn = B / np.where(nr == 0, 1.0, nr)
    Bp = Bn - s.X @ np.linalg.lstsq(s.X, Bn, rcond=None)[0]
    return _Workspace(Bp.T @ Bp, np.zeros((0, B.shape[1])), Bp.T @ s.r, slices, nr)


def _refit(s: SensorFit, Cn: np.ndarray, norms: np.ndarray) -> tuple[float, np.ndarray]:
    """The straightforward refit of the model plus a candidate's (normalised) columns on one sensor, by least
    squares on the samples (SVD). Returns the candidate's dRSS = RSS_0 - RSS_1 and its coefficients (raw
    units per column unit).

    The model's residual is refitted on the whole design ``A = [X C]`` (Frisch-Waugh: the same coefficients
    of C and the same RSS_1 as refitting y, since X is in A), so that dRSS is the squared norm of the fitted
    part, ``|A gamma|^2``, not a difference of two sums of N squares (which resolves it only to ~N eps RSS)."""
    A = np.column_stack([s.X, Cn])
    gamma = np.linalg.lstsq(A, s.r, rcond=None)[0]
    fitted = A @ gamma
    return float(fitted @ fitted), gamma[s.X.shape[1]:] / np.where(norms == 0, 1.0, norms)


def _whitener(ws: _Workspace, name: str, n_cols: int) -> tuple[np.ndarray | None, list[int]]:
    """W (k x k) such that ``U = C_perp W`` is an orthonormal basis of the candidate's columns outside the
    model's span, or None and the columns that add nothing (zero, or a combination of the model's)."""
    G = ws.perp_gram(name, name)
    lam, V = np.linalg.eigh(G)
    sv = np.sqrt(np.clip(lam, 0.0, None))
    bad = sv < 1e-6
    if np.any(bad):
        dead: list[int] = []
        for v in V.T[bad]:
            dead += [j for j in range(n_cols) if abs(v[j]) > 0.1 and j not in dead]
        return None, sorted(set(dead))
    return V / sv, []


def score_candidates(session: Session, fit: ModelFit, candidates: Sequence[Effect], alpha: float = 0.01,
                     method: str = "fast") -> list[CandidateTest]:
    """Test every candidate effect against the residual of ``fit``. Returns tests ranked by evidence.

    ``method="fast"`` (default): per sensor, one shared design of every candidate's columns
    (:func:`~rimu.diagnose.fitting.candidate_design`) appended to the model's by its inner products; each
    candidate's dRSS, coefficients and whitened basis follow in the small space. ``method="refit"``: the
    straightforward reference, each candidate refitted with the model by least squares on the samples (the
    same numbers to rounding, many times slower; for tests and the benchmark).

    Testable candidates come first, most significant first; ``significant`` is Holm-corrected over the
    testable candidates at level ``alpha``; a sensor is named (``SensorTest.significant``) when its own
    p-value passes Bonferroni over the sensors at ``alpha``.
    """
    if method not in ("fast", "refit"):
        raise ValueError(f"method must be 'fast' or 'refit', got {method!r}")
    tests: dict[str, CandidateTest] = {}
    reasons: dict[str, dict[str, list[str]]] = {}
    n_app: dict[str, int] = {}
    active: list[Effect] = []
    for eff in candidates:
        ct = CandidateTest(eff.name, True, description=getattr(eff, "description", ""),
                           advice=getattr(eff, "excited_by", ""))
        ct._effect, ct._session, ct._fit = eff, session, fit
        tests[eff.name] = ct
        reasons[eff.name], n_app[eff.name] = {}, 0
        if getattr(eff, "needs", "") == "temperature":
            temps = [seg.temperature for seg in session.segments if seg.temperature is not None]
            if not temps:
                ct.testable, ct.reason = False, "the session has no temperature"
            elif np.ptp(np.concatenate(temps)) < 0.1:
                ct.testable, ct.reason = False, (f"the temperature never changed "
                                                 f"({float(np.min(np.concatenate(temps))):.1f} degC throughout)")
            if not ct.testable:
                continue
        active.append(eff)
    from ..progress import bar

    many = len(active) * len(fit.sensors) > 60  # a bar on a terminal when the tests take a while
    for i, s in enumerate(bar(fit.sensors, total=len(fit.sensors), desc=f"testing {len(active)} candidate effects",
                              unit="sensor", enabled=None if many else False)):
        apps = [e for e in active if e.applies_to(s.ctx)]
        if not apps:
            continue
        for eff in apps:
            n_app[eff.name] += 1
        B, slices, why = candidate_design(session, fit, apps, i)
        for name, txt in why.items():
            reasons[name].setdefault(txt, []).append(s.name)
        if not slices:
            continue
        ws = (_workspace if method == "fast" else _refit_workspace)(B, slices, s)
        for name, sl in slices.items():
            ct, eff = tests[name], next(e for e in apps if e.name == name)
            if not np.any(ws.norms[sl] > 0):
                pn = [p.name for p in eff.parameters(s.ctx)]
                reasons[name].setdefault(f"the session does not excite {pn} (their columns are zero)", []).append(s.name)
                continue
            W, dead = _whitener(ws, name, sl.stop - sl.start)
            if W is None:
                pn = [p.name for p in eff.parameters(s.ctx)]
                what = [pn[j] for j in dead] if dead else pn
                reasons[name].setdefault(f"the session does not excite {what} apart from the model's own parameters "
                                         "(their columns are zero or a combination of the model's)", []).append(s.name)
                continue
            g = W.T @ ws.Btr[sl]
            k = W.shape[1]
            rss0 = s.rss
            if method == "fast":  # dRSS in the small space: |U^T r|^2, U = C_perp W orthonormal
                drss = float(g @ g)
                coef = (W @ g) / ws.norms[sl]
            else:  # the straightforward refit: least squares on the model's design and the candidate's columns
                drss, coef = _refit(s, B[:, sl] / ws.norms[sl], ws.norms[sl])
            dof1 = max(s.n_obs - s.n_par - k, 1)
            rss1 = max(rss0 - drss, np.finfo(float).tiny)
            f = (drss / k) / (rss1 / dof1) / s.inflation
            lp = _log10_fsf(f, k, dof1)
            excess = max(rss0 - s.dof * s.sigma**2, np.finfo(float).tiny)
            ct.sensors.append(SensorTest(s.name, k, drss, rss0, dof1, float(f), lp,
                                         float(s.n_obs * np.log(rss1 / rss0) + k * np.log(s.n_obs)),
                                         drss / rss0, 1.0 if drss >= excess else drss / excess))
            ct._W[i], ct._gamma[i], ct._ws[i], ct._coef[i] = W, g, ws, coef
    out = list(tests.values())
    for ct in out:
        if not ct.testable:
            continue
        if n_app[ct.name] == 0:
            ct.testable, ct.applicable = False, False
            ct.reason = f"does not apply to {fit.instrument}s"
            if ct.name == "earth_rate" and fit.instrument == "gyro":
                ct.reason = ("the Earth rate is already part of the gyro input of this model; diagnose with "
                             "include_earth_rate=False (rimu diagnose --no-earth-rate) to test whether the gyros see it")
        elif reasons[ct.name]:
            txt = "; ".join(f"{why} (sensors {', '.join(names)})" for why, names in reasons[ct.name].items())
            if ct.sensors:
                ct.reason = "only partly testable: " + txt
            else:
                ct.testable, ct.reason = False, txt
        if ct.sensors:
            lp_sens = np.array([x.log10_p for x in ct.sensors])
            # pooled statistic over sensors
            chi = sum(x.f * x.k for x in ct.sensors)
            K = sum(x.k for x in ct.sensors)
            lp_pool = _log10_chi2sf(chi, K)
            lp_min = float(lp_sens.min() + np.log10(len(ct.sensors)))
            ct.log10_p = float(min(0.0, min(lp_pool, lp_min) + np.log10(2.0)))
            ct.dbic = float(sum(x.dbic for x in ct.sensors))
    testable = [c for c in out if c.testable and c.sensors]
    if testable:
        adj, rej = holm([c.log10_p for c in testable], alpha)
        for c, a, r in zip(testable, adj, rej):
            c.log10_p_holm, c.significant = float(a), bool(r)
            # attribution: Bonferroni over the sensors (a sensor is named only on its own evidence)
            thr = np.log10(alpha / len(c.sensors))
            for x in c.sensors:
                x.significant = bool(x.log10_p <= thr) and c.significant
    out.sort(key=lambda c: (not (c.testable and c.sensors), not c.significant, c.log10_p, c.dbic))
    return out


def conditional_log10_p(fit: ModelFit, a: CandidateTest, b: CandidateTest) -> float:
    """Evidence for candidate ``a`` given the model plus candidate ``b`` (pooled and min-over-sensors, as
    in :func:`score_candidates`). 0 (p = 1) when ``a`` adds nothing outside ``b``'s span.

    Computed in the small space: with ``U_a = C_a_perp W_a`` and ``U_b`` orthonormal, the residual's projection
    on their joint span has squared norm ``g^T G^+ g`` with ``G = [[I, M], [M^T, I]]``, ``M = U_a^T U_b``,
    ``g = (U_a^T r, U_b^T r)``; ``a`` explains what it adds beyond ``|U_b^T r|^2``.
    """
    chi, K, lps = 0.0, 0, []
    for i, Wa in a._W.items():
        s = fit.sensors[i]
        ga = a._gamma[i]
        Wb = b._W.get(i)
        if Wb is None:
            lam = np.ones(ga.size)
            drss, k, kb, gb2 = float(ga @ ga), ga.size, 0, 0.0
        else:
            ws = a._ws[i]
            M = Wa.T @ ws.perp_gram(a.name, b.name) @ Wb
            ka, kb = Wa.shape[1], Wb.shape[1]
            G = np.block([[np.eye(ka), M], [M.T, np.eye(kb)]])
            g = np.concatenate([ga, b._gamma[i]])
            lam, V = np.linalg.eigh(G)
            keep = lam > 1e-9
            proj = float(np.sum((V[:, keep].T @ g) ** 2 / lam[keep]))
            gb2 = float(b._gamma[i] @ b._gamma[i])
            drss = max(proj - gb2, 0.0)
            k = int(keep.sum()) - kb
        if k <= 0:
            continue
        dof1 = max(s.n_obs - s.n_par - kb - k, 1)
        rss1 = max(s.rss - gb2 - drss, np.finfo(float).tiny)
        f = (drss / k) / (rss1 / dof1) / s.inflation
        chi += f * k
        K += k
        lps.append(_log10_fsf(f, k, dof1))
    if not K:
        return 0.0
    lp_pool = _log10_chi2sf(chi, K)
    lp_min = float(min(lps) + np.log10(len(lps)))
    return float(min(0.0, min(lp_pool, lp_min) + np.log10(2.0)))


def canonical_correlation(a: CandidateTest, b: CandidateTest) -> float:
    """Largest canonical correlation between two candidates' columns after the model's span is removed
    (cosine of the smallest principal angle), the largest over sensors both apply to."""
    best = 0.0
    for i, Wa in a._W.items():
        Wb = b._W.get(i)
        if Wb is None:
            continue
        M = Wa.T @ a._ws[i].perp_gram(a.name, b.name) @ Wb
        best = max(best, float(np.linalg.svd(M, compute_uv=False).max()))
    return best


def confounding(fit: ModelFit, tests: list[CandidateTest], alpha: float) -> list[list[str]]:
    """Groups of significant candidates that the session cannot tell apart, in rank order.

    Two significant candidates are confounded when neither adds significantly (at ``alpha``) to the model
    plus the other. Each group lists its members best first; singletons are clear findings.
    """
    sig = [c for c in tests if c.significant]
    parent = {c.name: c.name for c in sig}

    def find(x: str) -> str:
        while parent[x] != x:
            x = parent[x]
        return x

    la = np.log10(alpha)
    for ia, a in enumerate(sig):
        for b in sig[ia + 1:]:
            if canonical_correlation(a, b) < 0.5:
                continue
            if conditional_log10_p(fit, a, b) > la and conditional_log10_p(fit, b, a) > la:
                parent[find(b.name)] = find(a.name)
    groups: dict[str, list[str]] = {}
    for c in sig:
        groups.setdefault(find(c.name), []).append(c.name)
    return list(groups.values())
