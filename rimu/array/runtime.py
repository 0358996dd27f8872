"""The array as one sensor at runtime: lever-arm removal and the maximum-likelihood angular motion.

Signal model (Skog, Nilsson, Handel & Nehorai 2016, "Inertial sensor arrays, maximum likelihood, and
Cramer-Rao bound", Sec. II), all vectors in the body frame, triad j at position r_j from the reference point:

* gyro triad j:          ``z_g,j = w + n_g,j``
* accelerometer triad j: ``z_a,j = s + w' x r_j + w x (w x r_j) + n_a,j``

with ``s`` the specific force at the reference point, ``w`` the angular rate and ``w'`` the angular
acceleration. The model is linear in (w', s) and quadratic in w; the maximum-likelihood estimate of
``theta = (w, w', s)`` under white Gaussian noise is the weighted nonlinear least-squares solution, found here by
Gauss-Newton from the gyro mean (Skog et al. 2016, Sec. III, where the estimator is concentrated on w; plain
Gauss-Newton on all nine parameters has the same fixed point). Its covariance is the inverse of the Fisher
information ``J^T Sigma^-1 J`` (Skog et al. 2016, Sec. IV, the Cramer-Rao bound), evaluated at the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import NonFiniteError, ShapeError
from ..session import skew  # re-exported: the cross-product matrices this module uses
from .layout import ArrayLayout

__all__ = [
    "ArrayMotion",
    "skew",
    "lever_arm_acceleration",
    "remove_lever_arms",
    "accel_model",
    "accel_jacobian",
    "fisher_information",
    "crb",
    "ml_motion",
]


def lever_arm_acceleration(omega: np.ndarray, omega_dot: np.ndarray, positions_m: np.ndarray) -> np.ndarray:
    """The lever-arm terms ``w' x r + w x (w x r)`` for every sample and position: (N, 3), (N, 3), (k, 3) -> (N, k, 3).

    >>> a = lever_arm_acceleration(np.array([[0, 0, 2.0]]), np.zeros((1, 3)), np.array([[0.1, 0, 0]]))
    >>> a.round(6).tolist()   # centripetal: -|w|^2 r
    [[[-0.4, 0.0, 0.0]]]
    """
    w = np.asarray(omega, dtype=float)[:, None, :]
    wd = np.asarray(omega_dot, dtype=float)[:, None, :]
    r = np.asarray(positions_m, dtype=float)[None, :, :]
    return np.cross(wd, r) + np.cross(w, np.cross(w, r))


def remove_lever_arms(
    accel_body: np.ndarray, omega: np.ndarray, omega_dot: np.ndarray, positions_m: np.ndarray,
    reference_m: "np.ndarray | None" = None,
) -> np.ndarray:
    """Move every accelerometer triad's specific force to one reference point.

    ``f_ref = f_j - (w' x (r_j - r_ref) + w x (w x (r_j - r_ref)))`` for each triad j (rigid-body kinematics).

    Parameters
    ----------
    accel_body : ndarray, shape (N, k, 3)
        Specific force of each triad in the body frame [m/s^2] (see :meth:`ArrayLayout.to_body`).
    omega, omega_dot : ndarray, shape (N, 3)
        Angular rate [rad/s] and angular acceleration [rad/s^2] in the body frame.
    positions_m : ndarray, shape (k, 3)
        Triad positions [m].
    reference_m : ndarray, shape (3,), optional
        The reference point (default: the origin of ``positions_m``).

    Returns
    -------
    ndarray, shape (N, k, 3)
        Each triad's specific force at the reference point; their mean is the array's specific force there.
    """
    f = np.asarray(accel_body, dtype=float)
    r = np.asarray(positions_m, dtype=float)
    if f.ndim != 3 or f.shape[1:] != r.shape:
        raise ShapeError(f"accel_body must have shape (N, k, 3) with k = {r.shape[0]}, got {f.shape}")
    if reference_m is not None:
        r = r - np.asarray(reference_m, dtype=float)[None, :]
    return f - lever_arm_acceleration(omega, omega_dot, r)


def accel_model(theta: np.ndarray, positions_m: np.ndarray) -> np.ndarray:
    """Accelerometer triads' body-frame output for ``theta = (w, w', s)`` (N, 9) -> (N, k, 3) (Skog et al. 2016, Sec. II)."""
    theta = np.asarray(theta, dtype=float)
    return theta[:, None, 6:9] + lever_arm_acceleration(theta[:, 0:3], theta[:, 3:6], positions_m)


def accel_jacobian(omega: np.ndarray, positions_m: np.ndarray) -> np.ndarray:
    """Jacobian of :func:`accel_model` with respect to ``(w, w', s)``: (N, 3), (k, 3) -> (N, k, 3, 9).

    ``d[w x (w x r)]/dw = (w.r) I + w r^T - 2 r w^T``, ``d[w' x r]/dw' = -[r x]``, ``ds/ds = I``.
    """
    w = np.asarray(omega, dtype=float)
    r = np.asarray(positions_m, dtype=float)
    N, k = w.shape[0], r.shape[0]
    J = np.zeros((N, k, 3, 9))
    wr = np.einsum("ni,ki->nk", w, r)
    J[..., 0:3] = (wr[:, :, None, None] * np.eye(3) + w[:, None, :, None] * r[None, :, None, :]
                   - 2.0 * r[None, :, :, None] * w[:, None, None, :])
    J[..., 3:6] = -skew(r)[None]
    J[..., 6:9] = np.eye(3)
    return J


class _Structure:
    """The accelerometer Jacobian is affine in w: ``J_j(w) = J0_j + sum_m w_m J1_j,m``. With weights constant
    over samples, the Fisher information is ``K00 + sum_m w_m (K10_m + K10_m^T) + sum_mn w_m w_n K11_mn`` with
    9 x 9 constants: per sample a few hundred flops instead of a k-triad sum."""

    def __init__(self, positions_m: np.ndarray, c: np.ndarray) -> None:
        r = np.asarray(positions_m, dtype=float)
        k = r.shape[0]
        J0 = np.zeros((k, 3, 9))
        J0[:, :, 3:6] = -skew(r)
        J0[:, :, 6:9] = np.eye(3)
        J1 = np.zeros((k, 3, 3, 9))  # [j, m, a, i]
        eye = np.eye(3)
        for m in range(3):
            J1[:, m, :, 0:3] = (r[:, m, None, None] * eye + eye[m][None, :, None] * r[:, None, :]
                                - 2.0 * r[:, :, None] * eye[m][None, None, :])
        cJ0 = c[:, None, None] * J0
        cJ1 = c[:, None, None, None] * J1
        self.K00 = np.einsum("kai,kaj->ij", cJ0, J0)
        K10 = np.einsum("kmai,kaj->mij", cJ1, J0)
        self.K10s = (K10 + np.transpose(K10, (0, 2, 1))).reshape(3, 81)
        self.K11 = np.einsum("kmai,knaj->mnij", cJ1, J1).reshape(9, 81)
        self.G0 = cJ0.reshape(3 * k, 9)
        self.G1 = np.transpose(cJ1, (0, 2, 1, 3)).reshape(3 * k, 27)

    def info(self, w: np.ndarray) -> np.ndarray:
        ww = (w[:, :, None] * w[:, None, :]).reshape(-1, 9)
        return (self.K00.reshape(1, 81) + w @ self.K10s + ww @ self.K11).reshape(-1, 9, 9)

    def grad(self, w: np.ndarray, ra: np.ndarray) -> np.ndarray:
        R = ra.reshape(ra.shape[0], -1)
        return R @ self.G0 + np.einsum("nm,nmi->ni", w, (R @ self.G1).reshape(-1, 3, 9))


def _sigmas(value: "float | np.ndarray", k: int, what: str) -> np.ndarray:
    s = np.broadcast_to(np.asarray(value, dtype=float), (k,)).copy()
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ShapeError(f"{what} must be positive and finite (a scalar or one per triad), got {value!r}")
    return s


def fisher_information(
    omega: np.ndarray, positions_m: np.ndarray, gyro_noise_rad_s: "float | np.ndarray | None",
    accel_noise_m_s2: "float | np.ndarray", gyro_weight: "np.ndarray | None" = None,
    accel_weight: "np.ndarray | None" = None,
) -> np.ndarray:
    """Fisher information of ``(w, w', s)`` per sample, (N, 9, 9) (Skog et al. 2016, Sec. IV).

    ``I = sum_j J_a,j^T J_a,j / sigma_a,j^2 + sum_j J_g,j^T J_g,j / sigma_g,j^2`` with ``J_g,j = [I 0 0]``.
    ``gyro_weight``/``accel_weight`` (N, k) of 0/1 drop missing samples. ``gyro_noise_rad_s=None`` means an
    accelerometer-only (gyro-free) array.
    """
    w = np.atleast_2d(np.asarray(omega, dtype=float))
    r = np.asarray(positions_m, dtype=float)
    N, k = w.shape[0], r.shape[0]
    sa = _sigmas(accel_noise_m_s2, k, "accel_noise_m_s2")
    if accel_weight is None or np.all(accel_weight == 1):
        info = _Structure(r, 1 / sa**2).info(w)
    else:
        J = accel_jacobian(w, r)
        Jw = J * (accel_weight / sa[None] ** 2)[:, :, None, None]
        info = np.matmul(np.swapaxes(Jw.reshape(N, 3 * k, 9), 1, 2), J.reshape(N, 3 * k, 9))
    if gyro_noise_rad_s is not None:
        sg = _sigmas(gyro_noise_rad_s, k if np.ndim(gyro_noise_rad_s) == 0 else len(gyro_noise_rad_s),
                     "gyro_noise_rad_s")
        wg = np.ones((N, sg.size)) if gyro_weight is None else gyro_weight
        info[:, 0:3, 0:3] += (wg / sg[None] ** 2).sum(axis=1)[:, None, None] * np.eye(3)
    return info


def crb(omega: np.ndarray, positions_m: np.ndarray, gyro_noise_rad_s: "float | np.ndarray | None",
        accel_noise_m_s2: "float | np.ndarray") -> np.ndarray:
    """Cramer-Rao bound of ``(w, w', s)`` at the true angular rate: the inverse Fisher information, (N, 9, 9).

    >>> lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.02)
    >>> P = crb(np.array([[0.0, 0, 5.0]]), lay.positions_m, 0.01, 0.02)
    >>> bool(P[0, 2, 2] < 0.01**2 / 4)   # accelerometers add information on w at 5 rad/s
    True
    """
    return np.linalg.inv(fisher_information(omega, positions_m, gyro_noise_rad_s, accel_noise_m_s2))


@dataclass(frozen=True)
class ArrayMotion:
    """Maximum-likelihood angular motion and specific force of an array, per sample.

    Attributes
    ----------
    omega : ndarray (N, 3)
        Angular rate [rad/s], body frame.
    omega_dot : ndarray (N, 3)
        Angular acceleration [rad/s^2].
    specific_force : ndarray (N, 3)
        Specific force at the reference point (origin of the positions) [m/s^2].
    covariance : ndarray (N, 9, 9)
        Inverse Fisher information of ``(w, w', s)`` at the estimate.
    iterations : int
        Gauss-Newton iterations made.
    n_missing : int
        Non-finite triad samples left out (weight 0).
    """

    omega: np.ndarray
    omega_dot: np.ndarray
    specific_force: np.ndarray
    covariance: np.ndarray
    iterations: int
    n_missing: int = 0

    def specific_force_at(self, point_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Specific force at another point ``point_m`` (3,) of the body, with its covariance (N, 3, 3)."""
        p = np.asarray(point_m, dtype=float).reshape(1, 3)
        theta = np.column_stack([self.omega, self.omega_dot, self.specific_force])
        f = accel_model(theta, p)[:, 0]
        J = accel_jacobian(self.omega, p)[:, 0]
        return f, np.einsum("nai,nij,nbj->nab", J, self.covariance, J)


def _clean(x: "np.ndarray | None", k: int, what: str) -> tuple[np.ndarray | None, np.ndarray | None, int]:
    if x is None:
        return None, None, 0
    x = np.asarray(x, dtype=float)
    if x.ndim != 3 or x.shape[1:] != (k, 3):
        raise ShapeError(f"{what} must have shape (N, {k}, 3), body frame, got {x.shape}")
    ok = np.all(np.isfinite(x), axis=2)
    return np.where(ok[..., None], x, 0.0), ok.astype(float), int((~ok).sum())


def ml_motion(
    layout: ArrayLayout, accel_body: np.ndarray, gyro_body: "np.ndarray | None", accel_noise_m_s2: "float | np.ndarray",
    gyro_noise_rad_s: "float | np.ndarray | None" = None, omega_init: "np.ndarray | None" = None,
    max_iter: int = 10, tol: float = 1e-10,
) -> ArrayMotion:
    """Maximum-likelihood angular rate, angular acceleration and specific force from the whole array.

    Gauss-Newton on the weighted nonlinear least squares of Skog et al. 2016 (Sec. III), every sample at once
    (vectorised over samples), started from the noise-weighted gyro mean and the linear solution for (w', s)
    given it. Inputs are calibrated outputs rotated to the body frame (:meth:`ArrayLayout.to_body`).

    Parameters
    ----------
    layout : ArrayLayout
        Positions of the triads (rotations are not used: inputs are already in the body frame).
    accel_body : ndarray (N, k, 3)
        Accelerometer triads [m/s^2], body frame. A non-finite triad sample is left out (weight 0).
    gyro_body : ndarray (N, k, 3) or None
        Gyro triads [rad/s], body frame; ``None`` for a gyro-free array (then ``omega_init`` is needed:
        the accelerometers see w only through ``w x (w x r)``, which is even in w).
    accel_noise_m_s2, gyro_noise_rad_s : float or ndarray (k,)
        White-noise standard deviation per sample of each triad's axes.
    omega_init : ndarray (N, 3), optional
        Starting angular rate (default: gyro mean).

    Returns
    -------
    ArrayMotion

    Raises
    ------
    ShapeError
        Inputs of the wrong shape, or no gyros and no ``omega_init``.
    NonFiniteError
        A sample without any valid triad of the instrument it needs.

    Examples
    --------
    >>> lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.02)
    >>> w, wd, s = np.array([[1.0, -2, 3]]), np.array([[10.0, 0, -5]]), np.array([[0, 0, 9.81]])
    >>> fa = s[:, None] + lever_arm_acceleration(w, wd, lay.positions_m)
    >>> m = ml_motion(lay, fa, np.repeat(w[:, None], 4, axis=1), 0.01, 0.001)
    >>> bool(np.allclose(m.omega, w) and np.allclose(m.omega_dot[:, :2], wd[:, :2]))
    True
    """
    k = layout.k
    r = layout.positions_m
    fa, wa, miss_a = _clean(accel_body, k, "accel_body")
    fg, wg, miss_g = _clean(gyro_body, k, "gyro_body")
    sa = _sigmas(accel_noise_m_s2, k, "accel_noise_m_s2")
    N = fa.shape[0]
    if np.any(wa.sum(axis=1) == 0):
        raise NonFiniteError(f"{int((wa.sum(axis=1) == 0).sum())} sample(s) have no finite accelerometer triad")
    if fg is not None:
        if gyro_noise_rad_s is None:
            raise ShapeError("gyro_noise_rad_s is needed with gyro_body (the white-noise sigma per sample)")
        sg = _sigmas(gyro_noise_rad_s, k, "gyro_noise_rad_s")
        cg = wg / sg[None] ** 2
        if np.any(cg.sum(axis=1) == 0):
            raise NonFiniteError(f"{int((cg.sum(axis=1) == 0).sum())} sample(s) have no finite gyro triad")
        w0 = np.einsum("nk,nki->ni", cg, fg) / cg.sum(axis=1)[:, None]
    else:
        sg = None
    if omega_init is not None:
        w0 = np.asarray(omega_init, dtype=float).reshape(N, 3)
    elif fg is None:
        raise ShapeError("a gyro-free array needs omega_init (N, 3): w enters the accelerometers only quadratically")
    ca = wa / sa[None] ** 2
    fast = bool(np.all(wa == 1))
    st = _Structure(r, 1 / sa**2) if fast else None

    def info_grad(w: np.ndarray, ra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if fast:
            return st.info(w), st.grad(w, ra)
        J = accel_jacobian(w, r)
        Jw = (J * ca[:, :, None, None]).reshape(N, 3 * k, 9)
        Jt = np.swapaxes(Jw, 1, 2)
        return np.matmul(Jt, J.reshape(N, 3 * k, 9)), np.matmul(Jt, ra.reshape(N, 3 * k, 1))[..., 0]

    # linear start for (w', s) given w0
    y = fa - np.cross(w0[:, None], np.cross(w0[:, None], r[None]))
    info0, b0 = info_grad(w0, y)
    theta = np.column_stack([w0, np.linalg.solve(info0[:, 3:9, 3:9], b0[:, 3:9, None])[..., 0]])
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        ra = fa - accel_model(theta, r)
        info, grad = info_grad(theta[:, 0:3], ra)
        if fg is not None:
            info[:, 0:3, 0:3] += cg.sum(axis=1)[:, None, None] * np.eye(3)
            grad[:, 0:3] += np.einsum("nk,nki->ni", cg, fg - theta[:, None, 0:3])
        step = np.linalg.solve(info, grad[..., None])[..., 0]
        theta = theta + step
        if np.max(np.abs(step[:, 0:3])) < tol * max(1.0, float(np.abs(theta[:, 0:3]).max())):
            break
    info = fisher_information(theta[:, 0:3], r, None if fg is None else sg, sa, wg, wa)
    cov = np.linalg.inv(info)
    return ArrayMotion(theta[:, 0:3], theta[:, 3:6], theta[:, 6:9], cov, it, miss_a + miss_g)
