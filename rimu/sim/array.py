"""Simulated inertial sensor arrays under hand-held motion, with known truth.

k gyro + accelerometer triads on one rigid board (an :class:`rimu.array.ArrayLayout`), each with its own gain
matrix (scale and misalignment), bias, sampling offset, optional gyro g-sensitivity, angular-acceleration
sensitivity and rate nonlinearity, and white MEMS noise. The motion is a smooth random hand-held motion: angular
rates of hundreds of deg/s about every axis, angular accelerations of tens to hundreds of rad/s^2, gravity turning
in the body frame and a few m/s^2 of linear acceleration.

Triad j samples the motion at ``t + tau_j`` (its sampling offset); its raw outputs in its own axes are

* gyro:  ``y_g = D_g (R^T w) + b_g + G (R^T f_j) + K (R^T w') + n2 * (R^T w)**2 + noise``
* accel: ``y_a = D_a (R^T f_j) + b_a + noise``, ``f_j = s + w' x r_j + w x (w x r_j)``

with ``R`` the triad's rotation to the body frame and ``r_j`` its true position.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..array.layout import ArrayLayout
from ..array.runtime import lever_arm_acceleration
from ..units import DEG_TO_RAD, G0, UG_TO_MS2

__all__ = ["HandheldMotion", "ArrayTruth", "ArrayRecording", "random_array_truth", "simulate_array"]



@dataclass(frozen=True)
class HandheldMotion:
    """A smooth random hand-held motion: sums of sinusoids (analytic rate, acceleration and jerk).

    Parameters
    ----------
    rms_rate_deg_s : float
        Root-mean-square angular rate per axis [deg/s].
    band_hz : (float, float)
        Frequency band of the rotation and of the linear acceleration [Hz].
    rms_accel_m_s2 : float
        RMS linear acceleration per axis [m/s^2] (gravity comes on top).
    n_tones : int
        Sinusoids per axis.
    seed : int
        Random seed of the tones.
    """

    rms_rate_deg_s: float = 200.0
    band_hz: tuple[float, float] = (0.4, 4.0)
    rms_accel_m_s2: float = 3.0
    n_tones: int = 5
    seed: int = 0

    def _tones(self, rms: float, salt: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rng = np.random.default_rng([self.seed, salt])
        f = rng.uniform(*self.band_hz, size=(3, self.n_tones))
        a = rng.uniform(0.5, 1.0, size=(3, self.n_tones))
        a *= rms / np.sqrt(0.5 * (a**2).sum(axis=1, keepdims=True))
        ph = rng.uniform(0, 2 * np.pi, size=(3, self.n_tones))
        return 2 * np.pi * f, a, ph

    def angular(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angular rate [rad/s] and angular acceleration [rad/s^2], body frame, (N, 3) each."""
        om, a, ph = self._tones(self.rms_rate_deg_s * DEG_TO_RAD, 1)
        arg = t[:, None, None] * om[None] + ph[None]
        return (a * np.sin(arg)).sum(axis=2), (a * om * np.cos(arg)).sum(axis=2)

    def linear(self, t: np.ndarray) -> np.ndarray:
        """Linear acceleration in the body frame [m/s^2], (N, 3)."""
        om, a, ph = self._tones(self.rms_accel_m_s2, 2)
        return (a * np.sin(t[:, None, None] * om[None] + ph[None])).sum(axis=2)


@dataclass(frozen=True)
class ArrayTruth:
    """The true errors of every triad (SI units, each triad's own axes)."""

    layout: ArrayLayout
    gyro_gain: np.ndarray
    gyro_bias_rad_s: np.ndarray
    accel_gain: np.ndarray
    accel_bias_m_s2: np.ndarray
    sampling_offset_s: np.ndarray
    gyro_noise_rad_s: np.ndarray
    accel_noise_m_s2: np.ndarray
    gyro_g_sensitivity_rad_s_per_m_s2: np.ndarray
    gyro_aa_sensitivity_s: np.ndarray
    gyro_nonlinearity_s_rad: np.ndarray


def random_array_truth(
    layout: ArrayLayout, seed: int = 0, gyro_scale_sigma: float = 0.01, gyro_misalignment_sigma_rad: float = 0.005,
    gyro_bias_sigma_deg_s: float = 1.0, accel_scale_sigma: float = 0.01, accel_misalignment_sigma_rad: float = 0.005,
    accel_bias_sigma_m_s2: float = 0.1, sampling_offset_sigma_s: float = 100e-6,
    gyro_noise_density_deg_s_sqrt_hz: float = 0.005, accel_noise_density_ug_sqrt_hz: float = 300.0,
    rate_hz: float = 1000.0, g_sensitivity_sigma_deg_s_per_g: float = 0.0, aa_sensitivity_sigma_s: float = 0.0,
    nonlinearity_sigma_s_rad: float = 0.0, noise_spread: float = 0.2, centre_gyro_common_mode: bool = False,
) -> ArrayTruth:
    """Random MEMS-like errors for every triad of ``layout`` (consumer-grade, uncalibrated).

    Per-sample white noise is ``density * sqrt(rate_hz / 2)`` times a per-triad factor in
    ``1 +/- noise_spread``. With ``centre_gyro_common_mode`` the gyro array's mean gain is I and its mean bias and
    mean sampling offset are zero, and so is the common part of every other gyro term (the array-mean gyro is then
    exact: what a relative calibration cannot know).
    """
    rng = np.random.default_rng(seed)
    k = layout.k

    def gain(scale: float, mis: float) -> np.ndarray:
        D = np.eye(3)[None] + rng.normal(0, mis, (k, 3, 3)) * (1 - np.eye(3))
        return D + rng.normal(0, scale, (k, 3)) [:, :, None] * np.eye(3)

    bw = np.sqrt(rate_hz / 2.0)
    spread = lambda: 1.0 + rng.uniform(-noise_spread, noise_spread, k)  # noqa: E731
    Dg = gain(gyro_scale_sigma, gyro_misalignment_sigma_rad)
    bg = rng.normal(0, gyro_bias_sigma_deg_s * DEG_TO_RAD, (k, 3))
    Da = gain(accel_scale_sigma, accel_misalignment_sigma_rad)
    ba = rng.normal(0, accel_bias_sigma_m_s2, (k, 3))
    tau = rng.normal(0, sampling_offset_sigma_s, k)
    gsens = rng.normal(0, g_sensitivity_sigma_deg_s_per_g * DEG_TO_RAD / G0, (k, 3, 3))
    aasens = rng.normal(0, aa_sensitivity_sigma_s, (k, 3, 3))
    nonlin = rng.normal(0, nonlinearity_sigma_s_rad, (k, 3))
    if centre_gyro_common_mode:
        R = layout.rotations
        body = lambda M: np.einsum("kij,kjl,kml->kim", R, M, R)  # noqa: E731
        triad = lambda M: np.einsum("kji,kjl,klm->kim", R, M, R)  # noqa: E731
        Db = body(Dg)
        cb = np.einsum("kij,kj->ki", R, bg)
        Db = Db @ np.linalg.inv(Db.mean(axis=0))
        cb = cb - Db @ cb.mean(axis=0)
        Dg = triad(Db)
        bg = np.einsum("kji,kj->ki", R, cb)
        tau = tau - tau.mean()
        gsens = triad(body(gsens) - body(gsens).mean(axis=0))
        aasens = triad(body(aasens) - body(aasens).mean(axis=0))
        nonlin = nonlin - nonlin.mean(axis=0)   # exact for triads whose axes are body axes up to sign
    return ArrayTruth(
        layout=layout,
        gyro_gain=Dg,
        gyro_bias_rad_s=bg,
        accel_gain=Da,
        accel_bias_m_s2=ba,
        sampling_offset_s=tau,
        gyro_noise_rad_s=gyro_noise_density_deg_s_sqrt_hz * DEG_TO_RAD * bw * spread(),
        accel_noise_m_s2=accel_noise_density_ug_sqrt_hz * UG_TO_MS2 * bw * spread(),
        gyro_g_sensitivity_rad_s_per_m_s2=gsens,
        gyro_aa_sensitivity_s=aasens,
        gyro_nonlinearity_s_rad=nonlin,
    )


@dataclass(frozen=True)
class ArrayRecording:
    """What :func:`simulate_array` returns: raw triad outputs (own axes), the true motion and the truth."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    omega: np.ndarray
    omega_dot: np.ndarray
    specific_force: np.ndarray
    truth: ArrayTruth
    nominal_layout: ArrayLayout = field(repr=False, default=None)  # type: ignore[assignment]


def _gravity_body(t: np.ndarray, motion: HandheldMotion, g0: np.ndarray) -> np.ndarray:
    """Integrate u_b' = -w x u_b (the up vector in body axes) by exact rotations over each step with the
    midpoint rate (w analytic): second-order accurate, |u_b| kept."""
    h = np.diff(t)
    wm = motion.angular(0.5 * (t[1:] + t[:-1]))[0]
    phi = -wm * h[:, None]
    ang = np.linalg.norm(phi, axis=1)
    ax = phi / np.maximum(ang, 1e-300)[:, None]
    K = np.zeros((len(h), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -ax[:, 2], ax[:, 1], -ax[:, 0]
    K -= np.transpose(K, (0, 2, 1))
    Rs = np.eye(3) + np.sin(ang)[:, None, None] * K + (1 - np.cos(ang))[:, None, None] * (K @ K)
    g = np.empty((t.size, 3))
    g[0] = g0
    for i in range(t.size - 1):
        g[i + 1] = Rs[i] @ g[i]
    return g


def simulate_array(
    truth: ArrayTruth, duration_s: float = 4.0, rate_hz: float = 1000.0, motion: "HandheldMotion | None" = None,
    seed: int = 0, nominal_positions_m: "np.ndarray | None" = None,
) -> ArrayRecording:
    """Raw outputs of every triad of ``truth`` under ``motion`` (default :class:`HandheldMotion`).

    Examples
    --------
    >>> lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.01)
    >>> rec = simulate_array(random_array_truth(lay, seed=1), duration_s=0.5)
    >>> rec.gyro.shape, rec.accel.shape
    ((500, 8, 3), (500, 8, 3))
    """
    motion = motion or HandheldMotion(seed=seed)
    rng = np.random.default_rng([seed, 7])
    lay = truth.layout
    k = lay.k
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    # gravity in the body frame (pointing down: specific force at rest is +g up)
    g_up = np.array([0.0, 0.0, G0])
    g_b = _gravity_body(t, motion, g_up)  # the "up" vector in body axes; specific force = a + up*... (see below)
    w, wd = motion.angular(t)
    # second-order Taylor of the up vector to each triad's sampling instant
    gyro = np.empty((n, k, 3))
    accel = np.empty((n, k, 3))
    R = lay.rotations
    for j in range(k):
        tau = truth.sampling_offset_s[j]
        tj = t + tau
        wj, wdj = motion.angular(tj)
        gd = -np.cross(w, g_b)
        gdd = -np.cross(wd, g_b) - np.cross(w, gd)
        upj = g_b + tau * gd + 0.5 * tau**2 * gdd
        s = motion.linear(tj) + upj
        fj = s + lever_arm_acceleration(wj, wdj, lay.positions_m[j:j + 1])[:, 0]
        Rt = R[j].T
        w_s, wd_s, f_s = wj @ Rt.T, wdj @ Rt.T, fj @ Rt.T
        gyro[:, j] = (w_s @ truth.gyro_gain[j].T + truth.gyro_bias_rad_s[j]
                      + f_s @ truth.gyro_g_sensitivity_rad_s_per_m_s2[j].T + wd_s @ truth.gyro_aa_sensitivity_s[j].T
                      + truth.gyro_nonlinearity_s_rad[j] * w_s**2
                      + rng.normal(0, truth.gyro_noise_rad_s[j], (n, 3)))
        accel[:, j] = f_s @ truth.accel_gain[j].T + truth.accel_bias_m_s2[j] + rng.normal(0, truth.accel_noise_m_s2[j], (n, 3))
    s0 = motion.linear(t) + g_b
    nominal = lay if nominal_positions_m is None else lay.with_positions(nominal_positions_m)
    return ArrayRecording(t, gyro, accel, w, wd, s0, truth, nominal)
