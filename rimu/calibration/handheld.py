"""Hand-held calibration: any number of static poses of unknown attitude, rotations by hand between them.

No turntable, no attitude knowledge. The accelerometers are calibrated from the norm of the specific force at
rest (Zhang et al. 2010, Eq. 7-8 and 12-14; Tedaldi, Pretto & Menegatti 2014, Eq. 10), the gyros from the
rotations between poses: the compensated angular rate, integrated from one pose to the next, must turn the
calibrated gravity direction of the first pose into that of the second (Tedaldi et al. 2014, Eq. 14-18).

Model, per sensor i of an instrument (raw-domain form of Cho & Park 2005, Eq. 1-5)::

    y_i = w_i . u + c_i + v_i         SF_i = 1 / |w_i|,  axis a_i = w_i / |w_i|,  bias b_i = SF_i c_i

Accelerometers (:func:`fit_accel`)
    1. a *well-posed* linear initial solution for a well-conditioned triple of sensors: the quadric
       ``(y - c)^T M (y - c) = g^2`` (Zhang Eq. 12-13) written homogeneously as ``D v = 0`` and solved under the
       normalisation ``|vec(M)| = 1`` (the smallest eigenvector of the reduced scatter matrix of the quadratic
       part), so it can never return the trivial solution ``M = 0``; of the eigenvectors, the first whose M is
       definite is used (a sphere fit if none is). ``M = A^T A`` gives A by the reversed Cholesky factor
       (Zhang Eq. 14). The other sensors of a redundant set are then linear in the specific forces so found.
    2. a nonlinear least-squares refinement (``scipy.optimize.least_squares``) of the full model of every sensor
       on all poses. For each pose the specific force is the weighted least-squares estimate from all sensors,
       ``f_k = (W^T S^-1 W)^-1 W^T S^-1 (ybar_k - c)``; the residuals are its norm minus g (one per pose) and,
       for skewed sets (more than three sensors), the whitened parity residual ``ybar_k - c - W f_k``.
    3. covariance from the Jacobian at the solution and the residual noise (scaled by chi-square per degree of
       freedom when there are degrees of freedom), and an :class:`~rimu.errors.IdentifiabilityError` naming the
       parameter combinations the poses do not determine (the right singular vectors of the Jacobian whose
       singular values vanish).

    Frame (gauge): without attitude knowledge a rotation of MB is invisible. MB is fixed as Zhang's platform
    frame, generalised: the first sensor of the triple keeps its nominal axis, the second stays in the plane
    of the two nominal axes. Those three misalignment angles are zero by definition (reported with zero
    variance). :func:`gauge_fixed` expresses any calibration (e.g. a simulation's truth) in that frame.

Gyros (:func:`fit_gyro`)
    Bias from the static poses (each pose's mean output is a measurement of the bias; the Earth rate, below a
    MEMS gyro's resolution, is not modelled), scale and misalignment (all nine, relative to the accelerometer
    frame) from the motions: the compensated rate (least-squares estimate for skewed sets) is integrated
    sample by sample as exact rotations (a quaternion per sample, combined by a parallel prefix product), from
    the first sample of pose k to the last of pose k+1. The attitude of a pose is the mean attitude over its
    samples, so the hand's tremor and sway during a "static" pose are integrated, not ignored (the accelerometer
    mean of the pose is the specific force at that mean attitude). Residual: the calibrated gravity direction of
    pose k+1 minus that of pose k turned by the integrated rotation, in the tangent plane (two components).
    Skewed gyro sets add the parity of the integrated outputs of each motion. The fit is weighted by the
    scatter of each residual group (two passes) with a Huber loss against outliers (a bumped pose), and the
    covariance includes the accelerometer parameters' uncertainty (through the gravity directions).

    Pre-integration (Forster et al. 2017): the motion samples are integrated once at the current parameters,
    keeping each motion's rotation and the weighted sums of its mid-sample attitudes that give the rotation for
    any nearby G, c to first order in the rate change (linear in G and c); the fit iterates on these O(motions)
    quantities and integrates again only while a correction turns a motion by more than 3e-4 rad
    (``fit_gyro(..., preintegrate=False)``: the reference that integrates every sample at every evaluation).

Redundant units: ``mode="joint"`` calibrates all sensors of an instrument together (skewed sets through the
least-squares estimate of the specific force and angular rate); ``mode="subunits"`` calibrates each sub-unit
triad on its own (each in its own gauge frame).

Examples
--------
>>> from rimu.sim.handheld import handheld_run
>>> run = handheld_run(n_poses=24, seed=3)
>>> res = HandHeld().fit(run.session)
>>> sorted(res.instruments)
['accel', 'gyro']
>>> bool(res.extra["norm_rms_accel"] < 3 * res.extra["norm_noise_accel"])
True
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._backend import import_once
from .._backend import resolve as _resolve_backend
from ..errors import IdentifiabilityError, SessionFormatError
from ..geometry import Geometry
from ..session import Segment, Session
from .estimate import CalibrationResult, estimate_noise_sigma, make_sensor_fit
from .lsq import LsqResult, central_jacobian
from .model import ErrorModel, SensorContext
from .result import Calibration, InstrumentCalibration
from .steps import StepCheck

__all__ = [
    "STATIC_KINDS",
    "AccelFit",
    "GyroFit",
    "held_out_accel",
    "held_out_gyro",
    "HandHeld",
    "clip_levels",
    "ellipsoid_fit",
    "fit_accel",
    "fit_gyro",
    "gauge_fixed",
    "lower_factor",
    "pose_windows",
    "quat_exp",
    "quat_mul",
    "quat_to_matrix",
    "white_noise_sigma_hf",
]

#: segment kinds that are poses at rest
STATIC_KINDS = ("static", "static_unknown")

_KERNELS: list[Any] = []


def _kernels() -> Any:
    """The compiled kernels (:mod:`rimu.calibration._hh_kernels`, imports numba once), or None without numba."""
    return import_once(_KERNELS, "rimu.calibration._hh_kernels")


# ---------------------------------------------------------------------- algebra
def lower_factor(M: np.ndarray) -> np.ndarray:
    """Lower-triangular A with positive diagonal and ``A^T A = M`` (Zhang et al. 2010, Eq. 14)."""
    P = np.eye(3)[::-1]
    L = np.linalg.cholesky(P @ M @ P)
    return (P @ L @ P).T


def _quad(y: np.ndarray) -> np.ndarray:
    x, yy, z = y[:, 0], y[:, 1], y[:, 2]
    return np.column_stack([x * x, yy * yy, z * z, 2 * x * yy, 2 * x * z, 2 * yy * z])


def _sym(m: np.ndarray) -> np.ndarray:
    return np.array([[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]])


def ellipsoid_fit(y: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centre c and shape M (positive definite, up to scale) of the quadric ``(y - c)^T M (y - c) = 1`` through
    points y (K, 3): Zhang et al. 2010, Eq. 12-13 posed homogeneously, ``D v = 0`` with ``|vec(M)| = 1``.

    The linear part (``M c`` and the constant) is eliminated in closed form, leaving the 6 x 6 reduced scatter
    matrix of the quadratic part; its eigenvectors, smallest first, are tried until one gives a definite M, so
    the trivial solution ``v = 0`` cannot occur. If none is definite (degenerate or very noisy poses), the best
    sphere is returned (M = I). Needs at least nine points.

    >>> rng = np.random.default_rng(0)
    >>> u = rng.normal(size=(30, 3)); u /= np.linalg.norm(u, axis=1)[:, None]
    >>> A = np.array([[2.0, 0, 0], [0.1, 3.0, 0], [0.2, -0.1, 1.5]])
    >>> y = u @ np.linalg.inv(A).T + [1.0, -2.0, 0.5]
    >>> c, M = ellipsoid_fit(y)
    >>> bool(np.allclose(c, [1.0, -2.0, 0.5])), bool(np.allclose(M / M[0, 0], A.T @ A / (A.T @ A)[0, 0]))
    (True, True)
    """
    y = np.asarray(y, dtype=float)
    w = np.ones(len(y)) if weights is None else np.asarray(weights, dtype=float)
    mu = np.average(y, axis=0, weights=w)
    s = float(np.sqrt(np.average(np.sum((y - mu) ** 2, axis=1), weights=w))) or 1.0
    z = (y - mu) / s
    sw = np.sqrt(w)[:, None]
    D1 = _quad(z) * sw
    D2 = np.column_stack([-2 * z, np.ones(len(z))]) * sw
    # min |D1 m + D2 l| over l: l = -D2^+ D1 m; reduced scatter S = D1^T (I - P2) D1
    Q, _ = np.linalg.qr(D2)
    R = D1 - Q @ (Q.T @ D1)
    S = R.T @ R
    _ev, V = np.linalg.eigh(S)
    for k in range(6):
        Mz = _sym(V[:, k])
        e = np.linalg.eigvalsh(Mz)
        if e[0] * e[-1] > 0 and min(abs(e[0]), abs(e[-1])) > 1e-9 * max(abs(e[0]), abs(e[-1])):
            Mz = Mz * np.sign(e[0])
            l, *_ = np.linalg.lstsq(D2, -D1 @ (V[:, k] * np.sign(e[0])), rcond=None)
            cz = np.linalg.solve(Mz, l[:3])
            return mu + s * cz, Mz / s**2
    # sphere: |z|^2 = 2 c.z - e (linear)
    l, *_ = np.linalg.lstsq(D2, -np.sum(z * z, axis=1) * sw[:, 0], rcond=None)
    return mu + s * l[:3], np.eye(3) / s**2


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (..., 4), scalar first."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def quat_exp(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) of rotation vectors (..., 3): the exact rotation of one sample."""
    th = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * th
    k = np.where(th > 1e-12, np.sin(half) / np.where(th > 1e-12, th, 1.0), 0.5 - th**2 / 48.0)
    return np.concatenate([np.cos(half), rotvec * k], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) (body -> reference)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


# component-first ("planar") forms of the three helpers above, for the gyro fit's many-sample products: the same
# formulas in the same order (bit-identical results), on contiguous component planes (4, ...) instead of the
# interleaved last axis, without np.stack: about twice as fast on (motions x samples) arrays
def _qmul_planar(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    out = np.empty((4, *np.broadcast_shapes(pw.shape, qw.shape)))
    out[0] = pw * qw - px * qx - py * qy - pz * qz
    out[1] = pw * qx + px * qw + py * qz - pz * qy
    out[2] = pw * qy - px * qz + py * qw + pz * qx
    out[3] = pw * qz + px * qy - py * qx + pz * qw
    return out


def _qexp_planar(rotvec: np.ndarray) -> np.ndarray:
    """quat_exp of rotation vectors given as planes (3, ...) -> (4, ...)."""
    x, y, z = rotvec
    th = np.sqrt(x * x + y * y + z * z)
    half = 0.5 * th
    big = th > 1e-12
    k = np.where(big, np.sin(half) / np.where(big, th, 1.0), 0.5 - th**2 / 48.0)
    out = np.empty((4, *th.shape))
    out[0] = np.cos(half)
    out[1:] = rotvec * k
    return out


def _qmat_planar(q: np.ndarray) -> np.ndarray:
    """quat_to_matrix of quaternion planes (4, ...) -> (..., 3, 3)."""
    w, x, y, z = q
    R = np.empty((*w.shape, 3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def _prefix_product(q: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Cumulative quaternion products within contiguous groups (Hillis-Steele scan, log2(N) vector steps)."""
    out = q.copy()
    d = 1
    n = len(q)
    while d < n:
        same = (group[d:] == group[:-d])[:, None]
        prod = quat_mul(out[:-d], out[d:])
        out[d:] = np.where(same, prod, out[d:])
        d *= 2
    return out / np.linalg.norm(out, axis=1, keepdims=True)


# ---------------------------------------------------------------------- gauge
def _gauge_basis(H: np.ndarray, a: int, b: int, c: int) -> np.ndarray:
    """Orthonormal basis P (rows in MB): x along nominal axis a, y in the (a, b) plane, z towards axis c."""
    x = H[a] / np.linalg.norm(H[a])
    y = H[b] - x * (x @ H[b])
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    if z @ H[c] < 0:
        z = -z
    return np.vstack([x, y, z])


def _best_triple(H: np.ndarray) -> tuple[int, int, int]:
    n = len(H)
    if n == 3:
        return (0, 1, 2)
    combos = itertools.combinations(range(n), 3) if n <= 24 else [tuple(range(3))]
    return max(combos, key=lambda t: abs(np.linalg.det(H[list(t)])))


def gauge_fixed(cal: InstrumentCalibration, triple: Sequence[int], other: InstrumentCalibration | None = None,
                members: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Raw-domain rows ``W`` (n, 3) and raw biases ``c`` of a calibration expressed in the hand-held gauge frame
    of accelerometer sensors ``triple`` (see the module docstring): the frame in which the calibrated axis of
    ``triple[0]`` is its nominal one and that of ``triple[1]`` lies in the nominal plane of the two.

    ``cal`` defines the frame (the accelerometers); pass ``other`` to express another instrument (the gyros)
    in the same frame. ``members`` restricts the sensors defining the geometry's nominal rows (a sub-unit).
    Used to compare an estimate with a known truth.
    """
    g = cal.geometry
    H = g.nominal_rows() @ np.eye(3) if members is None else g.H
    Hn = _mb_nominal(g)
    a, b, c = triple
    P_nom = _gauge_basis(Hn, a, b, c)
    A = cal.axes_mb()
    P_true = _gauge_basis(A, a, b, c)
    R = P_nom.T @ P_true  # maps the true gauge basis onto the nominal one
    del H
    src = other if other is not None else cal
    W = (src.axes_mb() / src.scale[:, None]) @ R.T
    return W, src.bias / src.scale


def _mb_nominal(g: Geometry) -> np.ndarray:
    """Nominal sensing axes in MB (H itself: the nominal rows mapped back from each sub-unit basis)."""
    return np.asarray(g.H, dtype=float)


# ---------------------------------------------------------------------- pose data
@dataclass
class _RawStats:
    """One instrument's samples of every segment, back to back as rows (n, N) minus a reference sample (so sums of
    products keep their precision), with the per-segment sums and peaks: one pass over the data that the noise
    level, the clip levels, the pose means and the gyro fit's sums all read, instead of one pass each (each a
    strided reduction over the (N, n) sample arrays)."""

    X: np.ndarray | None  # (n, N) raw - ref (compiled path: None until asked for, see x())
    ref: np.ndarray  # (n,)
    starts: np.ndarray  # (S,) first column of each segment in X
    counts: np.ndarray  # (S,)
    sums: np.ndarray  # (S, n) sum of the raw samples of each segment
    peak: np.ndarray  # (S, n) largest |raw| of each segment
    t: np.ndarray  # (N,) sample times
    d3: np.ndarray | None = None  # (S, n) sum of squared third differences inside each segment (compiled pass)
    Y: np.ndarray | None = None  # (N, n) raw samples back to back (compiled pass; the kernels subtract ref)

    def x(self) -> np.ndarray:
        """The rows ``raw - ref`` (n, N) (formed from Y on first use on the compiled path)."""
        if self.X is None:
            self.X = np.ascontiguousarray((self.Y - self.ref).T)
        return self.X

    def means(self, seg_index: Sequence[int], idx: Sequence[int] | slice = slice(None)) -> np.ndarray:
        j = np.asarray(seg_index, dtype=int)
        return (self.sums[j] / self.counts[j, None])[:, idx]


def _raw_stats(session: Session, instrument: str, kern: Any = None) -> _RawStats:
    segs = session.segments
    counts = np.array([s.n_samples for s in segs], dtype=int)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
    n = session.geometries[instrument].n
    ref = np.asarray(segs[0].raw[instrument][0], dtype=float).copy() if counts[0] else np.zeros(n)
    if kern is not None and len(segs):  # compiled: one pass over the samples as stored (rows), no transpose
        Y = np.concatenate([s.raw[instrument] for s in segs]).astype(float, copy=False)
        sums, hi, lo, d3 = (np.empty((len(segs), n)) for _ in range(4))
        kern.segment_stats(Y, starts, counts, ref, sums, hi, lo, d3)
        sums += counts[:, None] * ref
        peak = np.where((counts > 0)[:, None], np.maximum(np.abs(hi + ref), np.abs(lo + ref)), 0.0)
        return _RawStats(None, ref, starts, counts, sums, peak, np.concatenate([s.t for s in segs]), d3, Y)
    X = np.empty((n, int(counts.sum())))
    for s, a, k in zip(segs, starts, counts):
        np.subtract(s.raw[instrument].T, ref[:, None], out=X[:, a:a + k])
    ok = counts > 0
    sums = np.zeros((len(segs), n))
    hi = np.full((len(segs), n), -np.inf)
    lo = np.full((len(segs), n), np.inf)
    if np.any(ok):
        st = starts[ok]
        sums[ok] = np.add.reduceat(X, st, axis=1).T
        hi[ok] = np.maximum.reduceat(X, st, axis=1).T
        lo[ok] = np.minimum.reduceat(X, st, axis=1).T
    sums += counts[:, None] * ref
    peak = np.where(ok[:, None], np.maximum(np.abs(hi + ref), np.abs(lo + ref)), 0.0)
    t = np.concatenate([s.t for s in segs]) if segs else np.zeros(0)
    return _RawStats(X, ref, starts, counts, sums, peak, t)


def _diff_power(rs: _RawStats, eligible: np.ndarray, order: int) -> tuple[np.ndarray, int]:
    """Sum over the eligible segments of the squared differences of order ``order`` (per sensor), and their count:
    ``sum_t (sum_k a_k x_t+k)^2 = sum_kl a_k a_l sum_t x_t+k x_t+l`` from the lagged products of the whole record
    (one dot product per lag and sensor), less the differences that are not inside one eligible segment (across a
    boundary, or in a motion), which are formed explicitly."""
    from math import comb

    X = rs.x()
    n, N = X.shape
    if N <= order:
        return np.zeros(n), 0
    a = np.array([(-1.0) ** (order - k) * comb(order, k) for k in range(order + 1)])
    m = N - order  # windows t = 0 .. m-1 over the whole record
    lag = [np.array([X[i, :N - d] @ X[i, d:] for i in range(n)]) for d in range(order + 1)]
    total = np.zeros(n)
    for k in range(order + 1):
        for l in range(order + 1):
            d = abs(l - k)
            lo = min(k, l)
            # sum_{t=0}^{m-1} x_{t+lo} x_{t+lo+d} = lag_d minus the products before lo and after m-1+lo
            head = np.einsum("ij,ij->i", X[:, :lo], X[:, d:d + lo])
            tail = np.einsum("ij,ij->i", X[:, m + lo:N - d], X[:, m + lo + d:N])
            total += a[k] * a[l] * (lag[d] - head - tail)
    valid = np.zeros(m, bool)
    cnt = 0
    for j in np.flatnonzero(eligible):
        s, c = rs.starts[j], rs.counts[j]
        valid[s:s + c - order] = True
        cnt += c - order
    bad = np.flatnonzero(~valid)
    if bad.size:
        e = X[:, bad[:, None] + np.arange(order + 1)] @ a  # (n, B)
        total -= np.einsum("ij,ij->i", e, e)
    return np.maximum(total, 0.0), cnt


def white_noise_sigma_hf(session: Session, instrument: str, order: int = 3,
                         _stats: _RawStats | None = None) -> np.ndarray:
    """Per-sample white-noise standard deviation (raw) from differences of order ``order`` within the poses.

    A hand-held pose is not still: tremor (8-12 Hz) and sway are real motion that the sensors measure and the
    calibration integrates, not noise. Differences of order k multiply white noise variance by C(2k, k) and
    attenuate a 10 Hz tremor sampled at 100 Hz by (2 sin(pi f / fs))^(2k) (0.06 for k = 3), so third
    differences see the white noise and hardly the hand. (Computed from lagged products in one pass, see
    :func:`_diff_power`; equal to the differences formed sample by sample, tested to 1e-9.)
    """
    from math import comb

    rs = _raw_stats(session, instrument) if _stats is None else _stats
    kinds = np.array([s.kind in STATIC_KINDS for s in session.segments], dtype=bool)
    if not np.any(kinds):
        kinds[:] = True
    eligible = kinds & (rs.counts > order + 2)
    if rs.d3 is not None and order == 3:  # the compiled pass formed them sample by sample
        acc, cnt = rs.d3[eligible].sum(axis=0), int(np.sum(rs.counts[eligible] - order))
    else:
        acc, cnt = _diff_power(rs, eligible, order)
    if cnt == 0:
        return estimate_noise_sigma(session, instrument)
    sig = np.sqrt(acc / cnt / comb(2 * order, order))
    return np.where(sig > 0, sig, max(float(sig.max()), 1e-12))


def _statics(session: Session) -> list[Segment]:
    return [s for s in session.segments if s.kind in STATIC_KINDS]


def _static_index(session: Session) -> list[int]:
    return [j for j, s in enumerate(session.segments) if s.kind in STATIC_KINDS]


def _pose_stats(segs: Sequence[Segment], inst: str, idx: Sequence[int], sigma: np.ndarray,
                ybar: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean raw output of each pose (K, n) and its standard deviation from the per-sample noise (K, n)."""
    if ybar is None:
        ybar = np.array([s.raw[inst][:, idx].mean(axis=0) for s in segs])
    N = np.array([s.n_samples for s in segs], dtype=float)
    return ybar, sigma[None, :] / np.sqrt(N)[:, None]


@dataclass
class AccelFit:
    """Result of :func:`fit_accel` for one set of accelerometers (all of a unit, or one sub-unit)."""

    members: list[int]
    triple: tuple[int, int, int]
    W: np.ndarray  # (n, 3) raw per (m/s^2), rows in MB
    c: np.ndarray  # (n,) raw bias
    cov: np.ndarray  # covariance of theta (free parameters)
    theta: np.ndarray
    free: np.ndarray  # mask of the free entries of W_p (n, 3)
    P: np.ndarray  # gauge basis: rows in MB
    f: np.ndarray  # (K, 3) estimated specific force per pose, MB
    norm_residual: np.ndarray  # (K,) |f_k| - g, m/s^2
    norm_sigma: np.ndarray  # (K,) a-priori std of |f_k| from the white noise
    chi2: float
    dof: int
    scale2: float  # residual variance factor applied to the covariance
    parity: np.ndarray | None = None  # (K, n) whitened parity residuals of skewed sets
    weak: list[str] = field(default_factory=list)  # weakly determined parameter combinations
    ybar: np.ndarray | None = None  # (K, n) pose means the fit used
    sd: np.ndarray | None = None  # (K, n) their weights (standard deviations, raw)
    tau2: float = 0.0  # additive pose-to-pose variance of the norm, (m/s^2)^2

    def rows_cov(self, i: int) -> np.ndarray:
        """Covariance (4, 4) of sensor i's (w_i in MB, c_i)."""
        J = self._row_jac(i)
        return J @ self.cov @ J.T

    def _row_jac(self, i: int) -> np.ndarray:
        n = len(self.members)
        nf = int(self.free.sum())
        J = np.zeros((4, nf + n))
        pos = np.cumsum(self.free.ravel()) - 1
        for col in range(3):
            if self.free[i, col]:
                J[:3, pos[i * 3 + col]] = self.P[col]
        J[3, nf + i] = 1.0
        return J

    def rms_norm(self) -> float:
        return float(np.sqrt(np.mean(self.norm_residual**2)))


def _unpack(theta: np.ndarray, free: np.ndarray, fixed: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    Wp = fixed.copy()
    nf = int(free.sum())
    Wp[free] = theta[:nf]
    return Wp, theta[nf:nf + n]


def _specific_forces(Wp: np.ndarray, c: np.ndarray, ybar: np.ndarray, sd: np.ndarray):
    """Weighted least-squares estimate of f per pose, its information matrix, and the whitened residual."""
    w = 1.0 / sd**2  # (K, n)
    info = np.einsum("ki,ia,ib->kab", w, Wp, Wp)
    rhs = np.einsum("ki,ia,ki->ka", w, Wp, ybar - c)
    f = np.linalg.solve(info, rhs[..., None])[..., 0]
    e = (ybar - c - f @ Wp.T) / sd
    return f, info, e


def _accel_problem(theta: np.ndarray, free: np.ndarray, fixed: np.ndarray, ybar: np.ndarray, sd: np.ndarray,
                   gravity: float, tau2: float, jac: bool = True):
    """Residuals of the accelerometer fit (:func:`fit_accel`, step 2) and their analytic Jacobian.

    Per pose k: ``f_k = (W^T S_k W)^-1 W^T S_k (ybar_k - c)`` (S_k = diag(1 / sd_k^2)), the norm residual
    ``(|f_k| - g) / sqrt(u_k^T info_k^-1 u_k + tau^2)`` and, for skewed sets, the whitened parity
    ``(ybar_k - c - W f_k) / sd_k``. Returns (r, J, df) with df = d f / d theta (K, 3, p) (None without ``jac``).
    With info = W^T S W and rho = ybar - c - W f: ``d f / d c_i = -info^-1 W_i s_i``,
    ``d f / d W_ia = info^-1 s_i (e_a rho_i - W_i f_a)``; ``d s2 = 2 (info^-1 u) . du - (info^-1 u)^T d info
    (info^-1 u)``, ``du = (I - u u^T) df / |f|``.
    """
    n = free.shape[0]
    Wp, c = _unpack(theta, free, fixed, n)
    f, info, e = _specific_forces(Wp, c, ybar, sd)
    Sinv = np.linalg.inv(info)  # (K, 3, 3)
    nf = np.sqrt(np.einsum("ka,ka->k", f, f))
    u = f / nf[:, None]
    Su = np.einsum("kab,kb->ka", Sinv, u)
    s2n = np.einsum("ka,ka->k", u, Su)
    den = np.sqrt(s2n + tau2)
    d = nf - gravity
    r = d / den
    if n > 3:
        r = np.concatenate([r, e.ravel()])
    if not jac:
        return r, None, None
    K = len(ybar)
    w = 1.0 / sd**2  # (K, n)
    rho = e * sd  # (K, n) unwhitened residual
    nfree = int(free.sum())
    p = nfree + n
    # d f / d W (K, 3, n, 3) and d f / d c (K, 3, n)
    SW = np.einsum("kab,ib->kai", Sinv, Wp) * w[:, None, :]  # info^-1 W_i s_i  (K, 3, n)
    dfW = (Sinv[:, :, None, :] * (w * rho)[:, None, :, None]
           - SW[:, :, :, None] * f[:, None, None, :])  # (K, 3(out), n, 3(a))
    df = np.empty((K, 3, p))
    df[:, :, :nfree] = dfW.reshape(K, 3, 3 * n)[:, :, free.ravel()]
    df[:, :, nfree:] = -SW
    du = (df - u[:, :, None] * np.einsum("ka,kap->kp", u, df)[:, None, :]) / nf[:, None, None]
    dnf = np.einsum("ka,kap->kp", u, df)
    ds2 = 2.0 * np.einsum("ka,kap->kp", Su, du)
    # - (Su)^T d info (Su), d info / d W_ia = s_i (e_a W_i^T + W_i e_a^T)
    dinfo = 2.0 * w[:, :, None] * Su[:, None, :] * (Su @ Wp.T)[:, :, None]  # (K, n, 3(a))
    ds2[:, :nfree] -= dinfo.reshape(K, 3 * n)[:, free.ravel()]
    J_norm = dnf / den[:, None] - 0.5 * (d / den**3)[:, None] * ds2
    if n <= 3:
        return r, J_norm, df
    # parity: e_ki = (ybar_ki - c_i - W_i . f_k) / sd_ki
    de = -np.einsum("ia,kap->kip", Wp, df)
    dW_direct = np.zeros((K, n, n, 3))
    idx = np.arange(n)
    dW_direct[:, idx, idx, :] = -f[:, None, :]
    de[:, :, :nfree] += dW_direct.reshape(K, n, 3 * n)[:, :, free.ravel()]
    de[:, :, nfree:] -= np.eye(n)[None]
    de /= sd[:, :, None]
    return r, np.vstack([J_norm, de.reshape(K * n, p)]), df


def fit_accel(ybar: np.ndarray, sd: np.ndarray, H: np.ndarray, gravity: float, names: Sequence[str],
              members: Sequence[int] | None = None, robust: bool = False, model: str = "full",
              quick: bool = False) -> AccelFit:
    """Accelerometers from static poses of unknown attitude (module docstring, steps 1-3).

    Parameters
    ----------
    ybar : ndarray (K, n)
        Mean raw output of each pose.
    sd : ndarray (K, n)
        Its standard deviation from the white noise (raw).
    H : ndarray (n, 3)
        Nominal sensing axes in MB.
    gravity : float
        Local gravity, m/s^2 (the norm of the specific force at rest).
    names : sequence of str
        Sensor names (for messages).
    model : {"full", "scale_bias"}
        ``"full"``: scale, misalignment and bias (9 parameters for a triad); ``"scale_bias"`` (triads): the
        axes kept nominal, 6 parameters, for poses that only put each axis up and down (a Ferraris recording).
    quick : bool
        One refinement without the pose-variance component, no covariance (zero) and no identifiability checks:
        for scoring many candidate detections.
    """
    ybar = np.asarray(ybar, float)
    K, n = ybar.shape
    members = list(range(n)) if members is None else list(members)
    if model not in ("full", "scale_bias"):
        raise ValueError(f"model must be 'full' or 'scale_bias', got {model!r}")
    if model == "scale_bias" and n != 3:
        raise IdentifiabilityError("accel: model 'scale_bias' is for a triad; a skewed set needs the full model",
                                   [])
    p = 4 * n - 3 if model == "full" else 2 * n
    distinct = _distinct_directions(ybar)
    if model == "full" and n == 3 and K >= 9 and distinct < 9:
        raise IdentifiabilityError(
            f"accel: the {K} poses hold only {distinct} distinct orientations (repeated poses add nothing on the "
            "misalignments); the full model needs at least 9: hold the unit in 20 to 50 different orientations, "
            "or fit scale and bias alone (model 'scale_bias')", [f"{s}.mis" for s in names])
    need = int(np.ceil(p / max(n - 2, 1))) if n > 3 else 9
    if model == "scale_bias":
        need = 6
    if K < max(need, (9 if model == "full" else 6) if n == 3 else 4):
        raise IdentifiabilityError(
            f"accel: {K} static poses for {p} parameters of {n} sensors; the norm of gravity gives one equation per "
            f"pose{' (plus ' + str(n - 3) + ' parity equations)' if n > 3 else ''}: record at least "
            f"{max(need, (9 if model == 'full' else 6) if n == 3 else 4)} poses (hand-held: 20 to 50 in varied "
            "orientations)",
            [f"{s}.{q}" for s in names for q in ("scale", "bias")])
    tri = _best_triple(H)
    P = _gauge_basis(H, *tri)
    Hp = H @ P.T
    # 1. linear initial solution on the triple (Zhang Eq. 12-14 posed with |vec M| = 1)
    t = list(tri)
    if model == "full":
        cen, M = ellipsoid_fit(ybar[:, t], 1.0 / np.mean(sd[:, t] ** 2, axis=1))
    else:
        cen, M = _axis_ellipsoid_fit(ybar)
    q = np.einsum("ki,ij,kj->k", ybar[:, t] - cen, M, ybar[:, t] - cen)
    M = M * gravity**2 / float(np.mean(q))
    A = lower_factor(M)
    # rows of the triple in its gauge basis: the triple's p frame (x along sensor a, y in the a-b plane)
    Wt = np.linalg.inv(A)
    sgn = np.sign(np.sum(Wt * Hp[t], axis=1))  # reflection ambiguity of the norm: take the nominal handedness
    if sgn[2] < 0:
        Wt[:, 2] *= -1
    f0 = (ybar[:, t] - cen) @ np.linalg.inv(Wt).T
    Wp0 = np.zeros((n, 3))
    c0 = np.zeros(n)
    Wp0[t] = Wt
    c0[t] = cen
    X = np.column_stack([f0, np.ones(K)])
    for i in range(n):
        if i not in t:
            beta, *_ = np.linalg.lstsq(X, ybar[:, i], rcond=None)
            Wp0[i], c0[i] = beta[:3], beta[3]
    free = np.ones((n, 3), bool)
    free[tri[0], 1] = free[tri[0], 2] = free[tri[1], 2] = False
    if model == "scale_bias":
        free = np.eye(3, dtype=bool)
        Wp0 = np.diag(np.diag(Wp0))
    fixed = np.zeros((n, 3))  # the gauge entries are zero by definition
    if model == "scale_bias":
        fixed = np.zeros((n, 3))  # nominal axes (an orthogonal triad is diagonal in its gauge frame)
    theta0 = np.concatenate([Wp0[free], c0])
    typ = np.concatenate([np.full(int(free.sum()), float(np.median(np.abs(Wp0[np.abs(Wp0) > 0])))),
                          np.maximum(np.abs(c0), np.median(sd) * 10)])

    def norm_parts(theta):
        Wp, c = _unpack(theta, free, fixed, n)
        f, info, e = _specific_forces(Wp, c, ybar, sd)
        nf = np.linalg.norm(f, axis=1)
        u = f / nf[:, None]
        return nf - gravity, np.einsum("ka,kab,kb->k", u, np.linalg.inv(info), u), e

    def fun(theta):
        return _accel_problem(theta, free, fixed, ybar, sd, gravity, tau2[0])[:2]

    # 2. nonlinear refinement of the full model on all poses (Gauss-Newton / Levenberg-Marquardt on the analytic
    # Jacobian of _accel_problem). A pose held by hand is disturbed by more than the
    # white noise (a pose-to-pose variance tau^2 that does not fall with the pose's length): when the norm
    # residuals exceed the white-noise prediction, tau^2 is the additive variance that brings their chi-square
    # to its degrees of freedom, and the fit is repeated with it (variance components; otherwise a long still
    # period would outweigh every hand-held pose)
    tau2 = [0.0]
    theta = theta0
    for _ in range(1 if quick else 3):
        theta = _gauss_newton(fun, theta, typ, robust, xtol=1e-8 if quick else 1e-12, max_iter=200)[0]
        if quick:
            break
        dof_n = K - len(theta) + (K * (n - 3) if n > 3 else 0)
        if dof_n < 1:
            break
        d_, s2_, e_ = norm_parts(theta)
        t_new = _extra_variance(d_, s2_, float(np.sum(e_**2)) if n > 3 else 0.0, dof_n)
        if abs(t_new - tau2[0]) <= 1e-3 * max(t_new, 1e-300):
            break
        tau2[0] = t_new
    if quick:
        Wp, c = _unpack(theta, free, fixed, n)
        d_, s2_, e_ = norm_parts(theta)
        return AccelFit(members, tri, Wp @ P, c, np.zeros((len(theta), len(theta))), theta, free, P,
                        np.zeros((K, 3)), d_, np.sqrt(s2_), 0.0, K - len(theta), 1.0, None, [], ybar, sd, 0.0)
    # 3. covariance from the (analytic) Jacobian and the residual noise
    r, J = fun(theta)
    nobs = K + (K * (n - 3) if n > 3 else 0)
    dof = nobs - len(theta)
    _check_jacobian(J, typ, _theta_names(free, names, P_names=("x", "y", "z")), "accel")
    Js = J * typ
    cov = np.linalg.pinv(Js.T @ Js) * np.outer(typ, typ)
    chi2 = float(r @ r)
    # the a-priori noise (white noise from third differences) unless the residual says it is larger (tremor,
    # pose-to-pose disturbances): an estimated variance of few degrees of freedom would make the errors
    # Student-t, wider than their stated sigma
    s2 = max(chi2 / dof, 1.0) if dof >= 1 else 1.0
    size = np.concatenate([np.full(int(free.sum()), typ[0]), np.full(n, typ[0] * gravity)])  # full-scale sizes
    weak = _check_spread(cov * s2 / np.outer(size, size), _theta_names(free, names), "accel")
    Wp, c = _unpack(theta, free, fixed, n)
    f, info, e = _specific_forces(Wp, c, ybar, sd)
    nf = np.linalg.norm(f, axis=1)
    u = f / nf[:, None]
    sn = np.sqrt(np.einsum("ka,kab,kb->k", u, np.linalg.inv(info), u))
    return AccelFit(members, tri, Wp @ P, c, cov * s2, theta, free, P, f @ P, nf - gravity, sn, chi2, dof, s2,
                    e if n > 3 else None, weak, ybar, sd, tau2[0])


def held_out_accel(ybar: np.ndarray, sd: np.ndarray, H: np.ndarray, gravity: float, names: Sequence[str],
                   members: Sequence[int] | None = None, refit: bool = False, _kern: Any = None
                   ) -> dict[str, Any] | None:
    """The accelerometer misalignment step checked on held-out poses: rms of the gravity-norm residual
    ``|f_k| - g`` of the model with scale and bias alone (the step's input) and of the full model (its result), on
    the poses they were fitted on and on each pose left out in turn (fitted on the others, ``f_k`` the least-squares
    solution of ``W f = y_k - c``). None when leaving a pose out leaves the full model unidentifiable (fewer than 10
    poses). Values in m/s^2, ``[scale_bias, full]``.

    Each leave-one-out fit is the minimum of the fit on every pose with one residual removed: it is reached by
    Gauss-Newton steps from the fit on every pose, all K problems at once (:func:`_accel_loo`), to 1e-12 of the
    typical parameter sizes (the refits from the linear start stop at 1e-8). ``refit=True``: the reference, every
    leave-one-out model fitted again from its own linear initial solution (:func:`fit_accel`); both give the same
    figures (tested to 1e-9 relative, measured 5e-11) and verdicts.
    """
    K = len(ybar)
    if K < 10 or H.shape[0] != 3:
        return None
    ybar, sd = np.asarray(ybar, float), np.asarray(sd, float)
    ins, out = [], []
    distinct = None
    for model in ("scale_bias", "full"):
        try:
            whole = fit_accel(ybar, sd, H, gravity, names, members, model=model, quick=True)
            ins.append(float(np.sqrt(np.mean(whole.norm_residual ** 2))))
            if refit:
                r = []
                for k in range(K):
                    keep = np.arange(K) != k
                    af = fit_accel(ybar[keep], sd[keep], H, gravity, names, members, model=model, quick=True)
                    f = np.linalg.lstsq(af.W, ybar[k] - af.c, rcond=None)[0]
                    r.append(float(np.linalg.norm(f)) - gravity)
            else:
                if model == "full":  # fit_accel's refusal of too few distinct orientations, per left-out pose
                    distinct = _distinct_directions_loo(ybar) if distinct is None else distinct
                    if np.any(distinct < 9):
                        raise IdentifiabilityError("accel: too few distinct orientations with a pose left out", [])
                r = _accel_loo(whole, ybar, sd, H, gravity, names, members, model, _kern=_kern)
        except IdentifiabilityError:
            return None
        out.append(float(np.sqrt(np.mean(np.square(r)))))
    return {"in_sample": ins, "held_out": out, "unit": "m/s^2", "models": ["scale_bias", "full"]}


def _accel_triad_batch(theta: np.ndarray, free: np.ndarray, ybar: np.ndarray, sd: np.ndarray,
                       gravity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_accel_problem` of a triad (no parity, no pose variance) for B parameter vectors at once: the norm
    residuals (B, K), their Jacobians (B, K, p) (the same formulas, named there) and the raw rows ``W_p`` (B, 3, 3)."""
    B = theta.shape[0]
    nfree = int(free.sum())
    fr = free.ravel()
    Wp = np.zeros((B, 9))
    Wp[:, fr] = theta[:, :nfree]
    Wp = Wp.reshape(B, 3, 3)
    c = theta[:, nfree:]
    w = 1.0 / sd**2  # (K, 3)
    info = np.einsum("ki,bia,bic->bkac", w, Wp, Wp)
    res = ybar[None] - c[:, None, :]  # (B, K, 3)
    rhs = np.einsum("ki,bia,bki->bka", w, Wp, res)
    Sinv = np.linalg.inv(info)  # (B, K, 3, 3)
    f = np.einsum("bkac,bkc->bka", Sinv, rhs)
    rho = res - np.einsum("bka,bia->bki", f, Wp)
    nf = np.sqrt(np.einsum("bka,bka->bk", f, f))
    u = f / nf[..., None]
    Su = np.einsum("bkac,bkc->bka", Sinv, u)
    den = np.sqrt(np.einsum("bka,bka->bk", u, Su))
    d = nf - gravity
    r = d / den
    SW = np.einsum("bkac,bic->bkai", Sinv, Wp) * w[None, :, None, :]  # (B, K, 3, n)
    dfW = Sinv[:, :, :, None, :] * (w * rho)[:, :, None, :, None] - SW[..., None] * f[:, :, None, None, :]
    p = theta.shape[1]
    df = np.empty((B, len(ybar), 3, p))
    df[..., :nfree] = dfW.reshape(B, len(ybar), 3, 9)[..., fr]
    df[..., nfree:] = -SW
    dnf = np.einsum("bka,bkap->bkp", u, df)
    du = (df - u[..., None] * dnf[:, :, None, :]) / nf[..., None, None]
    ds2 = 2.0 * np.einsum("bka,bkap->bkp", Su, du)
    dinfo = 2.0 * w[None, :, :, None] * Su[:, :, None, :] * np.einsum("bka,bia->bki", Su, Wp)[..., None]
    ds2[..., :nfree] -= dinfo.reshape(B, len(ybar), 9)[..., fr]
    J = dnf / den[..., None] - 0.5 * (d / den**3)[..., None] * ds2
    return r, J, Wp


def _accel_loo(whole: AccelFit, ybar: np.ndarray, sd: np.ndarray, H: np.ndarray, gravity: float, names: Sequence[str],
               members: Sequence[int] | None, model: str, xtol: float = 1e-12, max_iter: int = 50,
               _kern: Any = None) -> np.ndarray:
    """The held-out gravity-norm residual of every pose of a triad, each from the fit on the other poses
    (:func:`held_out_accel`): K Gauss-Newton problems solved together, each started from the fit on every pose
    (``whole``, its parameters in the gauge frame of the triad) with its own pose's residual left out, a step
    taken while it lowers that problem's cost, until every step is below ``xtol`` of the typical sizes. A problem
    whose step does not lower its cost, or that does not converge, is refitted from the linear start
    (:func:`fit_accel`), so the minimum reached is the refit's."""
    K = len(ybar)
    free = whole.free
    theta = np.tile(whole.theta, (K, 1))
    Wp0 = whole.W @ whole.P.T
    typ = np.concatenate([np.full(int(free.sum()), float(np.median(np.abs(Wp0[np.abs(Wp0) > 0])))),
                          np.maximum(np.abs(whole.c), np.median(sd) * 10)])
    keep = 1.0 - np.eye(K)
    if _kern is not None:  # compiled (rimu.calibration._hh_kernels.accel_triad_batch)
        fp = np.full(9, -1, dtype=np.int64)
        fp[free.ravel()] = np.arange(int(free.sum()))

        def evaluate(th, b):
            return _kern.accel_triad_batch(th, fp, ybar, sd, float(gravity), keep[b], typ)
    else:
        def evaluate(th, b):
            r, J, _ = _accel_triad_batch(th, free, ybar, sd, gravity)
            r, Js = r * keep[b], J * (keep[b, :, None] * typ)
            return r, Js, np.einsum("bkp,bkq->bpq", Js, Js), np.einsum("bkp,bk->bp", Js, r)

    r, _, A, g = evaluate(theta, np.arange(K))
    cost = np.einsum("bk,bk->b", r, r)
    todo = np.ones(K, bool)
    bad = np.zeros(K, bool)
    for _ in range(max_iter):
        b = np.flatnonzero(todo)
        try:
            step = -np.linalg.solve(A[b], g[b][..., None])[..., 0]
        except np.linalg.LinAlgError:
            bad[b] = True
            break
        th_new = theta[b] + step * typ
        r_new, _, A_new, g_new = evaluate(th_new, b)
        c_new = np.einsum("bk,bk->b", r_new, r_new)
        small = np.max(np.abs(step), axis=1) <= xtol
        ok = (c_new <= cost[b] * (1 + 1e-9)) | small
        bad[b[~ok]] = True
        acc = b[ok]
        theta[acc], A[acc], g[acc], cost[acc] = th_new[ok], A_new[ok], g_new[ok], c_new[ok]
        todo[b[~ok | small]] = False
        if not np.any(todo):
            break
    bad |= todo
    Wp = np.zeros((K, 9))
    Wp[:, free.ravel()] = theta[:, :int(free.sum())]
    Wp = Wp.reshape(K, 3, 3)
    c = theta[:, int(free.sum()):]
    f = np.linalg.solve(Wp, (ybar - c)[..., None])[..., 0]
    out = np.linalg.norm(f, axis=1) - gravity
    for k in np.flatnonzero(bad):  # the reference: a refit from the linear start
        sel = np.arange(K) != k
        af = fit_accel(ybar[sel], sd[sel], H, gravity, names, members, model=model, quick=True)
        out[k] = float(np.linalg.norm(np.linalg.lstsq(af.W, ybar[k] - af.c, rcond=None)[0])) - gravity
    return out


def _distinct_directions_loo(ybar: np.ndarray, deg: float = 5.0) -> np.ndarray:
    """:func:`_distinct_directions` of the poses with each one left out in turn (K,): the greedy clustering of
    every subset run together on the directions of all poses, a left-out pose skipped (the centre is that of all
    poses unless the left-out pose holds an extreme; those subsets are counted one by one)."""
    K = len(ybar)
    lo, hi = ybar.min(axis=0), ybar.max(axis=0)
    y = ybar - 0.5 * (hi + lo)
    u = y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-300)
    near = (u @ u.T) > np.cos(np.radians(deg))  # near[i, r]: pose i within deg of pose r
    absorbed = np.zeros((K, K), bool)  # [left out, pose]
    count = np.zeros(K, int)
    js = np.arange(K)
    for i in range(K):
        rep = ~absorbed[:, i] & (js != i)
        count += rep
        absorbed |= rep[:, None] & near[:, i][None, :]
    extreme = np.flatnonzero(np.any((ybar == lo) | (ybar == hi), axis=1))
    for j in extreme:
        count[j] = _distinct_directions(np.delete(ybar, j, axis=0), deg)
    return count


def _distinct_directions(ybar: np.ndarray, deg: float = 5.0) -> int:
    """Number of distinct directions among the pose means (centred roughly), clusters closer than ``deg``: in
    order, a pose is a new direction unless it lies within ``deg`` of one found before it."""
    y = ybar - 0.5 * (ybar.max(axis=0) + ybar.min(axis=0))
    u = y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-300)
    near = (u @ u.T) > np.cos(np.radians(deg))  # near[i, r]: pose i within deg of pose r
    absorbed = np.zeros(len(y), bool)
    count = 0
    for i in range(len(y)):
        if not absorbed[i]:
            count += 1
            absorbed |= near[:, i]
    return count


def _axis_ellipsoid_fit(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned ellipsoid ``sum_j m_j (y_j - c_j)^2 = 1`` by linear least squares (scale and bias only)."""
    D = np.column_stack([y**2, -2 * y, np.ones(len(y))])
    _, _, Vt = np.linalg.svd(D / np.abs(D).max(axis=0))
    v = Vt[-1] / np.abs(D).max(axis=0)
    v = v * np.sign(v[0])
    m = v[:3]
    if np.any(m <= 0):
        return y.mean(axis=0), np.eye(3) / float(np.mean(np.sum((y - y.mean(axis=0)) ** 2, axis=1)))
    c = v[3:6] / m
    return c, np.diag(m)


def _extra_variance(d: np.ndarray, s2: np.ndarray, rest: float, dof: int) -> float:
    """The additive pose variance tau^2 >= 0 with ``sum d_k^2 / (s2_k + tau^2) + rest = dof`` (0 when the white
    noise explains the residuals already). Newton's method from tau^2 = 0: the sum falls with tau^2 and is convex
    in it, so the iterates rise monotonically to the root without overshooting."""
    d2 = d**2
    if float(np.sum(d2 / s2)) + rest <= dof:
        return 0.0
    hi = float(np.max(d2)) * len(d) + float(np.max(s2))
    if float(np.sum(d2 / (s2 + hi))) + rest > dof:  # no root below this bound (the parity alone exceeds dof)
        return hi
    tau = 0.0
    for _ in range(200):
        q = d2 / (s2 + tau)
        g = float(np.sum(q)) + rest - dof
        step = g / float(np.sum(q / (s2 + tau)))
        tau += step
        if step <= 1e-15 * tau:
            break
    return tau


def _theta_names(free: np.ndarray, names: Sequence[str], P_names=("x", "y", "z")) -> list[str]:
    out = [f"{names[i]}.w_{P_names[j]}" for i in range(free.shape[0]) for j in range(3) if free[i, j]]
    return out + [f"{s}.bias" for s in names]


def _check_jacobian(J: np.ndarray, typ: np.ndarray, names: list[str], inst: str) -> None:
    """Raise IdentifiabilityError naming the parameter combinations the data leave free."""
    Js = J * typ
    p = Js.shape[1]
    s = np.linalg.svd(Js, compute_uv=False)  # (the directions only when some are left free)
    if len(s) == p and s[-1] >= 1e-7 * s[0]:
        return
    _, s, Vt = np.linalg.svd(Js, full_matrices=True)
    s_full = np.concatenate([s, np.zeros(p - len(s))])
    bad = np.flatnonzero(s_full < 1e-7 * s_full[0])
    if bad.size == 0:
        return
    combos = []
    for k in bad:
        v = Vt[k]
        order = np.argsort(-np.abs(v))[:3]
        combos.append(" + ".join(f"{v[j]:+.2f} {names[j]}" for j in order if abs(v[j]) > 0.1))
    raise IdentifiabilityError(
        f"{inst}: the poses do not identify {len(bad)} direction(s) of the model: " + "; ".join(combos)
        + ". Add poses that excite them (gravity along and between every sensor axis, both signs; for the gyros, "
          "rotations about every axis)", sorted({names[j] for k in bad for j in np.argsort(-np.abs(Vt[k]))[:2]}))


def _check_spread(C: np.ndarray, names: list[str], inst: str, limit: float = 0.5,
                  weak: float = 0.02) -> list[str]:
    """Raise IdentifiabilityError when a parameter combination is so poorly determined that its standard
    deviation exceeds ``limit`` of the parameters' full-scale size (``C`` is the covariance divided by those
    sizes: the scale factor for the axis rows, the scale times g (accelerometers) or 1 rad/s (gyros) for the
    biases): the poses excite it only through the noise. Returns the combinations whose relative standard
    deviation exceeds ``weak`` (weakly determined: reported, not refused)."""
    ev, V = np.linalg.eigh((C + C.T) / 2)

    def words(k: int) -> str:
        v = V[:, k]
        order = np.argsort(-np.abs(v))[:3]
        return (" + ".join(f"{v[j]:+.2f} {names[j]}" for j in order if abs(v[j]) > 0.1)
                + f" (relative sd {np.sqrt(max(ev[k], 0.0)):.2g})")

    bad = np.flatnonzero(ev > limit**2)
    if bad.size == 0:
        return [words(k) for k in np.flatnonzero(ev > weak**2)[::-1]]
    combos, params = [], set()
    for k in bad[::-1]:
        v = V[:, k]
        order = np.argsort(-np.abs(v))[:3]
        combos.append(" + ".join(f"{v[j]:+.2f} {names[j]}" for j in order if abs(v[j]) > 0.1)
                      + f" (relative sd {np.sqrt(ev[k]):.2g})")
        params |= {names[j] for j in order[:2]}
    raise IdentifiabilityError(
        f"{inst}: the poses do not identify {len(bad)} direction(s) of the model: " + "; ".join(combos)
        + ". Add poses that excite them (gravity along and between every sensor axis, both signs; for the gyros, "
          "rotations about every axis)", sorted(params))




# ---------------------------------------------------------------------- gyros
def pose_windows(session: Session) -> list[tuple[int, int, list[Segment]]]:
    """Consecutive pose pairs (k, k+1) (indices into the static segments) with the segments from the start of
    pose k to the end of pose k+1, when they are contiguous in time (no gap longer than two sample periods)."""
    segs = session.segments
    dt = 1.0 / session.sample_rate
    st_idx = [j for j, s in enumerate(segs) if s.kind in STATIC_KINDS]
    out = []
    for k in range(len(st_idx) - 1):
        a, b = st_idx[k], st_idx[k + 1]
        chain = segs[a:b + 1]
        if b - a < 2 or any(s.kind in ("rate", "angle") for s in chain[1:-1]):
            continue  # no motion between, or a table segment
        ok = all(abs(chain[j + 1].t[0] - chain[j].t[-1]) <= 2.5 * dt for j in range(len(chain) - 1))
        if ok:
            out.append((k, k + 1, chain))
    return out


class _LazyDict(dict):
    """A dict whose listed keys are computed on first access (``makers[key]()``), then kept."""

    def __init__(self, makers: dict[str, Any]) -> None:
        super().__init__()
        self._makers = makers

    def __missing__(self, key: str) -> Any:
        if key not in self._makers:
            raise KeyError(key)
        value = self[key] = self._makers[key]()
        return value


@dataclass
class GyroFit:
    """Result of :func:`fit_gyro`."""

    members: list[int]
    W: np.ndarray  # (n, 3) raw per (rad/s), rows in the accelerometer MB gauge frame
    c: np.ndarray
    cov: np.ndarray  # of theta = [W.ravel(), c]
    theta: np.ndarray
    pairs: list[tuple[int, int]]
    rotation_residual: np.ndarray  # (M, 2) rad: gravity-direction misfit after each motion
    angle: np.ndarray  # (M,) rad: integrated rotation angle of each motion
    static_residual: np.ndarray  # (K, n) raw: pose mean minus bias
    chi2: dict[str, float] = field(default_factory=dict)
    dof: int = 0
    group_scale: dict[str, float] = field(default_factory=dict)
    weak: list[str] = field(default_factory=list)
    #: the final weighted problem: ``resid(theta)``, its analytic ``jac(theta)`` and typical sizes ``typ``
    problem: dict[str, Any] = field(default_factory=dict, repr=False)

    def rows_cov(self, i: int) -> np.ndarray:
        n = len(self.members)
        J = np.zeros((4, 4 * n))
        J[:3, 3 * i:3 * i + 3] = np.eye(3)
        J[3, 3 * n + i] = 1.0
        return J @ self.cov @ J.T

    def rms_rotation_deg(self) -> float:
        return float(np.degrees(np.sqrt(np.mean(np.sum(self.rotation_residual**2, axis=1)))))


def _rodrigues(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (M, 3, 3) of rotation vectors (M, 3) (Rodrigues' formula, series near zero)."""
    x, y, z = v.T
    th2 = x * x + y * y + z * z
    if float(th2.max(initial=0.0)) < 1e-8:  # every angle below 1e-4 rad: the series to th^4 is exact in double
        a = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
        b = 0.5 - th2 / 24.0 + th2 * th2 / 720.0
    else:
        th = np.sqrt(th2)
        big = th > 1e-4
        ths = np.where(big, th, 1.0)
        a = np.where(big, np.sin(ths) / ths, 1.0 - th2 / 6.0 + th2 * th2 / 120.0)
        b = np.where(big, (1.0 - np.cos(ths)) / (ths * ths), 0.5 - th2 / 24.0 + th2 * th2 / 720.0)
    R = np.empty((len(v), 3, 3))
    bx, by = b * x, b * y
    ax, ay, az = a * x, a * y, a * z
    R[:, 0, 0] = 1.0 - b * (y * y + z * z)
    R[:, 1, 1] = 1.0 - b * (x * x + z * z)
    R[:, 2, 2] = 1.0 - b * (x * x + y * y)
    R[:, 0, 1] = bx * y - az
    R[:, 1, 0] = bx * y + az
    R[:, 0, 2] = bx * z + ay
    R[:, 2, 0] = bx * z - ay
    R[:, 1, 2] = by * z - ax
    R[:, 2, 1] = by * z + ax
    return R


def _right_jacobian(x: np.ndarray) -> np.ndarray:
    """Right Jacobians (M, 3, 3) of the rotation exponential at x (M, 3): ``Exp(x + dx) = Exp(x) Exp(Jr dx)``,
    ``Jr = I - (1 - cos t) / t^2 [x]x + (t - sin t) / t^3 [x]x^2``."""
    t2 = np.einsum("mi,mi->m", x, x)
    t = np.sqrt(t2)
    big = t > 1e-4
    ts = np.where(big, t, 1.0)
    a = np.where(big, (1.0 - np.cos(ts)) / ts**2, 0.5 - t2 / 24.0)
    b = np.where(big, (ts - np.sin(ts)) / ts**3, 1.0 / 6.0 - t2 / 120.0)
    # [x]x^2 = x x^T - t^2 I: Jr = (1 - b t^2) I - a [x]x + b x x^T, written entry by entry
    J = b[:, None, None] * (x[:, :, None] * x[:, None, :])
    d = 1.0 - b * t2
    J[:, 0, 0] += d
    J[:, 1, 1] += d
    J[:, 2, 2] += d
    ax = a[:, None] * x
    J[:, 0, 1] += ax[:, 2]
    J[:, 1, 0] -= ax[:, 2]
    J[:, 0, 2] -= ax[:, 1]
    J[:, 2, 0] += ax[:, 1]
    J[:, 1, 2] += ax[:, 0]
    J[:, 2, 1] -= ax[:, 0]
    return J


def _cross_cols(v: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``v x X`` for every column of X: v (M, 3), X (M, 3, p) -> (M, 3, p) (``skew(v) @ X``)."""
    out = np.empty_like(X)
    out[:, 0] = v[:, 1, None] * X[:, 2] - v[:, 2, None] * X[:, 1]
    out[:, 1] = v[:, 2, None] * X[:, 0] - v[:, 0, None] * X[:, 2]
    out[:, 2] = v[:, 0, None] * X[:, 1] - v[:, 1, None] * X[:, 0]
    return out


def _scan_planar(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exclusive prefix products along the last axis (length a power of two) of quaternion planes (4, M, L),
    and the total product (4, M): a work-efficient (Blelloch) up- and down-sweep, 2 L products in all."""
    levels = [q]
    while levels[-1].shape[-1] > 1:
        a = levels[-1]
        levels.append(_qmul_planar(a[..., 0::2], a[..., 1::2]))
    total = levels[-1][..., 0]
    ex = np.zeros_like(levels[-1])
    ex[0] = 1.0
    for a in levels[-2::-1]:
        nxt = np.empty_like(a)
        nxt[..., 0::2] = ex
        nxt[..., 1::2] = _qmul_planar(ex, a[..., 0::2])
        ex = nxt
    return ex, total


def _huber_weights(r: np.ndarray, robust: bool, f_scale: float) -> np.ndarray:
    """IRLS weights of scipy's ``loss="huber"`` (rho'(z), z = (r / f_scale)^2): 1 inside, f_scale / |r| beyond."""
    if not robust:
        return np.ones_like(r)
    a = np.abs(r)
    return np.where(a <= f_scale, 1.0, f_scale / np.maximum(a, 1e-300))


def _huber_cost(r: np.ndarray, robust: bool, f_scale: float) -> float:
    """scipy's ``0.5 * sum(f_scale^2 rho((r / f_scale)^2))`` for the Huber (or the linear) loss."""
    if not robust:
        return 0.5 * float(r @ r)
    z = (r / f_scale) ** 2
    return 0.5 * f_scale**2 * float(np.sum(np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)))


def _gauss_newton(fun, theta: np.ndarray, typ: np.ndarray, robust: bool, f_scale: float = 3.0,
                  xtol: float = 1e-10, max_iter: int = 100, reach=None, radius: float = np.inf):
    """Minimise the (Huber-)robust least-squares cost of ``fun(theta) -> (r, J)`` by Levenberg-Marquardt steps on
    iteratively reweighted residuals (the stationary point of scipy's ``least_squares(loss="huber")``): a step
    that does not lower the cost is retried with ten times the damping, an accepted one divides it by ten. Stops
    when the step is below ``xtol`` in units of ``typ`` (or the damping found no lower cost).

    ``reach(theta)`` (optional) measures how far theta is from where ``fun`` is valid (a model about a point); a
    step beyond ``radius`` is shortened to it and, if it lowers the cost, ends the solve there. Returns
    (theta, r, J, whether the solve stopped at the radius)."""
    r, J = fun(theta)
    cost = _huber_cost(r, robust, f_scale)
    lam = 0.0
    near = False
    for _ in range(max_iter):
        w = _huber_weights(r, robust, f_scale)
        Js = J * typ
        # curvature: the reweighted one (rho') while far, the Gauss-Newton model of the robust cost itself once the
        # steps are small (scipy's scaling: rho' + 2 rho'' z, for the Huber loss 0 beyond f_scale): the
        # stationary point is the same, reached at the rate of Gauss-Newton rather than of reweighting
        hw = np.where(w < 1.0, 1e-6, 1.0) if (robust and near) else w
        A = Js.T @ (Js * hw[:, None])
        g = Js.T @ (w * r)
        dA = np.diag(A).copy()
        here = reach(theta) if reach is not None else 0.0  # theta is fixed while the damping is retried
        while True:
            try:
                step = -np.linalg.solve(A + lam * np.diag(dA), g)
            except np.linalg.LinAlgError:
                step = -np.linalg.lstsq(A + lam * np.diag(dA), g, rcond=None)[0]
            small = float(np.max(np.abs(step))) <= xtol
            th_new = theta + step * typ
            edge = False
            if reach is not None:
                far = reach(th_new)
                if far > radius:  # the reach is convex along the step: shorten it to the radius
                    th_new = theta + step * typ * max(radius - here, 0.0) / max(far - here, 1e-300)
                    edge = True
            r_new, J_new = fun(th_new)
            c_new = _huber_cost(r_new, robust, f_scale)
            if c_new <= cost * (1 + 1e-9) or small:  # (rounding of the cost; a Jacobian first order in the poses)
                lam = lam / 10.0 if lam > 1e-6 else 0.0
                break
            lam = max(lam * 10.0, 1e-4)
            if lam > 1e8:
                return theta, r, J, False
        theta, r, J, cost = th_new, r_new, J_new, c_new
        near = lam == 0.0 and float(np.max(np.abs(step))) < 1e-3
        if small or edge:
            return theta, r, J, edge
    return theta, r, J, False


def fit_gyro(session: Session, windows: list[tuple[int, int, list[Segment]]], accel_dirs: np.ndarray,
             accel_dir_jac: np.ndarray | None, accel_cov: np.ndarray | None, idx: Sequence[int], sigma: np.ndarray,
             H: np.ndarray, robust: bool = True, dir_cov: np.ndarray | None = None,
             preintegrate: bool = True, _stats: _RawStats | None = None, _ybar: np.ndarray | None = None,
             _kern: Any = None, model: str = "full", _start: np.ndarray | None = None, _share: tuple | None = None,
             _pre: tuple | None = None) -> GyroFit:
    """Gyros from the rotations between poses (module docstring; Tedaldi et al. 2014, Eq. 14-18).

    Parameters
    ----------
    windows : from :func:`pose_windows`
    accel_dirs : ndarray (K, 3)
        Calibrated gravity direction (unit specific force) of every pose, MB.
    accel_dir_jac : ndarray (K*3, p_a), optional
        d accel_dirs / d accelerometer parameters; with ``accel_cov`` their uncertainty is propagated.
    idx : the gyro columns calibrated together; sigma their per-sample raw noise; H their nominal axes.
    dir_cov : ndarray (K, 3, 3), optional
        Covariance of each pose's gravity direction (from the accelerometer noise); default isotropic 1e-8.
    preintegrate : bool
        ``True`` (default): each motion's samples are integrated once at the current parameters, keeping the
        rotation and its Jacobian (pre-integration, as in Forster et al. 2017); the fit then iterates on these
        per-motion quantities, ``R(theta) = R(theta_l) Exp(J_l (theta - theta_l))``, and integrates again only
        while the correction turns some motion by more than 1e-4 rad (the model's error is second order in it).
        ``False``: the reference, every sample integrated again at every evaluation of a trust-region solver
        (``scipy.optimize.least_squares``); both reach the same optimum (tested).
    model : {"full", "scale_bias"}
        ``"full"``: every component of each sensor's row (scale and misalignment, relative to the accelerometer
        frame) and the biases; ``"scale_bias"``: the axes kept nominal (``W_i = s_i H_i``), a scale and a bias per
        sensor: the input of the misalignment step that :func:`held_out_gyro` checks.
    """
    if model not in ("full", "scale_bias"):
        raise ValueError(f"model must be 'full' or 'scale_bias', got {model!r}")
    statics = _statics(session)
    inst = "gyro"
    n = len(idx)
    if not windows:
        raise IdentifiabilityError("gyro: no motion between two consecutive static poses; record the rotations "
                                   "between poses (do not cut them out) to calibrate the gyros",
                                   ["scale", "misalignment"])
    ybar, sd = _pose_stats(statics, inst, idx, sigma, _ybar)
    if dir_cov is None:
        dir_cov = np.broadcast_to(np.eye(3) * 1e-8, (len(statics), 3, 3))
    # samples of every window, back to back, grouped
    M = len(windows)
    ka = np.array([w[0] for w in windows])
    kb = np.array([w[1] for w in windows])
    rst = _raw_stats(session, inst) if _stats is None else _stats
    rows = slice(None) if list(idx) == list(range(len(rst.ref))) else list(idx)
    ref = rst.ref[rows]
    seg_pos = {id(s): j for j, s in enumerate(session.segments)}
    # per window: the pose-k samples (first order: tremor and sway are small rotations), the motion samples
    # (exact rotations, padded to a common power-of-two length with identity steps) and the pose-(k+1) samples
    if _share is not None:  # a subset of the windows of a fit on every window (held_out_gyro's folds): its sums
        sh, sel = _share[0], np.asarray(_share[1], dtype=int)
        cols = [sh["cols"][m] for m in sel]
        parts_idx = [sh["parts_idx"][m] for m in sel]
        mot_dt = [sh["mot_dt"][m] for m in sel]
        SA_w, SB_w, Tw, Tw2, q_ab, mot_dd = (sh[k][sel] for k in ("SA_w", "SB_w", "Tw", "Tw2", "q_ab", "mot_dd"))
        L = 1 << int(np.ceil(np.log2(max(max(len(d) for d in mot_dt), 1))))
        DM = np.ascontiguousarray(sh["DM"][sel, :L])
        D0: dict[str, np.ndarray] | None = {
            "SA_y": sh["D"]["SA_y"][sel], "SB_y": sh["D"]["SB_y"][sel], "Yint": sh["D"]["Yint"][sel],
            "YD": np.ascontiguousarray(sh["D"]["YD"][:, sel, :L])}
        dt_all = None
    else:
        L = 1
        cols: list[tuple[int, int]] = []
        parts_idx: list[tuple[np.ndarray, np.ndarray, np.ndarray, int, int]] = []
        mot_dt = []
        SA_w, SB_w = np.zeros(M), np.zeros(M)
        Tw, Tw2 = np.zeros(M), np.zeros(M)
        q_ab_list: list[float] = []
        dt_all = np.zeros(len(rst.t))  # t[i+1] - t[i] (the last entry of every window is set below)
        np.subtract(rst.t[1:], rst.t[:-1], out=dt_all[:-1])
        ramp = np.arange(int(rst.counts.max()) + 1, dtype=float)
        for m, (_, _, chain) in enumerate(windows):
            j0, j1 = seg_pos[id(chain[0])], seg_pos[id(chain[-1])]
            c0, c1 = int(rst.starts[j0]), int(rst.starts[j1] + rst.counts[j1])
            cols.append((c0, c1))
            # dt[i] = t[i+1] - t[i] within the window, the last sample's the one before it
            dt = dt_all[c0:c1].copy() if c1 - c0 > 1 else np.array([1.0 / session.sample_rate])
            if c1 - c0 > 1:
                dt[-1] = dt_all[c1 - 2]
            na, nb = int(rst.counts[j0]), int(rst.counts[j1])
            # attitude at sample i of pose k relative to the end of the pose: -sum_{tau >= i} w dt; its mean
            wa = dt[:na] * ramp[1:na + 1] / na
            # attitude at sample j of pose k+1 relative to its start: sum_{tau < j} w dt; its mean
            wb = dt[c1 - c0 - nb:] * ramp[nb - 1::-1] / nb
            SA_w[m], SB_w[m] = wa.sum(), wb.sum()
            q_ab_list.append(float(wa @ wa + wb @ wb))
            mot_dt.append(dt[na:c1 - c0 - nb])
            L = max(L, c1 - c0 - na - nb)
            Tw[m], Tw2[m] = dt.sum(), dt @ dt
            parts_idx.append((wa, wb, dt, na, nb))
        L = 1 << int(np.ceil(np.log2(max(L, 1))))
        q_ab = np.array(q_ab_list)
        mot_dd = np.array([d @ d for d in mot_dt])  # (the motions' sum of dt^2, shared with the folds)
        DM = np.zeros((M, L))
        for m in range(M):
            DM[m, :len(mot_dt[m])] = mot_dt[m]

        D0 = None

    def window_samples(name: str) -> list:
        """The raw samples (N_m, n) of every window (gyro: the fitted columns; or the accelerometers'), built
        only when asked for (diagnosis)."""
        if name == "gyro":
            return [np.vstack([s.raw[inst][:, idx] for s in w[2]]) for w in windows]
        if "accel" not in session.geometries:
            return [None] * M
        return [np.vstack([s.raw["accel"] for s in w[2]]) for w in windows]

    def sums(ys_: list[np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The data sums the residual needs, from the raw samples of every window (linear in them): the
        dt-weighted motion samples as planes (n, M, L), the weighted pose sums and the window integrals. Without
        ``ys_``, from the one pass over the session (rows minus a reference sample; the reference added back)."""
        out = {"SA_y": np.zeros((M, n)), "SB_y": np.zeros((M, n)), "YD": np.zeros((n, M, L)),
               "Yint": np.zeros((M, n))}
        if ys_ is None and _kern is not None and rst.Y is not None and all(c1 - c0 > 1 for c0, c1 in cols):
            c0s, c1s = np.array(cols, dtype=np.int64).T  # compiled, every window in one call
            _kern.window_sums(rst.Y if isinstance(rows, slice) else rst.Y[:, rows], ref, dt_all, c0s, c1s,
                              np.array([p[3] for p in parts_idx], dtype=np.int64),
                              np.array([p[4] for p in parts_idx], dtype=np.int64), SA_w, SB_w, Tw,
                              out["SA_y"], out["SB_y"], out["YD"], out["Yint"])
            return out
        for m, (wa, wb, dt, na, nb) in enumerate(parts_idx):
            nm = len(dt) - na - nb
            if ys_ is None:  # each sample read once: the pose sums and their part of the integral together
                c0, c1 = cols[m]
                X = rst.x()[rows, c0:c1]
                Xa, Xb = X[:, :na], X[:, na + nm:]
                xm = X[:, na:na + nm] * dt[na:na + nm]
                out["SA_y"][m] = Xa @ wa + ref * SA_w[m]
                out["SB_y"][m] = Xb @ wb + ref * SB_w[m]
                out["YD"][:, m, :nm] = xm + ref[:, None] * dt[na:na + nm]
                out["Yint"][m] = Xa @ dt[:na] + Xb @ dt[na + nm:] + xm.sum(axis=1) + ref * Tw[m]
            else:
                y = ys_[m]
                out["SA_y"][m] = wa @ y[:na]
                out["SB_y"][m] = wb @ y[len(y) - nb:]
                out["YD"][:, m, :nm] = (y[na:len(y) - nb] * dt[na:len(y) - nb, None]).T
                out["Yint"][m] = dt @ y
        return out

    D = sums() if D0 is None else D0
    # (M, 2, 3) tangent basis at each measured end direction
    T = _tangent(accel_dirs[kb]) if _share is None else _share[0]["T"][_share[1]]
    sig_int = sigma[None, :] * np.sqrt(Tw2)[:, None]

    def _G(W):
        if n == 3:
            return np.linalg.inv(W)
        wi = 1.0 / sigma**2
        return np.linalg.solve(W.T @ (W * wi[:, None]), W.T * wi)

    def integrate(theta, jac=True, sel=None):
        """The rotation of every motion (M, 3, 3), exact (a quaternion per sample, combined pairwise), and with
        ``jac`` the pre-integration at theta: ``(theta, R, DG, Qc, G, c)`` for :func:`model_x`.

        To first order in the change of every sample's rate, ``R' = R Exp(sum_t dt A_t^T (omega'_t - omega_t))``
        with A_t the rotation from the middle of sample t to the end, ``A_t = C_mid,t^T R`` (C_mid,t: attitude at
        the middle of sample t relative to the start, from the exclusive prefix products). The rate is linear in
        G and c, ``omega_t = G (y_t - c)``, so the sum needs only the sums ``Q_i = R^T sum_t dt (y_ti - c_i)
        C_mid,t`` (one per sensor) and ``Qc = R^T sum_t dt C_mid,t``: one prefix scan and n + 1 weighted sums,
        after which any G, c near these is O(motions) work (Forster et al. 2017's pre-integration, here for the
        gyro scale, misalignment and bias)."""
        W = theta[:3 * n].reshape(n, 3)
        c = theta[3 * n:]
        Gm = _G(W)
        if not jac and _kern is not None:  # compiled, sample by sample (_hh_kernels.motion_rotations)
            YD, DMs = (D["YD"], DM) if sel is None else (np.ascontiguousarray(D["YD"][:, sel]), DM[sel])
            tot = _kern.motion_rotations(YD, DMs, Gm, c).T
            return _qmat_planar(tot / np.linalg.norm(tot, axis=0, keepdims=True))
        if sel is not None:  # (without jac) the rotations of these motions only
            YD, DMs = D["YD"][:, sel], DM[sel]
            omp = (Gm @ YD.reshape(n, -1)).reshape(3, len(DMs), L) - (Gm @ c)[:, None, None] * DMs
        elif not jac or _kern is None:
            omp = (Gm @ D["YD"].reshape(n, -1)).reshape(3, M, L) - (Gm @ c)[:, None, None] * DM  # rad per sample
        if not jac:
            q = _qexp_planar(omp)
            while q.shape[2] > 1:  # pairwise products: the rotation over the motion
                q = _qmul_planar(q[:, :, 0::2], q[:, :, 1::2])
            return _qmat_planar(q[:, :, 0] / np.linalg.norm(q[:, :, 0], axis=0, keepdims=True))
        if _kern is not None:  # compiled: the same quantities sample by sample (rimu.calibration._hh_kernels)
            tot, S = _kern.integrate_motions(D["YD"], DM, Gm, c)
            total = np.ascontiguousarray(tot.T)
        else:
            q = _qexp_planar(omp)
            ex, total = _scan_planar(q)
            mid = _qmul_planar(ex, q)
            mid += ex  # (P_t-1 q_t + P_t-1) / |.| = P_t-1 q_t^(1/2): the attitude at the middle of sample t
            mid /= np.sqrt(np.maximum(2.0 * (1.0 + q[0]), 1e-300))
            Cm = _qmat_planar(mid)  # (M, L, 3, 3)
            wts = np.concatenate([D["YD"] - c[:, None, None] * DM, DM[None]], axis=0)  # (n + 1, M, L)
            S = (wts.transpose(1, 0, 2) @ Cm.reshape(M, L, 9)).reshape(M, n + 1, 3, 3)  # sum_t w C_mid
        Rm = _qmat_planar(total / np.linalg.norm(total, axis=0, keepdims=True))
        Q = np.einsum("mba,mkbc->mkac", Rm, S)  # R^T sum_t w C_mid
        DG = Q[:, :n].transpose(0, 2, 3, 1).reshape(M, 3, 3 * n)  # d x / d vec(G), vec(G)[a n + i] = G[a, i]
        return (theta.copy(), Rm, DG, Q[:, n], Gm, c.copy())

    def model_x(theta, pre, jac=False, Gm=None):
        """The rotation vector x with ``R(theta) = R_l Exp(x)`` of the pre-integration ``pre`` (first order in the
        change of the sample rates, exact in their linear dependence on G), and with ``jac`` d x / d theta."""
        _, _, DG, Qc, G_l, c_l = pre
        c = theta[3 * n:]
        Gm = _G(theta[:3 * n].reshape(n, 3)) if Gm is None else Gm
        v = Gm @ (c - c_l)
        x = DG @ (Gm - G_l).ravel() - Qc @ v
        if not jac:
            return x
        dx = np.empty((M, 3, 4 * n))
        # d G / d W_ij = -G e_i e_j^T G (the least-squares G of skewed sets: the same, to first order)
        X = DG.reshape(M, 3, 3, n) @ Gm.T  # (M, 3, 3a, 3j)
        QG = Qc @ Gm  # (M, 3, n)
        dxW = -(Gm.T @ X) + QG[:, :, :, None] * v[None, None, None, :]
        dx[:, :, :3 * n] = dxW.reshape(M, 3, 3 * n)
        dx[:, :, 3 * n:] = -QG
        return x, dx

    def pose_rotations(theta):
        W = theta[:3 * n].reshape(n, 3)
        c = theta[3 * n:]
        Gm = _G(W)
        psi_a = -(D["SA_y"] - c * SA_w[:, None]) @ Gm.T  # mean attitude of pose k (end of pose k = reference)
        phi_b = (D["SB_y"] - c * SB_w[:, None]) @ Gm.T  # mean attitude of pose k+1 relative to its start
        return Gm, psi_a, phi_b

    def rotations(theta, pre=None, sel=None):
        """Cb^T Ca (pose-k body vector -> pose-(k+1) body) at theta; the motion rotations exact, or from the
        pre-integration ``pre = (theta_l, R_l, Dth_l)``; ``sel``: of these motions only (exact)."""
        Gm, psi_a, phi_b = pose_rotations(theta)
        if sel is not None:
            psi_a, phi_b = psi_a[sel], phi_b[sel]
        if pre is None:
            Rm = integrate(theta, jac=False, sel=sel)
            Eb, Ea = np.split(_rodrigues(np.concatenate([phi_b, psi_a])), 2)  # (one call: the same per vector)
        else:
            Rx, Eb, Ea = np.split(_rodrigues(np.concatenate([model_x(theta, pre, Gm=Gm), phi_b, psi_a])), 3)
            Rm = pre[1] @ Rx
        return np.einsum("mji,mjk->mik", Rm @ Eb, Ea)

    def parts(theta, dirs, R=None):
        c = theta[3 * n:]
        R = rotations(theta) if R is None else R  # R: the rotations at theta, when already known
        pred = np.einsum("mij,mj->mi", R, dirs[ka])
        rr = np.einsum("mai,mi->ma", T, pred - dirs[kb])
        rs = (ybar - c) / sd
        return rr, rs, parity(theta)

    def misfit(theta, sel=None):
        """The rotation residuals (M, 2) at theta, the motions integrated exactly; ``sel``: of these motions only."""
        if sel is None:
            return parts(theta, accel_dirs)[0]
        pred = np.einsum("mij,mj->mi", rotations(theta, sel=sel), accel_dirs[ka[sel]])
        return np.einsum("mai,mi->ma", T[sel], pred - accel_dirs[kb[sel]])

    def parity(theta):
        if n == 3:
            return np.zeros((M, 0))
        W = theta[:3 * n].reshape(n, 3)
        c = theta[3 * n:]
        z = D["Yint"] - c * Tw[:, None]
        return (z - z @ _G(W).T @ W.T) / sig_int

    def rot_parts(theta, pre, dirs):
        """Rotation residuals (M, 2) and d rr / d theta (M, 2, p) with the motion rotations of the pre-integration
        ``pre`` (:func:`integrate`); first order in the small pose rotations (module docstring)."""
        if _kern is not None:  # compiled, motion by motion (rimu.calibration._hh_kernels.rotation_model)
            return _kern.rotation_model(_G(theta[:3 * n].reshape(n, 3)), theta[3 * n:], pre[1], pre[2], pre[3],
                                        pre[4], pre[5], D["SA_y"], D["SB_y"], SA_w, SB_w, dirs[ka], dirs[kb], T)
        Gm, psi_a, phi_b = pose_rotations(theta)
        x, Dth = model_x(theta, pre, jac=True, Gm=Gm)
        Rx, Eb, Ca = np.split(_rodrigues(np.concatenate([x, phi_b, psi_a])), 3)
        Rm = pre[1] @ Rx
        if float(np.max(np.abs(x))) > 1e-3:  # d Exp(x) = Exp(x) [Jr(x) dx]x; Jr = I to 5e-4 below 1 mrad
            Dth = _right_jacobian(x) @ Dth
        Cb = Rm @ Eb
        v = (Ca @ dirs[ka][:, :, None])[:, :, 0]
        CbT = Cb.transpose(0, 2, 1)
        pred = (CbT @ v[:, :, None])[:, :, 0]
        p = 4 * n
        Dpsi = np.empty((M, 3, p))
        Dphi = np.empty((M, 3, p))
        Dpsi[:, :, :3 * n] = (-Gm[None, :, :, None] * psi_a[:, None, None, :]).reshape(M, 3, 3 * n)
        Dphi[:, :, :3 * n] = (-Gm[None, :, :, None] * phi_b[:, None, None, :]).reshape(M, 3, 3 * n)
        Dpsi[:, :, 3 * n:] = SA_w[:, None, None] * Gm
        Dphi[:, :, 3 * n:] = -SB_w[:, None, None] * Gm
        Dbeta = Eb.transpose(0, 2, 1) @ Dth + Dphi
        dpred = _cross_cols(pred, Dbeta) - CbT @ _cross_cols(v, Dpsi)
        rr = (T @ (pred - dirs[kb])[:, :, None])[:, :, 0]
        return rr, T @ dpred

    def rot_jac(theta, dirs):
        """d rr / d theta (M, 2, p) at theta, the motions integrated there."""
        return rot_parts(theta, integrate(theta), dirs)[1]

    # initial: W from the nominal axes and the accelerometers' scale ratio is not known; use the statics for c
    # and a first motion-based guess of one common scale from the integrated angles
    c0 = np.median(ybar, axis=0)
    W0 = H.copy()
    s0 = _initial_gyro_scale(D["Yint"], Tw, c0, H, accel_dirs, ka, kb)
    theta0 = np.concatenate([(W0 * s0).ravel(), c0])
    typ = np.concatenate([np.full(3 * n, abs(s0)), np.maximum(np.abs(c0), sd.mean() * 10)])
    # the parameters solved for: theta = Bm @ phi (the full model: phi = theta; scale_bias: W_i = s_i H_i)
    Bm = np.eye(4 * n)
    typ_p = typ
    if model == "scale_bias":
        Bm = np.zeros((4 * n, 2 * n))
        for i in range(n):
            Bm[3 * i:3 * i + 3, i] = H[i]
            Bm[3 * n + i, n + i] = 1.0
        typ_p = np.concatenate([np.full(n, abs(s0)), typ[3 * n:]])

    def to_phi(theta):
        """The least-squares phi of theta (scale_bias: Bm's columns are orthogonal, each row's scale is its
        projection on the nominal axis)."""
        if model == "full":
            return theta
        Wt = theta[:3 * n].reshape(n, 3)
        return np.concatenate([np.sum(Wt * H, axis=1) / np.sum(H * H, axis=1), theta[3 * n:]])

    def reduced(fun_):
        """``fun_`` (theta -> (r, J)) as a function of phi."""
        if model == "full":
            return fun_

        def f(phi):
            r, J = fun_(Bm @ phi)
            return r, J @ Bm
        return f
    w_rot = 1.0e3  # 1 mrad to start with; both weights are then set from the residual scatter
    w_st = 1.0
    w_par = 1.0

    problem = _LazyDict({"ys": lambda: window_samples("gyro"), "accel_ys": lambda: window_samples("accel")})
    Lw = np.eye(2 * M)  # whitening of the rotation residuals (set after the first pass)
    Lwi = Lw
    Js_static = np.zeros((ybar.size, 4 * n))
    for i in range(n):
        Js_static[i::n, 3 * n + i] = -1.0 / sd[:, i]

    def resid(theta, dirs=accel_dirs, R=None):
        rr, rs, rp = parts(theta, dirs, R)
        rw = np.linalg.solve(Lw, rr.ravel()) if M else rr.ravel()
        return np.concatenate([rw * w_rot, rs.ravel() * w_st, rp.ravel() * w_par])

    def rot_resid_shift(theta, deltas):
        """The weighted rotation residuals with the raw gyro samples of every window shifted by ``deltas``."""
        saved = dict(D)
        D.update(sums([y + d for y, d in zip(problem["ys"], deltas)]))
        try:
            return resid(theta)[:2 * M]
        finally:
            D.update(saved)

    def other_jac(theta):
        out = [Js_static * w_st]
        if n > 3:
            out.append(central_jacobian(lambda th: parity(th).ravel(), theta, typ * 1e-6) * w_par)
        return out

    def jac(theta, dirs=accel_dirs):
        Jr = np.linalg.solve(Lw, rot_jac(theta, dirs).reshape(2 * M, -1)) * w_rot
        return np.vstack([Jr, *other_jac(theta)])

    def model_fun(pre):
        """(r, J) with the motion rotations from the pre-integration ``pre``."""
        Lws = Lwi * w_rot  # the weights are fixed while the model of one pre-integration is solved
        J_st = Js_static * w_st
        nr = 2 * M + ybar.size

        def f(theta):
            rr, Jr = rot_parts(theta, pre, accel_dirs)
            rs = (ybar - theta[3 * n:]) / sd
            rj = Lws @ np.concatenate([rr.reshape(2 * M, 1), Jr.reshape(2 * M, -1)], axis=1)
            r = np.concatenate([rj[:, 0], rs.ravel() * w_st, parity(theta).ravel() * w_par])
            if n > 3:
                return r, np.vstack([rj[:, 1:], *other_jac(theta)])
            J = np.empty((nr, 4 * n))
            J[:2 * M] = rj[:, 1:]
            J[2 * M:] = J_st
            return r, J
        return f

    gain = np.diag(np.linalg.inv(H.T @ (H / sigma[:, None] ** 2)))  # per-sample rate variance / s0^2 (nominal)
    q_m = float(np.mean(gain)) / s0**2 * (mot_dd + q_ab)
    # (``_start``: a solution of the same model on other motions, e.g. all of them where this fit leaves some out: the
    # same minimum from nearer, fewer integrations; the weights and typical sizes are this fit's own)
    theta = theta0 if _start is None else np.asarray(_start, dtype=float).copy()
    # (``_pre``: the pre-integration of these motions at ``_start``, e.g. a subset of that of the fit on every motion;
    # ``_share``: (that fit's ``problem["setup"]``, the indices of these windows in it): its sums, not formed again)
    pre = _pre if _start is not None else None
    by_pose = {int(a): m for m, a in enumerate(ka)}
    for it in range(2):
        if preintegrate:
            for _ in range(20):  # integrate at theta, iterate on the motions' rotations and Jacobians
                if pre is None:
                    pre = integrate(theta)

                def reach(th, pre=pre):  # the largest change of a motion's rotation the model predicts, rad
                    return float(np.max(np.abs(model_x(th, pre))))

                if _kern is not None and n == 3:  # compiled: the same steps (_hh_kernels.gauss_newton_model)
                    phi, edge = _kern.gauss_newton_model(
                        to_phi(theta), typ_p, robust, 1e-8, 100, 1.0, Bm, model == "full", pre[1], pre[2], pre[3],
                        pre[4], pre[5], D["SA_y"], D["SB_y"], SA_w, SB_w, accel_dirs[ka], accel_dirs[kb], T,
                        Lwi * w_rot, ybar, sd, float(w_st), Js_static * w_st)
                else:
                    phi, _, _, edge = _gauss_newton(reduced(model_fun(pre)), to_phi(theta), typ_p, robust,
                                                    xtol=1e-8, reach=lambda p_, r_=reach: r_(Bm @ p_), radius=1.0)
                theta = Bm @ phi
                # done when the model's correction turns no motion by more than 1 mrad: its error, second order
                # in that, is below 1e-6 rad (the motions' residual scatter is ~1e-3 rad)
                if not edge and reach(theta) <= 3e-4:
                    break
                pre = None
            R = rotations(theta, pre)
        else:
            from scipy.optimize import least_squares

            sol = least_squares(lambda p_: resid(Bm @ p_), to_phi(theta), jac=lambda p_: jac(Bm @ p_) @ Bm,
                                x_scale=typ_p, loss="huber" if robust else "linear",
                                f_scale=3.0, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100 * len(theta))
            theta = Bm @ sol.x
            R = rotations(theta)  # at theta: for Cr, the weights and the end
        if it == 0:
            # correlated residuals: the gravity direction of pose k enters motions k-1 and k; generalised least
            # squares with the block-tridiagonal covariance of the pose-direction and integrated-gyro noise
            Cr4 = np.zeros((M, M, 2, 2))  # (m, m2) blocks
            TR = T @ R
            TRt, Tt = TR.transpose(0, 2, 1), T.transpose(0, 2, 1)
            ar = np.arange(M)
            Cr4[ar, ar] = TR @ dir_cov[ka] @ TRt + T @ dir_cov[kb] @ Tt + q_m[:, None, None] * np.eye(2)
            nxt = np.array([by_pose.get(int(k), -1) for k in kb])
            m1 = np.flatnonzero(nxt >= 0)
            if m1.size:
                m2 = nxt[m1]
                X = -T[m1] @ dir_cov[kb[m1]] @ TRt[m2]
                Cr4[m1, m2] = X
                Cr4[m2, m1] = X.transpose(0, 2, 1)
            Cr = Cr4.transpose(0, 2, 1, 3).reshape(2 * M, 2 * M)
            Lw = np.linalg.cholesky(Cr)
            Lwi = np.linalg.inv(Lw)
            w_rot = 1.0
        rr, rs, rp = parts(theta, accel_dirs, R)
        rw = np.linalg.solve(Lw, rr.ravel())
        dof_rot = max(rw.size - 3 * n, 1)
        # the rotation group has many degrees of freedom: its noise level is estimated; the static means and
        # the parity of skewed sets are noisier than white noise (sway), never quieter
        w_rot = 1.0 / np.sqrt(max(float(rw @ rw) / dof_rot, 1e-6)) if it == 1 else w_rot
        w_st = 1.0 / max(_robust_rms(rs), 1.0)
        w_par = 1.0 / max(_robust_rms(rp), 1.0) if rp.size else 1.0
    if preintegrate:
        J = model_fun(pre)(theta)[1]
    else:
        J = jac(theta)
    gnames = session.geometries["gyro"].names
    sn = [str(gnames[j]) if j < len(gnames) else str(i) for i, j in enumerate(idx)]
    # named as the tables name the sensors (x.w_z: the z component of sensor x's raw-domain row, axis / scale)
    names = [f"{sn[i]}.w_{a}" for i in range(n) for a in "xyz"] + [f"{sn[i]}.bias" for i in range(n)]
    size = np.concatenate([np.full(3 * n, abs(s0)), np.full(n, abs(s0) * 1.0)])  # scale; bias of 1 rad/s
    if model == "scale_bias":
        J = J @ Bm
        names = [f"{sn[i]}.scale" for i in range(n)] + [f"{sn[i]}.bias" for i in range(n)]
        size = np.concatenate([np.full(n, abs(s0)), np.full(n, abs(s0) * 1.0)])
    _check_jacobian(J, typ_p, names, "gyro")
    Js = J * typ_p
    Ninv = np.linalg.pinv(Js.T @ Js) * np.outer(typ_p, typ_p)
    weak = _check_spread(Ninv / np.outer(size, size), names, "gyro")
    cov = Bm @ Ninv @ Bm.T
    if accel_dir_jac is not None and accel_cov is not None:
        # d resid / d accel params through the gravity directions (the rotations do not depend on them; the
        # rotation residual T_m (R_m u_ka - u_kb) is linear in the directions)
        K = accel_dirs.shape[0]
        Jd = np.zeros((M, 2, K, 3))
        Jd[np.arange(M), :, ka, :] = np.einsum("mai,mij->maj", T, R)
        Jd[np.arange(M), :, kb, :] -= T
        Ja = np.zeros((J.shape[0], accel_dir_jac.shape[1]))
        Ja[:2 * M] = np.linalg.solve(Lw, Jd.reshape(2 * M, 3 * K) @ accel_dir_jac) * w_rot
        B = Bm @ Ninv @ J.T @ Ja
        cov = cov + B @ accel_cov @ B.T
    rr, rs_, rp = parts(theta, accel_dirs, R)
    W = theta[:3 * n].reshape(n, 3)
    c = theta[3 * n:]
    problem.update({"resid": resid, "jac": jac, "typ": typ, "dt": [p[2] for p in parts_idx], "n_rot": 2 * M,
                    "rotation_misfit": misfit,
                    "setup": {"cols": cols, "parts_idx": parts_idx, "mot_dt": mot_dt, "SA_w": SA_w, "SB_w": SB_w,
                              "Tw": Tw, "Tw2": Tw2, "q_ab": q_ab, "mot_dd": mot_dd, "DM": DM, "D": D, "T": T},
                    "rot_resid_shift": rot_resid_shift, "integrate": integrate, "model_x": model_x,
                    "model_fun": model_fun})
    ang = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
    rw = np.linalg.solve(Lw, rr.ravel())
    chi2 = {"rotation": float(rw @ rw * w_rot**2), "static": float(np.sum(rs_**2) * w_st**2)}
    if rp.size:
        chi2["parity"] = float(np.sum(rp**2) * w_par**2)
    scale = {"rotation_rad": 1.0 / w_rot, "static_sigma": 1.0 / w_st}
    return GyroFit(list(idx), W, c, cov, theta, list(zip(ka.tolist(), kb.tolist())), rr, ang, rs_ * sd,
                   chi2, J.shape[0] - J.shape[1], scale, weak,
                   problem)


def held_out_gyro(session: Session, windows: list[tuple[int, int, list[Segment]]], accel_dirs: np.ndarray,
                  idx: Sequence[int], sigma: np.ndarray, H: np.ndarray, robust: bool = True,
                  dir_cov: np.ndarray | None = None, folds: int | None = None, fitted: dict[str, GyroFit] | None = None,
                  **fit_kw: Any) -> dict[str, Any] | None:
    """The gyro misalignment step checked on held-out motions: rms rotation misfit (the gravity direction of pose
    k+1 against that of pose k turned by the integrated rotation, rad; :func:`fit_gyro`) of the model with the axes
    nominal, a scale and a bias per sensor (``"scale_bias"``, the step's input) and of the full model (its result),
    on the motions they were fitted on and on held-out motions: the motions split into ``folds`` groups (motion m
    in group ``m % folds``; default: every motion its own group up to 8 motions, else 4 groups), each group left
    out in turn,
    the model fitted on the others (biases from every pose) and its misfit on the left-out motions evaluated by
    exact integration. None when leaving a group out leaves a model unidentifiable (too few motions).
    ``fitted``: fits on every motion already made (by model name). Values in rad, ``[scale_bias, full]``.

    Examples
    --------
    >>> from rimu.sim.handheld import handheld_run
    >>> run = handheld_run(n_poses=12, static_s=1.0, seed=1)
    >>> s = run.session
    >>> res = HandHeld(instruments=["accel"]).fit(s)
    >>> dirs = _dirs_with_jacobian(res.fits["accel"][0], _statics(s), s, white_noise_sigma_hf(s, "accel"))[0]
    >>> c = held_out_gyro(s, pose_windows(s), dirs, [0, 1, 2], white_noise_sigma_hf(s, "gyro"), np.eye(3), folds=4)
    >>> c["models"], c["unit"], bool(c["in_sample"][1] <= c["in_sample"][0])
    (['scale_bias', 'full'], 'rad', True)
    """
    M = len(windows)
    k = min(int(folds), M) if folds is not None else (M if M <= 8 else 4)
    if k < 2:
        return None
    group = np.arange(M) % k
    fitted = dict(fitted or {})
    ins, out = [], []
    for model in ("scale_bias", "full"):
        try:
            full = fitted.get(model)
            if full is None:  # (with the window sums of a fit on the same windows, when there is one)
                other = next(iter(fitted.values()), None)
                share = None if other is None else (other.problem["setup"], np.arange(M))
                full = fit_gyro(session, windows, accel_dirs, None, None, idx, sigma, H, robust, dir_cov,
                                model=model, _share=share, **fit_kw)
            misfit = full.problem["rotation_misfit"]
            # every fold starts from the whole fit, with its sums and its pre-integration there (one for all folds)
            setup = full.problem["setup"]
            pre = full.problem["integrate"](full.theta)
            r = np.empty((M, 2))
            for g in range(k):
                sel = np.flatnonzero(group != g)
                keep = [windows[m] for m in sel]
                gf = fit_gyro(session, keep, accel_dirs, None, None, idx, sigma, H, robust, dir_cov, model=model,
                              _start=full.theta, _share=(setup, sel),
                              _pre=(pre[0], pre[1][sel], pre[2][sel], pre[3][sel], pre[4], pre[5]), **fit_kw)
                out_g = np.flatnonzero(group == g)
                r[out_g] = misfit(gf.theta, out_g)
        except (IdentifiabilityError, np.linalg.LinAlgError):
            return None
        ins.append(float(np.sqrt(np.mean(np.sum(full.rotation_residual ** 2, axis=1)))))
        out.append(float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
    return {"in_sample": ins, "held_out": out, "unit": "rad", "models": ["scale_bias", "full"], "folds": k}


def _robust_rms(r: np.ndarray) -> float:
    r = np.asarray(r).ravel()
    if r.size == 0:
        return 1.0
    return float(1.4826 * np.median(np.abs(r)))


def _tangent(u: np.ndarray) -> np.ndarray:
    """Orthonormal tangent bases (M, 2, 3) at directions u (M, 3) (or (2, 3) at one direction (3,))."""
    one = u.ndim == 1
    u = np.atleast_2d(u)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    a = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    out = np.stack([e1, np.cross(u, e1)], axis=1)
    return out[0] if one else out


def _initial_gyro_scale(Yint, Tw, c0, H, dirs, ka, kb) -> float:
    """One common raw-per-(rad/s) factor: the median ratio of integrated raw rate magnitude to the angle between
    the gravity directions of the two poses (a lower bound of the turn; good enough to start)."""
    z = Yint - c0 * Tw[:, None]
    u = np.linalg.lstsq(H, z.T, rcond=None)[0].T
    ang = np.arccos(np.clip(np.sum(dirs[ka] * dirs[kb], axis=1), -1, 1))
    ok = ang > np.radians(20)
    if not np.any(ok):
        raise IdentifiabilityError("gyro: no motion turns the gravity direction by more than 20 deg; rotate the "
                                   "unit between poses", ["scale"])
    return float(np.median(np.linalg.norm(u[ok], axis=1) / ang[ok]))


def clip_levels(session: Session, instrument: str, _stats: _RawStats | None = None) -> np.ndarray:
    """Per sensor, the raw level at which the output clips, or inf: the largest |raw| of the session when it is
    reached at least twice and is a power of two or one less (an ADC's full scale, e.g. 32767 / 32768)."""
    rs = _raw_stats(session, instrument) if _stats is None else _stats
    n = len(rs.ref)
    m = rs.peak.max(axis=0) if len(rs.peak) else np.zeros(n)
    out = np.full(n, np.inf)
    for i in range(n):
        v = round(m[i])
        if v >= 128 and abs(m[i] - v) < 1e-9 and ((v & (v - 1)) == 0 or ((v + 1) & v) == 0):
            cnt = int(np.sum(np.abs(rs.x()[i] + rs.ref[i]) >= m[i]))
            if cnt >= 2:
                out[i] = m[i]
    return out


# ---------------------------------------------------------------------- estimator
class HandHeld:
    """Hand-held calibration of accelerometers (and gyros) from static poses of unknown attitude and the
    rotations between them (module docstring).

    Parameters
    ----------
    sigma : dict[str, float or array], optional
        Per-sample raw white noise per instrument (default: first differences within the poses).
    mode : {"joint", "subunits"}
        ``"joint"``: every sensor of an instrument together (skewed sets through the least-squares estimate of
        the specific force / rate). ``"subunits"``: each sub-unit triad on its own.
    instruments : sequence of str, optional
        Default: accelerometers, and gyros when the session has motions between poses.
    robust : bool
        Huber loss on the gyro residuals, against a bumped pose.
    accel_model : {"full", "scale_bias"}
        See :func:`fit_accel`.
    pose_weights : {"noise", "equal"}
        ``"noise"``: each pose mean weighted by its white noise (its length), plus a common pose-to-pose variance
        when the residuals call for it; ``"equal"``: every pose alike (as imu_tk does).
    backend : {"auto", "numpy", "numba"}, optional
        Implementation of the pass over the samples and of the integration of the motions (:mod:`rimu._backend`;
        default ``RIMU_BACKEND``, else ``"auto"``: numba where installed). Both give the same calibration to
        rounding (tested to 1e-9 relative); numpy is the reference.
    held_out : bool
        Check the accelerometers' misalignment step (the full model against scale and bias alone) on held-out
        poses (:func:`held_out_accel`, a triad of 10 poses or more) and the gyros' (every component of each row
        against nominal axes with a scale and a bias) on held-out motions (:func:`held_out_gyro`); a step that
        raises the held-out residual is not applied, and a note says why with the figures (default True).
    """

    method = "hand-held (Zhang et al. 2010 accelerometers, Tedaldi et al. 2014 gyros)"

    def __init__(self, sigma: dict[str, Any] | None = None, mode: str = "joint",
                 instruments: Sequence[str] | None = None, robust: bool = True, pose_weights: str = "noise",
                 accel_model: str = "full", backend: str | None = None, held_out: bool = True) -> None:
        choices = (("mode", mode, ("joint", "subunits")), ("pose_weights", pose_weights, ("noise", "equal")))
        for name, value, allowed in choices:
            if value not in allowed:
                raise ValueError(f"{name} must be {' or '.join(repr(x) for x in allowed)}, got {value!r}")
        self.sigma, self.mode, self.instruments, self.robust = sigma, mode, instruments, robust
        self.pose_weights, self.accel_model, self.held_out = pose_weights, accel_model, held_out
        self.backend = _resolve_backend(backend, lambda: _kernels() is not None, "the compiled hand-held kernels")

    def _sigma(self, session: Session, inst: str, stats: _RawStats | None = None) -> np.ndarray:
        n = session.geometries[inst].n
        if self.sigma and inst in self.sigma:
            return np.broadcast_to(np.asarray(self.sigma[inst], float), (n,)).copy()
        return white_noise_sigma_hf(session, inst, _stats=stats)

    def _groups(self, g: Geometry) -> list[list[int]]:
        if self.mode == "joint":
            return [list(range(g.n))]
        groups = [list(su.members) for su in g.subunits]
        bad = [su.name for su in g.subunits if len(su.members) != 3]
        if bad:
            raise SessionFormatError(f"mode 'subunits' calibrates triads; sub-units {bad} of {g.name!r} are not "
                                     "triads: use mode 'joint' (skewed sets through the least-squares estimate)")
        return groups

    def fit(self, session: Session) -> CalibrationResult:
        if "accel" not in session.geometries:
            raise SessionFormatError("hand-held calibration needs the accelerometers (gravity defines the poses)")
        statics = _statics(session)
        if not statics:
            raise SessionFormatError("the session has no static poses (segments of kind 'static_unknown' or "
                                     "'static'); run 'rimu detect' on the raw recording first")
        windows = pose_windows(session)
        clipped: list[str] = []
        # one pass over each instrument's samples: noise level, clip levels, pose means and the gyro fit's sums
        kern = _kernels() if self.backend == "numba" else None
        raw = {k: _raw_stats(session, k, kern) for k in ("accel", "gyro") if k in session.geometries}
        st_idx = _static_index(session)
        seg_pos = {id(s): j for j, s in enumerate(session.segments)}
        if "gyro" in session.geometries and windows:
            lim = clip_levels(session, "gyro", _stats=raw["gyro"])
            keep = []
            hit = np.any(raw["gyro"].peak >= lim, axis=1).tolist()  # per segment
            for w in windows:
                if any(hit[seg_pos[id(s)]] for s in w[2]):
                    clipped.append(f"{w[2][0].label}->{w[2][-1].label}")
                else:
                    keep.append(w)
            windows = keep
        if self.instruments is not None:
            want = list(self.instruments)
        else:
            want = ["accel"] + (["gyro"] if "gyro" in session.geometries and windows else [])
        ga = session.geometries["accel"]
        sa = self._sigma(session, "accel", raw["accel"])
        model = ErrorModel.base()
        out: dict[str, LsqResult] = {}
        extra: dict[str, Any] = {}
        notes = [("MB is the hand-held gauge frame: the first accelerometer of each calibrated set keeps its nominal "
                 "axis and the second stays in their nominal plane (those misalignments are zero by definition)")]
        afits: list[AccelFit] = []
        gfits: list[GyroFit] = []
        acc_sensors: dict[int, Any] = {}
        labels = [s.label for s in statics]
        for grp in self._groups(ga):
            ybar, sd = _pose_stats(statics, "accel", grp, sa[grp], raw["accel"].means(st_idx, grp))
            if self.pose_weights == "equal":
                sd = np.broadcast_to(np.median(sd, axis=0), sd.shape).copy()
            names_g = [ga.names[i] for i in grp]
            af = fit_accel(ybar, sd, ga.H[grp], session.gravity, names_g, grp, robust=False, model=self.accel_model)
            if self.accel_model == "full" and len(grp) == 3 and self.held_out:
                check = held_out_accel(ybar, sd, ga.H[grp], session.gravity, names_g, grp, _kern=kern)
                if check is not None:
                    extra.setdefault("held_out_accel", []).append(check)
                    sc = StepCheck("accel", "misalignment", "scale and bias alone", "specific_force",
                                   tuple(check["in_sample"]), tuple(check["held_out"]), "poses",
                                   "scale and bias alone, axes nominal", residual="gravity-norm residual")
                    extra.setdefault("steps", []).append(sc.to_dict())
                    if not sc.applied:
                        af = fit_accel(ybar, sd, ga.H[grp], session.gravity, names_g, grp, robust=False,
                                       model="scale_bias")
                    notes.append(sc.note())
            afits.append(af)
            for j, i in enumerate(grp):
                ctx = SensorContext("accel", i, ga, session.latitude, session.gravity)
                beta = np.concatenate([af.W[j], [af.c[j]]])
                fit = make_sensor_fit(model, ctx, beta, af.rows_cov(j), float(sa[i]), self.sigma is not None,
                                      len(statics), 0.0, {lab: np.array([r]) for lab, r in
                                                          zip(labels, af.norm_residual / ga.n)})
                fit.rss = af.chi2 / max(af.dof, 1) * (fit.n_obs - 4) * fit.sigma**2 if af.dof > 0 else 0.0
                acc_sensors[i] = fit
        out["accel"] = LsqResult("accel", model, [acc_sensors[i] for i in range(ga.n)], labels, {})
        norm_res = np.mean([a.norm_residual for a in afits], axis=0)
        extra["norm_residual_accel"] = norm_res
        extra["norm_rms_accel"] = float(np.sqrt(np.mean(norm_res**2)))
        extra["norm_sigma_accel"] = np.mean([np.sqrt(a.norm_sigma**2 + a.tau2) for a in afits], axis=0)
        extra["norm_noise_accel"] = float(np.sqrt(np.mean(np.mean([a.norm_sigma for a in afits], axis=0) ** 2)))
        extra["gauge_accel"] = [[ga.names[a.members[t]] for t in a.triple[:2]] for a in afits]
        extra["chi2_dof_accel"] = [a.chi2 / a.dof if a.dof > 0 else None for a in afits]
        weak = [w for a in afits for w in a.weak]
        if weak:
            extra["weak_accel"] = weak
            notes.append("accel: weakly determined by these poses (relative sd > 2 %): " + "; ".join(weak)
                         + "; add poses (20 to 50, gravity along and between every axis)")
        if "gyro" in want:
            if "gyro" not in session.geometries:
                raise SessionFormatError("the session has no gyro data")
            gg = session.geometries["gyro"]
            sg = self._sigma(session, "gyro", raw["gyro"])
            gyro_sensors: dict[int, Any] = {}
            ggroups = self._groups(gg) if self.mode == "subunits" else [list(range(gg.n))]
            rot_res, angles = [], []
            for j_g, grp in enumerate(ggroups):
                af = afits[min(j_g, len(afits) - 1)]
                dirs, djac, acov, dcov = _dirs_with_jacobian(af, statics, session, sa)
                try:
                    gf = fit_gyro(session, windows, dirs, djac, acov, grp, sg[grp], gg.H[grp], robust=self.robust,
                                  dir_cov=dcov, _stats=raw["gyro"], _ybar=raw["gyro"].means(st_idx, grp),
                                  _kern=kern)
                except IdentifiabilityError as exc:
                    if self.instruments is not None:  # asked for explicitly: the caller hears why not
                        raise
                    notes.append(f"gyros not calibrated: {exc}")
                    gyro_sensors = {}
                    break
                if self.held_out:
                    gf = self._gyro_step(session, windows, dirs, djac, acov, dcov, grp, sg[grp], gg.H[grp],
                                         raw["gyro"], raw["gyro"].means(st_idx, grp), kern, gf, notes, extra)
                rot_res.append(gf.rotation_residual)
                gfits.append(gf)
                if gf.weak:
                    extra.setdefault("weak_gyro", []).extend(gf.weak)
                    notes.append("gyro: weakly determined by these motions (relative sd > 2 %; s.w_a: the a component of sensor s's axis divided by its scale): " + "; ".join(gf.weak)
                                 + "; turn about every axis between poses")
                angles.append(gf.angle)
                for j, i in enumerate(grp):
                    ctx = SensorContext("gyro", i, gg, session.latitude, session.gravity, include_earth_rate=False)
                    beta = np.concatenate([gf.W[j], [gf.c[j]]])
                    res = {lab: np.array([gf.static_residual[k, j]]) for k, lab in enumerate(labels)}
                    fit = make_sensor_fit(model, ctx, beta, gf.rows_cov(j), float(sg[i]), self.sigma is not None,
                                          len(statics) + 2 * len(windows), 0.0, res)
                    # chi-square per degree of freedom of the weighted fit (rotation and static groups)
                    fit.rss = sum(gf.chi2.values()) / max(gf.dof, 1) * max(fit.n_obs - 4, 1) * fit.sigma**2
                    gyro_sensors[i] = fit
        if "gyro" in want and len(gyro_sensors) == session.geometries["gyro"].n:
            gg = session.geometries["gyro"]
            out["gyro"] = LsqResult("gyro", model, [gyro_sensors[i] for i in range(gg.n)], labels, {})
            rr = np.mean(rot_res, axis=0)
            extra["rotation_residual_deg"] = np.degrees(np.linalg.norm(rr, axis=1))
            extra["rotation_rms_deg"] = float(np.degrees(np.sqrt(np.mean(np.sum(rr**2, axis=1)))))
            extra["rotation_sigma_deg"] = float(np.degrees(_robust_rms(rr)))
            extra["motion_angle_deg"] = np.degrees(np.mean(angles, axis=0))
            extra["motion_labels"] = [f"{labels[a]}->{labels[b]}" for a, b in gf.pairs]
            notes.append("gyro bias from the static poses (Earth rate not modelled); scale and misalignment from "
                         f"{len(windows)} motions between consecutive poses (Tedaldi et al. 2014)")
        if clipped:
            notes.append(f"{len(clipped)} motions left out of the gyro fit: the gyros clip (saturate) in them: "
                         + ", ".join(clipped) + "; turn more slowly between poses")
            extra["clipped_motions"] = clipped
        fits = {"accel": afits, "gyro": gfits if "gyro" in out else []}
        if "gyro" in session.geometries and "gyro" not in out and not any(
                x.startswith("gyros not calibrated") for x in notes):
            notes.append("gyros not calibrated: " + ("no motion segments between consecutive poses" if not windows
                                                      else "not asked for"))
        res = CalibrationResult(self.method, out, session.raw_unit, notes, extra)
        res.fits = fits  # type: ignore[attr-defined]  # the fitted problems (AccelFit, GyroFit), for diagnosis
        return res


    def _gyro_step(self, session: Session, windows: list, dirs: np.ndarray, djac: np.ndarray, acov: np.ndarray,
                   dcov: np.ndarray, grp: list[int], sigma: np.ndarray, H: np.ndarray, stats: _RawStats,
                   ybar: np.ndarray, kern: Any, gf: GyroFit, notes: list[str], extra: dict[str, Any]) -> GyroFit:
        """The gyro misalignment step checked on held-out motions (:func:`held_out_gyro`): ``gf`` (the full fit)
        when it does not raise the held-out rotation misfit, else the fit with nominal axes; the note says why."""
        kw = {"_stats": stats, "_ybar": ybar, "_kern": kern}
        check = held_out_gyro(session, windows, dirs, grp, sigma, H, self.robust, dcov, fitted={"full": gf}, **kw)
        if check is None:
            notes.append("gyro: the misalignment step could not be checked on held-out motions (too few motions: "
                         "leaving some out leaves a model unidentifiable); applied")
            return gf
        k, M = check["folds"], len(windows)
        sc = StepCheck("gyro", "misalignment", "nominal axes, a scale and a bias per gyro", "angle",
                       tuple(check["in_sample"]), tuple(check["held_out"]), "motions",
                       "nominal axes (relative to the accelerometers), a scale and a bias per gyro",
                       residual="rotation misfit",
                       how="each left out in turn" if k == M else f"{k} groups of motions, each left out in turn")
        extra.setdefault("held_out_gyro", []).append(check)
        extra.setdefault("steps", []).append(sc.to_dict())
        notes.append(sc.note())
        if sc.applied:
            return gf
        return fit_gyro(session, windows, dirs, djac, acov, grp, sigma, H, robust=self.robust, dir_cov=dcov,
                        model="scale_bias", **kw)


def _dirs_with_jacobian(af: AccelFit, statics: list[Segment], session: Session, sa: np.ndarray):
    """Gravity direction of every pose from an accelerometer fit, with its Jacobian w.r.t. the fit's parameters."""
    grp = af.members
    ybar, sd = af.ybar, af.sd
    n = len(grp)
    fixed = np.zeros((n, 3))

    Wp, c = _unpack(af.theta, af.free, fixed, n)
    f, info, _ = _specific_forces(Wp, c, ybar, sd)
    df = _accel_problem(af.theta, af.free, fixed, ybar, sd, session.gravity, af.tau2)[2]  # (K, 3, p)
    nf = np.linalg.norm(f, axis=1)
    up = f / nf[:, None]
    Pu = (np.eye(3) - up[:, :, None] * up[:, None, :]) / nf[:, None, None]
    J = (af.P.T @ (Pu @ df)).reshape(-1, df.shape[2])  # d (P^T f / |f|) / d theta
    u = up @ af.P
    Cf = af.P.T @ np.linalg.inv(info) @ af.P * af.scale2 / (np.linalg.norm(f, axis=1) ** 2)[:, None, None]
    Pu = np.eye(3) - np.einsum("ki,kj->kij", u, u)
    return u, J, af.cov, Pu @ Cf @ Pu


def _fixed_part(af: AccelFit) -> np.ndarray:
    Wp = af.W @ af.P.T
    return np.where(af.free, 0.0, Wp)


def to_calibration(result: CalibrationResult) -> Calibration:
    """Shorthand for ``result.to_calibration()``."""
    return result.to_calibration()
