"""Cho & Park 2005: calibration of a redundant IMU built of sub-units, from a multi-position and a rate test.

For sensor i of sub-unit j (sub-unit basis ``C_j = mat_sb_mb``), Cho & Park 2005, Eq. 3::

    SF_i y_i = m_i . (C_j u) + b_i + v_i

Accelerometers (multi-position test, Eq. 5-10): the mean output of each static position k is
``ybar_k = [s_k 1] [m_i/SF_i; b_i/SF_i]`` with ``s_k = C_j f_k`` (Eq. 5-6); the four coefficients follow by
least squares (Eq. 7-9, ``S^j`` stacks the rows), the scale factor from the unit-norm constraint (Eq. 10),
then misalignment and bias.

Gyros (rate test, Eq. 11-15): steps k, k+1 turn about the same axis at +w and -w; the difference of their
mean outputs is ``[r_k] [m_i/SF_i]`` with ``r_k = C_j (w_k - w_{k+1})`` (Eq. 11-12), so bias and the
Earth-rate component along the (fixed, vertical) table axis cancel, and the rotating horizontal Earth rate
averages out over whole turns. Least squares over the pairs (Eq. 13-15, ``R^j``). Biases from the static
positions (Eq. 16-17): ``b_i = SF_i mean(y)``.

Earth rate in Eq. 17: a gyro at rest senses the Earth rate, ``SF_i y_i = m_i . (C_j W_e) + b_i``; Eq. 17 as
printed attributes all of it to the bias (for a MEMS gyro of 0.1 deg/s resolution it is below the noise).
rimu subtracts ``w_i . W_e`` for every static position whose attitude is known and the session's latitude is
set, and says so in the result's notes; without them it uses Eq. 17 as printed and says that instead.

Weights: positions and steps may differ in length; each mean is weighted by its number of samples
(generalised least squares with the per-sample noise ``sigma``), which for equal lengths is exactly Eq. 7
and Eq. 13. Covariances follow from ``sigma^2 (S^T W S)^-1`` and ``(R^T W R)^-1`` (Eq. 19).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError
from ..session import Segment, Session, SessionStatistics, earth_rate_ln
from .estimate import CalibrationResult, _sigma_for, make_sensor_fit, segment_residuals
from .lsq import LsqResult
from .model import ErrorModel, SensorContext, contexts
from .steps import StepCheck, linear_step_check

__all__ = ["ChoPark", "accel_rows", "gyro_rows", "rate_pairs", "rate_step_check"]


def rate_pairs(segments: Sequence[Segment], tol: float = 1e-6) -> tuple[list[tuple[Segment, Segment]], list[str]]:
    """Pairs of rate segments turning about one axis at +w and -w (Cho & Park 2005, Eq. 11-12).

    Each rate segment is paired with the first later unpaired one whose table rate is its negative (relative
    tolerance ``tol``). Returns the pairs and the labels left unpaired.
    """
    rate = [s for s in segments if s.kind == "rate"]
    used: set[int] = set()
    pairs = []
    for a, sa in enumerate(rate):
        if a in used:
            continue
        wa = sa.table_rate()
        for b in range(a + 1, len(rate)):
            if b in used:
                continue
            wb = rate[b].table_rate()
            if np.linalg.norm(wa + wb) <= tol * max(np.linalg.norm(wa), 1e-300):
                pairs.append((sa, rate[b]))
                used |= {a, b}
                break
    left = [s.label for i, s in enumerate(rate) if i not in used]
    return pairs, left


def accel_rows(segments: Sequence[Segment], C: np.ndarray, gravity: float) -> tuple[np.ndarray, list[Segment]]:
    """``S^j`` of Cho & Park 2005, Eq. 6 and 8: rows ``[C_j f_k, 1]`` of the static positions with known force."""
    rows, used = [], []
    for s in segments:
        if s.kind != "static":
            continue
        f = s.specific_force(gravity)
        if f is None:
            continue
        fbar = f[0] if f.strides[0] == 0 else f.mean(axis=0)  # a static position's force is one vector
        rows.append(np.concatenate([C @ fbar, [1.0]]))
        used.append(s)
    return np.array(rows).reshape(-1, 4), used


def gyro_rows(pairs: Sequence[tuple[Segment, Segment]], C: np.ndarray) -> np.ndarray:
    """``R^j`` of Cho & Park 2005, Eq. 12 and 14: rows ``C_j (w_k - w_{k+1})``."""
    return np.array([C @ (a.table_rate() - b.table_rate()) for a, b in pairs]).reshape(-1, 3)


class ChoPark:
    """The calibration of Cho & Park 2005 (Eq. 5-17) for any geometry built of sub-units.

    Parameters
    ----------
    sigma : dict[str, float or array], optional
        Known per-sample raw noise per instrument; default estimated from the static segments.
    earth_rate : bool
        Subtract the Earth rate from the static gyro outputs where attitude and latitude are known (Eq. 17
        as printed leaves it in the bias).
    instruments : sequence of str, optional
        Default: every instrument of the session.
    held_out : bool
        Check the misalignment step (Eq. 7 and 13 against the nominal axes times a scale) with each position or
        +/- pair left out in turn (:mod:`rimu.calibration.steps`); a step that raises the held-out residual is not
        applied and a note says why with the figures (default True).

    Examples
    --------
    >>> from rimu.sim import Simulator, cho_park_procedure
    >>> run = Simulator(seed=1).run(cho_park_procedure(duration=5.0))
    >>> res = ChoPark().fit(run.session)
    >>> sorted(res.instruments)
    ['accel', 'gyro']
    >>> cal = res.to_calibration()
    >>> bool(abs(cal["gyro"].scale[0] / run.truth["gyro"].scale[0] - 1) < 1e-2)
    True
    """

    method = "Cho & Park 2005"

    def __init__(self, sigma: dict[str, Any] | None = None, earth_rate: bool = True,
                 instruments: Sequence[str] | None = None, held_out: bool = True) -> None:
        self.sigma = sigma
        self.held_out = held_out
        self.earth_rate = earth_rate
        self.instruments = instruments

    def fit(self, session: Session) -> CalibrationResult:
        """Estimate SF, misalignment and bias of every sensor; IdentifiabilityError before any fit if the
        procedure cannot identify them."""
        insts = list(self.instruments or session.instruments)
        self.check(session, insts)
        stats = SessionStatistics(session)  # each segment's sums once, shared by the noise level and the means
        notes: list[str] = []
        steps: list[dict[str, Any]] = []
        out: dict[str, LsqResult] = {}
        for inst in insts:
            sig = _sigma_for(self.sigma, session, inst, stats)
            if inst == "accel":
                out[inst], check = self._fit_accel(session, sig, stats)
            else:
                out[inst], note, check = self._fit_gyro(session, sig, stats)
                notes.append(note)
            notes.append(check.note() if check is not None else
                         f"{inst}: the misalignment step could not be checked on held-out segments (too few positions "
                         "or +/- rate pairs: leaving one out leaves it unidentifiable); applied")
            if check is not None:
                steps.append(check.to_dict())
        return CalibrationResult(self.method, out, session.raw_unit, notes, {"steps": steps})

    # ------------------------------------------------------------------ identifiability
    def check(self, session: Session, instruments: Sequence[str] | None = None) -> None:
        """Raise IdentifiabilityError naming the parameters the session's segments cannot identify."""
        for inst in instruments or session.instruments:
            if inst == "accel":
                rows = _subunit_rows(contexts(session, inst),
                                     lambda C: accel_rows(session.segments, C, session.gravity)[0])
            else:
                pairs, _ = rate_pairs(session.segments)
                rows = _subunit_rows(contexts(session, inst), lambda C, p=pairs: gyro_rows(p, C))
            for ctx, M, full in rows:
                if full:  # full column rank (the same for every sub-unit: C_j is orthonormal)
                    continue
                if inst == "accel":
                    _named_rank_check(M, ctx, inst, "at least four static positions with known attitude whose "
                                      "specific forces are not coplanar (Cho & Park Eq. 7)", True)
                else:
                    _named_rank_check(M, ctx, inst, "+/- rate pairs about three independent axes (Cho & Park Eq. 13)",
                                      False)
            if inst != "accel" and not any(s.kind == "static" for s in session.segments):
                raise IdentifiabilityError(
                    f"gyro: no static position for the biases (Cho & Park Eq. 17); cannot estimate "
                    f"{[f'{c.name}.bias' for c in contexts(session, inst)]}",
                    [f"{c.name}.bias" for c in contexts(session, inst)])

    # ------------------------------------------------------------------ accelerometers
    def _fit_accel(self, session: Session, sig: np.ndarray, stats: SessionStatistics
                   ) -> tuple[LsqResult, StepCheck | None]:
        model = ErrorModel.base()
        fits = []
        used: list[Segment] = []
        cache: dict = {}
        by_su: dict[int, tuple] = {}
        rows = []
        for ctx in contexts(session, "accel"):
            su = ctx.geometry.subunit_of(ctx.index)
            if id(su) not in by_su:  # the rows, weights and means of a sub-unit serve all its sensors
                C = su.mat_sb_mb
                S, used = accel_rows(session.segments, C, session.gravity)  # Eq. 6, 8
                W = np.array([s.n_samples for s in used], dtype=float)
                A = np.linalg.inv(S.T @ (W[:, None] * S))
                T = np.zeros((4, 4))
                T[:3, :3] = C.T  # w (MB) = C^T (m/SF)
                T[3, 3] = 1.0
                Ybar = np.array([stats.mean(s, "accel") for s in used]).reshape(len(used), -1)  # Eq. 9, all sensors
                by_su[id(su)] = (S, used, W, A, T, Ybar, A @ S.T @ (W[:, None] * Ybar))
            S, used, W, A, T, Ybar, X = by_su[id(su)]
            # the step's input: the nominal axis (sub-unit coordinates) times a scale, plus the bias
            e = ctx.geometry.nominal_rows()[ctx.index]
            Tr = np.zeros((4, 2))
            Tr[:3, 0], Tr[3, 1] = e, 1.0
            rows.append((ctx, S, W, T, Ybar[:, ctx.index], X[:, ctx.index], A, Tr))
        check = None
        if self.held_out:
            check = linear_step_check([r[1] for r in rows], [r[1] @ r[7] for r in rows], [r[4] for r in rows],
                                      rows[0][2], [1.0 / max(np.linalg.norm(r[5][:3]), 1e-300) for r in rows],
                                      instrument="accel", step="misalignment", against="scale and bias alone",
                                      quantity="specific_force", groups="positions",
                                      fallback="scale and bias alone, axes nominal")
        reduce = check is not None and not check.applied
        for ctx, S, W, T, Y, x, A, Tr in rows:
            s2 = float(sig[ctx.index]) ** 2
            if reduce:  # Eq. 7 with the nominal axis: two coefficients
                Sr = S @ Tr
                Ar = np.linalg.inv(Sr.T @ (W[:, None] * Sr))
                x, A = Tr @ (Ar @ Sr.T @ (W * Y)), Tr @ Ar @ Tr.T
            cov_x = s2 * A  # Eq. 7 (weighted by samples per position)
            chi2 = float(np.sum(W * (Y - S @ x) ** 2)) / s2
            beta, bcov = T @ x, T @ cov_x @ T.T
            res = segment_residuals(model, ctx, session.segments, beta, "accel", cache)
            fits.append(make_sensor_fit(model, ctx, beta, bcov, np.sqrt(s2), self.sigma is not None, len(Y), chi2, res))
        return LsqResult("accel", model, fits, [s.label for s in used], {}), check

    # ------------------------------------------------------------------ gyros
    def _fit_gyro(self, session: Session, sig: np.ndarray, stats: SessionStatistics
                  ) -> tuple[LsqResult, str, StepCheck | None]:
        model = ErrorModel.base()
        pairs, unpaired = rate_pairs(session.segments)
        statics = [s for s in session.segments if s.kind in ("static", "static_unknown")]
        fits = []
        earth_used = 0
        cache: dict = {}
        we = np.zeros((len(statics), 3))
        for k, s in enumerate(statics):
            if self.earth_rate and s.mat_ln_mb is not None and session.latitude is not None:
                we[k] = s.mat_ln_mb.T @ earth_rate_ln(session.latitude)
                earth_used += 1
        # the pair differences (Eq. 15) and static means (Eq. 16-17) of every sensor at once
        Yg_all = np.array([stats.mean(a, "gyro") - stats.mean(b, "gyro") for a, b in pairs]).reshape(len(pairs), -1)
        ybar_all = np.array([stats.mean(s, "gyro") for s in statics]).reshape(len(statics), -1)
        V = np.array([1.0 / a.n_samples + 1.0 / b.n_samples for a, b in pairs])
        N = np.array([s.n_samples for s in statics], dtype=float)
        wbar = (N @ we) / N.sum()
        by_su: dict[int, tuple] = {}
        check = self._gyro_check(session, pairs, Yg_all, V) if self.held_out else None
        reduce = check is not None and not check.applied
        for ctx in contexts(session, "gyro"):
            su = ctx.geometry.subunit_of(ctx.index)
            C = su.mat_sb_mb
            i = ctx.index
            s2 = float(sig[i]) ** 2
            if id(su) not in by_su:
                R = gyro_rows(pairs, C)  # Eq. 12, 14
                A = np.linalg.inv(R.T @ (R / V[:, None]))
                by_su[id(su)] = (R, A, A @ R.T @ (Yg_all / V[:, None]))
            R, A, MS = by_su[id(su)]
            Yg = Yg_all[:, i]
            m_sf = MS[:, i]  # Eq. 13 (weighted by the variance of each difference)
            cov_m = s2 * A
            if reduce:  # Eq. 13 with the nominal axis e (sub-unit coordinates): one coefficient, the scale
                e = ctx.geometry.nominal_rows()[i]
                re = R @ e
                a = float(re @ (Yg / V) / (re @ (re / V)))
                m_sf, cov_m = a * e, s2 * np.outer(e, e) / float(re @ (re / V))
            chi2 = float(np.sum((Yg - R @ m_sf) ** 2 / V)) / s2
            w = C.T @ m_sf
            cov_w = C.T @ cov_m @ C
            # Eq. 16-17: bias from the static positions, Earth rate subtracted where known
            ybar = ybar_all[:, i]
            c = float((N @ ybar) / N.sum() - w @ wbar)
            var_c = s2 / N.sum() + wbar @ cov_w @ wbar
            chi2 += float(np.sum(N * (ybar - w @ we.T - c) ** 2)) / s2
            beta = np.concatenate([w, [c]])
            bcov = np.zeros((4, 4))
            bcov[:3, :3] = cov_w
            bcov[:3, 3] = bcov[3, :3] = -cov_w @ wbar
            bcov[3, 3] = var_c
            res = segment_residuals(model, ctx, session.segments, beta, "gyro", cache)
            n_obs = len(Yg) + len(statics)
            fits.append(make_sensor_fit(model, ctx, beta, bcov, np.sqrt(s2), self.sigma is not None, n_obs, chi2, res))
        if earth_used == len(statics):
            note = f"gyro: Earth rate subtracted from all {len(statics)} static positions (Eq. 17 with W_e known)"
        elif earth_used:
            note = (f"gyro: Earth rate subtracted from {earth_used} of {len(statics)} static positions; the others "
                    "lack attitude or latitude and their Earth rate is counted as bias (Eq. 17 as printed)")
        else:
            note = ("gyro: Earth rate NOT subtracted (attitude or latitude unknown); the biases include the mean "
                    "Earth rate seen at the static positions (Eq. 17 as printed)")
        if unpaired:
            note += f"; rate segments without a -w partner, not used: {unpaired}"
        used = [s.label for p in pairs for s in p] + [s.label for s in statics]
        return LsqResult("gyro", model, fits, used, {x: "no -w partner" for x in unpaired}), note, check

    def _gyro_check(self, session: Session, pairs: Sequence[tuple[Segment, Segment]], Yg_all: np.ndarray,
                    V: np.ndarray) -> StepCheck | None:
        """The misalignment step of the rate test (Eq. 13 against the nominal axes times a scale) checked with
        each +/- pair left out in turn (:func:`rate_step_check`)."""
        return rate_step_check(session, "gyro", pairs, Yg_all, V)


def rate_step_check(session: Session, inst: str, pairs: Sequence[tuple[Segment, Segment]], Yg_all: np.ndarray,
                    V: np.ndarray) -> StepCheck | None:
    """The misalignment step of the rate test (Cho & Park 2005 Eq. 13, de Oliveira et al. 2012 Eq. 18: the pair
    differences ``G = R m/SF``) against the nominal axes times a scale, each +/- pair left out in turn; residuals
    in rad/s of the half difference. None when too few pairs to leave one out."""
    full, reduced, Y, to_si = [], [], [], []
    for ctx in contexts(session, inst):
        C = ctx.geometry.subunit_of(ctx.index).mat_sb_mb
        R = gyro_rows(pairs, C)
        e = ctx.geometry.nominal_rows()[ctx.index]
        y = Yg_all[:, ctx.index]
        full.append(R)
        reduced.append((R @ e)[:, None])
        Y.append(y)
        m = np.linalg.lstsq(R / np.sqrt(V)[:, None], y / np.sqrt(V), rcond=None)[0]
        to_si.append(0.5 / max(float(np.linalg.norm(m)), 1e-300))
    return linear_step_check(full, reduced, Y, 1.0 / V, to_si, instrument=inst, step="misalignment",
                             against="scale alone, axes nominal", quantity="rate", groups="+/- rate pairs",
                             fallback="scale and bias alone, axes nominal")


def _subunit_rows(ctxs: Sequence[SensorContext], rows_of: Any) -> list[tuple[SensorContext, np.ndarray, bool]]:
    """``(ctx, M, full)`` per sensor: the rows ``M = rows_of(C_j)`` of its sub-unit and whether they have full
    column rank by the criterion of :func:`_named_rank_check` (one SVD per sub-unit, not per sensor)."""
    by_su: dict[int, tuple[np.ndarray, bool]] = {}
    out = []
    for ctx in ctxs:
        su = ctx.geometry.subunit_of(ctx.index)
        hit = by_su.get(id(su))
        if hit is None:
            M = rows_of(su.mat_sb_mb)
            full = M.shape[0] >= M.shape[1]
            if full:
                sv = np.linalg.svd(M, compute_uv=False)
                full = bool(sv[-1] > 1e-9 * max(sv[0], 1e-300))
            hit = by_su[id(su)] = (M, full)
        out.append((ctx, hit[0], hit[1]))
    return out


def _named_rank_check(M: np.ndarray, ctx: SensorContext, inst: str, what: str, with_bias: bool) -> None:
    """Raise IdentifiabilityError naming the physical parameters (scale, misalignment angles, bias) that the
    rows M (sub-unit coordinates, plus a bias column when ``with_bias``) cannot separate."""
    p = M.shape[1]
    r = ctx.geometry.nominal_rows()[ctx.index]
    E, mis_names = ctx.geometry.off_axis_basis(ctx.index)
    n = ctx.name
    null: list[np.ndarray] = []
    if M.shape[0] == 0:
        null = list(np.eye(p))
    else:
        _, s, Vt = np.linalg.svd(M, full_matrices=True)
        s = np.concatenate([s, np.zeros(p - len(s))])
        null = [Vt[k] for k in range(p) if s[k] <= 1e-9 * max(s[0], 1e-300)]
    if not null:
        return
    involved: list[str] = []
    for v in null:
        if abs(v[:3] @ r) > 1e-6:
            involved.append(f"{n}.scale")
        for e, nm in zip(E, mis_names):
            if abs(v[:3] @ e) > 1e-6:
                involved.append(f"{n}.{nm}")
        if with_bias and abs(v[3]) > 1e-6:
            involved.append(f"{n}.bias")
    involved = sorted(set(involved), key=involved.index)
    raise IdentifiabilityError(
        f"{inst}: the procedure cannot identify {involved} ({M.shape[0]} rows, rank {p - len(null)} of {p}); "
        f"it needs {what}", involved)
