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

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import stats

from ...session import Session
from ..model import Effect
from .fitting import RANK_TOL, ModelFit, candidate_columns

__all__ = ["SensorTest", "CandidateTest", "score_candidates", "holm", "confounding", "conditional_log10_p",
           "canonical_correlation"]

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
    # per sensor: (Qc basis, projected residual share) kept for conditional tests and plots
    _bases: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _gamma: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

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


def _log10_chi2sf(x: float, k: int) -> float:
    """log10 of the chi-square survival function, with the asymptotic tail where scipy underflows."""
    if x <= 0:
        return 0.0
    v = float(stats.chi2.logsf(x, k))
    if not np.isfinite(v):
        from math import lgamma, log

        v = -x / 2 + (k / 2 - 1) * log(x / 2) - lgamma(k / 2)
    return float(min(0.0, v / _LN10))


def _log10_fsf(f: float, d1: int, d2: int) -> float:
    """log10 of the F(d1, d2) survival function (chi-square tail of d1 F where it underflows)."""
    if f <= 0:
        return 0.0
    v = float(stats.f.logsf(f, d1, d2))
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


def _basis(C: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray | None, list[int]]:
    """Orthonormal basis of the part of C outside span(Q), and the columns that add nothing to the model."""
    norms = np.linalg.norm(C, axis=0)
    dead = [j for j in range(C.shape[1]) if norms[j] == 0]
    if len(dead) == C.shape[1]:
        return None, dead
    Cn = C / np.where(norms == 0, 1.0, norms)
    Cp = Cn - Q @ (Q.T @ Cn)
    # orthonormal basis from the small Gram matrix: U = Cp V diag(1/sv)
    lam, V = np.linalg.eigh(Cp.T @ Cp)
    sv = np.sqrt(np.clip(lam, 0.0, None))
    bad = sv < 1e-6
    if np.any(bad):
        for v in V.T[bad]:
            dead += [j for j in range(C.shape[1]) if abs(v[j]) > 0.1 and j not in dead]
        return None, sorted(set(dead))
    U = Cp @ (V / sv)
    return U, dead


def score_candidates(session: Session, fit: ModelFit, candidates: Sequence[Effect], alpha: float = 0.01) -> list[CandidateTest]:
    """Test every candidate effect against the residual of ``fit``. Returns tests ranked by evidence.

    Testable candidates come first, most significant first; ``significant`` is Holm-corrected over the
    testable candidates at level ``alpha``; a sensor is named (``SensorTest.significant``) when its own
    p-value passes Bonferroni over the sensors at ``alpha``.
    """
    out: list[CandidateTest] = []
    for eff in candidates:
        ct = CandidateTest(eff.name, True, description=getattr(eff, "description", ""),
                           advice=getattr(eff, "excited_by", ""))
        reasons: dict[str, list[str]] = {}
        n_app = 0
        need = getattr(eff, "needs", "")
        if need == "temperature":
            temps = [seg.temperature for seg in session.segments if seg.temperature is not None]
            if not temps:
                ct.testable, ct.reason = False, "the session has no temperature"
            elif np.ptp(np.concatenate(temps)) < 0.1:
                ct.testable, ct.reason = False, (f"the temperature never changed "
                                                 f"({float(np.min(np.concatenate(temps))):.1f} degC throughout)")
            if not ct.testable:
                out.append(ct)
                continue
        for i, s in enumerate(fit.sensors):
            if not eff.applies_to(s.ctx):
                continue
            n_app += 1
            C, why = candidate_columns(session, fit, eff, i)
            if C is None:
                reasons.setdefault(why, []).append(s.name)
                continue
            U, dead = _basis(C, s.Q)
            if U is None:
                pn = [p.name for p in eff.parameters(s.ctx)]
                what = [pn[j] for j in dead] if dead else pn
                reasons.setdefault(f"the session does not excite {what} apart from the model's own parameters "
                                   "(their columns are zero or a combination of the model's)", []).append(s.name)
                continue
            g = U.T @ s.r
            drss = float(g @ g)
            k = U.shape[1]
            rss0 = s.rss
            dof1 = max(s.n_obs - s.n_par - k, 1)
            rss1 = max(rss0 - drss, np.finfo(float).tiny)
            f = (drss / k) / (rss1 / dof1) / s.inflation
            lp = _log10_fsf(f, k, dof1)
            excess = max(rss0 - s.dof * s.sigma**2, np.finfo(float).tiny)
            ct.sensors.append(SensorTest(s.name, k, drss, rss0, dof1, float(f), lp,
                                         float(s.n_obs * np.log(rss1 / rss0) + k * np.log(s.n_obs)),
                                         drss / rss0, 1.0 if drss >= excess else drss / excess))
            ct._bases[i] = U
            ct._gamma[i] = g
        if n_app == 0:
            ct.testable, ct.applicable = False, False
            ct.reason = f"does not apply to {fit.instrument}s"
            if eff.name == "earth_rate" and fit.instrument == "gyro":
                ct.reason = ("the Earth rate is already part of the gyro input of this model; diagnose with "
                             "include_earth_rate=False (rimu diagnose --no-earth-rate) to test whether the gyros see it")
        elif reasons:
            txt = "; ".join(f"{why} (sensors {', '.join(names)})" for why, names in reasons.items())
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
        out.append(ct)
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
    in :func:`score_candidates`). 0 (p = 1) when ``a`` adds nothing outside ``b``'s span."""
    chi, K, lps = 0.0, 0, []
    for i, Ua in a._bases.items():
        s = fit.sensors[i]
        Ub = b._bases.get(i)
        r = s.r
        if Ub is not None:
            r = r - Ub @ (Ub.T @ r)
            Ua = Ua - Ub @ (Ub.T @ Ua)
        lam, V = np.linalg.eigh(Ua.T @ Ua)
        keep = lam > 1e-12
        if not np.any(keep):
            continue
        U = Ua @ (V[:, keep] / np.sqrt(lam[keep]))
        g = U.T @ r
        drss = float(g @ g)
        k = U.shape[1]
        dof1 = max(s.n_obs - s.n_par - (0 if Ub is None else Ub.shape[1]) - k, 1)
        rss1 = max(float(r @ r) - drss, np.finfo(float).tiny)
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
    for i, Ua in a._bases.items():
        Ub = b._bases.get(i)
        if Ub is None:
            continue
        best = max(best, float(np.linalg.svd(Ua.T @ Ub, compute_uv=False).max()))
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
