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
    "angular_acceleration",
    "remove_lever_arms",
    "LeverArmTransfer",
    "transfer_to_reference",
    "DERIVATIVE_NOISE_GAIN",
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


def angular_acceleration(t: np.ndarray, omega: np.ndarray, order: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Angular acceleration by a central difference of the (array-mean) rate, centred on each sample, where it
    is known: ``(omega_dot (N, 3), ok (N,))``.

    ``order`` 2: ``(w[n+1] - w[n-1]) / 2h``, truncation error ``h^2 w'''/6``; ``order`` 4:
    ``(w[n-2] - 8 w[n-1] + 8 w[n+1] - w[n+2]) / 12h``, error ``h^4 w^(5)/30``. A sample is known (``ok``) only
    when it and every sample of its stencil are finite and on the grid (``t`` steps within 10 % of the median
    step): an epoch next to a clipped or missing gyro sample has no angular acceleration (NaN), never a
    difference across the gap.

    >>> t = np.arange(10) * 0.01
    >>> w = np.stack([np.sin(t), 0 * t, t**2], axis=1)
    >>> wd, ok = angular_acceleration(t, w)
    >>> ok.astype(int).tolist()
    [0, 0, 1, 1, 1, 1, 1, 1, 0, 0]
    >>> bool(np.allclose(wd[ok], np.stack([np.cos(t), 0 * t, 2 * t], axis=1)[ok], atol=1e-9))
    True
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(omega, dtype=float)
    if order not in (2, 4):
        raise ShapeError(f"order must be 2 or 4, got {order}")
    n, m = len(t), order // 2
    wd = np.full(w.shape, np.nan)
    ok = np.zeros(n, bool)
    if n < 2 * m + 1:
        return wd, ok
    dt = np.diff(t)
    h = float(np.median(dt))
    step_ok = np.abs(dt - h) <= 0.1 * h
    fin = np.isfinite(w).all(axis=1)
    good = fin.copy()
    for j in range(-m, m + 1):  # every stencil sample finite, every step inside the stencil on the grid
        good[m:n - m] &= fin[m + j:n - m + j]
    for j in range(-m, m):
        good[m:n - m] &= step_ok[m + j:n - m + j]
    good[:m] = False
    good[n - m:] = False
    if order == 2:
        wd[1:-1] = (w[2:] - w[:-2]) / (2 * h)
    else:
        wd[2:-2] = (w[:-4] - 8 * w[1:-3] + 8 * w[3:-1] - w[4:]) / (12 * h)
    wd[~good] = np.nan
    return wd, good


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


#: noise gain of the central differences: the derivative's noise is ``sigma_w * gain / h`` (order -> gain)
DERIVATIVE_NOISE_GAIN = {2: float(np.sqrt(0.5)), 4: float(np.sqrt(130.0) / 12.0)}


@dataclass
class LeverArmTransfer:
    """Result of :func:`transfer_to_reference` (body frame, SI).

    Attributes
    ----------
    accel_m_s2 : ndarray (N, k, 3)
        Each triad's specific force moved to the reference point; NaN where ``valid`` is False.
    valid : ndarray (N,)
        Whether the angular acceleration is known at the epoch (no clipped, missing or off-grid gyro sample in
        the derivative's stencil): elsewhere the transfer is not computed (never a wrong number).
    omega_dot : ndarray (N, 3)
        The angular acceleration used [rad/s^2] (NaN where unknown).
    sigma_m_s2 : ndarray (N, k)
        1-sigma per axis of each triad's transfer error: the gyro noise through the centripetal term and the
        derivative, the position uncertainty through ``K = [w' x] + [w x]^2``, and the derivative's truncation
        error (estimated from the data: the difference of the order-2 and order-4 derivatives, which is order 2's
        leading error ``h^2 w'''/6``, its largest over five samples; for order 4 a quarter of it, a bound for motion below ``0.178 / h`` Hz).
    """

    accel_m_s2: np.ndarray
    valid: np.ndarray
    omega_dot: np.ndarray
    sigma_m_s2: np.ndarray


def transfer_to_reference(
    t: np.ndarray, accel_body: np.ndarray, omega: np.ndarray, positions_m: np.ndarray,
    reference_m: "np.ndarray | None" = None, order: int = 2, gyro_noise_rad_s: float = 0.0,
    position_std_m: "float | np.ndarray" = 0.0, truncation: bool = True,
) -> LeverArmTransfer:
    """Every accelerometer triad's specific force transferred to the reference point with the gyros' rate and its
    central-difference derivative (Skog et al. 2016, Sec. II: ``z_a,j = s + w' x r_j + w x (w x r_j)``).

    Parameters
    ----------
    t : ndarray (N,)
        Sample times [s] on a uniform grid (gaps and non-finite rates make the neighbouring epochs invalid).
    accel_body : ndarray (N, k, 3)
        Specific force of each triad, body frame [m/s^2].
    omega : ndarray (N, 3)
        The array's angular rate [rad/s] (the mean of the gyro triads: less noise than any one), NaN where a gyro
        clipped.
    positions_m : ndarray (k, 3)
        Triad positions [m]; ``reference_m`` the reference point (default: their origin).
    order : {2, 4}
        Order of the central difference (:func:`angular_acceleration`).
    gyro_noise_rad_s : float
        1-sigma per axis of ``omega``'s noise per sample.
    position_std_m : float or ndarray (k,)
        1-sigma per axis of the positions.
    truncation : bool
        Include the estimated truncation error in ``sigma_m_s2`` (its estimate carries the gyro noise too: at rest
        it makes the stated sigma conservative).

    Returns
    -------
    LeverArmTransfer

    Examples
    --------
    A board spinning up about z at 100 rad/s^2: every triad's specific force comes back to the reference's.

    >>> t = np.arange(20) * 0.01
    >>> w = np.stack([0 * t, 0 * t, 100 * t], axis=1)
    >>> r = np.array([[0.01, 0, 0], [0, 0.01, 0]])
    >>> f = lever_arm_acceleration(w, np.tile([0, 0, 100.0], (20, 1)), r) + [0, 0, 9.81]
    >>> tr = transfer_to_reference(t, f, w, r)
    >>> bool(np.allclose(tr.accel_m_s2[tr.valid], [0, 0, 9.81])), int(tr.valid.sum())
    (True, 18)
    """
    from scipy.ndimage import maximum_filter1d

    f = np.asarray(accel_body, dtype=float)
    r = np.asarray(positions_m, dtype=float)
    w = np.asarray(omega, dtype=float)
    if f.ndim != 3 or f.shape[1:] != r.shape or w.shape != (f.shape[0], 3):
        raise ShapeError(f"accel_body (N, k, 3) with k = {r.shape[0]} and omega (N, 3) expected, got {f.shape} "
                         f"and {w.shape}")
    if reference_m is not None:
        r = r - np.asarray(reference_m, dtype=float)[None, :]
    wd, ok = angular_acceleration(t, w, order)
    wz = np.where(ok[:, None], w, 0.0)
    wdz = np.where(ok[:, None], wd, 0.0)
    out = f - lever_arm_acceleration(wz, wdz, r)
    out[~ok] = np.nan
    h = float(np.median(np.diff(t)))
    rn = np.linalg.norm(r, axis=1)
    wn = np.linalg.norm(wz, axis=1)
    # truncation: order 2's error is about its difference from order 4; order 4's is smaller (bounded by it)
    other, ok2 = angular_acceleration(t, w, 4 if order == 2 else 2)
    trunc = np.where(ok & ok2, np.linalg.norm(np.nan_to_num(wd - other), axis=1), 0.0)
    # its largest value over five samples: defined where the wider stencil is not (next to a gap), and a bound
    trunc = maximum_filter1d(trunc, 5, mode="nearest") if truncation else 0.0 * trunc
    if order == 4:  # its error is (2 pi f h)^2 / 5 times order 2's for motion at f: a quarter bounds f < 0.178 / h
        trunc = trunc / 4.0
    s_wd = gyro_noise_rad_s * DERIVATIVE_NOISE_GAIN[order] / h
    sp = np.broadcast_to(np.asarray(position_std_m, dtype=float), (r.shape[0],))
    knorm = np.linalg.norm(wdz, axis=1) + wn**2
    var = ((2 * wn[:, None] * gyro_noise_rad_s * rn[None]) ** 2 + (s_wd * rn[None]) ** 2
           + (knorm[:, None] * sp[None]) ** 2 + (trunc[:, None] * rn[None]) ** 2 / 3.0)
    sigma = np.sqrt(var)
    sigma[~ok] = np.nan
    return LeverArmTransfer(out, ok, wd, sigma)


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
