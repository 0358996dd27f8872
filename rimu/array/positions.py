"""Accelerometer triads' positions (lever arms), gains and biases from motion (Carlsson, Skog & Jalden 2021).

Model, body frame, triad j (its samples already moved to the array's time by its gyro sampling offset)::

    z_j(t) = D_j (s(t) + K(t) r_j) + c_j + noise,      K = [w' x] + [w x]^2

with ``w``, ``w'`` from the (relatively calibrated) gyro array, ``s`` the specific force at the reference point
(a nuisance, one per sample), ``D_j`` the triad's gain matrix, ``c_j`` its bias and ``r_j`` its position. Unlike
the gyros, the accelerometers' common gain is largely observable through the lever-arm terms (the gyros fix the
frame of ``K``); what is not:

* a common translation of all positions (absorbed by ``s``): positions are reported with the mean of the nominal
  positions, or centred when none are given;
* a common isotropic scale of the accelerometers together with the scale of all positions: fixed by
  ``mean_j trace(D_j) = 3`` (mean accelerometer scale taken as exact);
* a common bias (absorbed by ``s``): fixed by ``sum_j c_j = 0``;
* any common-mode error of the gyro array (its scale enters K): the positions are in the gyro array's frame.

Estimation: Gauss-Newton on all triads' parameters jointly with ``s`` eliminated per sample (its normal-equation
block is the same in every sample), the three gauges as equality constraints (KKT), covariance from the
constrained inverse of the Fisher information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import IdentifiabilityError, ShapeError
from .layout import ArrayLayout
from .relative import (
    DERIVATIVE_CUTOFF_HZ,
    RelativeFit,
    _noise_from_differences,
    _sigma_from_residual_var,
    derivative,
    time_shift,
)
from .runtime import angular_acceleration, skew

__all__ = ["PositionFit", "aa_from_accelerometers_refusal", "accel_angular_acceleration", "angular_acceleration_check",
           "fit_positions"]


@dataclass
class PositionFit:
    """Result of :func:`fit_positions` (body frame).

    Attributes
    ----------
    layout : ArrayLayout
        The layout with the estimated positions.
    gain : ndarray (k, 3, 3)
    bias_m_s2 : ndarray (k, 3)
    positions_m : ndarray (k, 3)
    covariance : ndarray (k, 15, 15) or (k, 16, 16)
        Per triad: gain (9, row-major), bias (3), position (3)[, accelerometer sampling offset (1)].
    sigma_m_s2 : ndarray (k,)
    parity_rms_m_s2 : dict of str -> ndarray (k,)
        ``"raw"``; ``"aligned"`` (moved by the gyro sampling offsets); ``"raw_nominal_lever_arms"`` (aligned,
        lever-arm terms at the nominal positions removed); ``"gain_bias_nominal_lever_arms"`` (and gains and
        biases removed); ``"positions"`` (lever arms at the estimated positions): rms of each triad's difference
        from the array mean, in motion; ``"accel_angular_acceleration"``: the angular acceleration taken from the
        accelerometers themselves in every sample, not from the gyros' derivative (the centripetal term from the
        gyros' rate), scaled by leverage to compare like for like (:func:`accel_angular_acceleration`); NaN with
        fewer than three triads or positions on one line.
    nominal_m : ndarray (k, 3) or None
    iterations : int
    """

    layout: ArrayLayout
    gain: np.ndarray
    bias_m_s2: np.ndarray
    positions_m: np.ndarray
    covariance: np.ndarray
    sigma_m_s2: np.ndarray
    parity_rms_m_s2: dict
    nominal_m: "np.ndarray | None"
    iterations: int
    sampling_offset_s: "np.ndarray | None" = None
    gain_mode: str = "absolute"
    accel_offset_s: "np.ndarray | None" = None
    #: epochs in motion left out because their angular acceleration is unknown (a clipped or missing gyro sample
    #: inside the derivative's stencil), and the epochs in motion in all
    lever_arm_invalid: int = 0
    moving_epochs: int = 0
    derivative_order: int = 4

    def apply(self, t: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """Compensate raw accelerometer triads (N, k, 3, own axes): body-frame specific force at each triad,
        on the array's time (moved by the gyro sampling offsets), gains and biases removed. Feed it with
        ``positions_m`` to :func:`rimu.array.ml_motion` or :func:`rimu.array.remove_lever_arms`."""
        z = self.layout.to_body(np.asarray(accel, dtype=float))
        tau = np.zeros(z.shape[1])
        if self.sampling_offset_s is not None:
            tau = tau + self.sampling_offset_s
        if self.accel_offset_s is not None:
            tau = tau + self.accel_offset_s
        if np.any(tau != 0):
            z = _shifted(t, z, tau)
        return np.einsum("kab,nkb->nka", np.linalg.inv(self.gain), z - self.bias_m_s2[None])

    def parity_on(self, t: np.ndarray, accel: np.ndarray, omega: np.ndarray,
                  motion_threshold_deg_s: float = 30.0) -> tuple[dict, int, int]:
        """The parity rms in motion of every step on other data (a held-out part): ``(steps, moving, invalid)``.

        ``steps`` has the keys of :attr:`parity_rms_m_s2` (m/s^2, per triad), computed on ``t``, raw
        ``accel`` (N, k, 3, own axes) and the array rate ``omega`` (N, 3) with this fit's parameters; epochs
        whose angular acceleration is unknown (:func:`rimu.array.angular_acceleration`) are left out and
        counted (``invalid``, of ``moving`` epochs in motion).
        """
        t = np.asarray(t, dtype=float)
        z = self.layout.to_body(np.asarray(accel, dtype=float))
        wd, ok = _omega_dot(t, omega, self.derivative_order)
        fin = ok & np.isfinite(z).all(axis=(1, 2))
        moving = np.linalg.norm(np.nan_to_num(omega), axis=1) > np.radians(motion_threshold_deg_s)
        use = moving & fin
        if use.sum() < 10:
            raise ShapeError(f"only {int(use.sum())} epochs in motion with a known angular acceleration")
        Kt = _K(np.where(fin[:, None], omega, 0.0), np.where(fin[:, None], wd, 0.0))
        nominal = self.layout.positions_m if self.nominal_m is None else np.asarray(self.nominal_m)
        c0 = nominal.mean(axis=0)
        tau = np.zeros(z.shape[1]) if self.sampling_offset_s is None else self.sampling_offset_s
        za = _shifted(t, np.where(np.isfinite(z), z, 0.0), tau) if np.any(tau != 0) else z
        f_gb = self.apply(t, np.where(np.isfinite(z), accel, 0.0))
        steps = {"raw": _rms_parity(z, use), "aligned": _rms_parity(za, use),
                 "raw_nominal_lever_arms": _rms_parity(za - np.einsum("nab,kb->nka", Kt, nominal - c0), use),
                 "gain_bias_nominal_lever_arms": _rms_parity(f_gb - np.einsum("nab,kb->nka", Kt, nominal - c0), use),
                 "positions": _rms_parity(f_gb - np.einsum("nab,kb->nka", Kt, self.positions_m - c0), use),
                 "accel_angular_acceleration": _rms_parity_accel_aa(f_gb, np.nan_to_num(omega), self.positions_m - c0,
                                                                    use)}
        return steps, int(moving.sum()), int((moving & ~fin).sum())

    def to_dict(self) -> dict:
        """Plain dictionary (JSON-ready), SI units, body frame."""
        return {"type": "rimu.array.PositionFit", "version": 1, "triads": list(self.layout.names),
                "gain_mode": self.gain_mode, "gain": self.gain.tolist(), "bias_m_s2": self.bias_m_s2.tolist(),
                "positions_m": self.positions_m.tolist(), "position_std_m": self.position_std_m().tolist(),
                "sigma_m_s2": self.sigma_m_s2.tolist(),
                "accel_offset_s": None if self.accel_offset_s is None else self.accel_offset_s.tolist(),
                "nominal_m": None if self.nominal_m is None else np.asarray(self.nominal_m).tolist(),
                "lever_arm_invalid_epochs": self.lever_arm_invalid, "moving_epochs": self.moving_epochs,
                "parity_rms_m_s2": {k: v.tolist() for k, v in self.parity_rms_m_s2.items()}}

    def vector(self) -> np.ndarray:
        """(k, 15 or 16): gain - I (row-major), bias, position[, accelerometer sampling offset]."""
        parts = [(self.gain - np.eye(3)).reshape(-1, 9), self.bias_m_s2, self.positions_m]
        if self.accel_offset_s is not None:
            parts.append(self.accel_offset_s[:, None])
        return np.hstack(parts)

    def std(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.einsum("kii->ki", self.covariance), 0.0))

    def position_std_m(self) -> np.ndarray:
        return self.std()[:, 12:15]

    def offset_from_nominal_m(self) -> np.ndarray:
        """Estimated minus nominal position [m] (k, 3); raises when no nominal positions were given."""
        if self.nominal_m is None:
            raise ShapeError("no nominal positions were given to fit_positions")
        return self.positions_m - self.nominal_m


def _omega_dot(t: np.ndarray, omega: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rimu.array.angular_acceleration`, after the zero-phase low-pass of :func:`derivative` (at
    ``DERIVATIVE_CUTOFF_HZ``, where that is below 0.4 times the sampling rate) when the rate has no gap: fast-sampled
    arrays keep the gyro noise out of the derivative; a 62.5 Hz board is not filtered."""
    t = np.asarray(t, dtype=float)
    dt = np.diff(t)
    fs = 1.0 / float(np.median(dt))
    clean = np.isfinite(omega).all() and np.allclose(dt, dt.mean(), rtol=1e-6, atol=0)
    if clean and DERIVATIVE_CUTOFF_HZ < 0.4 * fs and len(t) > 30:
        from scipy.signal import butter, sosfiltfilt

        omega = sosfiltfilt(butter(4, DERIVATIVE_CUTOFF_HZ, fs=fs, output="sos"), omega, axis=0,
                            padlen=min(len(t) - 1, int(4 * fs / DERIVATIVE_CUTOFF_HZ)))
    wd, ok = angular_acceleration(t, omega, order)
    # the record's own ends (not a gap) keep the one-sided second-order difference they always had
    m = order // 2
    if len(t) > 2 * m + 2 and np.isfinite(omega[: 2 * m + 1]).all() and np.isfinite(omega[-2 * m - 1:]).all():
        edge = np.gradient(omega, t, axis=0, edge_order=2)
        wd[:m], wd[-m:] = edge[:m], edge[-m:]
        ok[:m] = ok[-m:] = True
    return wd, ok


def _K(w: np.ndarray, wd: np.ndarray) -> np.ndarray:
    W = skew(w)
    return skew(wd) + W @ W


def _jac(Kt, D, r, s, dv=None) -> np.ndarray:
    """Jacobian of every triad's output w.r.t. its parameters (gain 9, bias 3, position 3, and the sampling
    offset when ``dv``, the time derivative of ``s + K r_j`` (n, k, 3), is given): (n, k, 3, 15 or 16)."""
    n, k = s.shape[0], D.shape[0]
    X = np.zeros((n, k, 3, 15 if dv is None else 16))
    v = s[:, None] + np.einsum("nab,kb->nka", Kt, r)
    for i in range(3):
        X[:, :, i, 3 * i:3 * i + 3] = v
    X[:, :, :, 9:12] = np.eye(3)
    X[:, :, :, 12:15] = np.einsum("kab,nbc->nkac", D, Kt)
    if dv is not None:
        X[:, :, :, 15] = np.einsum("kab,nkb->nka", D, dv)
    return X


def _kkt(Kt, D, r, s, sigma, G, dv=None) -> np.ndarray:
    """Normal matrix with the per-sample specific force eliminated, bordered by the gauge constraints G."""
    n, k, p = s.shape[0], D.shape[0], 15 if dv is None else 16
    wj = 1 / sigma**2
    X = _jac(Kt, D, r, s, dv)
    Xw = X * wj[None, :, None, None]
    Nd = np.einsum("nkap,nkaq->kpq", Xw, X)
    M = np.einsum("k,kai,kaj->ij", wj, D, D)
    C = np.einsum("kai,nkap->nikp", D, Xw).reshape(n, 3, k * p)
    Mi_C = np.einsum("ij,njq->niq", np.linalg.inv(M), C).reshape(n * 3, k * p)
    Nfull = -(C.reshape(n * 3, k * p).T @ Mi_C)
    for j in range(k):
        Nfull[j * p:(j + 1) * p, j * p:(j + 1) * p] += Nd[j]
    nc = G.shape[0]
    KKT = np.zeros((k * p + nc, k * p + nc))
    KKT[:k * p, :k * p] = Nfull
    KKT[:k * p, k * p:] = G.T
    KKT[k * p:, :k * p] = G
    return KKT


#: largest predicted standard deviation at which a parameter counts as identified (positions: a tenth of the
#: nominal array's extent, or this when no nominal positions are known)
_MAX_SD = {"gain": 0.05, "position": 0.01, "offset": 0.005}


def _check_identifiable(Kt, z, D, c, r, sigma, G, gain, t=None) -> None:
    """Predicted standard deviations at the start (gain = I, nominal positions): refuse what the motion cannot give."""
    k = D.shape[0]
    wj = 1 / sigma**2
    Kr, s, _e = _specific_force(z, Kt, D, c, r, wj)
    dv = None if t is None else derivative(t, s[:, None] + Kr)
    p = 15 if dv is None else 16
    KKT = _kkt(Kt, D, r, s, sigma, G, dv)
    sd = np.sqrt(np.abs(np.diag(np.linalg.inv(KKT))[:k * p])).reshape(k, p)
    msgs, names = [], []
    if dv is not None and sd[:, 15].max() > _MAX_SD["offset"]:
        names.append("accel_offset")
        msgs.append(f"the accelerometer sampling offsets need a changing specific force (jerk): predicted sd up "
                    f"to {sd[:, 15].max() * 1e3:.3g} ms")
    if gain != "none" and sd[:, 0:9].max() > _MAX_SD["gain"]:
        ev, V = np.linalg.eigh(np.cov(s.T))
        d0 = V[:, 0] * np.sign(V[np.argmax(np.abs(V[:, 0])), 0])
        names.append("accel_gain")
        extra = (" and, for their common part (gain='absolute'), lever arms: nominal positions spread over the "
                 "board and fast rotation" if gain == "absolute" else "")
        msgs.append(f"the {gain} accelerometer gains need specific force along every axis (turn the array against "
                    f"gravity){extra}: predicted sd up to {sd[:, 0:9].max():.2g}; the specific force varies least "
                    f"along body [{d0[0]:+.2f} {d0[1]:+.2f} {d0[2]:+.2f}], {np.sqrt(max(ev[0], 0)):.3g} m/s^2 rms; "
                    "try gain='relative' or gain='none'")
    extent = float(np.linalg.norm(r[:, None] - r[None], axis=2).max())
    pos_limit = 0.1 * extent if extent > 0 else _MAX_SD["position"]
    if sd[:, 12:15].max() > pos_limit:
        names.append("position")
        msgs.append(f"the positions need angular rate and angular acceleration about every axis (the lever-arm "
                    f"terms w' x r + w x (w x r)): predicted sd up to {sd[:, 12:15].max() * 1e3:.3g} mm, more than "
                    f"{pos_limit * 1e3:.3g} mm (a tenth of the array's extent)")
    if names:
        raise IdentifiabilityError("the motion cannot identify " + ", ".join(names) + ": " + "; ".join(msgs),
                                   parameters=names)


def _shifted(t, z0, tau) -> np.ndarray:
    return np.stack([time_shift(t, z0[:, j], -tau[j]) for j in range(z0.shape[1])], axis=1)


def _specific_force(z, Kt, D, c, r, wj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``K r_j`` (n, k, 3), the specific force ``s`` at the reference point (n, 3) by weighted least squares given
    the triads' parameters (the nuisance eliminated per sample, module docstring), and the residuals (n, k, 3)."""
    Kr = np.einsum("nab,kb->nka", Kt, r)
    M = np.einsum("k,kai,kaj->ij", wj, D, D)
    rhs = np.einsum("k,kai,nka->ni", wj, D, z - c[None] - np.einsum("kab,nkb->nka", D, Kr))
    s = np.linalg.solve(M, rhs.T).T
    e = z - np.einsum("kab,nkb->nka", D, s[:, None] + Kr) - c[None]
    return Kr, s, e


def _cost(z, Kt, D, c, r, wj) -> float:
    e = _specific_force(z, Kt, D, c, r, wj)[2]
    return float(np.einsum("k,nka,nka->", wj, e, e))


def aa_from_accelerometers_refusal(positions_m: np.ndarray) -> "str | None":
    """Why the angular acceleration cannot be taken from the accelerometers of triads at ``positions_m`` (k, 3),
    or None when it can: six unknowns per epoch (``s``, ``w'``) need 3k - 6 > 0 parity dof (k >= 3) and positions
    not on one line (a line leaves the angular acceleration about it unseen)."""
    r = np.asarray(positions_m, dtype=float)
    k = r.shape[0]
    if k < 3:
        return (f"{k} triads: the angular acceleration from the accelerometers has 6 unknowns per epoch and needs "
                f"3 triads at least (parity dof 3k - 6 = {3 * k - 6})")
    sv = np.linalg.svd(r - r.mean(axis=0), compute_uv=False)
    if sv[0] <= 0 or sv[1] < 1e-3 * sv[0]:
        return ("the triads' positions lie on one line: the angular acceleration about it is not seen by the "
                "accelerometers")
    return None


def accel_angular_acceleration(f: np.ndarray, omega: np.ndarray, positions_m: np.ndarray,
                               sigma_m_s2: "float | None" = None) -> dict:
    """The angular acceleration and specific force per epoch from the accelerometers themselves, and the parity
    that is left (Skog et al. 2016, Sec. II, the accelerometer-array model with ``w`` from the gyros).

    Model, body frame, triad j at ``r_j`` (relative to the reference point), every epoch ``n``::

        f_j - [w x]^2 r_j = s - [r_j x] w'  + noise,    i.e.   g_n = A (s_n, w'_n) + noise,
        A = [[I, -[r_1 x]], ..., [I, -[r_k x]]]      (3k x 6)

    ``w`` from the gyros (the centripetal term), ``s`` and ``w'`` unknown per epoch: least squares, ``(s, w')_n =
    A^+ g_n``, covariance ``sigma^2 (A^T A)^-1``. The parity is the residual projected onto the left null space of
    ``A``: ``e_n = (I - A A^+) g_n``, 3k - 6 dof per epoch (the plain model, ``s`` only, leaves 3k - 3).

    Degrees of freedom. With white noise of variance ``sigma^2`` per axis, ``E[e_i^2] = sigma^2 (1 - h_i)`` where
    ``h_i`` is the leverage (diagonal of ``A A^+``, summing to 6). The plain model's parity (each triad minus the
    array mean, as in every other step of the table) has ``h_i = 1/k``: its rms per triad is ``sigma sqrt((k -
    1)/k)``. So that the two compare like for like, each component here is scaled by ``sqrt(((k - 1)/k) / (1 -
    h_i))``::

        parity_rms_j = sqrt( mean_{n, a} e_{n,ja}^2 (k - 1) / (k (1 - h_ja)) )

    which has the same expectation, ``sigma^2 (k - 1)/k``, as the plain figure (over all triads: the residual sum
    of squares divided by its dof, ``3k - 6``, times ``(3k - 3) / 3k``). ``per_dof_m_s2``, the rms per parity dof,
    ``sqrt(sum ||e_n||^2 / (N (3k - 6)))``, estimates ``sigma`` itself.

    Parameters
    ----------
    f : ndarray (N, k, 3)
        Specific force at each triad, body frame [m/s^2] (gains and biases removed).
    omega : ndarray (N, 3)
        Angular rate from the gyros [rad/s].
    positions_m : ndarray (k, 3)
        Triad positions relative to the reference point [m].
    sigma_m_s2 : float, optional
        Accelerometer noise per axis for the covariance; default the per-dof figure.

    Returns
    -------
    dict
        ``angular_acceleration_rad_s2`` (N, 3), ``specific_force_m_s2`` (N, 3), ``covariance`` (6, 6) per epoch
        ((s, w'), SI), ``parity_rms_m_s2`` (k,) (scaled like the plain parity, above), ``per_dof_m_s2`` and
        ``dof`` (3k - 6), ``parity_m_s2`` (N, k, 3) the projected residual ``e_n`` (unscaled).

    Raises
    ------
    IdentifiabilityError
        Fewer than 3 triads, or positions on one line (:func:`aa_from_accelerometers_refusal`).

    Examples
    --------
    >>> r = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]) - 0.025
    >>> wd = np.array([[1.0, -2.0, 3.0]])
    >>> f = np.array([9.8, 0, 0]) - np.cross(r, wd)[None]       # w = 0: f_j = s + w' x r_j
    >>> out = accel_angular_acceleration(f, np.zeros((1, 3)), r)
    >>> np.round(out["angular_acceleration_rad_s2"], 6).tolist(), out["dof"]
    ([[1.0, -2.0, 3.0]], 6)
    """
    r = np.asarray(positions_m, dtype=float)
    why = aa_from_accelerometers_refusal(r)
    if why is not None:
        raise IdentifiabilityError(why, parameters=["angular_acceleration"])
    k = r.shape[0]
    f = np.asarray(f, dtype=float)
    W = skew(np.asarray(omega, dtype=float))
    g = (f - np.einsum("nab,kb->nka", W @ W, r)).reshape(len(f), 3 * k)
    A = np.zeros((k, 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -skew(r)
    A = A.reshape(3 * k, 6)
    Ap = np.linalg.pinv(A)
    x = g @ Ap.T
    e = g - x @ A.T
    h = np.einsum("ij,ji->i", A, Ap)
    dof = 3 * k - 6
    per_dof = float(np.sqrt(np.sum(e**2) / (len(f) * dof))) if len(f) else float("nan")
    scaled = e**2 * ((k - 1) / k) / (1 - h)[None]
    sig = per_dof if sigma_m_s2 is None else float(sigma_m_s2)
    return {"angular_acceleration_rad_s2": x[:, 3:], "specific_force_m_s2": x[:, :3],
            "covariance": sig**2 * np.linalg.inv(A.T @ A), "parity_rms_m_s2":
            np.sqrt(scaled.reshape(len(f), k, 3).mean(axis=(0, 2))), "per_dof_m_s2": per_dof, "dof": dof,
            "parity_m_s2": e.reshape(len(f), k, 3)}


def _rms_parity_accel_aa(f: np.ndarray, omega: np.ndarray, r: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Parity rms per triad with the angular acceleration taken from the accelerometers themselves
    (:func:`accel_angular_acceleration`, scaled like the plain parity); NaN where it cannot be taken (fewer than
    three triads, positions on one line)."""
    if aa_from_accelerometers_refusal(r) is not None:
        return np.full(r.shape[0], np.nan)
    return accel_angular_acceleration(f[moving], omega[moving], r)["parity_rms_m_s2"]


def _rms_parity(e: np.ndarray, moving: np.ndarray) -> np.ndarray:
    y = e[moving] - e[moving].mean(axis=1, keepdims=True)
    return np.sqrt(np.mean(y**2, axis=(0, 2)))


def angular_acceleration_check(t: np.ndarray, accel_body: np.ndarray, omega: np.ndarray, positions_m: np.ndarray,
                               order: int = 2, motion_threshold_deg_s: float = 30.0, lags: int = 2) -> dict:
    """What limits the accelerometers' agreement once the lever arms are removed with the gyros' angular
    acceleration: the share of what is left that an angular acceleration explains, and whether the gyro samples
    hold it.

    In every epoch in motion with a known angular acceleration (:func:`rimu.array.angular_acceleration`), the
    angular acceleration is also estimated from the accelerometers themselves (``f_j - w x (w x r_j) = s -
    [r_j x] w'``, least squares per sample, Skog et al. 2016, Sec. II). Returned (SI):

    * ``parity_gyro_m_s2``: rms of the residual with the gyros' ``w'`` (per triad axis, triads minus their mean);
    * ``parity_accel_m_s2``: the same with the accelerometers' ``w'`` (scaled for its three more parameters per
      sample, ``sqrt((3k - 3) / (3k - 6))``), and ``share``: ``1 - (parity_accel / parity_gyro)^2``, the part of
      the residual's variance an angular acceleration explains;
    * ``difference_rad_s2``: rms per axis of the accelerometers' ``w'`` minus the gyros', ``gyro_rad_s2`` the rms
      of the gyros' ``w'``;
    * ``held_out``: the accelerometers' ``w'`` predicted on the second half of the epochs from the gyro rate by
      a linear filter over ``+-lags`` samples (all axes, fitted on the first half) and by the central difference:
      rms of what each leaves, ``{"fir_rad_s2", "central_difference_rad_s2", "epochs"}``. A filter no better
      than the difference says the angular acceleration the accelerometers see is not in the gyro samples.
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(omega, dtype=float)
    f = np.asarray(accel_body, dtype=float)
    r = np.asarray(positions_m, dtype=float)
    k = r.shape[0]
    if k < 3:
        raise ShapeError(f"{k} triads: the angular acceleration from the accelerometers needs three at least")
    wd, ok = angular_acceleration(t, w, order)
    moving = np.linalg.norm(np.nan_to_num(w), axis=1) > np.radians(motion_threshold_deg_s)
    use = ok & moving & np.isfinite(f).all(axis=(1, 2))
    idx = np.flatnonzero(use)
    if len(idx) < 20:
        raise ShapeError(f"only {len(idx)} epochs in motion with a known angular acceleration")
    W = skew(w[idx])
    g = f[idx] - np.einsum("nab,kb->nka", W @ W, r)
    ea = g - np.cross(wd[idx][:, None], r[None])
    ea = ea - ea.mean(axis=0)
    ya = ea - ea.mean(axis=1, keepdims=True)
    A = np.zeros((k, 3, 6))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:] = -skew(r)
    A = A.reshape(3 * k, 6)
    g2 = (g - g.mean(axis=0)).reshape(len(idx), 3 * k)
    sol = np.einsum("ij,nj->ni", np.linalg.pinv(A), g2)
    eb = g2 - sol @ A.T
    wd_acc = np.einsum("ij,nj->ni", np.linalg.pinv(A), g.reshape(len(idx), 3 * k))[:, 3:]
    pa = float(np.sqrt(np.mean(ya**2)))
    pb = float(np.sqrt(np.mean(eb**2) * (3 * k - 3) / (3 * k - 6)))
    cols, fin = [], np.ones(len(idx), bool)
    for lag in range(-lags, lags + 1):
        j = np.clip(idx + lag, 0, len(w) - 1)
        x = w[j]
        fin &= np.isfinite(x).all(axis=1) & (np.abs(t[j] - t[idx] - lag * np.median(np.diff(t))) < 1e-6 + 0.1 * abs(
            float(np.median(np.diff(t)))))
        cols.append(np.nan_to_num(x))
    X = np.hstack([*cols, np.ones((len(idx), 1))])
    half = np.arange(len(idx)) < len(idx) // 2
    fit_, test = fin & half, fin & ~half
    held = {"fir_rad_s2": float("nan"), "central_difference_rad_s2": float("nan"), "epochs": int(test.sum())}
    if fit_.sum() > X.shape[1] and test.sum() > 0:
        coef = np.linalg.lstsq(X[fit_], wd_acc[fit_], rcond=None)[0]
        held["fir_rad_s2"] = float(np.sqrt(np.mean((wd_acc[test] - X[test] @ coef) ** 2)))
        held["central_difference_rad_s2"] = float(np.sqrt(np.mean((wd_acc[test] - wd[idx][test]) ** 2)))
    return {"epochs": int(len(idx)), "parity_gyro_m_s2": pa, "parity_accel_m_s2": pb, "share": 1.0 - (pb / pa) ** 2,
            "difference_rad_s2": np.sqrt(np.mean((wd_acc - wd[idx]) ** 2, axis=0)).tolist(),
            "gyro_rad_s2": np.sqrt(np.mean(wd[idx] ** 2, axis=0)).tolist(), "held_out": held}


def fit_positions(
    layout: ArrayLayout, t: np.ndarray, accel: np.ndarray, gyro_fit: "RelativeFit | None" = None,
    gyro: "np.ndarray | None" = None, omega: "np.ndarray | None" = None, nominal_positions_m: "np.ndarray | None" = None,
    max_iter: int = 15, motion_threshold_deg_s: float = 30.0, gain: str = "absolute", align: bool = True,
    offsets: bool = False, derivative_order: int = 4,
) -> PositionFit:
    """Positions, gains and biases of the accelerometer triads from motion (Carlsson, Skog & Jalden 2021).

    Parameters
    ----------
    layout : ArrayLayout
        Triad rotations; its positions are the nominal ones unless ``nominal_positions_m`` is given.
    t : ndarray (N,)
    accel : ndarray (N, k, 3)
        Raw accelerometer outputs in each triad's own axes [m/s^2].
    gyro_fit, gyro : RelativeFit and ndarray (N, k, 3), optional
        The gyros' relative calibration and raw outputs: give the array rate and each triad's sampling offset
        (the accelerometer samples are moved by it). Or pass ``omega`` (N, 3) directly.
    nominal_positions_m : ndarray (k, 3), optional
        Default: ``layout.positions_m``.
    gain : {"absolute", "relative", "none"}
        ``"absolute"`` (Carlsson et al.): every triad's gain matrix, their common part (but for the isotropic
        scale) seen through the lever-arm terms; needs nominal positions away from one point and lever-arm
        excitation. ``"relative"``: gains relative to the array mean (``mean_j D_j = I``), like the gyros.
        ``"none"``: gains kept at I, biases and positions only.
    align : bool
        Move every accelerometer triad by its gyro's sampling offset (one chip, one clock). False when the
        accelerometers and gyros are separate chips.
    offsets : bool
        Also estimate every accelerometer triad's own sampling offset (relative: their mean is zero), on top of
        ``align``; its column is the time derivative of the triad's modelled specific force.
    derivative_order : {2, 4}
        The central difference of the array rate that gives the angular acceleration
        (:func:`rimu.array.angular_acceleration`). An epoch whose stencil holds a gap (a clipped or missing gyro
        sample the caller left out: ``t`` steps off the grid) or a non-finite rate has no angular acceleration:
        it is left out of the fit and the parity figures, and counted (``PositionFit.lever_arm_invalid``).

    Raises
    ------
    IdentifiabilityError
        The motion cannot identify the gains or the positions; the message names the excitation they need.

    Returns
    -------
    PositionFit
    """
    t = np.asarray(t, dtype=float)
    z = layout.to_body(np.asarray(accel, dtype=float))
    N, k = z.shape[:2]
    nominal = np.asarray(layout.positions_m if nominal_positions_m is None else nominal_positions_m, dtype=float)
    if nominal.shape != (k, 3):
        raise ShapeError(f"nominal_positions_m must be ({k}, 3), got {nominal.shape}")
    if omega is None:
        if gyro_fit is None or gyro is None:
            raise ShapeError("pass gyro_fit and gyro (the array's gyros), or omega (N, 3)")
        u = gyro_fit.apply(t, gyro)
        a = 1 / gyro_fit.sigma_rad_s**2
        omega = np.einsum("k,nki->ni", a / a.sum(), u)
        tau = gyro_fit.sampling_offset_s if align else np.zeros(k)
    else:
        omega = np.asarray(omega, dtype=float)
        tau = np.zeros(k)
    z_raw = z
    moving_all = np.linalg.norm(omega, axis=1) > np.radians(motion_threshold_deg_s)
    raw_all = _rms_parity(z, moving_all if moving_all.sum() >= 10 else np.ones(N, bool))
    if np.any(tau != 0):
        z = np.stack([time_shift(t, z[:, j], -tau[j]) for j in range(k)], axis=1)
    aligned_all = _rms_parity(z, moving_all if moving_all.sum() >= 10 else np.ones(N, bool))
    m = int(np.ceil(np.abs(tau).max() / np.max(np.diff(t)))) + 3
    z, t, omega = z[m:N - m], t[m:N - m], omega[m:N - m]
    # the lever-arm terms need w and w' at the accelerometer's sample: an epoch whose derivative stencil crosses a
    # gap (a clipped gyro sample left out) or holds a non-finite rate is invalid for this step, never bridged
    wd, lever_ok = _omega_dot(t, omega, derivative_order)
    lever_ok &= np.isfinite(z).all(axis=(1, 2))
    moving0 = np.linalg.norm(np.nan_to_num(omega), axis=1) > np.radians(motion_threshold_deg_s)
    n_moving, n_invalid = int(moving0.sum()), int((moving0 & ~lever_ok).sum())
    if lever_ok.sum() < 10:
        raise IdentifiabilityError(f"only {int(lever_ok.sum())} epochs have a known angular acceleration (the gyros "
                                   "clip or are missing around the others)", parameters=["position"])
    z, t, omega, wd = z[lever_ok], t[lever_ok], omega[lever_ok], wd[lever_ok]
    Kt = _K(omega, wd)
    n = len(t)
    moving = np.linalg.norm(omega, axis=1) > np.radians(motion_threshold_deg_s)
    if moving.sum() < 10:
        moving[:] = True
    # the raw figures on the same epochs as the steps after them (those with a known angular acceleration)
    raw_rms = _rms_parity(z_raw[m:N - m][lever_ok], moving)
    aligned_rms = _rms_parity(z, moving)
    D = np.repeat(np.eye(3)[None], k, axis=0)
    c = np.zeros((k, 3))
    r = nominal - nominal.mean(axis=0)
    sigma = _noise_from_differences(z - z.mean(axis=1, keepdims=True))
    p = 16 if offsets else 15
    if gain not in ("absolute", "relative", "none"):
        raise ShapeError(f"gain must be 'absolute', 'relative' or 'none', got {gain!r}")
    # gauge constraints G theta = 0 on the update: sum r (3), sum c (3), and sum trace D (1, absolute),
    # sum D (9, relative) or every D entry (none)
    G = np.zeros((6 + {"absolute": 1, "relative": 9, "none": 9 * k}[gain] + int(offsets), k * p))
    for j in range(k):
        if offsets:
            G[-1, j * p + 15] = 1.0
        G[0:3, j * p + 12:j * p + 15] = np.eye(3)
        G[3:6, j * p + 9:j * p + 12] = np.eye(3)
        if gain == "absolute":
            G[6, j * p + 0] = G[6, j * p + 4] = G[6, j * p + 8] = 1.0
        elif gain == "relative":
            G[6:15, j * p:j * p + 9] = np.eye(9)
        else:
            G[6 + 9 * j:6 + 9 * j + 9, j * p:j * p + 9] = np.eye(9)
    nc = G.shape[0]
    _check_identifiable(Kt, z, D, c, r, sigma, G, gain, t if offsets else None)
    z0 = z
    tau_a = np.zeros(k)
    # weights fixed during the iterations (from the high-frequency noise): re-estimating them inside the loop
    # lets the joint fit trade a triad's gain for its noise (a degenerate optimum with D_j -> 0)
    wj = 1 / sigma**2
    it = 0
    # the fit leaves out the ends, where a time shift would reach past the recording
    e0 = int(np.ceil(0.02 / np.median(np.diff(t)))) + 1 if offsets else 0
    sl = slice(e0, n - e0)
    Kt_f = Kt[sl]
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        z = _shifted(t, z0, tau_a) if offsets else z0
        zf = z[sl]
        Kr, s, e = _specific_force(zf, Kt_f, D, c, r, wj)   # s per sample by weighted LS given the parameters
        dv = derivative(t[sl], s[:, None] + Kr) if offsets else None
        KKT = _kkt(Kt_f, D, r, s, 1 / np.sqrt(wj), G, dv)
        Xw = _jac(Kt_f, D, r, s, dv) * wj[None, :, None, None]
        g = np.einsum("nkap,nka->kp", Xw, e).ravel()
        # (s is already the LS solution, so the elimination term of the gradient vanishes)
        sol = np.linalg.solve(KKT, np.concatenate([g, np.zeros(nc)]))
        d = sol[:k * p].reshape(k, p)
        # backtracking: a full Gauss-Newton step can overshoot when the motion barely excites the lever arms
        c0 = _cost(zf, Kt_f, D, c, r, wj)
        lam = 1.0
        for _ in range(12):
            Dn, cn, rn = D + lam * d[:, 0:9].reshape(k, 3, 3), c + lam * d[:, 9:12], r + lam * d[:, 12:15]
            tn = tau_a + lam * d[:, 15] if offsets else tau_a
            zn = _shifted(t, z0, tn)[sl] if offsets else zf
            if _cost(zn, Kt_f, Dn, cn, rn, wj) <= c0 * (1 + 1e-12):
                break
            lam *= 0.5
        else:
            Dn, cn, rn, tn = D, c, r, tau_a
        D, c, r, tau_a = Dn, cn, rn, tn
        d = lam * d
        sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(KKT))[:k * p], 0)).reshape(k, p)
        scale = np.hstack([D.reshape(k, 9), c, r] + ([tau_a[:, None]] if offsets else []))
        if np.all(np.abs(d) <= 0.05 * sd + 1e-12 * (1 + np.abs(scale))):
            break
    if offsets:
        z = _shifted(t, z0, tau_a)[sl]
        Kt, t, n, omega = Kt_f, t[sl], z.shape[0], omega[sl]
        moving = moving[sl]
    # covariance: the constrained inverse Fisher information with the noise from the residual
    Kr, s, e = _specific_force(z, Kt, D, c, r, wj)
    # residual of triad j has variance ~ sigma_j^2 - (its share in s); same fixed point as for the gyros
    sigma = _sigma_from_residual_var(np.einsum("nka,nka->k", e, e) / (3 * n - p))
    KKT = _kkt(Kt, D, r, s, sigma, G, derivative(t, s[:, None] + Kr) if offsets else None)
    cov_full = np.linalg.inv(KKT)[:k * p, :k * p]
    cov = np.stack([cov_full[j * p:(j + 1) * p, j * p:(j + 1) * p] for j in range(k)])
    r = r + nominal.mean(axis=0)
    # parity figures: the triads moved to the reference point, with and without the estimated terms
    f_gb = np.einsum("kab,nkb->nka", np.linalg.inv(D), z - c[None])
    nom_rms = _rms_parity(f_gb - np.einsum("nab,kb->nka", Kt, nominal - nominal.mean(axis=0)), moving)
    pos_rms = _rms_parity(f_gb - np.einsum("nab,kb->nka", Kt, r - nominal.mean(axis=0)), moving)
    raw_lever = _rms_parity(z - np.einsum("nab,kb->nka", Kt, nominal - nominal.mean(axis=0)), moving)
    aa_rms = _rms_parity_accel_aa(f_gb, omega, r - nominal.mean(axis=0), moving)
    return PositionFit(layout.with_positions(r), D, c, r, cov, sigma,
                       {"raw": raw_rms, "aligned": aligned_rms, "raw_nominal_lever_arms": raw_lever,
                        "gain_bias_nominal_lever_arms": nom_rms, "positions": pos_rms,
                        "accel_angular_acceleration": aa_rms, "raw_all": raw_all, "aligned_all": aligned_all},
                       nominal, it, np.asarray(tau, dtype=float), gain,
                       tau_a if offsets else None, n_invalid, n_moving, derivative_order)
