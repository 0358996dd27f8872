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
4. nonlinear refinement of both triads on the norm residuals of Eq. 7-8 and Eq. 19, 23, weighted by their noise:
   two independent problems (accelerometers; gyros), analytic Jacobians (:func:`norm_problem`), damped Newton
   steps on the exact cost (:func:`refine_norms`); the Jacobian gives the covariance;
5. inter-triad misalignment: rotation axes from the gyros (Eq. 41) and from the accelerometers (the null
   vector of ``[s^p(t)^T, -1]``, Eq. 42-47), then ``R_p^o`` by the SVD solution of Wahba's problem
   (Eq. 39-40 generalised to more than two axes, as the paper suggests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError, SessionFormatError
from ..session import Segment, Session, SessionStatistics, skew
from ..units import EARTH_RATE
from .estimate import CalibrationResult, _sigma_for, make_sensor_fit
from .lsq import LsqResult
from .model import ErrorModel, contexts
from .result import Calibration, InstrumentCalibration
from .steps import StepCheck, linear_step_check

__all__ = [
    "Zhang",
    "accel_rotation_axis",
    "inter_triad_step_check",
    "lower_factor",
    "norm_problem",
    "norm_residuals",
    "refine_norms",
    "platform_frame",
    "rotation_axes",
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

    rot = [(s, a) for s, a in ((s, angle(s)) for s in segments) if a is not None]
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


#: np.tril_indices(3): the order of the six entries of a lower-triangular 3x3 matrix in a parameter vector
_IL = (np.array([0, 1, 1, 2, 2, 2]), np.array([0, 0, 1, 0, 1, 2]))


def _sum(y: np.ndarray) -> np.ndarray:
    """Column sums of samples (N, k) as one matrix-vector product (a strided reduction over N is ~20x slower)."""
    return np.ones(len(y)) @ y


def _mean(y: np.ndarray) -> np.ndarray:
    return _sum(y) / len(y)


def _fs(s: Segment) -> float:
    return (s.n_samples - 1) / s.duration if s.duration > 0 else 1.0


def accel_rotation_axis(f: np.ndarray | Sequence[np.ndarray],
                        sums: Sequence[tuple[np.ndarray, np.ndarray]] | None = None) -> tuple[np.ndarray, float]:
    """Zhang et al. 2010, Eq. 42-47: the rotation axis l^p from specific forces f (N, 3) seen during a rotation
    about a fixed axis: the null vector of ``[f^T, -1]``. Returns (unit axis, angular variance estimate).

    ``f`` may be given in pieces (a sequence of (N_i, 3) arrays, e.g. the CW and the CCW segment), as if stacked.
    The null vector is the right singular vector of the smallest singular value of ``[f, -1] D`` (D the column
    scaling, the rms norm of f on the last column), computed as the eigenvector of the 4x4 Gram matrix
    ``D [f, -1]^T [f, -1] D`` from the sums ``f^T f``, ``sum f`` and N (equal to the singular vector to rounding,
    checked in the tests: the gap to the other singular values is large).
    ``sums``: the ``(f^T f, sum f)`` of each piece when already known (a fit's
    :class:`~rimu.session.SessionStatistics`), so the samples are not read again. :func:`rotation_axes` does
    several rotations at once.
    """
    chunks = [np.asarray(f, float)] if isinstance(f, np.ndarray) else [np.asarray(c, float) for c in f]
    if sums is None:
        sums = [(_gram3(c), _sum(c)) for c in chunks]
    l, var = rotation_axes([chunks], [sums])
    return l[0], float(var[0])


def rotation_axes(chunks: Sequence[Sequence[np.ndarray]],
                  sums: Sequence[Sequence[tuple[np.ndarray, np.ndarray]]]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`accel_rotation_axis` of several rotations at once (one batched eigen-decomposition each step):
    ``chunks[k]`` the sample pieces of rotation k, ``sums[k]`` their ``(f^T f, sum f)``. Returns the unit axes
    (K, 3) and their angular variances (K,)."""
    K = len(chunks)
    N = np.array([sum(len(c) for c in ch) for ch in chunks], dtype=float)
    S = np.array([sum(g for g, _ in sm) for sm in sums]).reshape(K, 3, 3)  # f^T f
    m = np.array([sum(t for _, t in sm) for sm in sums]).reshape(K, 3)  # sum of f
    sc4 = np.sqrt(np.trace(S, axis1=1, axis2=2) / N)
    G = np.empty((K, 4, 4))
    G[:, :3, :3] = S
    G[:, :3, 3] = G[:, 3, :3] = -m * sc4[:, None]
    G[:, 3, 3] = N * sc4**2
    lam, V = np.linalg.eigh(G)
    v = V[:, :, 0].copy()
    v[:, 3] *= sc4
    n = np.sqrt(np.sum(v[:, :3] ** 2, axis=1))
    l = v[:, :3] / n[:, None]
    # first-order spread of the axis from the residual (total least squares): |[f, -1] v|^2 is the smallest
    # eigenvalue; recomputed from the samples when it is too small against the largest for its rounding
    rr = lam[:, 0].copy()
    for k in np.flatnonzero(~(lam[:, 0] > 1e-6 * lam[:, -1])):
        rr[k] = sum(float(np.sum(np.square(c @ v[k, :3] - v[k, 3]))) for c in chunks[k])
    s2 = rr / n**2 / np.maximum(N - 4, 1)
    FtF = S - m[:, :, None] * m[:, None, :] / N[:, None, None]  # F = f - mean(f)
    P = np.eye(3) - l[:, :, None] * l[:, None, :]
    ev = np.linalg.eigvalsh(P @ FtF @ P)  # trace of the pseudo-inverse (singular values below 1e-10 dropped)
    keep = ev > 1e-10 * np.max(np.abs(ev), axis=1)[:, None]
    var = s2 * np.sum(np.where(keep, 1.0 / np.where(keep, ev, 1.0), 0.0), axis=1) / 2.0
    return l, var


def _gram3(c: np.ndarray) -> np.ndarray:
    """``c^T c`` of samples (N, 3): squares by one matrix-vector product, the three cross sums by dot products
    (``c.T @ c`` is slower for three columns)."""
    S = np.diag(_sum(c * c))
    for i, j in ((0, 1), (0, 2), (1, 2)):
        S[i, j] = S[j, i] = c[:, i] @ c[:, j]
    return S


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


def norm_residuals(q: np.ndarray, groups: Sequence[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Weighted norm residuals of one triad and their analytic Jacobian (Zhang et al. 2010, Eq. 7-8 for the
    accelerometers, Eq. 19 and 23 for the gyros): ``norm_problem(groups)(q)``, see :func:`norm_problem`."""
    return norm_problem(groups)(q)


def norm_problem(groups: Sequence[tuple]) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The weighted norm residuals of one triad and their analytic Jacobian, as a function of the parameters
    (Zhang et al. 2010, Eq. 7-8 for the accelerometers, Eq. 19 and 23 for the gyros).

    ``q = [L[tril], b]`` with ``L = K T`` lower triangular (``A = L^-1``, tril order of ``np.tril_indices(3)``)
    and the raw bias b; ``q`` may also be a stack (B, 9) of parameter vectors, evaluated at once. Each group is
    ``(Y (K, 3), norm (scalar or K), s2 (3,), f (K,), biased)``: the residual of row k is
    ``(|A (y_k - b)| - norm_k) / sqrt(sum_i g_ki^2 s2_i f_k)`` with ``g_k = A^T u_k`` the gradient of the norm
    with respect to the raw data ``y_k`` (``u_k`` the unit vector of ``A (y_k - b)``), i.e. the norm's error in
    units of its standard deviation from the noise of y_k. For an unbiased group (the integrated CW-minus-CCW
    outputs phi of Eq. 18-19) b is left out. The weights depend on the parameters and are differentiated too.
    The function returns (r (..., sum K), J (..., sum K, 9)); J is checked against central differences in the
    tests.
    """
    Y = np.vstack([np.asarray(g[0], float).reshape(-1, 3) for g in groups])
    K = len(Y)
    tgt = np.concatenate([np.broadcast_to(np.asarray(g[1], float), (len(g[0]),)) for g in groups])
    C = np.vstack([np.asarray(g[2], float)[None, :] * np.asarray(g[3], float).reshape(-1, 1) * np.ones((len(g[0]), 1))
                   for g in groups])  # variance of each datum, (K, 3)
    mb = np.concatenate([np.full(len(g[0]), 1.0 if g[4] else 0.0) for g in groups])  # rows with the bias
    il = _IL
    i0, i1 = il
    mbk = mb[None, :, None]

    def prob(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, float)
        Q = q.reshape(-1, 9)
        B = len(Q)
        L = np.zeros((B, 3, 3))
        L[:, i0, i1] = Q[:, :6]
        A = np.linalg.inv(L)
        At = np.swapaxes(A, 1, 2)
        s = (Y[None] - mbk * Q[:, None, 6:9]) @ At  # (B, K, 3)
        n = np.sqrt((s * s).sum(axis=2))
        u = s / n[..., None]
        g = u @ A  # d|s| / dy = A^T u
        gc = g * C[None]
        v2 = (g * gc).sum(axis=2)
        v = np.sqrt(v2)
        r = (n - tgt) / v
        # directions: dL = E_ij gives dA = -A E_ij A, ds = -A[:, i] s_j, dA^T u = -A[j, :] g_i; db_m gives
        # ds = -A[:, m]. Then dn = u.ds, d(A^T u) = (A^T ds - g dn) / n + dA^T u and dv = d(A^T u).gc / v, with
        # A^T A[:, i] . gc = w_i (w = gc A^T A) and A[j, :] . gc = z_j (z = gc A^T)
        w = gc @ (At @ A)
        z = gc @ At
        ms, g0 = -s[..., i1], g[..., i0]
        nn, vv, v2n = n[..., None], v[..., None], v2[..., None]
        dn = np.empty((B, K, 9))
        dn[..., :6] = ms * g0
        dn[..., 6:] = -mbk * g
        dv = np.empty((B, K, 9))
        dv[..., :6] = (ms * w[..., i0] - v2n * dn[..., :6]) / nn - z[..., i1] * g0
        dv[..., 6:] = (-mbk * w - v2n * dn[..., 6:]) / nn
        J = (dn - r[..., None] * dv / vv) / vv
        if q.ndim == 1:
            return r[0], J[0]
        return r.reshape(*q.shape[:-1], K), J.reshape(*q.shape[:-1], K, 9)

    return prob


def refine_norms(prob: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], q0: np.ndarray, typ: np.ndarray,
                 max_iter: int = 100) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool]:
    """Minimise ``|r(q)|^2`` for ``prob(q) -> (r, J)`` (:func:`norm_residuals`) by damped Newton steps on the
    exact cost: analytic gradient ``J^T r``, Hessian by forward differences of that gradient (one stacked call per
    step), Levenberg-Marquardt damping when the Hessian is not positive definite or a step does not lower the cost.

    Gauss-Newton (``scipy.optimize.least_squares``) leaves out the curvature of the residuals, which is not small
    here: the weights depend on the parameters and the static gyro norms (the Earth rate, Eq. 23) are of the size
    of their noise, so it converges only linearly there (hundreds of steps); with the full Hessian a few steps
    reach the minimum. Converged when the step, in units of ``typ``, is below 1e-12. Returns (q, r(q), J(q), steps,
    converged).
    """
    p = len(q0)
    h = typ * 1e-7
    pts = np.vstack([np.zeros(p), np.diag(h)])

    def evaluate(q):
        r, J = prob(q + pts)
        grads = np.einsum("bkp,bk->bp", J, r)
        H = (grads[1:] - grads[0]).T / h
        return r[0], J[0], grads[0], (H + H.T) / 2

    q = np.asarray(q0, float).copy()
    r, J, g, H = evaluate(q)
    cost = float(r @ r)
    mu = 0.0
    for it in range(1, max_iter + 1):
        Hs = H * np.outer(typ, typ)
        gs = g * typ
        d0 = float(np.max(np.abs(np.diag(Hs))))
        if not (np.isfinite(d0) and d0 > 0 and np.all(np.isfinite(Hs))):
            return q, r, J, it, False
        while True:
            if mu > 1e12:
                return q, r, J, it, False
            try:
                C = np.linalg.cholesky(Hs + (mu * d0) * np.eye(p))
            except np.linalg.LinAlgError:
                mu = max(10 * mu, 1e-9)
                continue
            step = -np.linalg.solve(C.T, np.linalg.solve(C, gs)) * typ
            if np.max(np.abs(step / typ)) <= 1e-12:
                return q, r, J, it, True
            r_n, J_n, g_n, H_n = evaluate(q + step)
            cost_n = float(r_n @ r_n)
            if np.isfinite(cost_n) and cost_n <= cost:
                q, r, J, g, H, cost = q + step, r_n, J_n, g_n, H_n, cost_n
                mu = 0.0 if mu < 1e-8 else mu / 10
                break
            mu = max(10 * mu, 1e-9)
    return q, r, J, max_iter, False


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
    held_out : bool
        Check each triad's misalignment step (the off-diagonal of ``K T``) on held-out segments: the
        accelerometers with each static position left out (:func:`rimu.calibration.handheld.held_out_accel`, ten
        positions or more), the gyros with each CW/CCW pair left out in Eq. 21 (seven pairs or more). A step that
        raises the held-out residual is not applied (``T`` nominal) and a note says why with the figures.

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
                 earth_rate: float = EARTH_RATE, held_out: bool = True) -> None:
        self.sigma = sigma
        self.held_out = held_out
        self.refine = refine
        self.earth_rate = earth_rate

    def fit(self, session: Session) -> CalibrationResult:
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
        stats = SessionStatistics(session)  # each segment's sums once: noise level, means, integrals
        sa = _sigma_for(self.sigma, session, "accel", stats)
        sg = _sigma_for(self.sigma, session, "gyro", stats)
        ya = np.array([stats.mean(s, "accel") for s in statics]).reshape(-1, 3)
        yg = np.array([stats.mean(s, "gyro") for s in statics]).reshape(-1, 3)
        Ns = np.array([s.n_samples for s in statics], dtype=float)
        # 1. accelerometers (Eq. 12-14)
        Aa, ba = solve_ma(ya, gg)
        # 2. gyros (Eq. 16-22)
        phi = np.array([stats.sums(a, "gyro").total / _fs(a) - stats.sums(b, "gyro").total / _fs(b)
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
        # 4. nonlinear refinement on the norm residuals, weighted by their noise. The accelerometer residuals
        # (Eq. 7-8) depend only on (A_a, b_a), the gyro residuals (Eq. 19, 23) only on (A_g, b_g): two independent
        # 9-parameter problems, each with its analytic Jacobian (norm_residuals), the same optimum as the joint one
        Npair = np.array([(a.n_samples, b.n_samples) for a, b, _ in pairs], dtype=float).reshape(-1, 2)
        dts = np.array([1.0 / _fs(a) for a, _, _ in pairs])
        il = _IL
        problems = (  # (data, norm, per-sample variance, factor of the data's variance per row, biased)
            norm_problem([(ya, gg, sa**2, 1.0 / Ns, True)]),
            norm_problem([(phi, ang, sg**2, dts**2 * Npair.sum(axis=1), False),
                          (yg, self.earth_rate, sg**2, 1.0 / Ns, True)]),
        )
        La0, Lg0 = np.linalg.inv(Aa), np.linalg.inv(Ag)
        p0 = np.concatenate([La0[il], ba, Lg0[il], bg])
        # the misalignment steps (the off-diagonal of L = K T) checked on held-out positions and pairs
        checks = _step_checks(session, ya, sa, Ns, phi, ang) if self.held_out else [None, None]
        keep = [np.arange(9) if c is None or c.applied else _DIAG_AND_BIAS for c in checks]
        for k in (0, 1):
            off = np.setdiff1d(np.arange(9), keep[k])
            p0[9 * k + off] = 0.0  # the nominal axes: L diagonal (a refit from there when refused)
        p = p0.copy()
        Js, rs_, typs, steps, stalled = [], [], [], [], []
        for k, (prob, sig) in enumerate(zip(problems, (sa, sg))):
            sl = slice(9 * k, 9 * k + 9)
            rows = np.linalg.norm(La0 if k == 0 else Lg0, axis=1)
            typ = np.concatenate([rows[il[0]], np.maximum(np.abs(p0[sl][6:]), sig)])  # row size; bias or noise
            typs.append(typ)
            prob = _masked(prob, keep[k])
            if self.refine:
                qk, rk, Jk, nit, ok = refine_norms(prob, p0[sl][keep[k]], typ[keep[k]])
                p[9 * k + keep[k]] = qk
                steps.append(nit)
                if not ok:
                    stalled.append(f"{('accelerometer', 'gyro')[k]} norms after {nit} steps")
            else:
                rk, Jk = prob(p[sl][keep[k]])
            Jf = np.zeros((len(rk), 9))
            Jf[:, keep[k]] = Jk  # a parameter held at zero has no column: zero variance
            rs_.append(rk)
            Js.append(Jf)
        r = np.concatenate(rs_)
        J = np.zeros((len(r), 18))
        J[:len(rs_[0]), :9] = Js[0]
        J[len(rs_[0]):, 9:] = Js[1]
        cov_p = np.linalg.pinv(J.T @ J)

        def unpack(p):
            La = np.zeros((3, 3))
            La[il] = p[0:6]
            Lg = np.zeros((3, 3))
            Lg[il] = p[9:15]
            return La, p[6:9], Lg, p[15:18]

        La, ba, Lg, bg = unpack(p)
        Aa, Ag = np.linalg.inv(La), np.linalg.inv(Lg)
        # 5. inter-triad misalignment (Eq. 39-47). The plane s^p . l = kappa of Eq. 42 is a plane in raw space
        # too (s^p = A_a (y - b_a)), with normal n ~ A_a^T l: fit it once in raw space (Eq. 44-47), then
        # l^p = A_a^-T n for any accelerometer parameters, so theta's dependence on them is propagated.
        n_raw_a, var_raw = rotation_axes(
            [[a.raw["accel"], b.raw["accel"]] for a, b, _ in pairs],
            [[(stats.sums(x, "accel").gram, stats.sums(x, "accel").total) for x in (a, b)] for a, b, _ in pairs])
        phis_a = phi
        if len(pairs) < 2 or np.linalg.matrix_rank(n_raw_a, tol=1e-3) < 2:
            raise IdentifiabilityError("inter-triad misalignment needs rotations about two independent axes that "
                                       "are not vertical (Zhang Eq. 40, 46)", ["theta_x", "theta_y", "theta_z"])

        def axes(pp):
            """Unit axes (lo, lp), (..., M, 3), of parameter vectors pp (..., 18)."""
            pp = np.asarray(pp, float)
            La_ = np.zeros((*pp.shape[:-1], 3, 3))
            La_[..., il[0], il[1]] = pp[..., 0:6]
            Lg_ = np.zeros_like(La_)
            Lg_[..., il[0], il[1]] = pp[..., 9:15]
            lp_ = n_raw_a @ La_  # A_a^-T n = La^T n (A_a = La^-1), as rows
            lp_ /= np.linalg.norm(lp_, axis=-1)[..., None]
            lo_ = np.swapaxes(np.linalg.solve(Lg_, phis_a.T), -1, -2)  # Eq. 41: A_g phi
            lo_ /= np.linalg.norm(lo_, axis=-1)[..., None]
            lp_ *= np.sign(np.sum(lp_ * lo_, axis=-1))[..., None]
            return lo_, lp_

        def theta_of(pp):
            """theta of a stack of parameter vectors (B, 18): Wahba's solution (wahba) for each at once."""
            lo_, lp_ = axes(pp)
            U, _, Vt = np.linalg.svd(np.swapaxes(lo_ * w_a[:, None], -1, -2) @ lp_)
            D = np.ones((len(pp), 3))
            D[:, 2] = np.sign(np.linalg.det(U @ Vt))
            R_ = (U * D[:, None, :]) @ Vt
            return np.stack([R_[:, 2, 1] - R_[:, 1, 2], R_[:, 0, 2] - R_[:, 2, 0], R_[:, 1, 0] - R_[:, 0, 1]], -1) / 2.0

        lo_a, lp_a = axes(p)
        # angular variance of each accelerometer axis: the raw-space spread mapped by A_a^-T (~ isotropic)
        la2 = float(np.linalg.norm(La, 2)) ** 2
        w_a = np.array([1.0 / max(v * la2 / float(np.linalg.norm(n @ La)) ** 2, 1e-30)
                        for v, n in zip(var_raw, n_raw_a)])
        Rpo = wahba(lo_a, lp_a, w_a)
        # the inter-triad step checked on held-out pairs: refused, the gyro frame is taken as the accelerometers'
        inter = inter_triad_step_check(lo_a, lp_a, w_a) if self.held_out else None
        if inter is not None and not inter.applied:
            Rpo = np.eye(3)
        info = sum(w * (np.eye(3) - np.outer(l, l)) for w, l in zip(w_a, lp_a))
        # d theta / d p by central differences (theta does not depend on the biases: those columns are zero)
        Jt = np.zeros((3, 18))
        cols = np.r_[0:6, 9:15]
        h = np.concatenate([np.linalg.norm(La, axis=1)[il[0]], np.linalg.norm(Lg, axis=1)[il[0]]]) * 1e-6
        dP = np.zeros((len(cols), 18))
        dP[np.arange(len(cols)), cols] = h
        th = theta_of(np.vstack([p + dP, p - dP]))
        Jt[:, cols] = ((th[:len(cols)] - th[len(cols):]) / (2 * h[:, None])).T
        cov_th = np.linalg.inv(info) + Jt @ cov_p @ Jt.T
        if inter is not None and not inter.applied:
            cov_th = np.zeros((3, 3))  # not estimated: held at zero
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
                ks = np.flatnonzero(il[0] == i)  # the tril entries of row i: L[i, il[1][k]]
                Jb[:3, ks + offs[0]] = R[il[1][ks], :].T
                Jb[3, (6 if inst == "accel" else 15) + i] = 1.0
                bc = Jb @ cov_p @ Jb.T
                if inst == "gyro":
                    # theta uncertainty: d(L R) = L skew(dth) R -> row i: (L[i] @ skew(dth)) @ R, and
                    # L[i] @ skew(e_k) = L[i] x e_k, the rows of -skew(L[i])
                    G = (-skew(L[i]) @ R).T
                    bc[:3, :3] += G @ cov_th @ G.T
                bc = (bc + bc.T) / 2
                beta = np.concatenate([W[i], [b[i]]])
                fits.append(make_sensor_fit(model, ctx, beta, bc, float(sig[i]), self.sigma is not None,
                                            nobs, 0.0, {}))
            out[inst] = LsqResult(inst, model, fits, [s.label for s in statics], {})
        # residuals of the norms per segment, in units of their standard deviation
        notes = [("MB is Zhang's platform frame p: x along the x accelerometer, y in the x-y accelerometer plane; "
                  "x.mis_y, x.mis_z, y.mis_z of the accelerometers are zero by that definition")]
        if stalled:
            notes.append("the nonlinear refinement (step 4) stopped before converging: " + "; ".join(stalled)
                         + "; the estimates are the last accepted step (check the static positions and rotations)")
        for inst, c in zip(("accel", "gyro"), checks):
            notes.append(c.note() if c is not None else
                         f"{inst}: the misalignment step could not be checked on held-out segments (too few "
                         f"{'static positions' if inst == 'accel' else 'CW/CCW pairs'}: leaving one out leaves it "
                         "unidentifiable); applied")
        notes.append(inter.note() if inter is not None else
                     "gyro: the inter-triad misalignment step could not be checked on held-out CW/CCW pairs (fewer "
                     "than three pairs, or the others' axes in one direction); applied" if self.held_out else
                     "gyro: the inter-triad misalignment step not checked on held-out pairs (held_out=False)")
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
                 "R_p_o": Rpo, "norm_residuals_accel": r[:nA], "refined": bool(self.refine),
                 "steps": [c.to_dict() for c in (*checks, inter) if c is not None]}
        res = CalibrationResult(self.method, out, session.raw_unit, notes, extra)
        # the two refinement problems (accelerometers, gyros): start, optimum, scales, Newton steps (for tests)
        res.refinement = {"problems": problems, "p0": (p0[:9], p0[9:]), "p": (p[:9], p[9:]),  # type: ignore[attr-defined]
                          "typ": typs, "steps": steps}
        for inst, chi, nobs in (("accel", chi_a, nA), ("gyro", chi_g, nG)):
            for f in res.instruments[inst].sensors:
                # the norm fit has 9 parameters per triad: chi2 per dof of the triad, shared by its sensors
                f.rss = chi / max(nobs - 9, 1) * (f.n_obs - 4) * f.sigma**2
        return res


_DIAG_AND_BIAS = np.array([0, 2, 5, 6, 7, 8])  # L[0,0], L[1,1], L[2,2] in tril order, and the bias


def _masked(prob: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], keep: np.ndarray
            ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """The norm problem in the parameters ``keep`` alone, the others held at zero."""
    if len(keep) == 9:
        return prob

    def sub(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, float)
        full = np.zeros((*q.shape[:-1], 9))
        full[..., keep] = q
        r, J = prob(full)
        return r, J[..., keep]

    return sub


def inter_triad_step_check(lo: np.ndarray, lp: np.ndarray, w: np.ndarray | None = None) -> StepCheck | None:
    """The inter-triad misalignment step (Zhang et al. 2010, Eq. 39-47: ``R_p^o`` by Wahba's problem) checked on
    held-out CW/CCW pairs: the angle between each pair's gyro rotation axis ``lo_k`` (Eq. 41) and its
    accelerometer axis turned by R, ``R lp_k`` (Eq. 42-47), with ``R = I`` (the step's input: the gyro frame taken
    as the accelerometers') and with R from :func:`wahba` on every pair, or on the others with each pair left out
    in turn. None with fewer than three pairs, or when the others' accelerometer axes span one direction only.

    Examples
    --------
    >>> from rimu.session import rotation_matrix
    >>> lp = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0], [0, 0.6, 0.8]], float)
    >>> c = inter_triad_step_check(lp @ rotation_matrix(np.array([2e-3, 0, 0])).T, lp)
    >>> c.applied, round(c.held_out[0] * 1e3, 2), c.held_out[1] < 1e-12  # 2 mrad * rms(|l x x|) = 1.71 mrad
    (True, 1.71, True)
    """
    lo, lp = np.asarray(lo, float), np.asarray(lp, float)
    M = len(lo)
    w = np.ones(M) if w is None else np.asarray(w, float)
    if M < 3:
        return None

    def angles(R: np.ndarray, k: slice | np.ndarray) -> np.ndarray:
        c = np.einsum("ki,ki->k", lo[k], lp[k] @ R.T)
        s = np.linalg.norm(np.cross(lo[k], lp[k] @ R.T), axis=1)
        return np.arctan2(s, c)

    every = slice(None)
    base = angles(np.eye(3), every)
    fitted = angles(wahba(lo, lp, w), every)
    out = np.empty(M)
    for k in range(M):
        keep = np.arange(M) != k
        if np.linalg.matrix_rank(lp[keep], tol=1e-3) < 2:
            return None
        out[k] = angles(wahba(lo[keep], lp[keep], w[keep]), np.array([k]))[0]

    def rms(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean(a * a)))

    return StepCheck("gyro", "inter-triad misalignment", "the gyro frame taken as the accelerometers'", "angle",
                     (rms(base), rms(fitted)), (rms(base), rms(out)), "CW/CCW pairs",
                     "no inter-triad rotation (R_p^o = I)", residual="rotation-axis misfit")


def _step_checks(session: Session, ya: np.ndarray, sa: np.ndarray, Ns: np.ndarray, phi: np.ndarray,
                 ang: np.ndarray) -> list[StepCheck | None]:
    """The accelerometer and gyro misalignment steps checked on held-out segments: the gravity norm of each
    static position predicted from the others (Eq. 7-8, the hand-held check) and the angle of each CW/CCW pair
    predicted from the others by Eq. 21 (linearised: ``|phi|_M^2 = angle^2`` divided by ``2 angle``)."""
    from .handheld import held_out_accel

    ga = session.geometries["accel"]
    sd = np.asarray(sa, float)[None, :] / np.sqrt(Ns)[:, None]
    c = held_out_accel(ya, sd, ga.H, session.gravity, list(ga.names))
    acc = None if c is None else StepCheck(
        "accel", "misalignment", "scale and bias alone", "specific_force", tuple(c["in_sample"]),
        tuple(c["held_out"]), "static positions", "scale and bias alone, axes nominal",
        residual="gravity-norm residual")
    sc = float(np.median(np.linalg.norm(phi, axis=1)))
    X = _quad_rows(phi / sc) / (2 * ang)[:, None]
    y = (ang / sc) ** 2 / (2 * ang)
    Xs = [X * sc**2]
    gyro = linear_step_check(Xs, [Xs[0][:, :3]], [y * sc**2], np.ones(len(ang)), [1.0], instrument="gyro",
                             step="misalignment", against="scale alone", quantity="angle",
                             groups="CW/CCW pairs", fallback="scale and bias alone, axes nominal",
                             residual="rotation-angle residual")
    return [acc, gyro]


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


