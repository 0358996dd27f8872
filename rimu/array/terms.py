"""Error terms of an array triad, as regressor columns on the array's common signals.

Every term owns a few parameters per triad and the columns (N, 3, p) it adds to that triad's body-frame output,
given the array's common signals (angular rate, angular acceleration, specific force). Adding a term is one new
class plus one line in :data:`GYRO_TERMS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Signals", "Term", "GYRO_TERMS", "traceless_basis"]

_AX = "xyz"


@dataclass(frozen=True)
class Signals:
    """The array's common signals, body frame: rate [rad/s], angular acceleration [rad/s^2], specific force [m/s^2]."""

    omega: np.ndarray
    omega_dot: np.ndarray
    specific_force: "np.ndarray | None" = None


def _matrix_cols(u: np.ndarray) -> np.ndarray:
    """Columns of ``M u`` for the 9 entries of M (row-major): (N, 3) -> (N, 3, 9)."""
    N = u.shape[0]
    X = np.zeros((N, 3, 9))
    for i in range(3):
        X[:, i, 3 * i:3 * i + 3] = u
    return X


def traceless_basis() -> np.ndarray:
    """Eight orthonormal traceless 3x3 matrices (Frobenius inner product), (8, 3, 3)."""
    B = []
    for i in range(3):
        for m in range(3):
            if i != m:
                E = np.zeros((3, 3))
                E[i, m] = 1.0
                B.append(E)
    B.append(np.diag([1.0, -1.0, 0.0]) / np.sqrt(2))
    B.append(np.diag([1.0, 1.0, -2.0]) / np.sqrt(6))
    return np.array(B)


class Term:
    """One error term: ``name``, ``n_cols``, ``labels``, ``excitation`` and ``columns(signals)``."""

    name: str = ""
    n_cols: int = 0
    excitation: str = ""
    unit: str = ""
    labels: tuple[str, ...] = ()

    def columns(self, s: Signals) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def excitation_report(self, s: Signals) -> str:
        return self.excitation


class ScaleMisalignment(Term):
    """``F w``: the triad's gain matrix relative to the array (scale on the diagonal, misalignment off it)."""

    name, n_cols, unit = "scale_misalignment", 9, "1"
    labels = tuple(f"F_{a}{b}" for a in _AX for b in _AX)
    excitation = "angular rate about every axis"

    def columns(self, s: Signals) -> np.ndarray:
        return _matrix_cols(s.omega)

    def excitation_report(self, s: Signals) -> str:
        ev, V = np.linalg.eigh(s.omega.T @ s.omega / len(s.omega))
        d = V[:, 0] * np.sign(V[np.argmax(np.abs(V[:, 0])), 0])
        return (f"angular rate about every axis: the weakest direction, body [{d[0]:+.2f} {d[1]:+.2f} {d[2]:+.2f}], "
                f"has {np.degrees(np.sqrt(max(ev[0], 0))):.3g} deg/s rms; rotate about it")


class Bias(Term):
    """``c``: the triad's bias relative to the array."""

    name, n_cols, unit = "bias", 3, "rad/s"
    labels = ("b_x", "b_y", "b_z")
    excitation = "nothing (any recording)"

    def columns(self, s: Signals) -> np.ndarray:
        return np.broadcast_to(np.eye(3), (s.omega.shape[0], 3, 3)).copy()


class SamplingOffset(Term):
    """``tau w'``: the triad samples the motion ``tau`` seconds after the array mean."""

    name, n_cols, unit = "sampling_offset", 1, "s"
    labels = ("tau",)
    excitation = "angular acceleration"

    def columns(self, s: Signals) -> np.ndarray:
        return s.omega_dot[:, :, None].copy()

    def excitation_report(self, s: Signals) -> str:
        return f"angular acceleration: the recording has {np.sqrt(np.mean(s.omega_dot**2)):.3g} rad/s^2 rms per axis"


class AngularAccelerationSensitivity(Term):
    """``K w'`` with K traceless (its isotropic part is the sampling offset): angular-acceleration sensitivity."""

    name, n_cols, unit = "aa_sensitivity", 8, "s"
    labels = ("K_xy", "K_xz", "K_yx", "K_yz", "K_zx", "K_zy", "K_d1", "K_d2")
    excitation = "angular acceleration about every axis"

    def columns(self, s: Signals) -> np.ndarray:
        return np.einsum("qij,nj->niq", traceless_basis(), s.omega_dot)


class GSensitivity(Term):
    """``G f``: gyro sensitivity to specific force (needs the array's specific force)."""

    name, n_cols, unit = "g_sensitivity", 9, "rad/s/(m/s^2)"
    labels = tuple(f"G_{a}{b}" for a in _AX for b in _AX)
    excitation = "specific force along every axis (turn the array against gravity; pass specific_force)"

    def columns(self, s: Signals) -> np.ndarray:
        if s.specific_force is None:
            return np.zeros((s.omega.shape[0], 3, 9))
        return _matrix_cols(s.specific_force)


class RateNonlinearity(Term):
    """``n_i w_i^2`` on each body axis: scale nonlinearity (exact for triads whose axes are body axes up to sign)."""

    name, n_cols, unit = "rate_nonlinearity", 3, "s/rad"
    labels = ("n_x", "n_y", "n_z")
    excitation = "large angular rates about every axis"

    def columns(self, s: Signals) -> np.ndarray:
        N = s.omega.shape[0]
        X = np.zeros((N, 3, 3))
        X[:, [0, 1, 2], [0, 1, 2]] = s.omega**2
        return X


#: The gyro terms by name; the first two are the base model.
GYRO_TERMS: dict[str, Term] = {
    t.name: t for t in (ScaleMisalignment(), Bias(), SamplingOffset(), AngularAccelerationSensitivity(),
                        GSensitivity(), RateNonlinearity())
}
