"""Simulated multi-triad gyro units under hand-held motion: k triads with relative scale, misalignment, time
offset and vibration that the nominal calibration does not know (issue 19).

The true output of gyro i of triad j (sensing axis h_i, nominal calibration: scale 1, bias b_i)::

    y_i(t) = (1 + s_i) h_i . (R(theta_j) w(t + tau_j)) + b_i + sigma_i e_i + q_i |w(t)| e'_i

with s_i the relative scale error, theta_j the triad's small rotation error (rad), tau_j its time offset (s),
sigma_i the white noise and q_i |w| a vibration noise proportional to the rate (e, e' unit normals). The
motion w(t) is a sum of sinusoids per axis, so the rate and the angular acceleration are exact at any time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..calibration.result import InstrumentCalibration
from ..geometry import Geometry, SubUnit
from ..units import DS_TO_RS

__all__ = ["Motion", "MultiTriadTruth", "handheld_motion", "random_multitriad", "triad_array"]


def triad_array(k: int, orientation: str = "skewed", seed: int = 0) -> Geometry:
    """A unit of k orthogonal triads (3k gyros), one sub-unit per triad.

    ``orientation``: ``"skewed"`` (each triad at a random rotation: every axis in its own direction) or
    ``"parallel"`` (all triads aligned, as on a board of identical IMUs).

    >>> g = triad_array(32)
    >>> g.n, len(g.subunits), g.names[:4]
    (96, 32, ('t1x', 't1y', 't1z', 't2x'))
    """
    if k < 1:
        raise ValueError(f"a triad array needs at least one triad, got {k}")
    if orientation == "skewed":
        rots = Rotation.random(k, random_state=seed).as_matrix() if k > 1 else np.eye(3)[None]
        rots = np.asarray(rots).reshape(k, 3, 3)
    elif orientation == "parallel":
        rots = np.broadcast_to(np.eye(3), (k, 3, 3))
    else:
        raise ValueError(f"orientation must be 'skewed' or 'parallel', got {orientation!r}")
    H = np.concatenate([r for r in rots])  # rows of mat_sb_mb are the triad's axes in MB
    names = [f"t{j + 1}{a}" for j in range(k) for a in "xyz"]
    subs = [SubUnit(f"T{j + 1}", np.array(rots[j]), (3 * j, 3 * j + 1, 3 * j + 2)) for j in range(k)]
    return Geometry(H, names, subs, name=f"triads{k}_{orientation}")


@dataclass
class Motion:
    """Angular rate as a sum of sinusoids per axis: ``w_c(t) = sum_m amp[c, m] sin(2 pi freq[c, m] t + phase[c, m])``."""

    amp: np.ndarray
    freq: np.ndarray
    phase: np.ndarray

    def rate(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) rad/s."""
        arg = 2 * np.pi * self.freq[None] * np.asarray(t, float)[:, None, None] + self.phase[None]
        return np.einsum("cm,ncm->nc", self.amp, np.sin(arg))

    def angular_acceleration(self, t: np.ndarray) -> np.ndarray:
        """(N, 3) rad/s^2."""
        arg = 2 * np.pi * self.freq[None] * np.asarray(t, float)[:, None, None] + self.phase[None]
        return np.einsum("cm,ncm->nc", self.amp * 2 * np.pi * self.freq, np.cos(arg))

    @classmethod
    def still(cls) -> Motion:
        return cls(np.zeros((3, 1)), np.ones((3, 1)), np.zeros((3, 1)))


def handheld_motion(rate_rms_dps: float = 300.0, band_hz: tuple[float, float] = (0.3, 3.0), terms: int = 6,
                    seed: int = 0) -> Motion:
    """Random smooth rotation like a unit turned by hand: ``terms`` sinusoids per axis with frequencies in
    ``band_hz``, scaled so that the rms of |w| is ``rate_rms_dps``."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(*band_hz, (3, terms))
    amp = rng.standard_normal((3, terms))
    phase = rng.uniform(0, 2 * np.pi, (3, terms))
    rms = np.sqrt(0.5 * np.sum(amp**2))  # rms of |w| for incommensurate frequencies
    return Motion(amp * rate_rms_dps * DS_TO_RS / rms, freq, phase)


@dataclass
class MultiTriadTruth:
    """The true relative errors of a multi-triad gyro unit (see the module docstring)."""

    geometry: Geometry
    scale_rel: np.ndarray
    misalignment_rad: np.ndarray
    time_offset_s: np.ndarray
    sigma: np.ndarray
    vibration: np.ndarray
    bias: np.ndarray

    def calibration(self, range_raw: float | None = None) -> InstrumentCalibration:
        """What the user knows: nominal axes, scale 1, the biases, the noise (and a range limit)."""
        g = self.geometry
        cal = InstrumentCalibration.nominal("gyro", g, 1.0, self.bias, self.sigma)
        if range_raw is not None:
            cal.range_raw = np.full(g.n, float(range_raw))
        return cal

    def output(self, motion: Motion, t: np.ndarray, seed: int = 0, range_raw: float | None = None) -> np.ndarray:
        """Raw outputs (N, n) at times t (clipped at +-range_raw when given)."""
        g = self.geometry
        rng = np.random.default_rng(seed)
        t = np.asarray(t, float)
        Y = np.empty((len(t), g.n))
        for j, su in enumerate(g.subunits):
            idx = list(su.members)
            w = motion.rate(t + self.time_offset_s[j])
            Rj = Rotation.from_rotvec(self.misalignment_rad[j]).as_matrix()
            Y[:, idx] = (w @ Rj.T) @ g.H[idx].T * (1 + self.scale_rel[idx])
        wn = np.linalg.norm(motion.rate(t), axis=1)
        Y += self.bias + self.sigma * rng.standard_normal(Y.shape)
        Y += self.vibration * wn[:, None] * rng.standard_normal(Y.shape)
        if range_raw is not None:
            Y = np.clip(Y, -range_raw, range_raw)
        return Y


def random_multitriad(geometry: Geometry, scale_rel: float = 0.0075, misalignment_rad: float = 0.005,
                      time_offset_s: float = 0.001, sigma: float = 0.2 * DS_TO_RS, vibration: float = 0.001,
                      bias: float = 0.05, seed: int = 0) -> MultiTriadTruth:
    """Draw relative errors: scale uniform in +-scale_rel, misalignment normal with std ``misalignment_rad``
    per component, time offsets uniform in +-time_offset_s, biases normal with std ``bias`` (rad/s, known to
    the calibration), white noise ``sigma`` (rad/s) and vibration ``vibration`` (rad/s per rad/s of |w|)."""
    rng = np.random.default_rng(seed)
    n, k = geometry.n, len(geometry.subunits)
    return MultiTriadTruth(geometry, rng.uniform(-scale_rel, scale_rel, n),
                           misalignment_rad * rng.standard_normal((k, 3)),
                           rng.uniform(-time_offset_s, time_offset_s, k), np.full(n, float(sigma)),
                           np.full(n, float(vibration)), bias * rng.standard_normal(n))
