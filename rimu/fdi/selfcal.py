"""In-flight self-calibration: a Kalman filter on the parity keeps the observable part of the calibration true.

A calibration is true on the day it was made. In flight the biases drift with time and temperature and the scale
factors move a little; a fixed calibration turns that drift into parity. The part of every drift that breaks the
sensors' agreement is observable in the parity space from ordinary flight, without any reference; the part that
moves every sensor as one true input would (the range of the sensing matrix) is not, and only an external
reference gives it.

Model (per sensor i, on the compensated output ``z_i = SF_i y_i - B_i`` of Cho & Park 2005, Eq. 20)::

    z_i = a_i . u + d_i + v_i,
    d_i = b_i + k_i s_i + c1_i dT + c2_i dT^2 + c3_i dT^3,      s_i = a_i . u,   dT = T - T_ref

with ``b_i`` a random walk (intensity ``q_b``: from the noise model's bias instability and rate random walk, or
the user's), ``k_i`` the relative scale drift (a random walk of intensity ``q_k``; tracked where the motion
excites it), ``c1..c3`` constant temperature coefficients (tracked where a temperature channel exists). The state
``theta`` stacks the blocks ``bias, scale, tc1, tc2, tc3`` (each n values) and is estimated by a Kalman filter
whose measurement is the window mean of the normalised parity of the active sensors (de Oliveira et al. 2012,
Eq. 6-11: ``p = Vz z``, ``Vz A = 0``, ``Cov p = I`` per sample)::

    p_bar = Vz Phi_bar theta + e,   Cov e = I / M,   Phi_bar = [diag(1), diag(s_bar), diag(dT_bar) ...]

(M samples in the window; the regressors are window means, exact for a constant theta).

**What is not observable.** ``Vz A = 0``: any drift ``d = A w`` (a common mode: it looks like a true input
``w``) never reaches the parity. For the bias and temperature blocks this is ``theta_b in range(A)`` (three
directions per block); for the scale block it is ``diag(k) A = A N`` for some 3 x 3 N (one direction, the common
scale, for axes in general position; three for parallel triads). :func:`unobservable_basis` gives these
directions. The tracker never moves the common mode: the correction it exposes is
``c = Pi Phi theta`` with ``Pi = I - A (A^T W A)^-1 A^T W`` (W = diag(1 / sigma^2), the fusion's weights), so
``A^T W c = 0``: the fused estimate of the full set is exactly unchanged, and the parity of ``c`` is that of
``Phi theta`` (``Vz Pi = Vz``).

**Fault-aware.** The filter absorbs what the drift model allows and nothing faster: a window whose innovation
fails the chi-square gate (``gate_p``) is not absorbed; :class:`SelfCalLoop` applies a window only after
``hold_s`` more seconds without any alarm of the detector (so the lead-up to an alarm is never absorbed), not at all
while an alarm episode is open, and never to the states of isolated sensors (Schmidt's consider update: their
gain rows are zero, the Joseph form keeps the covariance exact). Re-admission sees outputs corrected with the
(frozen) tracked values of the isolated sensor.

**In the runtime.** :class:`rimu.fdi.Runtime` (``selfcal=``) holds one :class:`SelfCalLoop` per tracked
instrument, the one definition of the loop: every epoch's compensated outputs are corrected by
``correction / SF`` before the manager's step; :class:`TrackedGltWindow` whitens the detector's window sum with
``L = chol(I + M Vz Sigma_c Vz^T)^-1`` for a window of M samples (:func:`minimum_detectable_bias` gives what that
costs in detection); the windows are absorbed as above. :class:`SelfCalibratingRun` runs the same loop around a bare
manager.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special

from ..calibration.result import InstrumentCalibration
from ..errors import MissingInputError, MissingNoiseError, ShapeError
from ..geometry.base import null_space_rows
from ..noise.model import FLICKER_AVAR
from .glt import GltSnapshot, GltWindow, glt_threshold
from .health import SensorState

__all__ = ["BLOCKS", "GROUPS", "SelfCalLoop", "SelfCalSettings", "SelfCalState", "SelfCalTracker", "SelfCalUpdate", "SelfCalibratingRun",
           "SelfCalRunResult", "TrackedGltWindow", "bias_random_walk", "minimum_detectable_bias",
           "tracked_cusum_design", "unobservable_basis", "CUSUM_RHO_NODES", "CUSUM_RHO_STEP"]

#: the state's blocks, in order (each holds one value per sensor)
BLOCKS = ("bias", "scale", "tc1", "tc2", "tc3")
_BIAS_LIKE = ("bias", "tc1", "tc2", "tc3")
#: the groups of blocks the held-out check of :class:`SelfCalLoop` applies or suspends as one
GROUPS = (("bias", ("bias",)), ("scale", ("scale",)), ("temperature", ("tc1", "tc2", "tc3")))


def bias_random_walk(noise: Any, factor: float = 1.0, horizon_s: float = 3600.0) -> np.ndarray:
    """Random-walk intensity q (n,), SI^2/s, of a bias drifting ``factor`` times as fast as the noise model says.

    The random walk with the Allan variance of the model's slow terms at ``horizon_s`` (IEEE Std 952, Annex C:
    ``AVAR_rw(tau) = q tau / 3``; the flicker floor ``(2 ln 2 / pi) B^2``, the rate random walk ``K^2 tau / 3``)::

        q = factor^2 (3 (2 ln 2 / pi) B^2 / horizon + K^2)

    Parameters
    ----------
    noise : rimu.noise.InstrumentNoise
        With ``terms["bias_instability"]`` (B) and ``terms["rate_random_walk"]`` (K), SI.
    factor : float
        Drift rate relative to the model (3: biases drifting at three times their bias instability).
    horizon_s : float
        Time scale at which the random walk matches the flicker, s (the mission length).

    Examples
    --------
    >>> from rimu.noise import InstrumentNoise
    >>> from rimu.units import DH_TO_RS
    >>> m = InstrumentNoise.from_terms("gyro", ["x"], 100.0, bias_instability=10 * DH_TO_RS)
    >>> q = bias_random_walk(m, 3.0, 3600.0)
    >>> round(float(np.sqrt(q[0] * 3600.0) / DH_TO_RS), 2)      # 1-sigma wander after one hour, deg/h
    34.52
    """
    B = np.asarray(noise.terms["bias_instability"], dtype=float)
    K = np.asarray(noise.terms["rate_random_walk"], dtype=float)
    if not horizon_s > 0:
        raise ValueError(f"horizon_s must be positive, got {horizon_s}")
    return float(factor) ** 2 * (3.0 * FLICKER_AVAR * B * B / float(horizon_s) + K * K)


def _vec(v: Any, n: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()
    if np.any(~np.isfinite(a)) or np.any(a < 0):
        raise ShapeError(f"{name} must be finite and non-negative, got {a.tolist()}")
    return a


@dataclass
class SelfCalSettings:
    """Everything the tracker is told (SI units; per-sensor values broadcast from scalars).

    Attributes
    ----------
    bias_rw : float or ndarray (n,)
        Random-walk intensity of each bias, SI^2/s ((rad/s)^2/s for gyros); see :func:`bias_random_walk`.
    bias_sigma0 : float or ndarray (n,)
        1-sigma of the bias change at the start (0: the calibration is true when tracking starts), SI.
    scale_rw : float, ndarray (n,) or None
        Random-walk intensity of the relative scale, 1/s; None: the scale is not tracked.
    scale_sigma0 : float or ndarray (n,)
        1-sigma of the relative scale change at the start.
    temperature_sigma : sequence of float, or None
        Prior 1-sigma of the first-, second-, third-order temperature coefficients of the bias (SI/K, SI/K^2,
        SI/K^3; one value per order tracked, at most three; each a float or (n,)); None: no temperature terms.
    reference_temperature : float
        T_ref, degC (the calibration's; rimu's effects use 25 degC).
    window_s : float
        Length of the windows whose mean parity is one measurement, s.
    gate_p : float
        Probability of the innovation gate: a window whose innovation exceeds ``chi2_{1 - gate_p}(dof)`` is not
        absorbed.
    hold_s : float
        :class:`SelfCalLoop` (the runtime's) absorbs a window only after this many further seconds without an alarm.
    watch_p : float
        :class:`SelfCalLoop` treats a detector statistic above ``chi2_{1 - watch_p}(dof)`` like an alarm
        for the tracker (a fault building up below the alarm threshold is not absorbed).
    guard_s : float or None
        Memory (time constant, s) of :class:`SelfCalLoop`'s held-out check: each group of terms (biases, scales,
        temperature) corrects the outputs only while, on the windows of about the last ``guard_s`` and on all windows
        since the start, the terms fitted before each window lowered that window's parity (see :class:`SelfCalLoop`); None: no check,
        every tracked term is applied.
    guard_z : float
        How significant the held-out gain must be: a group is applied while its summed gain exceeds ``guard_z``
        times its standard deviation (2: about 2.3 % one-sided).
    """

    bias_rw: Any
    bias_sigma0: Any = 0.0
    scale_rw: Any = None
    scale_sigma0: Any = 0.0
    temperature_sigma: Sequence[Any] | None = None
    reference_temperature: float = 25.0
    window_s: float = 1.0
    gate_p: float = 1e-4
    hold_s: float = 10.0
    watch_p: float = 0.01
    guard_s: float | None = 60.0
    guard_z: float = 2.0

    def __post_init__(self) -> None:
        if not (self.window_s > 0 and 0 < self.gate_p < 1 and self.hold_s >= 0 and 0 < self.watch_p < 1):
            raise ValueError("window_s must be positive, gate_p and watch_p in (0, 1), hold_s >= 0")
        if self.guard_s is not None and not self.guard_s > 0:
            raise ValueError(f"guard_s must be positive (s) or None, got {self.guard_s}")
        if self.temperature_sigma is not None and not 1 <= len(self.temperature_sigma) <= 3:
            raise ValueError("temperature_sigma holds one prior sigma per order, orders 1 to 3")

    @property
    def blocks(self) -> tuple[str, ...]:
        """The blocks of the state these settings track, in :data:`BLOCKS` order."""
        tc = () if self.temperature_sigma is None else BLOCKS[2:2 + len(self.temperature_sigma)]
        return ("bias",) + (("scale",) if self.scale_rw is not None else ()) + tc


@dataclass(frozen=True)
class SelfCalState:
    """The tracker's estimate: plain data, replaced (never mutated) by every step.

    ``theta`` (m n,) the block-major state (``theta[b * n + i]``: block b of sensor i, SI; the scale block
    relative), ``P`` its covariance, ``t`` the time it refers to (s), ``updates``/``rejected`` counts of absorbed
    and gated windows.
    """

    theta: np.ndarray
    P: np.ndarray
    t: float
    updates: int = 0
    rejected: int = 0


@dataclass(frozen=True)
class SelfCalUpdate:
    """What one window did: ``accepted``, the normalised innovation ``d2`` (chi-square, ``dof``) and its gate."""

    accepted: bool
    d2: float
    gate: float
    dof: int


def unobservable_basis(axes: np.ndarray, blocks: Sequence[str]) -> np.ndarray:
    """Orthonormal basis (m n, k) of the state directions the parity never sees, whatever the motion.

    Bias and temperature blocks: ``theta_b in range(A)``; scale block: ``diag(k) A = A N`` for some 3 x 3 N
    (the null space of that linear map in (k, N)).

    >>> from rimu.geometry import cone6
    >>> unobservable_basis(cone6().H, ["bias", "scale"]).shape     # 3 common-mode biases, 1 common scale
    (12, 4)
    >>> from rimu.geometry import triads
    >>> unobservable_basis(triads(2).H, ["scale"]).shape            # parallel triads: a common scale per axis
    (6, 3)
    """
    A = np.asarray(axes, dtype=float)
    n = A.shape[0]
    Q, _ = np.linalg.qr(A)
    cols = []
    for b, name in enumerate(blocks):
        if name == "scale":
            # unknowns (k (n), N (9, row-major)); equations diag(k) A - A N = 0, (n, 3)
            Mmap = np.zeros((3 * n, n + 9))
            for i in range(n):
                for c in range(3):
                    Mmap[3 * i + c, i] = A[i, c]
                    Mmap[3 * i + c, n + 3 * np.arange(3) + c] = -A[i]
            _, s, Vt = np.linalg.svd(Mmap)
            rank = int(np.sum(s > 1e-9 * s[0]))
            K = Vt[rank:, :n].T
            if K.size:
                U, sv, _ = np.linalg.svd(K, full_matrices=False)
                U = U[:, sv > 1e-9]
                blk = np.zeros((len(blocks) * n, U.shape[1]))
                blk[b * n:(b + 1) * n] = U
                cols.append(blk)
        else:
            blk = np.zeros((len(blocks) * n, 3))
            blk[b * n:(b + 1) * n] = Q
            cols.append(blk)
    return np.concatenate(cols, axis=1) if cols else np.zeros((len(blocks) * n, 0))


class SelfCalTracker:
    """The Kalman filter on the parity of the compensated outputs (see the module docstring).

    The tracker holds only its settings and constants of the geometry; the estimate is a :class:`SelfCalState`
    that every step takes and returns (the runtime owns it).

    Parameters
    ----------
    calibration : InstrumentCalibration
        The fixed calibration (axes, scale, bias, noise).
    settings : SelfCalSettings
    sigma : float or ndarray (n,), optional
        Per-sample white noise of the compensated outputs, SI; default the calibration's ``noise_sigma``, else
        its noise model's per-sample sigma.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-6, bias_sigma0=0.01))
    >>> st = trk.initial_state()
    >>> rng = np.random.default_rng(0)
    >>> drift = np.array([0.02, 0, 0, 0, 0, 0])                      # sensor x1 drifted by 2 sigma
    >>> for k in range(20):
    ...     z = drift + 0.01 * rng.standard_normal((100, 6))
    ...     st, info = trk.update(trk.predict(st, k + 1.0), z, trk.regressors(100))
    >>> c = trk.correction(st, trk.regressors(1))[0]
    >>> bool(abs(c[0] - (drift - trk.common_mode(drift))[0]) < 3e-3), float(np.abs(cal.axes_mb().T @ c).max()) < 1e-15
    (True, True)
    """

    def __init__(self, calibration: InstrumentCalibration, settings: SelfCalSettings,
                 sigma: float | np.ndarray | None = None) -> None:
        self.calibration = calibration
        self.settings = settings
        A = calibration.axes_mb()
        n = A.shape[0]
        if sigma is None:
            if calibration.noise_sigma is not None:
                sigma = calibration.noise_sigma
            elif calibration.noise is not None:
                sigma = calibration.noise.sample_sigma()
            else:
                raise MissingNoiseError("the tracker needs the sensors' noise: give sigma= or a calibration with "
                                        "noise_sigma or a noise model")
        self.sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
        self.n = n
        self.axes = A
        self.blocks = settings.blocks
        self.m = len(self.blocks)
        w2 = 1.0 / self.sigma ** 2
        G = np.linalg.solve(A.T @ (A * w2[:, None]), (A * w2[:, None]).T)  # (3, n) weighted LS
        #: the fusion's weighted least-squares solution for the full set, (3, n)
        self.G = G
        #: ``I - A G``: removes the common mode (``A^T W Pi = 0``)
        self.Pi = np.eye(n) - A @ G
        q, p0 = [], []
        for b in self.blocks:
            if b == "bias":
                q.append(_vec(settings.bias_rw, n, "bias_rw"))
                p0.append(_vec(settings.bias_sigma0, n, "bias_sigma0") ** 2)
            elif b == "scale":
                q.append(_vec(settings.scale_rw, n, "scale_rw"))
                p0.append(_vec(settings.scale_sigma0, n, "scale_sigma0") ** 2)
            else:
                q.append(np.zeros(n))
                order = int(b[2])
                p0.append(_vec(settings.temperature_sigma[order - 1], n, f"temperature_sigma[{order - 1}]") ** 2)
        self.q = np.concatenate(q)
        self.p0 = np.concatenate(p0)
        self._Vz: dict[bytes, np.ndarray] = {}
        self._gates: dict[int, float] = {}

    # ------------------------------------------------------------------ helpers
    def block(self, name: str) -> slice:
        """The slice of block ``name`` in ``theta``."""
        b = self.blocks.index(name)
        return slice(b * self.n, (b + 1) * self.n)

    def common_mode(self, d: np.ndarray) -> np.ndarray:
        """The part ``A G d`` of a sensor-space vector (..., n) that looks like a true input (not observable)."""
        return np.asarray(d, dtype=float) @ (self.axes @ self.G).T

    def parity_rows(self, active: np.ndarray | None = None) -> np.ndarray:
        """``Vz`` (dof, n) of the active sensors: normalised parity rows, zero columns for the others."""
        act = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        key = act.tobytes()
        if key not in self._Vz:
            idx = np.flatnonzero(act)
            w = 1.0 / self.sigma
            Vz = np.zeros((0, self.n))
            if len(idx) > 3:
                Aw = self.axes[idx] * w[idx, None]
                if np.linalg.matrix_rank(Aw, tol=1e-9) >= 3:
                    Vw = null_space_rows(Aw)
                    Vz = np.zeros((Vw.shape[0], self.n))
                    Vz[:, idx] = Vw * w[idx][None, :]
            self._Vz[key] = Vz
        return self._Vz[key]

    def regressors(self, N: int, u: np.ndarray | None = None, temperature: np.ndarray | None = None) -> np.ndarray:
        """The regressors (N, m, n) of N samples: 1, ``s_i = a_i . u``, ``dT^k``.

        ``u`` (N, 3): the input in MB (SI; needed when the scale is tracked), ``temperature`` (N,) degC (needed
        for the temperature terms).
        """
        g = np.empty((N, self.m, self.n))
        for b, name in enumerate(self.blocks):
            if name == "bias":
                g[:, b] = 1.0
            elif name == "scale":
                if u is None:
                    raise MissingInputError("the scale is tracked: give the input u (N, 3) for the regressors")
                g[:, b] = np.asarray(u, dtype=float).reshape(N, 3) @ self.axes.T
            else:
                if temperature is None:
                    raise MissingInputError("temperature terms are tracked: give the temperature (degC) of the samples")
                dT = np.asarray(temperature, dtype=float).reshape(N) - self.settings.reference_temperature
                g[:, b] = (dT ** int(name[2]))[:, None]
        return g

    # ------------------------------------------------------------------ the filter
    def initial_state(self, t: float = 0.0) -> SelfCalState:
        """Zero drift (the calibration as given) with the prior covariance, at time ``t`` (s)."""
        return SelfCalState(np.zeros(self.m * self.n), np.diag(self.p0), float(t))

    def predict(self, state: SelfCalState, t: float) -> SelfCalState:
        """The state at time ``t`` (s): the random walks' variance grows by ``q (t - state.t)``."""
        dt = float(t) - state.t
        if dt < 0:
            raise ValueError(f"cannot predict backwards: state at {state.t} s, asked for {t} s")
        P = state.P.copy()
        P[np.diag_indices_from(P)] += self.q * dt
        return SelfCalState(state.theta, P, float(t), state.updates, state.rejected)

    def update(self, state: SelfCalState, z: np.ndarray, g: np.ndarray, active: np.ndarray | None = None,
               frozen: np.ndarray | None = None) -> tuple[SelfCalState, SelfCalUpdate]:
        """Absorb one window: ``z`` (M, n) compensated outputs (``SF y - B``, without the tracked correction),
        ``g`` (M, m, n) their regressors; sensors not ``active`` are left out of the parity, the states of
        ``frozen`` (and inactive) sensors are not moved (consider states). A window whose innovation fails the
        gate is not absorbed.
        """
        z = np.asarray(z, dtype=float)
        M = z.shape[0]
        act = np.ones(self.n, bool) if active is None else np.asarray(active, bool)
        Vz = self.parity_rows(act)
        r = Vz.shape[0]
        if M < 1 or r < 1:
            return state, SelfCalUpdate(False, 0.0, float("inf"), r)
        zbar = z.mean(axis=0)
        gbar = g.mean(axis=0)                           # (m, n)
        H = np.concatenate([Vz * gbar[b][None, :] for b in range(self.m)], axis=1)   # (r, m n)
        nu = Vz @ zbar - H @ state.theta
        PHt = state.P @ H.T
        S = H @ PHt + np.eye(r) / M
        Sinv_nu = np.linalg.solve(S, nu)
        d2 = float(nu @ Sinv_nu)
        gate = self._gates.get(r)
        if gate is None:
            gate = self._gates[r] = float(special.chdtri(r, self.settings.gate_p))  # chi2.isf
        if not d2 <= gate:
            return (SelfCalState(state.theta, state.P, state.t, state.updates, state.rejected + 1),
                    SelfCalUpdate(False, d2, gate, r))
        K = np.linalg.solve(S, PHt.T).T                # (m n, r)
        keep = act.copy()
        if frozen is not None:
            keep &= ~np.asarray(frozen, bool)
        if keep.all():
            theta = state.theta + K @ nu
            P = state.P - K @ PHt.T                    # the optimal gain: P - K S K^T
        else:
            K[~np.tile(keep, self.m)] = 0.0            # Schmidt: frozen sensors' states are not moved
            theta = state.theta + K @ nu
            J = np.eye(self.m * self.n) - K @ H
            P = J @ state.P @ J.T + (K @ K.T) / M      # Joseph form: exact for any gain
        P = 0.5 * (P + P.T)
        return SelfCalState(theta, P, state.t, state.updates + 1, state.rejected), SelfCalUpdate(True, d2, gate, r)

    # ------------------------------------------------------------------ what the runtime uses
    def correction(self, state: SelfCalState, g: np.ndarray) -> np.ndarray:
        """The correction (N, n), SI, to subtract from the compensated outputs: ``Pi Phi theta`` per sample
        (``A^T W c = 0``: the common mode is not touched)."""
        th = state.theta.reshape(self.m, self.n)
        d = np.einsum("kbn,bn->kn", g, th)
        return d @ self.Pi.T

    def correction_covariance(self, state: SelfCalState, g: np.ndarray, applied: np.ndarray | None = None
                              ) -> np.ndarray:
        """Covariance (n, n), SI^2, of the correction's error for regressors ``g`` (m, n) (e.g. rms values).

        ``applied`` (m,) bool: the blocks the correction applies (default all). A block left out (the held-out check
        of :class:`SelfCalLoop` suspends its group) leaves its whole term in the outputs, ``theta_b`` rather than
        ``theta_b - theta_hat_b``: the error's second moment is then ``P + o o^T`` with ``o`` the estimate on the
        blocks left out (zero elsewhere): what the data say of the drift the outputs still carry (its mean, the
        estimate, and its uncertainty, P; the cross terms stay P's, the estimate's error having zero mean)::

            Sigma_c = Pi Phi (P + o o^T) Phi^T Pi^T
        """
        Phi = np.concatenate([np.diag(g[b]) for b in range(self.m)], axis=1)
        C = self.Pi @ Phi
        out = C @ state.P @ C.T
        if applied is not None and not np.all(applied):
            o = self.unapplied_correction(state, g, applied)
            out = out + np.outer(o, o)
        return out

    def unapplied_correction(self, state: SelfCalState, g: np.ndarray, applied: np.ndarray) -> np.ndarray:
        """``o`` (n,), SI: the correction the blocks not ``applied`` (m,) would make for regressors ``g`` (m, n)
        (``Pi Phi`` of the estimate on those blocks): the drift the outputs still carry, as the tracker sees it."""
        off = ~np.asarray(applied, bool)
        th = state.theta.reshape(self.m, self.n)
        return self.Pi @ np.einsum("bn,bn->n", np.asarray(g, dtype=float)[off], th[off])

    def parity_covariance(self, state: SelfCalState, g: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """The tracked terms' uncertainty in the normalised parity, ``Vz Sigma_c Vz^T`` (dof, dof), per sample
        of a persistent error: the covariance a detector adds to its own."""
        Vz = self.parity_rows(active)
        return Vz @ self.correction_covariance(state, g) @ Vz.T

    def terms(self, state: SelfCalState) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The tracked terms and their 1-sigma per block, SI: ``{block: (value (n,), sigma (n,))}``.

        Bias and temperature blocks without their common mode (``Pi theta_b``: what the parity can tell), the
        scale block as estimated (its common part, unobservable, stays at the prior).
        """
        out = {}
        for b, name in enumerate(self.blocks):
            s = slice(b * self.n, (b + 1) * self.n)
            th, Pb = state.theta[s], state.P[s, s]
            if name in _BIAS_LIKE:
                th, Pb = self.Pi @ th, self.Pi @ Pb @ self.Pi.T
            out[name] = (th.copy(), np.sqrt(np.clip(np.diag(Pb), 0.0, None)))
        return out

    def calibration_at(self, state: SelfCalState, temperature: float | None = None) -> InstrumentCalibration:
        """The calibration with the tracked terms folded in, and their covariance.

        Scale and bias: ``SF' = SF / (1 + k)``, ``B' = (B + b) / (1 + k)`` (so that ``SF' y - B'`` removes the
        tracked bias and relative scale); temperature coefficients are added to the ``bias_temperature`` (order
        1), ``bias_temperature2`` (order 2) and ``bias_temperature3`` (order 3) effects. The covariance names ``x1.bias``, ``x1.scale`` (SI per raw
        unit), ``x1.bias_tc1``... over the tracked blocks (the calibration's previous covariance is replaced).
        """
        cal = self.calibration
        names = list(cal.geometry.names)
        terms = self.terms(state)
        b = terms["bias"][0]
        k = terms["scale"][0] if "scale" in terms else np.zeros(self.n)
        scale = cal.scale / (1.0 + k)
        bias = (cal.bias + b) / (1.0 + k)
        effects = {e: dict(v) for e, v in cal.effects.items()}
        for name, eff in (("tc1", "bias_temperature"), ("tc2", "bias_temperature2"), ("tc3", "bias_temperature3")):
            if name in terms:
                d = effects.setdefault(eff, {})
                for i, nm in enumerate(names):
                    key = f"{nm}.bias_{name}"
                    d[key] = float(d.get(key, 0.0) + terms[name][0][i])
        # covariance: bias-like blocks without their common mode; the scale in SI per raw unit
        J = np.zeros((self.m * self.n, self.m * self.n))
        pnames = []
        for bi, name in enumerate(self.blocks):
            s = slice(bi * self.n, (bi + 1) * self.n)
            J[s, s] = self.Pi if name in _BIAS_LIKE else np.diag(-cal.scale)
            suffix = {"bias": "bias", "scale": "scale"}.get(name, f"bias_{name}")
            pnames += [f"{nm}.{suffix}" for nm in names]
        cov = J @ state.P @ J.T
        # the calibration's other parameters keep their covariance; the tracked ones get the tracker's (no
        # correlation between the two is known)
        keep = [i for i, nm in enumerate(cal.param_names) if nm not in set(pnames)]
        if keep and cal.covariance is not None:
            old = cal.covariance[np.ix_(keep, keep)]
            full = np.zeros((len(keep) + len(pnames),) * 2)
            full[:len(keep), :len(keep)] = old
            full[len(keep):, len(keep):] = cov
            cov, pnames = full, [cal.param_names[i] for i in keep] + pnames
        return InstrumentCalibration(cal.instrument, cal.geometry, scale, cal.misalignment.copy(), bias,
                                     None if cal.noise_sigma is None else cal.noise_sigma.copy(), cov, pnames,
                                     effects, None if cal.range_raw is None else cal.range_raw.copy(), cal.noise)


#: the CUSUM part of :class:`TrackedGltWindow` tabulates its thresholds over ``rho = sigma_mu / k`` at these steps and
#: uses the next node up (conservative); beyond the last node the sensor's CUSUM is off (its window GLT remains)
CUSUM_RHO_STEP = 1.0 / 32.0
CUSUM_RHO_NODES = 29


def _siegmund_arl(drift: np.ndarray, h: float) -> np.ndarray:
    """Siegmund's ARL (rimu.fdi.cusum.siegmund_arl) for an array of drifts ``mu - k`` (units of X)."""
    b = h + 1.166
    d = np.where(np.abs(drift) < 1e-9, 1.0, drift)
    with np.errstate(over="ignore"):
        arl = (np.exp(-2.0 * d * b) + 2.0 * d * b - 1.0) / (2.0 * d * d)
    return np.where(np.abs(drift) < 1e-9, b * b, arl)


def tracked_cusum_design(dof: int, window: int, p_fa: float, p_d: float = 0.5) -> tuple[float, np.ndarray]:
    """The CUSUM of :class:`TrackedGltWindow` for ``dof`` parity dimensions: its design shift ``delta`` (units of
    the unit-variance statistic ``X_j = u_j . p``) and its thresholds ``h`` (:data:`CUSUM_RHO_NODES`,) over
    ``rho = sigma_mu / k`` (``k = delta / 2``, ``rho = i *`` :data:`CUSUM_RHO_STEP`).

    ``delta``: the shift of the window GLT's minimum detectable bias (probability ``p_d`` at its own threshold,
    ``chi2_(1 - p_fa/2)(dof)`` over ``window`` samples): ``window delta^2 = lambda`` with
    ``P(ncx2(dof, lambda) > thr) = p_d``, the smallest fault the window test is there for. The bank holds
    ``2 (dof + 3)`` one-sided statistics (both signs of each sensor) and gets half of the false-alarm budget, a rate
    of ``p_fa / 2`` per sample: each statistic is designed for an in-control ARL of ``2 (dof + 3) * 2 / p_fa``
    samples, averaged over a slowly varying mean ``mu ~ N(0, sigma_mu^2)`` (the tracked terms' error along u_j:
    :func:`rimu.fdi.cusum.cusum_threshold_mixture`, Siegmund 1985 Eq. 2.57, Gauss-Hermite over mu).

    >>> delta, h = tracked_cusum_design(3, 20, 1e-6)
    >>> round(delta, 3), bool(np.all(np.diff(h) > 0))        # thresholds grow with the tracker's uncertainty
    (1.226, True)
    """
    thr = float(special.chdtri(dof, p_fa / 2.0))
    lam = float(special.chndtrinc(thr, dof, 1.0 - p_d))
    delta = math.sqrt(lam / float(window))
    k = delta / 2.0
    arl = 2.0 * (dof + 3) * 2.0 / p_fa
    x, w = np.polynomial.hermite_e.hermegauss(40)
    w = w / w.sum()
    h = np.empty(CUSUM_RHO_NODES)
    for i in range(CUSUM_RHO_NODES):
        mu = (i * CUSUM_RHO_STEP * k) * x

        def excess(hh: float, mu: np.ndarray = mu) -> float:
            with np.errstate(divide="ignore"):
                return float(np.log(np.sum(w / _siegmund_arl(mu - k, hh)) * arl))

        lo, hi = 0.0, 1.0
        while excess(hi) > 0.0:
            lo, hi = hi, 2.0 * hi
        for _ in range(60):       # bisection: the rate falls monotonically with h
            mid = 0.5 * (lo + hi)
            if excess(mid) > 0.0:
                lo = mid
            else:
                hi = mid
        h[i] = hi
    return delta, h


class TrackedGltWindow(GltWindow):
    """The window GLT with the tracker's uncertainty in its covariance (Daly, Gai & Harrison 1979, whitened), and a
    CUSUM bank beside it that carries the same uncertainty (Page 1954; Siegmund 1985 Eq. 2.57).

    **The window GLT.** The window sum S of M parity samples under no fault has covariance
    ``M (I + M Vz Sigma_c Vz^T)`` when the compensation carries a persistent error of covariance Sigma_c (the
    tracked terms' uncertainty), so the statistic ``|L S|^2 / M`` with ``L = chol(I + M Vz Sigma_c Vz^T)^-1`` is
    chi-square with dof degrees of freedom again; isolation uses the whitened columns. That costs detection: the
    minimum detectable bias grows by the factor :func:`minimum_detectable_bias` gives (1.08-1.11 after 2 h of the
    simulated flight of docs/selfcal.md), and a step is found later than by a fresh unit.

    **The CUSUM** (``cusum=True``; ``rimu replay --selfcal --selfcal-cusum``). The tracker's error is persistent: per sample it moves the
    unit-variance statistic ``X_j = u_j . p`` of sensor j (``u_j = v_j / |v_j|``) by a slowly varying mean
    ``mu_j ~ N(0, sigma_mu,j^2)``, ``sigma_mu,j^2 = u_j^T Vz Sigma_c Vz^T u_j``. Two one-sided CUSUMs per active
    sensor, ``S = max(0, S +- X_j - k)``, ``k = delta / 2`` with ``delta`` the shift of the window GLT's
    minimum detectable bias (:func:`tracked_cusum_design`), alarm when ``S > h(sigma_mu,j / k)``: the threshold
    whose false-alarm rate averaged over that mean is the bank's share (:func:`rimu.fdi.cusum.cusum_threshold_mixture`,
    tabulated over ``sigma_mu / k``, the next node up). The false-alarm budget is split: the window GLT at
    ``p_fa / 2`` per sample, the bank at a rate of ``p_fa / 2`` (``2 (dof + 3)`` statistics, each designed for
    ``2 (dof + 3)`` times the bank's ARL). A sensor whose ``sigma_mu / k`` passes the table has no CUSUM (the window
    GLT still watches it). The CUSUM accumulates the evidence of a step from its onset, where the window GLT
    needs its window to fill (Lorden 1971: the CUSUM's delay is the least for a given false-alarm rate), so it finds a
    step of the GLT's design size sooner even though it carries the tracker's covariance. It is not the default: it
    is as sensitive to any slow disagreement the drift model does not hold (an unmodelled g-sensitivity, the real
    recordings' vibration) as to a fault, and isolates there where the window GLT alone does not
    (``tests/fdi/test_selfcal_guard.py``, ``tests/fdi/test_selfcal_real.py``: docs/selfcal.md).

    :meth:`update` returns the larger of the GLT's statistic and the bank's ratio ``max S / h``, both on the
    scale of the ``chi2_(1 - p_fa)(dof)`` threshold it returns (the GLT's scaled by ``thr(p_fa) / thr(p_fa / 2)``,
    the bank's ratio times ``thr(p_fa)``): an alarm is either part's, the manager's threshold and watch levels are
    unchanged. The bank restarts with the window (:meth:`configure`: a new active set). Isolation is the manager's
    (the set GLT on the episode's evidence) or, with ``isolator="detector"``, the whitened window GLT's.

    :meth:`set_tracker_covariance` is called by whoever owns the tracker (SI^2, sensor space, (n, n)); until then
    this is the plain window GLT (with the bank: at ``p_fa / 2``, and a white-noise CUSUM).

    >>> from rimu.geometry import cone6
    >>> det = TrackedGltWindow(window=10, cusum=False)
    >>> det.configure(cone6().parity_matrix() / 0.01, 3)
    >>> det.set_tracker_covariance(np.eye(6) * 0.001 ** 2)        # 0.1 sigma per sensor, persistent
    >>> L = det.whitening(cone6().parity_matrix() / 0.01, 3)
    >>> np.round(np.linalg.inv(L @ L.T), 6).tolist()[0]               # I + 10 * 0.01 I (orthonormal rows)
    [1.1, 0.0, 0.0]
    >>> v = cone6().parity_matrix()[:, 2]
    >>> for cusum in (False, True):                  # a 1.5-sigma step on z1 (no noise), 0.05 sigma tracker error
    ...     det = TrackedGltWindow(window=20, p_fa=1e-6, cusum=cusum)
    ...     det.configure(cone6().parity_matrix(), 3)
    ...     det.set_tracker_covariance(np.eye(6) * 0.05 ** 2)
    ...     alarms = [det.update(1.5 * v) for _ in range(40)]
    ...     print(next((k + 1 for k, (s, thr) in enumerate(alarms) if s > thr), None))
    None
    30
    """

    name = "glt_window_tracked"

    def __init__(self, window: int = 5, p_fa: float = 1e-3, cusum: bool = False) -> None:
        super().__init__(window, p_fa / 2.0 if cusum else p_fa, None)
        #: the false-alarm probability per sample of the whole detector (the window GLT's and the bank's shares)
        self.p_fa_total = float(p_fa)
        self.cusum = bool(cusum)
        self._sigma_c: np.ndarray | None = None
        self._Vraw = np.zeros((0, 0))
        self._thr_full: dict[int, float] = {}
        self._scale = 1.0
        self._U = np.zeros((0, 0))
        self._ck = 0.0
        self._h = np.zeros(0)
        self._inv_h = np.zeros(0)
        self._Sp = np.zeros(0)
        self._Sm = np.zeros(0)
        self._node = np.zeros(0, int)
        #: the last :meth:`update`'s two parts on the returned threshold's scale: (window GLT, CUSUM bank)
        self.last_parts = (0.0, 0.0)

    def whitening(self, Vz: np.ndarray, dof: int) -> np.ndarray | None:
        if self._sigma_c is None or dof < 1:
            return None
        V = np.asarray(Vz, dtype=float)[:dof]
        C = np.eye(dof) + self.window * (V @ self._sigma_c @ V.T)
        return np.linalg.inv(np.linalg.cholesky(0.5 * (C + C.T)))

    def threshold(self, dof: int) -> float:
        """``chi2_(1 - p_fa)(dof)`` of the whole detector (the statistic :meth:`update` returns is on its scale)."""
        if not self.cusum:
            return super().threshold(dof)
        v = self._thr_full.get(dof)
        if v is None:
            v = self._thr_full[dof] = glt_threshold(self.p_fa_total, dof)
        return v

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        self._Vraw = np.asarray(Vz, dtype=float)[:dof].copy()
        super().configure(Vz, dof)
        if not self.cusum:
            return
        d = max(int(dof), 0)
        self._t = self.threshold(d) if d >= 1 else float("inf")
        self._scale = self._t / GltSnapshot.threshold(self, d) if d >= 1 else 1.0
        n = self._Vraw.shape[1] if self._Vraw.ndim == 2 else 0
        self._Sp = np.zeros(n)
        self._Sm = np.zeros(n)
        self._node = np.full(n, CUSUM_RHO_NODES)
        self._U = np.zeros((d, n))
        self._inv_h = np.zeros(n)
        if d < 1 or n == 0:
            return
        nv = np.sqrt(np.einsum("ij,ij->j", self._Vraw, self._Vraw))
        act = nv > 1e-12
        self._U[:, act] = self._Vraw[:, act] / nv[act]
        delta, self._h = _cusum_design(d, self.window, self.p_fa_total)
        self._ck = 0.5 * delta
        self._cusum_thresholds()

    def _cusum_thresholds(self) -> None:
        """Each active sensor's CUSUM threshold for the current tracker covariance (its inverse; 0: off)."""
        U = self._U
        n = U.shape[1]
        on = np.einsum("ij,ij->j", U, U) > 0.5
        if self._sigma_c is None:
            rho = np.zeros(n)
        else:
            W = self._Vraw.T @ U                                  # (n, n): column j = Vz^T u_j
            var = np.einsum("ij,ij->j", W, self._sigma_c @ W)
            rho = np.sqrt(np.clip(var, 0.0, None)) / self._ck
        node = np.where(on, np.ceil(rho / CUSUM_RHO_STEP - 1e-9), CUSUM_RHO_NODES).astype(int)
        ok = node < CUSUM_RHO_NODES
        inv = np.zeros(n)
        inv[ok] = 1.0 / self._h[node[ok]]
        # a statistic restarts when its threshold falls (its sum was gathered under a larger uncertainty) and is held
        # at zero while it is off
        restart = ~ok | (node < self._node)
        self._Sp[restart] = 0.0
        self._Sm[restart] = 0.0
        self._node = node
        self._inv_h = inv

    def set_tracker_covariance(self, sigma_c: np.ndarray | None) -> None:
        """Use ``sigma_c`` (n, n), SI^2, from now on (None: none); the window's sums and the CUSUMs are kept."""
        self._sigma_c = None if sigma_c is None else np.asarray(sigma_c, dtype=float)
        self._L = self.whitening(self._Vraw, self._dof)
        self._V = self._Vraw if self._L is None else self._L @ self._Vraw
        if self.cusum and self._dof >= 1 and self._U.size:
            self._cusum_thresholds()

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        stat, thr = super().update(parity)
        if not self.cusum or self._dof < 1:
            return stat, thr
        X = np.asarray(parity, dtype=float)[:self._dof] @ self._U
        np.maximum(self._Sp + X - self._ck, 0.0, out=self._Sp)
        np.maximum(self._Sm - X - self._ck, 0.0, out=self._Sm)
        off = self._inv_h == 0.0
        self._Sp[off] = 0.0
        self._Sm[off] = 0.0
        ratio = float(np.max(np.maximum(self._Sp, self._Sm) * self._inv_h))
        self.last_parts = (stat * self._scale, ratio * thr)
        return max(self.last_parts), thr

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        """The statistics of N samples of one set, one after the other (:meth:`configure`, then :meth:`update`):
        (statistic (N,), threshold, isolated (N,) by the whitened window sum)."""
        self.configure(Vz, dof)
        stat = np.zeros(len(P))
        iso = np.full(len(P), -1)
        thr = float("inf")
        for i, p in enumerate(np.asarray(P, dtype=float)):
            stat[i], thr = self.update(p)
            iso[i] = self.isolate(p)[0]
        return stat, thr, iso


_DESIGNS: dict[tuple[int, int, float], tuple[float, np.ndarray]] = {}


def _cusum_design(dof: int, window: int, p_fa: float) -> tuple[float, np.ndarray]:
    key = (int(dof), int(window), float(p_fa))
    if key not in _DESIGNS:
        _DESIGNS[key] = tracked_cusum_design(*key)
    return _DESIGNS[key]


def minimum_detectable_bias(Vz: np.ndarray, window: int = 1, sigma_c: np.ndarray | None = None,
                            p_fa: float = 1e-3, p_d: float = 0.5) -> np.ndarray:
    """Smallest bias (n,), SI, on each sensor that the window GLT detects with probability ``p_d``.

    A bias b on sensor j gives the window statistic the noncentrality ``lambda = M b^2 v_j^T C^-1 v_j``
    (``C = I + M Vz Sigma_c Vz^T``, v_j the column of ``Vz``); b is where ``P(chi2(dof, lambda) > thr) = p_d``.

    >>> from rimu.geometry import cone6
    >>> mdb = minimum_detectable_bias(cone6().parity_matrix() / 0.01, window=1)
    >>> round(float(mdb[0]), 4)          # in sigma = 0.01: sqrt(lambda_50% / |v_j|^2), |v_j|^2 = 1/2
    0.0534
    """
    V = np.asarray(Vz, dtype=float)
    dof = V.shape[0]
    thr = glt_threshold(p_fa, dof)
    from scipy import optimize, stats  # analysis only: not imported with the runtime (~60 MB)

    lam = optimize.brentq(lambda x: stats.ncx2.sf(thr, dof, x) - p_d, 1e-9, 1e4)
    C = np.eye(dof) if sigma_c is None else np.eye(dof) + window * (V @ sigma_c @ V.T)
    info = np.einsum("ij,ij->j", V, np.linalg.solve(C, V))
    with np.errstate(divide="ignore"):
        return np.sqrt(lam / (window * info))


@dataclass
class SelfCalRunResult:
    """What :meth:`SelfCalibratingRun.run` returns.

    ``replay``: the manager's outputs over the whole run (:class:`rimu.fdi.ReplayResult`); ``t`` (W,) the end of
    each window, s; ``values``/``sigmas`` (W, m, n) the tracked terms of :meth:`SelfCalTracker.terms` after
    each window (SI); ``accepted``/``rejected``/``discarded`` windows absorbed, gated out, thrown away because of
    an alarm; ``correction`` (N, n) the correction applied to each sample, SI; ``theta`` (W, m n) the state itself
    after each window (per sensor, common mode included: what is frozen for an isolated sensor).
    """

    replay: Any
    t: np.ndarray
    values: np.ndarray
    sigmas: np.ndarray
    accepted: int
    rejected: int
    discarded: int
    correction: np.ndarray
    blocks: tuple[str, ...] = field(default_factory=tuple)
    theta: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def isolations(self) -> int:
        """Isolation events (by the detector or by invalid data) over the run."""
        return sum(1 for e in self.replay.events if e.kind in ("isolated", "invalid_isolated"))


class SelfCalLoop:
    """The tracker in the runtime's loop for one instrument: the one definition of what the runtime does with it.

    :class:`rimu.fdi.Runtime` holds one per tracked instrument (``Runtime(..., selfcal={"gyro": loop})``) and calls,
    for every epoch, :meth:`correct` on the instrument's compensated raw outputs before its manager's step and
    :meth:`observe` after it; :class:`SelfCalibratingRun` does the same around a bare manager. The loop owns the
    tracker's state (:attr:`state`, a :class:`SelfCalState`), the windows waiting to be absorbed and the counts.

    Per window of ``M = round(window_s * sample_rate)`` samples:

    * **compensation with the tracked values**: every sample's outputs are corrected by ``c / SF``
      (:meth:`SelfCalTracker.correction`, regressors from the uncorrected fused estimate and the temperature), so
      the detector, the estimate and the re-admission test see the tracked terms taken out;
    * **thresholds with the tracker's covariance**: at the window's first sample the detector (when a
      :class:`TrackedGltWindow`) gets the largest correction covariance of the windows its sum spans (the state
      predicted to the window's end, the previous window's rms regressors);
    * **fault-aware absorption**: a window in which the manager alarmed, or its statistic exceeded the ``watch_p``
      level, throws away itself and every window still waiting (an open alarm episode and its lead-up are never
      absorbed); the others are absorbed ``hold_s`` later, the sensors isolated then frozen (Schmidt), the sensors
      invalid in the window left out;
    * **never worse silently: the held-out check** (``guard_s``; :data:`GROUPS`). At the end of every window
      (absorbed later or thrown away: the violent stretches count; the sensors not isolated, on the samples where
      all of them are valid, or if there is none, those valid throughout the window), its parity is computed with the terms fitted
      before it (the window is held out) with and without each group of terms (biases, scales, temperature). The group's gain is the sum of squares of the
      normalised parity it removes, given the other groups applied: ``g = |p - D_(-g)|^2 - |p - D|^2`` summed over
      the window's samples (``p`` the fixed calibration's parity, ``D`` that of the applied correction). Its
      expectation ``2 e.D_g - |D_g|^2`` (``e`` the true error's parity) is positive exactly when the group's
      correction is nearer to the truth than no correction; its variance is estimated from the window itself,
      ``4 sum_k (r_k . D_gk)^2`` (``r`` the parity without the group; White's sandwich estimate: ``4 |D_g|^2`` for
      white parity, larger where the parity is not). The gains and these variances are summed with the memory ``guard_s`` (exponential forgetting)
      and over the whole run, and a group corrects the outputs only while both sums exceed ``guard_z`` standard
      deviations (it has lowered the held-out parity significantly, lately and since the start); otherwise it is
      suspended (the filter keeps tracking it, so it comes back when its predictions do). :meth:`guard` reports
      which groups are applied, how often they were suspended, the held-out parity rms with the fixed calibration
      and with the terms applied, and the filter's normalised innovations per degree of freedom (1 when the model
      fits the data).

    Parameters
    ----------
    tracker : SelfCalTracker
    sample_rate : float
        Hz (the windows are counted in samples).
    detector : optional
        The manager's detector; kept informed of the tracker's covariance when it is a :class:`TrackedGltWindow`.
    state : SelfCalState, optional
        Start from it (default the tracker's initial state at the first sample's time).
    history : bool
        Keep the tracked terms after every window (:attr:`history`: ``(t, values (m, n), sigmas (m, n), theta)``,
        SI), for reports and estimates files; off, the loop's memory does not grow with the run.

    Examples
    --------
    >>> from rimu.calibration import InstrumentCalibration
    >>> from rimu.fusion import InstrumentPipeline
    >>> from rimu.fdi import RedundancyManager
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-6, bias_sigma0=0.01, window_s=1.0, hold_s=1.0))
    >>> det = TrackedGltWindow(10, 1e-4)
    >>> mgr = RedundancyManager(InstrumentPipeline(cal), det, p_fa=1e-4)
    >>> loop = SelfCalLoop(trk, 10.0, det)
    >>> rng = np.random.default_rng(0)
    >>> for k in range(300):                      # 30 s; x1 drifted by 2 sigma
    ...     y = 0.01 * rng.standard_normal(6) + np.array([0.02, 0, 0, 0, 0, 0])
    ...     r = mgr.step(loop.correct(y, None, 0.1 * k), None, 0.1 * k)
    ...     loop.observe(r, mgr.sensors.state >= SensorState.ISOLATED)
    >>> c = loop.terms()["bias"][0]                   # what the parity tells: the drift without its common mode
    >>> d = np.array([0.02, 0, 0, 0, 0, 0])
    >>> bool(np.abs(c - (d - trk.common_mode(d))).max() < 3e-3), loop.accepted, mgr.health.isolated
    (True, 29, [])
    >>> loop.guard()["groups"]["bias"]["applied"]      # the held-out check: the bias lowers the parity, applied
    True
    """

    def __init__(self, tracker: SelfCalTracker, sample_rate: float, detector: Any = None,
                 state: SelfCalState | None = None, history: bool = False) -> None:
        if not (sample_rate > 0 and math.isfinite(sample_rate)):
            raise ValueError(f"sample_rate must be positive (Hz), got {sample_rate}")
        self.tracker = tracker
        st = tracker.settings
        self.M = max(1, int(round(st.window_s * float(sample_rate))))
        self.sample_rate = float(sample_rate)
        self.detector = detector if isinstance(detector, TrackedGltWindow) else None
        self.span = 1 if self.detector is None else int(math.ceil(self.detector.window / self.M)) + 1
        self.state = state
        self.keep_history = bool(history)
        self.history: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self.accepted = self.rejected = self.discarded = 0
        n, m = tracker.n, tracker.m
        self._z = np.zeros((self.M, n))
        self._g = np.zeros((self.M, m, n))
        self._ok = np.ones((self.M, n), bool)
        self._k = 0
        self._flag = False
        self._t_end = 0.0
        self._th = np.zeros((m, n))
        self._g_last: np.ndarray | None = None
        self._pending: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._recent: list[np.ndarray] = []
        self._watch: dict[int, float] = {}
        self._scale = tracker.calibration.scale
        self.last_correction = np.zeros(n)
        # the held-out check: per group, the blocks it holds, its forgotten gain, its counts
        self._groups = [(g, np.array([b in blks for b in tracker.blocks]))
                        for g, blks in GROUPS if any(b in blks for b in tracker.blocks)]
        G = len(self._groups)
        self._guard = st.guard_s is not None
        self._applied = np.full(G, not self._guard)
        self._mask = self._block_mask()
        self._gain = np.zeros(G)
        self._gain_total = np.zeros(G)
        self._var = np.zeros(G)
        self._var_total = np.zeros(G)
        self._t_gain: float | None = None
        self._suspended_windows = np.zeros(G, int)
        self._suspensions = np.zeros(G, int)
        self._ss = np.zeros(2)              # held-out sums of squares: fixed, applied
        self._n_par = 0
        self._nis = np.zeros(2)             # sum of d2, sum of dof (windows tested by the gate)

    def _watch_level(self, dof: int) -> float:
        v = self._watch.get(dof)
        if v is None:
            v = self._watch[dof] = glt_threshold(self.tracker.settings.watch_p, max(int(dof), 1))
        return v

    def _block_mask(self) -> np.ndarray:
        mask = np.zeros(self.tracker.m)
        for (_, blk), on in zip(self._groups, self._applied):
            mask[blk] = float(on)
        return mask

    def _check(self, state: SelfCalState, z: np.ndarray, g: np.ndarray, active: np.ndarray, t: float) -> None:
        """The held-out check of one window (``z`` (M, n) compensated outputs, ``g`` (M, m, n) regressors, ``active``
        the sensors not isolated) with the state fitted before it; updates which groups are applied (see the class
        docstring)."""
        trk = self.tracker
        full = self._ok[:, active].all(axis=1)
        if full.any():      # the samples where every sensor not isolated is valid, with all of them
            z, g = z[full], g[full]
        else:               # else the sensors valid throughout the window
            active = active & self._ok.all(axis=0)
        Vz = trk.parity_rows(active)
        if Vz.shape[0] < 1 or not self._groups:
            return
        p = z @ Vz.T                                                      # (M, r) the fixed calibration's parity
        D = np.einsum("kbn,bn,rn->bkr", g, state.theta.reshape(trk.m, trk.n), Vz)
        Dg = np.stack([D[blk].sum(axis=0) for _, blk in self._groups])    # (G, M, r)
        app = self._applied
        Da = Dg[app].sum(axis=0) if app.any() else np.zeros_like(p)
        ss_a = float(np.sum((p - Da) ** 2))
        gains = np.array([float(np.sum((p - Da + Dg[j]) ** 2)) - ss_a if app[j]
                          else ss_a - float(np.sum((p - Da - Dg[j]) ** 2)) for j in range(len(self._groups))])
        # the gain's variance, robust to parity that is not white (White's sandwich): 4 sum_k (r_k . D_gk)^2, r the
        # parity without the group
        R = p[None] - Da[None] + np.where(app[:, None, None], Dg, 0.0)
        var = 4.0 * np.sum(np.sum(R * Dg, axis=2) ** 2, axis=1)
        decay = 1.0 if self._t_gain is None else math.exp(-max(t - self._t_gain, 0.0) / trk.settings.guard_s)
        self._t_gain = t
        self._gain = decay * self._gain + gains
        self._var = decay * decay * self._var + var
        self._gain_total += gains
        self._var_total += var
        self._ss += (float(np.sum(p * p)), ss_a)
        self._n_par += p.size
        z = trk.settings.guard_z
        new = (self._gain > z * np.sqrt(self._var)) & (self._gain_total > z * np.sqrt(self._var_total))
        self._suspensions += app & ~new
        self._applied = new
        self._mask = self._block_mask()

    def _absorb(self, t: float, iso: np.ndarray) -> None:
        """Absorb the waiting windows that ended ``hold_s`` or more before ``t`` (s)."""
        trk = self.tracker
        while self._pending and self._pending[0][0] <= t - trk.settings.hold_s:
            tp, zp, gp, actp = self._pending.pop(0)
            s0 = trk.predict(self.state, max(tp, self.state.t))
            s1, info = trk.update(s0, zp, gp, actp, ~actp | iso)
            if info.dof >= 1 and info.gate < float("inf"):
                self._nis += (info.d2, info.dof)
            self.accepted += int(info.accepted)
            self.rejected += int(not info.accepted and info.gate < float("inf"))
            self.state = s1

    def guard(self) -> dict[str, Any]:
        """What the held-out check did (see the class docstring): per group ``applied`` (now), ``suspended_windows``
        (windows started while suspended), ``suspensions`` (times it was switched off), ``heldout_gain`` (sum of
        squares of the normalised parity it removed on held-out windows, sigma^2, with every window; negative: it
        made them worse); overall ``heldout_rms_fixed`` / ``heldout_rms_applied`` (normalised parity rms of the
        windows with the fixed calibration and with the terms applied, sigma), ``nis_per_dof`` (the
        filter's normalised innovations per degree of freedom, 1 when its model fits; None before any window)."""
        npar = max(self._n_par, 1)
        return {"enabled": self._guard,
                "groups": {g: {"applied": bool(a), "suspended_windows": int(sw), "suspensions": int(sn),
                               "heldout_gain": float(gt)}
                           for (g, _), a, sw, sn, gt in zip(self._groups, self._applied, self._suspended_windows,
                                                            self._suspensions, self._gain_total)},
                "heldout_windows_parity_values": int(self._n_par),
                "heldout_rms_fixed": float(math.sqrt(self._ss[0] / npar)),
                "heldout_rms_applied": float(math.sqrt(self._ss[1] / npar)),
                "nis_per_dof": float(self._nis[0] / self._nis[1]) if self._nis[1] > 0 else None}

    def take_history(self) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
        """The windows' entries of :attr:`history` since the last call (and forget them: a long replay's memory
        stays that of one chunk)."""
        out, self.history = self.history, []
        return out

    def terms(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The tracked terms now (:meth:`SelfCalTracker.terms` of the current state), SI."""
        trk = self.tracker
        return trk.terms(self.state if self.state is not None else trk.initial_state())

    def correct(self, y: np.ndarray, valid: np.ndarray | None, t: float, temperature: float | None = None
                ) -> np.ndarray:
        """The compensated raw outputs ``y`` (n,) of one epoch corrected by the tracked terms, ``y - c / SF``."""
        trk = self.tracker
        y = np.asarray(y, dtype=float)
        ok = np.isfinite(y) if valid is None else (np.isfinite(y) & np.asarray(valid, bool))
        if self.state is None:
            self.state = trk.initial_state(float(t))
        k = self._k
        z = np.where(ok, y * self._scale - trk.calibration.bias, 0.0)
        u = z @ trk.G.T if ok.all() else np.zeros(3)
        T = None if temperature is None else np.array([float(temperature)])
        if T is not None and not np.isfinite(T[0]):
            ok = np.zeros_like(ok)
            T = np.array([trk.settings.reference_temperature])
        g = trk.regressors(1, u[None], T)[0]
        if k == 0:  # a new window: the state's terms, and the detector's covariance for the windows its sum spans
            self._th = self.state.theta.reshape(trk.m, trk.n)
            if self.detector is not None:
                st = trk.predict(self.state, max(float(t) + trk.settings.window_s, self.state.t))
                gc = g if self._g_last is None else self._g_last
                self._recent.append((trk.correction_covariance(st, gc), trk.unapplied_correction(st, gc, self._mask > 0.5)))
                del self._recent[:-self.span]
                # the estimate's error: the largest of the windows the sum spans; the drift left in by suspended
                # groups: every window's, summed (the sum's share of each is a convex combination: bounded by the sum
                # of the outer products)
                cov = max((c for c, _ in self._recent), key=lambda c: float(np.trace(c))).copy()
                for _, o in self._recent:
                    cov += np.outer(o, o)
                self.detector.set_tracker_covariance(cov)
            self._flag = False
            self._suspended_windows += ~self._applied
        c = trk.Pi @ np.einsum("bn,bn->n", g, self._th * self._mask[:, None])
        self._z[k] = z
        self._g[k] = g
        self._ok[k] = ok
        self._t_end = float(t)
        self.last_correction = c
        return y - c / self._scale

    def observe(self, result: Any, isolated: np.ndarray) -> None:
        """After the manager's step on :meth:`correct`'s outputs: its alarm and statistic (``result``, an
        :class:`rimu.fdi.FdiResult`) and the sensors it keeps isolated (n,) bool."""
        if result.alarm or (result.dof >= 1 and result.statistic > self._watch_level(result.dof)):
            self._flag = True
        self._k += 1
        if self._k < self.M:
            return
        self._k = 0
        trk = self.tracker
        t = self._t_end
        iso = np.asarray(isolated, bool)
        g_rms = np.sqrt(np.mean(self._g * self._g, axis=0)) * np.sign(np.mean(self._g, axis=0) + 1e-300)
        self._g_last = g_rms
        if self._flag:
            self.discarded += len(self._pending) + 1
            self._pending = []
        else:
            self._absorb(t, iso)       # the windows whose hold has passed, before this one
        if self._guard:  # every window, absorbed or not, with the terms fitted before it (held out)
            self._check(self.state, self._z, self._g, ~iso, t)
        if not self._flag:
            self._pending.append((t, self._z.copy(), self._g.copy(), self._ok.all(axis=0) & ~iso))
            self._absorb(t, iso)
        if self.keep_history:
            terms = trk.terms(trk.predict(self.state, max(t, self.state.t)))
            self.history.append((t, np.stack([terms[b][0] for b in trk.blocks]),
                                 np.stack([terms[b][1] for b in trk.blocks]), self.state.theta))


class SelfCalibratingRun:
    """A :class:`rimu.fdi.RedundancyManager` stepped with a :class:`SelfCalLoop` (what :class:`rimu.fdi.Runtime`
    does per instrument, around a bare manager: tests and studies of one instrument).

    Parameters
    ----------
    manager : RedundancyManager
        Its pipeline's calibration is the fixed one; its detector, when a :class:`TrackedGltWindow`, is kept
        informed of the tracker's covariance.
    tracker : SelfCalTracker
    state : SelfCalState, optional
        Start from it (default the tracker's initial state at the first sample's time).
    """

    def __init__(self, manager: Any, tracker: SelfCalTracker, state: SelfCalState | None = None) -> None:
        self.manager = manager
        self.tracker = tracker
        self._state0 = state
        self.loop: SelfCalLoop | None = None

    @property
    def state(self) -> SelfCalState | None:
        """The tracker's state now (the loop's)."""
        return self._state0 if self.loop is None else self.loop.state

    def run(self, Y: np.ndarray, valid: np.ndarray | None = None, t: np.ndarray | None = None,
            temperature: np.ndarray | None = None) -> SelfCalRunResult:
        """Process N raw samples (N, n) with their times ``t`` (s) and temperature (degC) when tracked; continues
        from the previous call."""
        from .manager import _Collector

        mgr, trk = self.manager, self.tracker
        Y = np.asarray(Y, dtype=float)
        N = len(Y)
        if t is None:
            raise MissingInputError("give the sample times t (s)")
        t = np.asarray(t, dtype=float)
        if self.loop is None:
            fs = 1.0 / float(np.median(np.diff(t))) if N > 1 else 1.0
            self.loop = SelfCalLoop(trk, fs, mgr.detector, self._state0, history=True)
        loop = self.loop
        h0 = len(loop.history)
        a0, r0, d0 = loop.accepted, loop.rejected, loop.discarded
        out = _Collector(mgr, N)
        corr = np.zeros((N, trk.n))
        T = None if temperature is None else np.asarray(temperature, dtype=float)
        with np.errstate(invalid="ignore", over="ignore"):
            for k in range(N):
                v = None if valid is None else valid[k]
                yk = loop.correct(Y[k], v, float(t[k]), None if T is None else float(T[k]))
                r = mgr.step(yk, v, float(t[k]))
                loop.observe(r, mgr.sensors.state >= SensorState.ISOLATED)
                out.add(k, r)
                corr[k] = loop.last_correction
        hist = loop.history[h0:]
        m, n = trk.m, trk.n
        return SelfCalRunResult(out.result(t), np.array([h[0] for h in hist]),
                                np.array([h[1] for h in hist]).reshape(-1, m, n),
                                np.array([h[2] for h in hist]).reshape(-1, m, n), loop.accepted - a0,
                                loop.rejected - r0, loop.discarded - d0, corr, trk.blocks,
                                np.array([h[3] for h in hist]).reshape(-1, m * n))
