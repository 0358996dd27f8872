"""Axis alignment of triads from the data: the rotation between two triads, with its uncertainty.

Two triads on one body see the same angular rate (anywhere on a rigid body) and, at rest, the same specific
force (gravity). With ``r_i`` a vector in the reference triad's axes and ``b_i`` the same vector in the other
triad's axes, ``b_i = R r_i + c + n_i``: ``R`` is the rotation from the reference's axes to the triad's
(``mat_unit_ref``), ``c`` an optional constant offset (the difference of the gyro biases) and ``n_i`` noise.
Finding R is Wahba's problem (Wahba 1965); its solution by the SVD of the attitude profile matrix
``B = sum_i w_i (b_i - b_mean)(r_i - r_mean)^T`` is ``R = U diag(1, 1, det U det V) V^T`` (Markley 1988; the
orthogonal Procrustes solution of Kabsch with a translation when c is fitted).

Uncertainty. With the error of R written as a small rotation ``phi`` in the triad's axes
(``R_true = exp([phi]x) R_est``), each pair contributes ``-[v_i]x`` to the Jacobian (``v_i = R r_i``), so the
Fisher information is ``F = sum_i (|v_i|^2 I - v_i v_i^T) / s^2`` (Shuster's QUEST covariance, generalised to
vectors of any length and centred where c is fitted), with ``s^2`` the per-component variance of the
residuals ``b_i - R r_i - c`` estimated from the data, one level per set of vectors (rates, specific forces).
Where the residuals are correlated in time (vibration, unmodelled dynamics) the covariance is inflated by the
ratio of samples to effective samples from the residuals' autocorrelation (Bartlett's formula), so that the
stated uncertainty does not claim independent samples that are not.

Sets of vectors: rates in motion (from both triads' gyros, c = the gyro bias difference) and specific forces
at rest (gravity in each pose; no offset: the accelerometer bias difference is not separable from the rotation
with one or two poses). One direction alone (gravity in a single pose) leaves the rotation about it
unobserved: :class:`~rimu.errors.IdentifiabilityError` names it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError, ShapeError
from ..units import RAD_TO_DEG

__all__ = ["AlignmentResult", "VectorSet", "align_triads", "effective_fraction", "fit_rotation", "rotvec_of"]


@dataclass
class VectorSet:
    """Paired vectors for :func:`fit_rotation`: ``reference`` (N, 3) in the reference triad's axes, ``unit``
    (N, 3) the same vectors in the aligned triad's axes; ``fit_offset`` fits a constant difference c;
    ``sigma`` (per-component noise of ``unit - R reference``) is estimated when None."""

    name: str
    reference: np.ndarray
    unit: np.ndarray
    fit_offset: bool = False
    sigma: float | None = None

    def __post_init__(self) -> None:
        self.reference = np.asarray(self.reference, dtype=float)
        self.unit = np.asarray(self.unit, dtype=float)
        if self.reference.ndim != 2 or self.reference.shape[1] != 3 or self.unit.shape != self.reference.shape:
            raise ShapeError(f"vector set {self.name!r}: reference and unit must both be (N, 3), got "
                             f"{self.reference.shape} and {self.unit.shape}")
        ok = np.isfinite(self.reference).all(1) & np.isfinite(self.unit).all(1)
        self.reference, self.unit = self.reference[ok], self.unit[ok]
        if len(self.reference) < (3 if self.fit_offset else 2):
            raise ShapeError(f"vector set {self.name!r} has {len(self.reference)} finite pairs; it needs at least "
                             f"{3 if self.fit_offset else 2}")


@dataclass
class AlignmentResult:
    """The fitted rotation of one triad against the reference triad.

    Attributes
    ----------
    mat_unit_ref : ndarray (3, 3)
        Maps a vector in the reference triad's axes into this triad's axes. For a unit whose reference triad
        defines MB, it is the triad's ``mat_sb_mb`` (:func:`rimu.geometry.triads`).
    covariance : ndarray (3, 3)
        Covariance of the rotation error ``phi`` (rad^2, triad axes): ``R_true = exp([phi]x) R``.
    offsets : dict[str, ndarray (3,)]
        Fitted constant differences per vector set (SI, triad axes), e.g. the gyro bias difference.
    sigma : dict[str, float]
        Per-component residual noise per vector set (SI).
    n : dict[str, int]
        Pairs used per set.
    inflation : dict[str, float]
        Covariance inflation for correlated residuals per set (1 = independent samples).
    """

    mat_unit_ref: np.ndarray
    covariance: np.ndarray
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    sigma: dict[str, float] = field(default_factory=dict)
    n: dict[str, int] = field(default_factory=dict)
    inflation: dict[str, float] = field(default_factory=dict)
    name: str = "unit"

    @property
    def rotvec_deg(self) -> np.ndarray:
        """The rotation as a rotation vector, degrees (triad axes)."""
        return rotvec_of(self.mat_unit_ref) * RAD_TO_DEG

    @property
    def angle_deg(self) -> float:
        """Total angle between the two triads, degrees."""
        return float(np.linalg.norm(self.rotvec_deg))

    @property
    def sigma_deg(self) -> np.ndarray:
        """1-sigma uncertainty of the rotation about each triad axis, degrees."""
        return np.sqrt(np.diag(self.covariance)) * RAD_TO_DEG

    def table(self) -> str:
        """One line: angle, rotation vector and its 1-sigma, degrees."""
        rv, sd = self.rotvec_deg, self.sigma_deg
        parts = ", ".join(f"{a} {v:+.3f} +- {s:.3f}" for a, v, s in zip("xyz", rv, sd))
        return f"{self.name}: {self.angle_deg:.3f} deg ({parts} deg)"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "mat_unit_ref": self.mat_unit_ref.tolist(), "angle_deg": self.angle_deg,
                "rotvec_deg": self.rotvec_deg.tolist(), "sigma_deg": self.sigma_deg.tolist(),
                "covariance_rad2": self.covariance.tolist(), "sigma": dict(self.sigma), "n": dict(self.n),
                "inflation": dict(self.inflation), "offsets": {k: v.tolist() for k, v in self.offsets.items()}}


def rotvec_of(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix (the inverse of Rodrigues' formula).

    >>> from rimu.session.model import rotation_matrix
    >>> np.round(rotvec_of(rotation_matrix(np.array([0.1, -0.2, 0.3]))), 12).tolist()
    [0.1, -0.2, 0.3]
    """
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(c))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-7:
        return 0.5 * w
    if np.pi - th < 1e-6:  # half-turn: axis from the symmetric part
        k = int(np.argmax(np.diag(R)))
        a = (R[:, k] + np.eye(3)[k]) / np.sqrt(2.0 * (1.0 + R[k, k]))
        return th * a
    return th / (2.0 * np.sin(th)) * w


def effective_fraction(residuals: np.ndarray, max_lag: int = 200, cutoff: float = 0.05) -> float:
    """N_eff / N of a residual series (N, m) from its autocorrelation (Bartlett):
    ``1 / (1 + 2 sum_k rho_k)``, summing lags until the mean autocorrelation first drops below ``cutoff``.

    >>> rng = np.random.default_rng(0)
    >>> round(effective_fraction(rng.standard_normal((5000, 3))), 2)
    1.0
    >>> x = np.convolve(rng.standard_normal(20000), np.ones(10) / 10, "same")[:, None]
    >>> 0.05 < effective_fraction(x) < 0.2      # a 10-sample moving average: about 1/10 as many samples
    True
    """
    E = np.asarray(residuals, dtype=float)
    if E.ndim == 1:
        E = E[:, None]
    E = E - E.mean(axis=0)
    N = len(E)
    var = float((E * E).sum())
    if N < 10 or var <= 0:
        return 1.0
    total = 0.0
    for k in range(1, min(max_lag, N // 4)):
        rho = float((E[k:] * E[:-k]).sum()) / var
        if rho < cutoff:
            break
        total += rho
    return 1.0 / (1.0 + 2.0 * total)


def fit_rotation(sets: Sequence[VectorSet], correlated: bool = True, iterations: int = 3,
                 name: str = "unit") -> AlignmentResult:
    """Weighted Wahba / Procrustes solution over several sets of paired vectors, with its covariance.

    Parameters
    ----------
    sets : sequence of VectorSet
    correlated : bool
        Inflate the covariance for correlated residuals (see the module docstring). Off: independent samples.
    iterations : int
        Re-weightings (each set's weight is 1 / its residual variance).

    Raises
    ------
    IdentifiabilityError
        The vectors span fewer than two directions (a rotation about the one direction is unobserved).

    Examples
    --------
    >>> from rimu.session.model import rotation_matrix
    >>> rng = np.random.default_rng(1)
    >>> R = rotation_matrix(np.radians([2.0, -5.0, 1.0]))
    >>> r = rng.normal(size=(500, 3))
    >>> res = fit_rotation([VectorSet("rate", r, r @ R.T + 0.001 * rng.normal(size=(500, 3)))], correlated=False)
    >>> np.round(res.rotvec_deg, 2).tolist()
    [2.0, -5.0, 1.0]
    """
    if not sets:
        raise ShapeError("fit_rotation needs at least one set of paired vectors")
    w = {s.name: 1.0 for s in sets}
    R = np.eye(3)
    cent: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
    for s in sets:
        rm = s.reference.mean(axis=0) if s.fit_offset else np.zeros(3)
        bm = s.unit.mean(axis=0) if s.fit_offset else np.zeros(3)
        cent[s.name] = (s.reference - rm, s.unit - bm, rm, bm)
    sig: dict[str, float] = {}
    for _it in range(max(1, iterations)):
        B = np.zeros((3, 3))
        for s in sets:
            rc, bc, _, _ = cent[s.name]
            B += w[s.name] * bc.T @ rc
        U, _, Vt = np.linalg.svd(B)
        d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
        R = U @ np.diag([1.0, 1.0, d]) @ Vt
        for s in sets:
            rc, bc, _, _ = cent[s.name]
            e = bc - rc @ R.T
            dof = 3 * len(rc) - (3 if s.fit_offset else 0) - 3 * (len(sets) == 1)
            sig[s.name] = s.sigma if s.sigma is not None else float(np.sqrt((e * e).sum() / max(dof, 1)))
            w[s.name] = 1.0 / max(sig[s.name], 1e-300) ** 2
    F = np.zeros((3, 3))
    infl: dict[str, float] = {}
    offsets: dict[str, np.ndarray] = {}
    for s in sets:
        rc, bc, rm, bm = cent[s.name]
        v = rc @ R.T
        Fs = (np.sum(v * v) * np.eye(3) - v.T @ v) * w[s.name]
        e = bc - v
        f = 1.0 / effective_fraction(e) if correlated else 1.0
        infl[s.name] = f
        F += Fs / f
        if s.fit_offset:
            offsets[s.name] = bm - R @ rm
    ev = np.linalg.eigvalsh(F)
    if ev[0] <= 1e-4 * ev[-1]:  # the vectors spread less than 1 % of their size about one axis
        _, vecs = np.linalg.eigh(F)
        raise IdentifiabilityError(
            f"the vectors span one direction only; the rotation about {np.round(vecs[:, 0], 3).tolist()} (triad "
            "axes) is not observed: add rates in motion, or rest in a second attitude", ["rotation"])
    return AlignmentResult(R, np.linalg.inv(F), offsets, sig, {s.name: len(s.reference) for s in sets}, infl, name)


def align_triads(gyro_ref: np.ndarray, gyro: np.ndarray, accel_ref: np.ndarray | None = None,
                 accel: np.ndarray | None = None, static: np.ndarray | None = None, min_rate_rad_s: float = 0.0,
                 average: int = 1, correlated: bool = True, name: str = "unit") -> AlignmentResult:
    """The rotation of a triad against a reference triad from their samples on one time base.

    Parameters
    ----------
    gyro_ref, gyro : ndarray (N, 3)
        Rates of the reference triad and of the triad, rad/s, same instants (NaN rows are skipped).
    accel_ref, accel : ndarray (N, 3), optional
        Specific forces, m/s^2; used at the samples flagged ``static`` (gravity).
    static : ndarray (N,) of bool, optional
        Samples at rest.
    min_rate_rad_s : float
        Use rate pairs where the reference rate exceeds this (motion).
    average : int
        Average blocks of this many samples first (vibration; sub-sample timing errors).
    correlated : bool
        See :func:`fit_rotation`.

    Returns
    -------
    AlignmentResult
        ``mat_unit_ref`` maps reference-triad vectors into the triad's axes; the gyro bias difference is in
        ``offsets["rate"]``.
    """
    def blocks(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        x = np.where(mask[:, None], np.asarray(x, dtype=float), np.nan)
        if average <= 1:
            return x
        m = (len(x) // average) * average
        xb = x[:m].reshape(-1, average, 3)
        keep = np.isfinite(xb).all(axis=(1, 2))
        out = np.full((len(xb), 3), np.nan)
        out[keep] = xb[keep].mean(axis=1)
        return out

    gyro_ref = np.asarray(gyro_ref, dtype=float)
    N = len(gyro_ref)
    if np.shape(gyro) != (N, 3) or gyro_ref.shape != (N, 3):
        raise ShapeError(f"gyro_ref and gyro must both be (N, 3), got {gyro_ref.shape} and {np.shape(gyro)}")
    moving = np.linalg.norm(np.nan_to_num(gyro_ref), axis=1) >= min_rate_rad_s
    if static is not None:
        moving &= ~np.asarray(static, bool)
    sets = [VectorSet("rate", blocks(gyro_ref, moving), blocks(gyro, moving), fit_offset=True)]
    if accel_ref is not None and accel is not None and static is not None and np.any(static):
        st = np.asarray(static, bool)
        sets.append(VectorSet("gravity", blocks(accel_ref, st), blocks(accel, st)))
    return fit_rotation(sets, correlated=correlated, name=name)
