"""Multiple-fault isolation: a generalised likelihood test over sets of 1..k sensors.

A bias vector ``b_S`` on the sensors of a set S moves the normalised parity vector (unit covariance, see
:mod:`rimu.fusion.projection`) by ``V_S b_S``, where ``V_S`` holds the columns of S of the normalised parity
matrix ``Vz`` (dof rows). The fault subspace of S is ``span(V_S)``; with ``Q_S`` an orthonormal basis of it,
the generalised likelihood ratio of "the fault is on S" (``b_S`` unknown, maximised out) is
``T_S = |Q_S^T p|^2`` and what S leaves unexplained is

    R_S = |p|^2 - T_S  ~  chi2(dof - |S|)   (central, exactly, when the fault is on S; independent of T_S)

(Daly, Gai & Harrison 1979, extended from one column to a subspace). The decision rule of
:class:`FaultSetGlt`, applied after the detection test ``|p|^2 > chi2_{1 - p_fa}(dof)`` has alarmed:

1. for k = 1, 2, ... up to ``K = min(max_size, dof - 1)`` (one parity dimension must remain to test a
   hypothesis), a set S of size k is *consistent* when ``R_S <= c_k = chi2_{1 - alpha}(dof - k)``;
2. a consistent set is *minimal* when no proper subset of it is consistent (a superset of a consistent set
   is always consistent: it only adds freedom). Exactly one minimal consistent set -> **isolated** (that
   set); more than one -> **ambiguous** ("fault present, not isolable"; the union of the minimal sets is
   suspect). A single sensor is therefore named only when no pair without it explains the data as well:
   in a three-dimensional parity space a pair's plane passes close to many single columns, and naming the
   smallest explanation without that check isolates a wrong sensor under two simultaneous faults;
3. no consistent set up to K -> **unexplained** (more faulty sensors than the parity space can separate:
   also "fault present, not isolable").

Sets whose columns are (nearly) linearly dependent are not hypotheses: their subspace equals a smaller
set's. Collinear columns make two singles always consistent together, so they come out *ambiguous*, never
isolated: where a geometry cannot tell two explanations apart the rule says so instead of guessing.

Error rates for a single fault on sensor j with parity signal ``m = |b| |v_j|`` (in sigma), ``u_j = v_j / |v_j|``,
``rho_jk = u_j . u_k`` (derived in ``docs/fdi.md``; :func:`single_fault_rates`):

* the true set is rejected (missed isolation) with ``P(R_j > c_1, T_j + R_j > c_dof)``: exactly ``alpha`` once
  detection is certain, since ``R_j ~ chi2(dof - 1)`` whatever m;
* a wrong single k is consistent with ``F_k = P(ncx2(dof - 1, m^2 (1 - rho_jk^2)) <= c_1)``, a pair {k, l}
  without j with ``G_kl = P(ncx2(dof - 2, m^2 d_kl^2) <= c_2)``, ``d_kl`` the distance of ``u_j`` from the
  pair's plane; a *wrong isolation* needs the true set rejected and a wrong one consistent, so its
  probability is at most ``min(alpha, sum F + sum G)``; *ambiguous* is at most ``sum F + sum G + missed``;
* correct isolation is at least ``P_D - missed - sum_k F_k - sum_kl G_kl``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from math import comb
from typing import Any

import numpy as np
from scipy.special import chdtri

__all__ = ["FaultSetGlt", "SetDecision", "set_fault_rates", "single_fault_rates"]


@dataclass
class SetDecision:
    """Outcome of one :meth:`FaultSetGlt.decide`.

    kind : ``isolated`` (one consistent set at the smallest size), ``ambiguous`` (several), ``unexplained``
        (none up to the largest size tested), ``not_isolable`` (parity dimension below 2: detection only).
    sensors : the isolated set (empty otherwise), sensor indices in ascending order.
    suspects : the union of the consistent sets of the deciding size (the isolated set, or every sensor that
        could explain the fault).
    residual : ``R_S`` of the isolated set (smallest residual otherwise).
    size : the set size the decision was taken at (0 when none).
    """

    kind: str
    sensors: tuple[int, ...] = ()
    suspects: tuple[int, ...] = ()
    residual: float = float("nan")
    size: int = 0


@dataclass
class _Design:
    sizes: list[int]
    sets: list[np.ndarray]        # per size: (m_k, k) sensor indices
    Q: list[np.ndarray]           # per size: (m_k, dof, k) orthonormal bases
    dof: int


@dataclass
class FaultSetGlt:
    """Generalised likelihood test over fault sets of 1..``max_size`` sensors (see the module docstring).

    Parameters
    ----------
    alpha : float
        Level of the consistency test of each hypothesis (probability that the true set is rejected).
    max_size : int
        Largest set tested (also limited by ``dof - 1`` and by ``max_sets``).
    max_sets : int
        Budget of hypotheses per active set; sizes whose count would exceed it are not tested (a unit of
        96 axes has 4560 pairs but 142 880 triples).
    collinear_tol : float
        Sets whose normalised columns have a smallest singular value below this are not hypotheses.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> V = cone6().parity_matrix()              # unit noise: the normalised parity matrix
    >>> glt = FaultSetGlt(alpha=1e-3)
    >>> f = 12 * V[:, 1] - 15 * V[:, 4]          # two simultaneous faults (12 and -15 sigma), noise-free signal
    >>> glt.decide(f, V, 3).kind                 # one sample: other pairs explain it within the noise
    'ambiguous'
    >>> glt.decide(5 * f, V, 3).sensors          # the mean of 25 samples (evidence sqrt(25) f) separates them
    (1, 4)
    >>> d = glt.decide(12 * V[:, 2], V, 3)      # one fault: the pair (x2, y2) without z1 still explains it
    >>> d.kind, d.suspects
    ('ambiguous', (2, 3, 4))
    >>> glt.decide(24 * V[:, 2], V, 3).sensors   # four samples of evidence (twice the signal): named
    (2,)
    """

    alpha: float = 1e-3
    max_size: int = 2
    max_sets: int = 20000
    collinear_tol: float = 1e-3
    _designs: dict[Any, _Design] = field(default_factory=dict, repr=False)
    _thr: dict[Any, float] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
        if self.max_size < 1:
            raise ValueError(f"max_size must be at least 1, got {self.max_size}")

    # ---------------------------------------------------------------- design per active set
    def design(self, Vz: np.ndarray, dof: int) -> _Design:
        """Hypotheses, their orthonormal bases and thresholds for one active set (cached per set)."""
        V = np.ascontiguousarray(np.asarray(Vz, dtype=float)[:dof])
        key = (V.tobytes(), int(dof), V.shape)
        d = self._designs.get(key)
        if d is None:
            d = self._design(V, int(dof))
            if len(self._designs) > 256:
                self._designs.clear()
            self._designs[key] = d
        return d

    def _design(self, V: np.ndarray, dof: int) -> _Design:
        norms = np.linalg.norm(V, axis=0) if V.size else np.zeros(V.shape[1])
        act = np.flatnonzero(norms > 1e-12)
        U = np.zeros_like(V)
        U[:, act] = V[:, act] / norms[act]
        K = min(self.max_size, dof - 1, len(act))
        sizes, sets, Qs = [], [], []
        for k in range(1, K + 1):
            if comb(len(act), k) > self.max_sets:
                break
            S = np.array(list(combinations(act.tolist(), k)), dtype=np.int64).reshape(-1, k)
            B = U[:, S].transpose(1, 0, 2)                     # (m, dof, k)
            Q, _ = np.linalg.qr(B)
            sv = np.linalg.svd(B, compute_uv=False)            # (m, k)
            ok = sv[:, -1] > self.collinear_tol
            sizes.append(k)
            sets.append(S[ok])
            Qs.append(np.ascontiguousarray(Q[ok]))
        return _Design(sizes, sets, Qs, dof)

    # ---------------------------------------------------------------- per alarm
    def threshold(self, dof: int, size: int, samples: int = 1) -> float:
        """``c = chi2_{1 - alpha}(samples (dof - size))``: consistency threshold of a set of ``size``."""
        key = (int(dof), int(size), int(samples))
        c = self._thr.get(key)
        if c is None:
            c = float(chdtri(samples * (dof - size), self.alpha))  # chi2.isf
            if len(self._thr) > 4096:
                self._thr.clear()
            self._thr[key] = c
        return c

    def decide(self, evidence: np.ndarray, Vz: np.ndarray, dof: int) -> SetDecision:
        """Decide on one parity vector (or any unit-covariance evidence in parity space, (dof,) or padded)."""
        p = np.asarray(evidence, dtype=float)[:dof]
        return self.decide_scatter(np.outer(p, p), 1, Vz, dof)

    def decide_scatter(self, M: np.ndarray, samples: int, Vz: np.ndarray, dof: int) -> SetDecision:
        """Decide on ``samples`` parity vectors at once through their scatter ``M = sum_t p_t p_t^T`` (dof, dof).

        The fault on S may change size from sample to sample (its direction stays in ``span(V_S)``): the
        likelihood maximised over every ``b_S(t)`` leaves ``R_S = trace(M) - trace(Q_S^T M Q_S)``, distributed
        as ``chi2(samples (dof - |S|))`` when the fault is on S, so wrong sets are rejected more surely as
        evidence accumulates.
        """
        if dof < 2:
            return SetDecision("not_isolable")
        d = self.design(Vz, dof)
        M = np.asarray(M, dtype=float)[:dof, :dof]
        total = float(np.trace(M))
        best = float("inf")
        minimal: list[tuple[tuple[int, ...], float, int]] = []
        for k, S, Q in zip(d.sizes, d.sets, d.Q):
            if not len(S):
                continue
            c = self.threshold(dof, k, samples)
            MQ = M @ Q                                          # (m, dof, k)
            R = total - (Q * MQ).sum(axis=(1, 2))
            best = min(best, float(R.min()))
            cons = np.flatnonzero(R <= c)
            if not cons.size:
                continue
            smaller = [set(m[0]) for m in minimal]
            for cand, r in zip(S[cons].tolist(), R[cons].tolist()):
                if not smaller or not any(sm.issubset(cand) for sm in smaller):
                    minimal.append((tuple(cand), r, k))
        if len(minimal) == 1:
            S1, R1, k1 = minimal[0]
            return SetDecision("isolated", S1, S1, R1, k1)
        if minimal:
            sus = tuple(sorted({i for m in minimal for i in m[0]}))
            return SetDecision("ambiguous", (), sus, min(m[1] for m in minimal), minimal[0][2])
        return SetDecision("unexplained", (), (), best, 0)

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> list[SetDecision]:
        """:meth:`decide` for every row of P (N, dof) (campaigns and tests)."""
        return [self.decide(p, Vz, dof) for p in np.asarray(P)]


# ---------------------------------------------------------------------- theory
def _unit(V: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(V, axis=0)
    U = np.zeros_like(V)
    ok = n > 1e-12
    U[:, ok] = V[:, ok] / n[ok]
    return U


def _residual_noncentrality(U: np.ndarray, cols: tuple[int, ...], f: np.ndarray) -> float:
    """|P_S^perp f|^2: the part of the fault's parity signal f that the set's subspace leaves unexplained."""
    Q, _ = np.linalg.qr(U[:, list(cols)])
    r = f - Q @ (Q.T @ f)
    return float(r @ r)


def single_fault_rates(Vz: np.ndarray, j: int, m: float, alpha: float = 1e-3, p_fa: float = 1e-3,
                       max_size: int = 2) -> dict[str, float]:
    """Per-sample rates of :class:`FaultSetGlt` for a bias on sensor ``j`` of parity signal ``m`` (sigma).

    Returns ``detect`` (chi-square test, Daly, Gai & Harrison 1979), ``missed`` (detected and the true set
    rejected: exact, one integral), ``wrong_upper`` (a set without j isolated: ``min(missed, F + G)``),
    ``ambiguous_upper`` (``F + G + missed``), ``correct_lower`` (``detect - missed - F - G``), ``F`` (sum
    over the other singles of ``P(R_k <= c_1)``) and ``G`` (sum over the pairs without j of
    ``P(R_kl <= c_2)``). Outcomes not counted: a pair containing j isolated (at most ``missed``).

    >>> from rimu.geometry import dodecahedron6
    >>> r = single_fault_rates(dodecahedron6().parity_matrix(), 0, 14.0)
    >>> round(r["missed"], 6), r["correct_lower"] > 0.99
    (0.001, True)
    """
    from scipy.integrate import quad
    from scipy.stats import chi2, ncx2  # analysis only: not imported with the runtime (~40 MB)
    V = np.asarray(Vz, dtype=float)
    dof = V.shape[0]
    U = _unit(V)
    cd = float(chi2.isf(p_fa, dof))
    c1 = float(chi2.isf(alpha, dof - 1))
    lam = m * m
    detect = float(ncx2.sf(cd, dof, lam)) if lam > 0 else p_fa
    # P(R_j > c1 and T_j + R_j > cd), R_j ~ chi2(dof - 1), T_j ~ ncx2(1, m^2), independent
    missed = quad(lambda r: ncx2.sf(max(cd - r, 0.0), 1, lam) * chi2.pdf(r, dof - 1), c1, np.inf, limit=200)[0]
    f = m * U[:, j]
    others = [k for k in range(V.shape[1]) if k != j and np.linalg.norm(V[:, k]) > 1e-12]
    F = np.array([ncx2.cdf(c1, dof - 1, max(_residual_noncentrality(U, (k,), f), 1e-12)) for k in others])
    G = 0.0
    if max_size >= 2 and dof >= 3:
        c2 = float(chi2.isf(alpha, dof - 2))
        for kl in combinations(others, 2):
            if np.linalg.svd(U[:, list(kl)], compute_uv=False)[-1] > 1e-3:
                G += float(ncx2.cdf(c2, dof - 2, max(_residual_noncentrality(U, kl, f), 1e-12)))
    return {
        "detect": detect,
        "missed": float(missed),
        "wrong_upper": float(min(missed, F.sum() + G)),
        "ambiguous_upper": float(min(1.0, F.sum() + G + missed)),
        "correct_lower": float(max(detect - missed - F.sum() - G, 0.0)),
        "F": float(F.sum()),
        "G": float(G),
    }


def set_fault_rates(Vz: np.ndarray, sensors: tuple[int, ...], b: np.ndarray, alpha: float = 1e-3) -> dict[str, float]:
    """Per-sample rates for a fault on a *set* (bias ``b`` in sigma of each sensor, normalised parity columns).

    The fault signal is ``f = V_S b``. Returns ``rejected`` (the true set inconsistent: exactly ``alpha``),
    ``single_consistent`` (sum over singles k of ``P(R_k <= c_1)``: the rule then decides at size 1) and
    ``other_set_consistent`` (sum over the other sets S' of the same size of ``P(R_S' <= c_|S|)``), so that
    correct isolation is at least ``1 - rejected - single_consistent - other_set_consistent`` once detection
    is certain.
    """
    from scipy.stats import chi2, ncx2  # analysis only: not imported with the runtime (~40 MB)
    V = np.asarray(Vz, dtype=float)
    dof = V.shape[0]
    U = _unit(V)
    S = tuple(sorted(int(s) for s in sensors))
    f = V[:, list(S)] @ np.asarray(b, dtype=float)
    act = [k for k in range(V.shape[1]) if np.linalg.norm(V[:, k]) > 1e-12]
    out = {"rejected": float(alpha), "single_consistent": 0.0, "other_set_consistent": 0.0}
    for size in range(1, len(S)):
        c = float(chi2.isf(alpha, dof - size))
        for T in combinations(act, size):
            out["single_consistent"] += float(ncx2.cdf(c, dof - size, max(_residual_noncentrality(U, T, f), 1e-12)))
    c = float(chi2.isf(alpha, dof - len(S)))
    for T in combinations(act, len(S)):
        if T != S and np.linalg.svd(U[:, list(T)], compute_uv=False)[-1] > 1e-3:
            out["other_set_consistent"] += float(ncx2.cdf(c, dof - len(S), max(_residual_noncentrality(U, T, f),
                                                                                1e-12)))
    return out
