"""Zhang et al. 2010: norm-based multi-position calibration of a gyro triad and an accelerometer triad,
with the inter-triad misalignment from rotation axes seen by both. No attitude knowledge is needed.

Sensor models (Zhang et al. 2010, Eq. 1-6)::

    accel:  y_a = K_a T_p^a s^p + b_a            (raw)
    gyro:   y_g = K_g T_o^g R_p^o w^p + b_g

K diagonal scale factors (raw per SI unit), T lower triangular with unit rows (the sensing axes),
``R_p^o`` the small rotation between the gyro frame o and the platform frame p.

Frames and how they map to rimu. Zhang's platform frame p is defined by the accelerometers: x_p along the
x accelerometer, y_p in the plane of the x and y accelerometers, z_p completing a right-handed frame. Without
attitude knowledge nothing else can define it. rimu's master-body frame MB is therefore *taken to be* p:
rimu's accelerometer axis rows are the rows of T_p^a, so ``x.mis_y = x.mis_z = y.mis_z = 0`` by definition
(reported with zero variance), and Zhang's misalignment angles are
``alpha_yz = y.mis_x``, ``alpha_zy = -z.mis_x``, ``alpha_zx = z.mis_y``. The gyro axes in MB are the rows of
``T_o^g R_p^o``; rimu's SF is ``1 / k`` (SI per raw unit) and rimu's bias is ``SF * b`` (SI).
:func:`platform_frame` expresses any triad calibration in Zhang's p frame (used to compare with a truth given in
another MB frame) and :func:`zhang_parameters` gives Zhang's parameter set (k, alpha, gamma, b, theta).

Steps (each names its equations):

1. accelerometers, static positions: linear least squares for the symmetric M^A (Eq. 12-14), decomposed into
   ``(K_a T_p^a)^-1`` (lower triangular, a "reversed" Cholesky factor) and b_a;
2. gyros, CW/CCW rotation pairs: integrated differences phi (Eq. 16-18), linear least squares for M^G
   (Eq. 19-22), decomposed into ``(K_g T_o^g)^-1``;
3. gyro biases from the static positions (Eq. 23-25);
4. nonlinear refinement of both triads (scipy.optimize.least_squares) on the norm residuals of Eq. 7-8 and
   Eq. 19, weighted by their noise; its Jacobian gives the covariance;
5. inter-triad misalignment: rotation axes from the gyros (Eq. 41) and from the accelerometers (the null
   vector of ``[s^p(t)^T, -1]``, Eq. 42-47), then ``R_p^o`` by the SVD solution of Wahba's problem
   (Eq. 39-40 generalised to more than two axes, as the paper suggests).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError, SessionFormatError
from ..session import Segment, Session, skew
from ..units import EARTH_RATE
from .estimate import CalibrationResult, _sigma_for, make_sensor_fit
from .lsq import LsqResult, central_jacobian
from .model import ErrorModel, contexts
from .result import Calibration, InstrumentCalibration

__all__ = [
    "Zhang",
    "accel_rotation_axis",
    "lower_factor",
    "platform_frame",
    "rotation_pairs",
    "solve_ma",
    "solve_mg",
    "wahba",
    "zhang_parameters",
]


# ---------------------------------------------------------------------- algebra
def lower_factor(M: np.ndarray) -> np.ndarray:
    """Lower-triangular A with positive diagonal and ``A^T A = M`` (the factor of Zhang et al. 2010, Eq. 14
    and 22: ``M = [(K T)^-1]^T (K T)^-1`` with K T lower triangular)."""
    P = np.eye(3)[::-1]
    L = np.linalg.cholesky(P @ M @ P)  # P M P = L L^T
    U = P @ L @ P  # upper triangular, M = U U^T
    return U.T


def _quad_rows(y: np.ndarray) -> np.ndarray:
    x, yy, z = y[:, 0], y[:, 1], y[:, 2]
    return np.column_stack([x * x, yy * yy, z * z, 2 * x * yy, 2 * x * z, 2 * yy * z])


def solve_ma(ybar: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Zhang et al. 2010, Eq. 12-14: (A = (K_a T_p^a)^-1, b_a) from the mean raw outputs of static positions.

    Eq. 12-13 is posed homogeneously, ``(y - b)^T M^A (y - b) = g^2`` as ``D v = 0`` under the normalisation
    ``|vec(M^A)| = 1`` (:func:`rimu.calibration.handheld.ellipsoid_fit`), so it cannot return the trivial
    solution and holds for nine positions (exact) as for any larger noisy set (least squares); the scale is then
    set by the norms, and Eq. 14 factors M^A by the reversed Cholesky factor. Nine positions at least.

    >>> A = np.array([[1e-3, 0, 0], [2e-6, 1.1e-3, 0], [-3e-6, 4e-6, 0.9e-3]])
    >>> b = np.array([100.0, -50.0, 20.0])
    >>> rng = np.random.default_rng(1)
    >>> u = rng.normal(size=(40, 3)); u /= np.linalg.norm(u, axis=1)[:, None]
    >>> ybar = (9.8 * u) @ np.linalg.inv(A).T + b
    >>> A_, b_ = solve_ma(ybar, 9.8)
    >>> bool(np.allclose(A_, A)), bool(np.allclose(b_, b))
    (True, True)
    """
    from .handheld import ellipsoid_fit

    ybar = np.asarray(ybar, dtype=float)
    if ybar.shape[0] < 9:
        raise IdentifiabilityError(f"accel: {ybar.shape[0]} static positions; Zhang's Eq. 13 needs at least nine "
                                   "(the six axes up and down and three in-plane 45 deg positions)",
                                   ["x.scale", "y.scale", "z.scale", "y.mis_x", "z.mis_x", "z.mis_y",
                                    "x.bias", "y.bias", "z.bias"])
    sc = float(np.median(np.linalg.norm(ybar - ybar.mean(axis=0), axis=1)))
    z = (ybar - ybar.mean(axis=0)) / sc
    D = np.column_stack([_quad_rows(z), z, np.ones(len(z))])
    if np.linalg.matrix_rank(D, tol=1e-9 * np.abs(D).max()) < 9:
        raise IdentifiabilityError("accel: the static positions do not identify M^A (Zhang Eq. 13); add positions "
                                   "with gravity in each axis plane", ["y.mis_x", "z.mis_x", "z.mis_y"])
    b, M = ellipsoid_fit(ybar)
    q = np.einsum("ki,ij,kj->k", ybar - b, M, ybar - b)
    M = M * g**2 / float(np.mean(q))
    return lower_factor(M), b


def solve_mg(phi: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Zhang et al. 2010, Eq. 19-22: A = (K_g T_o^g)^-1 from integrated CW-minus-CCW outputs ``phi`` (raw * s)
    and the norms of the table's angle differences ``2 |w_r| t_r`` (rad)."""
    phi = np.asarray(phi, dtype=float)
    if phi.shape[0] < 6:
        raise IdentifiabilityError(f"gyro: {phi.shape[0]} CW/CCW rotation pairs; Zhang's Eq. 21 needs at least six "
                                   "(three axes and three in-plane 45 deg axes)",
                                   ["x.scale", "y.scale", "z.scale", "y.mis_x", "z.mis_x", "z.mis_y"])
    sc = float(np.median(np.linalg.norm(phi, axis=1)))
    R = _quad_rows(phi / sc)
    if np.linalg.matrix_rank(R, tol=1e-10 * np.abs(R).max()) < 6:
        raise IdentifiabilityError("gyro: the rotation axes do not identify M^G (Zhang Eq. 21); rotate about three "
                                   "axes and three in-plane diagonals", ["y.mis_x", "z.mis_x", "z.mis_y"])
    m, *_ = np.linalg.lstsq(R, (np.asarray(angles, float) / sc) ** 2, rcond=None)
    M = np.array([[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]])
    if not np.all(np.linalg.eigvalsh(M) > 0):
        raise IdentifiabilityError("gyro: the estimated M^G is not positive definite (Zhang Eq. 22)")
    return lower_factor(M)


def rotation_pairs(segments: Sequence[Segment]) -> list[tuple[Segment, Segment, np.ndarray]]:
    """CW/CCW pairs: segments of kind 'angle' (or 'rate', angle = rate * duration) about one axis with opposite
    angles. Returns (cw, ccw, angle difference vector in MB, rad) -- Zhang et al. 2010, Eq. 16-18."""
    def angle(s: Segment) -> np.ndarray | None:
        if s.kind == "angle":
            return np.asarray(s.angle_mb, float).reshape(-1, 3)[-1]
        if s.kind == "rate":
            return s.table_rate() * s.n_samples / _fs(s)
        return None

    rot = [(s, angle(s)) for s in segments if angle(s) is not None]
    used: set[int] = set()
    out = []
    for a, (sa, va) in enumerate(rot):
        if a in used:
            continue
        for b in range(a + 1, len(rot)):
            sb, vb = rot[b]
            if b not in used and np.linalg.norm(va + vb) <= 1e-6 * np.linalg.norm(va):
                out.append((sa, sb, va - vb))
                used |= {a, b}
                break
    return out


def _fs(s: Segment) -> float:
    return (s.n_samples - 1) / s.duration if s.duration > 0 else 1.0


def accel_rotation_axis(f: np.ndarray) -> tuple[np.ndarray, float]:
    """Zhang et al. 2010, Eq. 42-47: the rotation axis l^p from specific forces f (N, 3) seen during a rotation
    about a fixed axis: the null vector of ``[f^T, -1]``. Returns (unit axis, angular variance estimate)."""
    A = np.column_stack([f, -np.ones(len(f))])
    sc = np.array([1.0, 1.0, 1.0, float(np.median(np.linalg.norm(f, axis=1)))])
    _, _, Vt = np.linalg.svd(A * sc, full_matrices=False)
    v = Vt[-1] * sc
    n = float(np.linalg.norm(v[:3]))
    l = v[:3] / n
    # first-order spread of the axis from the residual (total least squares)
    r = (A @ v) / n
    s2 = float(r @ r) / max(len(f) - 4, 1)
    F = f - f.mean(axis=0)
    P = np.eye(3) - np.outer(l, l)
    info = P @ F.T @ F @ P
    var = float(s2 * np.trace(np.linalg.pinv(info, rcond=1e-10)) / 2.0)
    return l, var


def wahba(lo: np.ndarray, lp: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Rotation R with ``lo_k = R lp_k`` in the weighted least-squares sense (Zhang et al. 2010, Eq. 39-40 for
    more than two axes: the SVD solution of Wahba's problem, their ref. [18])."""
    w = np.ones(len(lo)) if w is None else np.asarray(w, float)
    B = (lo * w[:, None]).T @ lp
    U, _, Vt = np.linalg.svd(B)
    d = np.sign(np.linalg.det(U @ Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def platform_frame(cal_accel: InstrumentCalibration) -> np.ndarray:
    """Rotation Q (MB -> Zhang's p frame) defined by an accelerometer triad calibration: x_p along the x
    accelerometer, y_p in the x-y accelerometer plane (Zhang et al. 2010, Section 2)."""
    A = cal_accel.axes_mb()
    x = A[0] / np.linalg.norm(A[0])
    z = np.cross(x, A[1])
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    return np.vstack([x, y, z])


def _lq(W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W = L Q with L lower triangular (positive diagonal), Q orthogonal."""
    Q, R = np.linalg.qr(W.T)
    s = np.sign(np.diag(R))
    s[s == 0] = 1.0
    return (R.T * s), (Q * s).T


def zhang_parameters(cal: Calibration) -> dict[str, np.ndarray]:
    """Zhang et al. 2010's parameter set of a triad calibration, whatever MB frame it is in.

    Returns k_a, k_g (SI per raw unit, i.e. rimu's SF), alpha (yz, zy, zx) and gamma (yz, zy, zx) in rad,
    b_a (m/s^2), b_g (rad/s) and theta (x, y, z) in rad (``R_p^o ~ I + skew(theta)``, Eq. 6).
    """
    acc, gyr = cal["accel"], cal["gyro"]
    La, Qa = _lq(acc.axes_mb() / acc.scale[:, None])  # K_a T_p^a, MB -> p
    Lg, Qg = _lq(gyr.axes_mb() / gyr.scale[:, None])  # K_g T_o^g, MB -> o
    Rpo = Qg @ Qa.T
    Ta = La / np.linalg.norm(La, axis=1)[:, None]
    Tg = Lg / np.linalg.norm(Lg, axis=1)[:, None]
    th = np.array([Rpo[2, 1] - Rpo[1, 2], Rpo[0, 2] - Rpo[2, 0], Rpo[1, 0] - Rpo[0, 1]]) / 2.0
    return {
        "k_a": 1.0 / np.linalg.norm(La, axis=1), "k_g": 1.0 / np.linalg.norm(Lg, axis=1),
        "alpha": np.array([Ta[1, 0], -Ta[2, 0], Ta[2, 1]]), "gamma": np.array([Tg[1, 0], -Tg[2, 0], Tg[2, 1]]),
        "b_a": acc.bias.copy(), "b_g": gyr.bias.copy(), "theta": th,
    }


# ---------------------------------------------------------------------- estimator
class Zhang:
    """Zhang et al. 2010 for a gyro triad and an accelerometer triad (three sensors each, one sub-unit).

    Parameters
    ----------
    sigma : dict[str, float or array], optional
        Known per-sample raw noise per instrument (default: estimated from the static segments).
    refine : bool
        Run the nonlinear refinement (step 4); without it the covariance is still from the refinement's
        Jacobian at the closed-form estimate.
    earth_rate : float
        Magnitude of the Earth rate (rad/s) the static gyro norms equal (Eq. 23).

    Examples
    --------
    >>> from rimu.geometry import triad3
    >>> from rimu.sim import Simulator, zhang_scheme
    >>> g = triad3()
    >>> run = Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.01, seed=2).run(
    ...     zhang_scheme(static_duration=10.0, rotation_duration=36.0))
    >>> res = Zhang().fit(run.session)
    >>> bool(abs(res.to_calibration()["gyro"].scale[2] / run.truth["gyro"].scale[2] - 1) < 1e-4)
    True
    """

    method = "Zhang et al. 2010"

    def _fit_accel_only(self, session: Session, statics: list[Segment]) -> CalibrationResult:
        return _accel_only(self, session, statics)

    def __init__(self, sigma: dict[str, Any] | None = None, refine: bool = True,
                 earth_rate: float = EARTH_RATE) -> None:
        self.sigma = sigma
        self.refine = refine
        self.earth_rate = earth_rate

    def fit(self, session: Session) -> CalibrationResult:
        from scipy.optimize import least_squares

        for k in ("gyro", "accel"):
            g = session.geometries.get(k)
            if (g is None and k == "accel") or (g is not None and g.n != 3):
                raise SessionFormatError(f"Zhang et al. 2010 calibrates a gyro triad and an accelerometer triad; "
                                         f"the session's {k} geometry is {None if g is None else g.name}")
        gg = session.gravity
        statics = [s for s in session.segments if s.kind in ("static", "static_unknown")]
        pairs = rotation_pairs(session.segments)
        if "gyro" not in session.geometries or not pairs:
            return self._fit_accel_only(session, statics)
        sa = _sigma_for(self.sigma, session, "accel")
        sg = _sigma_for(self.sigma, session, "gyro")
        ya = np.array([s.raw["accel"].mean(axis=0) for s in statics]).reshape(-1, 3)
        yg = np.array([s.raw["gyro"].mean(axis=0) for s in statics]).reshape(-1, 3)
        Ns = np.array([s.n_samples for s in statics], dtype=float)
        # 1. accelerometers (Eq. 12-14)
        Aa, ba = solve_ma(ya, gg)
        # 2. gyros (Eq. 16-22)
        phi = np.array([a.raw["gyro"].sum(axis=0) / _fs(a) - b.raw["gyro"].sum(axis=0) / _fs(b)
                        for a, b, _ in pairs]).reshape(-1, 3)
        ang = np.array([np.linalg.norm(d) for _, _, d in pairs])
        dur_mismatch = [a.label for a, b, _ in pairs if a.n_samples != b.n_samples]
        Ag = solve_mg(phi, ang)
        # 3. gyro biases (Eq. 23-25): |Ag y_j - z|^2 = We^2, linear in (z, |z|^2 - We^2)
        if len(statics) < 4:
            raise IdentifiabilityError("gyro: Eq. 25 needs at least four static positions for the biases",
                                       ["x.bias", "y.bias", "z.bias"])
        u = yg @ Ag.T
        D = np.column_stack([-2 * u, np.ones(len(u))])
        zz, *_ = np.linalg.lstsq(D, self.earth_rate**2 - np.sum(u * u, axis=1), rcond=None)
        bg = np.linalg.solve(Ag, zz[:3])
        # 4. nonlinear refinement on the norm residuals, weighted by their noise
        Npair = np.array([(a.n_samples, b.n_samples) for a, b, _ in pairs], dtype=float).reshape(-1, 2)
        dts = np.array([1.0 / _fs(a) for a, _, _ in pairs])
        il = np.tril_indices(3)

        def unpack(p):
            La = np.zeros((3, 3))
            La[il] = p[0:6]
            Lg = np.zeros((3, 3))
            Lg[il] = p[9:15]
            return La, p[6:9], Lg, p[15:18]

        def resid(p):
            La, b_a, Lg, b_g = unpack(p)
            Aa_ = np.linalg.inv(La)
            Ag_ = np.linalg.inv(Lg)
            s = (ya - b_a) @ Aa_.T
            ns = np.linalg.norm(s, axis=1)
            ga = (s / ns[:, None]) @ Aa_  # d|s|/dy
            ra = (ns - gg) / np.sqrt((ga**2 @ sa**2) / Ns)
            w = phi @ Ag_.T
            nw = np.linalg.norm(w, axis=1)
            gw = (w / nw[:, None]) @ Ag_
            rp = (nw - ang) / np.sqrt((gw**2 @ sg**2) * dts**2 * Npair.sum(axis=1))
            e = (yg - b_g) @ Ag_.T
            ne = np.linalg.norm(e, axis=1)
            ge = (e / ne[:, None]) @ Ag_
            rs = (ne - self.earth_rate) / np.sqrt((ge**2 @ sg**2) / Ns)
            return np.concatenate([ra, rp, rs])

        p0 = np.concatenate([np.linalg.inv(Aa)[il], ba, np.linalg.inv(Ag)[il], bg])
        typ = np.abs(p0) + 1e-12
        if self.refine:
            sol = least_squares(resid, p0, x_scale=typ, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
            p = sol.x
        else:
            p = p0
        J = central_jacobian(resid, p, typ * 1e-6)
        r = resid(p)
        cov_p = np.linalg.pinv(J.T @ J)
        La, ba, Lg, bg = unpack(p)
        Aa, Ag = np.linalg.inv(La), np.linalg.inv(Lg)
        # 5. inter-triad misalignment (Eq. 39-47). The plane s^p . l = kappa of Eq. 42 is a plane in raw space
        # too (s^p = A_a (y - b_a)), with normal n ~ A_a^T l: fit it once in raw space (Eq. 44-47), then
        # l^p = A_a^-T n for any accelerometer parameters, so theta's dependence on them is propagated.
        n_raw, var_raw, phis = [], [], []
        for a, b, _ in pairs:
            f = np.vstack([a.raw["accel"], b.raw["accel"]])
            n_k, v_k = accel_rotation_axis(f)
            n_raw.append(n_k)
            var_raw.append(v_k)
            phis.append(a.raw["gyro"].sum(axis=0) / _fs(a) - b.raw["gyro"].sum(axis=0) / _fs(b))
        n_raw_a, phis_a = np.array(n_raw), np.array(phis)
        if len(pairs) < 2 or np.linalg.matrix_rank(n_raw_a, tol=1e-3) < 2:
            raise IdentifiabilityError("inter-triad misalignment needs rotations about two independent axes that "
                                       "are not vertical (Zhang Eq. 40, 46)", ["theta_x", "theta_y", "theta_z"])

        def axes(pp):
            La_, _, Lg_, _ = unpack(pp)
            lp_ = n_raw_a @ La_  # A_a^-T n = La^T n (A_a = La^-1), as rows
            lp_ /= np.linalg.norm(lp_, axis=1)[:, None]
            lo_ = np.linalg.solve(Lg_, phis_a.T).T  # Eq. 41: A_g phi
            lo_ /= np.linalg.norm(lo_, axis=1)[:, None]
            lp_ *= np.sign(np.sum(lp_ * lo_, axis=1))[:, None]
            return lo_, lp_

        def theta_of(pp):
            lo_, lp_ = axes(pp)
            R_ = wahba(lo_, lp_, w_a)
            return np.array([R_[2, 1] - R_[1, 2], R_[0, 2] - R_[2, 0], R_[1, 0] - R_[0, 1]]) / 2.0

        lo_a, lp_a = axes(p)
        # angular variance of each accelerometer axis: the raw-space spread mapped by A_a^-T (~ isotropic)
        w_a = np.array([1.0 / max(v * float(np.linalg.norm(La, 2)) ** 2 / float(np.linalg.norm(n @ La)) ** 2, 1e-30)
                        for v, n in zip(var_raw, n_raw_a)])
        Rpo = wahba(lo_a, lp_a, w_a)
        info = sum(w * (np.eye(3) - np.outer(l, l)) for w, l in zip(w_a, lp_a))
        Jt = central_jacobian(theta_of, p, typ * 1e-6)
        cov_th = np.linalg.inv(info) + Jt @ cov_p @ Jt.T
        theta = np.array([Rpo[2, 1] - Rpo[1, 2], Rpo[0, 2] - Rpo[2, 0], Rpo[1, 0] - Rpo[0, 1]]) / 2.0
        # map to rimu's per-sensor raw-domain coefficients in MB = p
        model = ErrorModel.base()
        out: dict[str, LsqResult] = {}
        nA = len(ya)
        nG = len(phi) + len(yg)
        chi_a = float(np.sum(r[:nA] ** 2))
        chi_g = float(np.sum(r[nA:] ** 2))
        for inst, L, b, R, sig, offs, _chi, nobs in (
            ("accel", La, ba, np.eye(3), sa, (0, 6), chi_a, nA),
            ("gyro", Lg, bg, Rpo, sg, (9, 15), chi_g, nG),
        ):
            W = L @ R
            fits = []
            for ctx in contexts(session, inst):
                i = ctx.index
                # d w_i / d params: w_i = L[i, :] R; L[i, j] is parameter offs[0] + index in tril order
                Jb = np.zeros((4, 18))
                for k, (ri, ci) in enumerate(zip(*il)):
                    if ri == i:
                        Jb[:3, k + offs[0]] = R[ci, :]
                Jb[3, (6 if inst == "accel" else 15) + i] = 1.0
                bc = Jb @ cov_p @ Jb.T
                if inst == "gyro":
                    # theta uncertainty: d(L R) = L skew(dth) R -> row i: (L[i] @ skew(dth)) @ R
                    G = np.zeros((3, 3))
                    for k in range(3):
                        e = np.zeros(3)
                        e[k] = 1.0
                        G[:, k] = L[i] @ skew(e) @ R
                    bc[:3, :3] += G @ cov_th @ G.T
                bc = (bc + bc.T) / 2
                beta = np.concatenate([W[i], [b[i]]])
                fits.append(make_sensor_fit(model, ctx, beta, bc, float(sig[i]), self.sigma is not None,
                                            nobs, 0.0, {}))
            out[inst] = LsqResult(inst, model, fits, [s.label for s in statics], {})
        # residuals of the norms per segment, in units of their standard deviation
        notes = [("MB is Zhang's platform frame p: x along the x accelerometer, y in the x-y accelerometer plane; "
                  "x.mis_y, x.mis_z, y.mis_z of the accelerometers are zero by that definition")]
        if dur_mismatch:
            notes.append(f"CW/CCW segments of unequal length ({dur_mismatch}): the gyro bias does not cancel "
                         "exactly in Eq. 18")
        for k, s in enumerate(statics):  # the norm residual of each static position (Eq. 7), in raw-noise units
            for f in out["accel"].sensors:
                f.residuals[s.label] = np.array([r[k] * f.sigma])
            for f in out["gyro"].sensors:
                f.residuals[s.label] = np.array([r[nA + len(phi) + k] * f.sigma])
        notes.append("residuals of this method are the norm residuals of each static position (Eq. 7-8, 23), "
                     "one value per segment shared by the triad's sensors")
        extra = {"inter_triad_rad": theta, "inter_triad_std_rad": np.sqrt(np.diag(cov_th)),
                 "R_p_o": Rpo, "norm_residuals_accel": r[:nA], "refined": bool(self.refine)}
        res = CalibrationResult(self.method, out, session.raw_unit, notes, extra)
        for inst, chi, nobs in (("accel", chi_a, nA), ("gyro", chi_g, nG)):
            for f in res.instruments[inst].sensors:
                # the norm fit has 9 parameters per triad: chi2 per dof of the triad, shared by its sensors
                f.rss = chi / max(nobs - 9, 1) * (f.n_obs - 4) * f.sigma**2
        return res


def _accel_only(est: Zhang, session: Session, statics: list[Segment]) -> CalibrationResult:
    """Accelerometers alone (no gyro triad, or no CW/CCW rotation pairs): Zhang's Eq. 12-14 start and the norm
    refinement of Eq. 7-8, as in :func:`rimu.calibration.handheld.fit_accel`."""
    from .handheld import HandHeld

    if len(statics) < 9:
        raise IdentifiabilityError(f"accel: {len(statics)} static positions; Zhang's Eq. 13 needs at least nine",
                                   ["x.scale", "y.scale", "z.scale", "x.bias", "y.bias", "z.bias"])
    sig = None if est.sigma is None or "accel" not in est.sigma else {"accel": est.sigma["accel"]}
    res = HandHeld(sigma=sig, instruments=["accel"], robust=False).fit(session)
    res.method = est.method
    res.notes.insert(0, "accelerometers only: " + ("the session has no gyro triad" if "gyro" not in session.geometries
                                                   else "no CW/CCW rotation pairs for the gyros (Zhang Eq. 16-22)"))
    res.notes.append("MB is Zhang's platform frame p: x along the x accelerometer, y in the x-y accelerometer "
                     "plane")
    return res


