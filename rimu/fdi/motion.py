"""Motion-aware parity test: thresholds that hold while a real unit moves (issue 19, item 4).

A still unit's noise model does not hold in motion. The compensated output of sensor i carries, besides its white
noise sigma_i, errors that grow with the motion: residual relative scale ``s_i`` and misalignment ``theta_j`` of
its triad (sub-unit j), the triad's time offset ``tau_j``, and vibration. To first order (Cho & Park 2005, Eq. 1
with small errors; de Oliveira et al. 2012, Eq. 5 and 13)::

    e_i = s_i (a_i . u) - (a_i x u) . theta_j + tau_j (a_i . du/dt) + n_i

with u the input (angular rate for gyros, specific force for accelerometers) and a_i the calibrated axis. Over
the stated spread of these errors (the model, :class:`MotionNoiseModel`), the outputs' covariance is, per
sub-unit block (sensors of one sub-unit share theta_j and tau_j)::

    Sigma_j(t) = diag(sigma_i^2 + s_i^2 (a_i.u)^2 + q_w,i |w|^2 + q_a,i |dw/dt|^2)
                 + m_j^2 A_j (|u|^2 I - u u^T) A_j^T + t_j^2 (A_j du/dt)(A_j du/dt)^T  [+ calibration term]

(q_w, q_a: vibration variance per |rate|^2 and per |angular acceleration|^2, fitted from fault-free data by
:func:`fit_motion_terms`; the calibration term is the calibration covariance of
:class:`rimu.fdi.CalibrationCovariance` restricted to each sub-unit's block).

The test (:class:`MotionAwareGlt`) is the generalized likelihood test of Daly, Gai & Harrison 1979 under this
per-sample covariance, computed from the pipeline's normalised parity without redoing any projection:
the weighted least-squares residual of the outputs is ``r = sigma^2 * (Vz^T p)`` (de Oliveira Eq. 11 inverted:
``W z = W A x + V_w^T p``), and for any positive definite ``Sigma``::

    T = min_d (r - A d)^T Sigma^-1 (r - A d) = r^T Sigma^-1 r - b^T M^-1 b,   M = A^T Sigma^-1 A,  b = A^T Sigma^-1 r

which is chi-square with ``dof`` degrees of freedom without a fault. Isolation is the bias likelihood ratio
``(Sigma^-1 r~)_j^2 / ((Sigma^-1)_jj - (Sigma^-1 A M^-1 A^T Sigma^-1)_jj)`` with ``r~ = r - A M^-1 b``. With
``Sigma = diag(sigma^2)`` both are exactly the plain GLT (``p^T p`` and ``(v_j^T p)^2 / |v_j|^2``). The
per-sample cost is O(n dof) for ``Vz^T p`` plus one batched solve of the sub-unit blocks (3 x 3 for triads):
no decomposition of an n x n or dof x dof matrix. Cross-sub-unit correlations of the calibration covariance
are dropped (documented limitation). At rest ``u = 0`` and the test is the plain GLT: a fault of a few sigma
at rest is isolated as fast as before.

**Window** (``window=L``): the same test on the mean residual of the last L samples of one active set. Its
covariance is ``W / L + (1/L) sum_t M(u_t)`` with W the white noise (times ``window_gain``, the variance of an
L-sample mean of the sensor's own noise over ``sigma^2 / L``: 1 for white noise, more for noise the chip's
low-pass correlates) and M(u_t) the motion part at each sample: ``Cov(mean_t m_t) <= mean_t Cov(m_t)`` for any
correlation of the motion errors (Jensen's inequality for the outer product), so the motion part is bounded, not
assumed to average down; the constant ``extra_var`` does not average down either. At rest a bias b is then L
times its snapshot noncentrality: at the full rate of a fast-sampled unit the window gives the sensitivity of
block averages while deciding at every sample. The window statistics overlap, so an alarm carries up to L
samples of the same evidence: the manager confirms on ``(confirm - 1) L + 1`` consecutive alarms
(``evidence_span``), i.e. ``confirm`` disjoint windows.

**Relative-bias tracker** (``bias_track_s=tau``): MEMS biases drift (warm-up, temperature); a triad's bias
against the array that moved by a few tenths of its noise since the setup makes the window means at rest
alarm (the MIMU4444's exp_6: 0.1 deg/s in seven minutes against a noise of 0.06 deg/s at 0.1 s). At rest
(``|rate| < rest_rate``) and without an alarm, each active sensor's residual feeds an exponential mean of time
constant tau (``tracked_bias``), subtracted from the residual before the test, its own variance
(``sigma^2 alpha / (2 - alpha)``, alpha = 1 / (tau fs)) added to the covariance. Only the part of a drift that
breaks the sensors' agreement reaches the residual, so only that is tracked; an abrupt fault moves it by
``t / tau`` of itself in t seconds (4 % in the 0.27 s it takes to isolate 1 deg/s with exp_6's tau = 6.7 s), a
fault that grows more slowly than tau is absorbed (the price of following drift). The tracker is kept across set
changes. tau is measured on the fit span (``fit_motion_detector(bias_track_s="auto")``): ``tau = N / K`` of the
residuals' white noise density and bias random walk, where the tracker's error ``N^2 / (2 tau) + K^2 tau / 2`` is
smallest (:mod:`rimu.fdi.bias_drift`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import cho_factor, solve_triangular

from ..calibration.result import InstrumentCalibration
from ..errors import ShapeError
from ..fusion import InstrumentPipeline, Validity
from .calaware import CalibrationCovariance
from .glt import glt_threshold

__all__ = [
    "check_fit_span", "MotionAwareGlt", "MotionNoiseModel", "envelope_text", "fit_motion_detector", "fit_motion_terms",
    "motion_detector_from_dict", "motion_detector_to_dict"]

#: the fitted terms a unit file stores (:func:`motion_detector_to_dict`)
_STORED_TERMS = ("scale_rel", "misalignment_rad", "time_offset_s", "rate_var", "accel_var", "extra_var")

_EYE3 = np.eye(3)


def _per(v: Any, m: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, dtype=float), (m,)).copy()
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be finite and non-negative, got {a.tolist()}")
    return a


class MotionNoiseModel:
    """The motion-dependent error spread of a unit (1 sigma), per sensor and per sub-unit.

    Parameters
    ----------
    calibration : InstrumentCalibration
        Calibrated axes, noise ``noise_sigma`` (or ``sigma``) and sub-units (the blocks).
    scale_rel : float or ndarray (n,)
        Std of the residual relative scale error of each sensor (e.g. 0.01 / sqrt(3) for a uniform +-1 %).
    misalignment_rad : float or ndarray (k,)
        Std of each component of each sub-unit's residual rotation, rad.
    time_offset_s : float or ndarray (k,)
        Std of each sub-unit's residual time offset, s.
    extra_var : float or ndarray (n,)
        Constant variance added to the white noise (output units^2): vibration that does not follow the rate
        (rotors), or a noise level the calibration under-states. The projection keeps its own sigma.
    rate_var : float or ndarray (n,)
        Vibration variance per |angular rate|^2 (output units^2 per (rad/s)^2).
    accel_var : float or ndarray (n,)
        Vibration variance per |angular acceleration|^2 (output units^2 per (rad/s^2)^2).
    calibration_covariance : bool
        Add the calibration's own parameter covariance (scale, misalignment, bias) per sub-unit block.
    sigma : float or ndarray (n,), optional
        White noise, overriding the calibration's.
    """

    def __init__(self, calibration: InstrumentCalibration, scale_rel: Any = 0.0, misalignment_rad: Any = 0.0,
                 time_offset_s: Any = 0.0, rate_var: Any = 0.0, accel_var: Any = 0.0,
                 calibration_covariance: bool = False, sigma: Any = None, extra_var: Any = 0.0) -> None:
        g = calibration.geometry
        n, k = g.n, len(g.subunits)
        if sigma is None:
            sigma = calibration.noise_sigma if calibration.noise_sigma is not None else 1.0
        self.n, self.k = n, k
        self.sigma = _per(sigma, n, "sigma")
        self.scale_rel = _per(scale_rel, n, "scale_rel")
        self.misalignment_rad = _per(misalignment_rad, k, "misalignment_rad")
        self.time_offset_s = _per(time_offset_s, k, "time_offset_s")
        self.rate_var = _per(rate_var, n, "rate_var")
        self.extra_var = _per(extra_var, n, "extra_var")
        self.accel_var = _per(accel_var, n, "accel_var")
        self.axes = calibration.axes_mb()
        gs = max(len(su.members) for su in g.subunits)
        self.pos = np.full((k, gs), -1, dtype=np.int64)  # sensor index of each block slot (-1: padding)
        for j, su in enumerate(g.subunits):
            self.pos[j, :len(su.members)] = su.members
        self.real = self.pos >= 0
        self.cal_blocks = None
        if calibration_covariance:
            cc = CalibrationCovariance(calibration)
            D, S = cc.D, cc.Sigma
            blk = np.zeros((k, 4, 4, gs, gs))
            for j in range(k):
                idx = self.pos[j][self.real[j]]
                Dj = D[:, idx, :]  # (4, m, p)
                m = len(idx)
                blk[j, :, :, :m, :m] = np.einsum("cip,pq,djq->cdij", Dj, S, Dj)
            self.cal_blocks = blk
        self._prepare()

    def _prepare(self) -> None:
        """Slot arrays (k, g) of the per-sensor terms, so that :meth:`blocks` is a few array operations."""
        real = self.real
        p0 = np.where(real, self.pos, 0)
        self._p0 = p0
        self._Ab = self.axes[p0] * real[..., None]  # (k, g, 3)
        self._AbT = np.ascontiguousarray(self._Ab.transpose(0, 2, 1))
        self._s2 = np.where(real, self.sigma[p0] ** 2 + self.extra_var[p0], 1.0)
        self._sc2 = self.scale_rel[p0] ** 2 * real
        self._qw = self.rate_var[p0] * real
        self._qa = self.accel_var[p0] * real
        self._m2 = self.misalignment_rad[:, None, None] ** 2
        self._t2 = self.time_offset_s[:, None] ** 2  # (k, 1)
        self._diag = (slice(None), np.arange(self.pos.shape[1]), np.arange(self.pos.shape[1]))

    def with_terms(self, **kw: Any) -> MotionNoiseModel:
        """A copy with some terms replaced (e.g. the fitted ``rate_var`` and ``accel_var``)."""
        new = object.__new__(MotionNoiseModel)
        new.__dict__.update(self.__dict__)
        for key, v in kw.items():
            if key not in ("scale_rel", "misalignment_rad", "time_offset_s", "rate_var", "accel_var", "extra_var"):
                raise TypeError(f"unknown term {key!r}")
            m = self.k if key in ("misalignment_rad", "time_offset_s") else self.n
            setattr(new, key, _per(v, m, key))
        new._prepare()
        return new

    def blocks(self, u: np.ndarray, du: np.ndarray, rate: np.ndarray | None = None,
               dgyro: np.ndarray | None = None, white: bool = True) -> np.ndarray:
        """Sub-unit covariance blocks (k, g, g) of the outputs at input u, its derivative du, angular rate and
        angular acceleration (default: u and du, i.e. gyros). Padding slots hold 1 on the diagonal."""
        rate = u if rate is None else rate
        dgyro = du if dgyro is None else dgyro
        Ab = self._Ab
        Au = Ab @ u
        diag = self._sc2 * Au * Au + (self._qw * float(rate @ rate) + self._qa * float(dgyro @ dgyro))
        diag += self._s2 if white else ~self.real
        # misalignment and time offset: A_j (m_j^2 (|u|^2 I - u u^T) + t_j^2 du du^T) A_j^T, one 3 x 3 per block
        K1 = float(u @ u) * _EYE3 - np.outer(u, u)
        K2 = np.outer(du, du)
        C = self._m2 * K1 + self._t2[:, :, None] * K2
        B = Ab @ C @ self._AbT
        if self.cal_blocks is not None:
            ut = np.array([u[0], u[1], u[2], 1.0])
            B += np.einsum("c,d,jcdgh->jgh", ut, ut, self.cal_blocks)
        B[self._diag] += diag
        return B

    def output_variance(self, u: np.ndarray, du: np.ndarray, rate: np.ndarray | None = None,
                        dgyro: np.ndarray | None = None) -> np.ndarray:
        """Variance of each sensor's output error (n,) at one input (the diagonal of :meth:`blocks`)."""
        B = self.blocks(u, du, rate, dgyro)
        gs = self.pos.shape[1]
        d = B[:, np.arange(gs), np.arange(gs)]
        out = np.zeros(self.n)
        out[self.pos[self.real]] = d[self.real]
        return out


class MotionAwareGlt:
    """GLT under the per-sample output covariance of a :class:`MotionNoiseModel` (see the module docstring).

    Parameters
    ----------
    model : MotionNoiseModel
    p_fa : float
        Per-sample false-alarm probability (chi-square threshold with dof degrees of freedom).
    sample_rate : float
        Hz: the derivative of the input is the difference of successive estimates times ``sample_rate``.
    input_is_rate : bool
        True for gyros: the estimate x is the angular rate and its difference the angular acceleration. For
        accelerometers pass False and give the rate and angular acceleration by :meth:`set_motion` per sample.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> det = MotionAwareGlt(MotionNoiseModel(cal, scale_rel=0.01), sample_rate=100.0)
    >>> V = cone6().parity_matrix() / 0.01
    >>> det.configure(V, 3)
    >>> det.set_input(10.0 * cone6().H[0])       # 10 rad/s along x1: a 1 % scale spread is 10 sigma on x1
    >>> z = np.zeros(6); z[0] = 0.1              # 1 % of the rate on x1: consistent with the model
    >>> stat, thr = det.update(V @ z)
    >>> bool(stat < thr), bool(float((V @ z) @ (V @ z)) > thr)   # the plain GLT would alarm
    (True, True)
    """

    name = "glt_motion"
    uses_input = True

    def __init__(self, model: MotionNoiseModel, p_fa: float = 1e-3, sample_rate: float = 1.0,
                 input_is_rate: bool = True, window: int = 1, window_gain: Any = 1.0,
                 bias_track_s: float | None = None, rest_rate: float = 0.02, rest_level: Any = None) -> None:
        if not sample_rate > 0:
            raise ValueError(f"sample_rate must be positive (Hz), got {sample_rate}")
        if int(window) < 1:
            raise ValueError(f"window must be at least 1 sample, got {window}")
        #: samples of the window mean (1: the snapshot test); the manager confirms on ``confirm`` disjoint windows
        self.window = int(window)
        self.evidence_span = self.window
        #: per sensor (n,): the variance of a window mean of its white noise over ``sigma^2 / window`` (1 for white
        #: noise; more for noise correlated between samples: the chip's low-pass)
        self.window_gain = _per(window_gain, model.n, "window_gain")
        if bias_track_s is not None and not bias_track_s > 0:
            raise ValueError(f"bias_track_s must be positive (s) or None, got {bias_track_s}")
        #: time constant (s) of the relative-bias tracker at rest (None: none; module docstring)
        self.bias_track_s = None if bias_track_s is None else float(bias_track_s)
        self.rest_rate = float(rest_rate)
        #: the estimate at rest (3,): the common bias no parity sees (the reference triad's), subtracted from the
        #: input (the motion terms act on the rate); rest is ``|u - rest_level| < rest_rate``
        self.rest_level = np.zeros(3) if rest_level is None else np.asarray(rest_level, float).reshape(3)
        #: the tracked residual bias of each sensor (n,), output units: kept across set changes
        self.tracked_bias = np.zeros(model.n)
        self._r_raw: np.ndarray | None = None
        self._r_last: np.ndarray | None = None
        self.model = model
        self.p_fa = p_fa
        self.sample_rate = float(sample_rate)
        self.input_is_rate = bool(input_is_rate)
        self._dof = 0
        self._u = np.zeros(3)
        self._u_prev: np.ndarray | None = None
        self._du = np.zeros(3)
        self._rate: np.ndarray | None = None
        self._dgyro: np.ndarray | None = None
        self._thr_cache: dict[int, float] = {}
        #: samples the motion terms were fitted on (set by :func:`fit_motion_detector`; 0: stated, not fitted)
        self.fit_samples = 0
        #: samples of the fit span in motion (rate of at least ``MOTION_RATE``); with fewer than ``min_samples`` no
        #: terms are fitted
        self.moving_samples = 0
        #: the drift measured where ``bias_track_s`` came from the data (:func:`fit_motion_detector`, "auto")
        self.bias_drift: Any = None
        #: (largest |rate| rad/s, largest |angular acceleration| rad/s^2) the terms hold for; None: no limit
        self.envelope: tuple[float, float] | None = None
        #: the last sample's motion was outside :attr:`envelope` (its alarm is no evidence against one sensor:
        #: :mod:`rimu.fdi.common_cause`)
        self.model_exceeded = False

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        mdl = self.model
        self._dof = int(dof)
        V = np.asarray(Vz)[: self._dof]
        self._V = V
        act = np.einsum("ij,ij->j", V, V) > 1e-24
        a = act[mdl._p0] & mdl.real  # active slots (k, g)
        self._act = a
        self._pair = a[:, :, None] & a[:, None, :]
        self._pad = (~a).astype(float)
        self._all = bool(a.sum() == mdl.real.sum())
        self._Ab = mdl._Ab * a[..., None]
        self._rhs = np.zeros(a.shape + (4,))
        self._rhs[..., 1:] = self._Ab
        self._s2 = mdl.sigma**2
        if self._dof not in self._thr_cache:
            self._thr_cache[self._dof] = glt_threshold(self.p_fa, self._dof) if self._dof else float("inf")
        self._thr = self._thr_cache[self._dof]
        self._u_prev = None  # the derivative restarts with the set (the estimate may jump)
        self._act_n = act
        # each sub-unit's own rate from its outputs (x + A_j^+ r_j: the fused rate along what it does not measure),
        # for the motion the envelope is judged on
        seeing = a.any(axis=1)
        self._Pj = np.array([np.linalg.pinv(Ab) for Ab in self._Ab[seeing]]) if seeing.any() else None
        self._pj_rows = seeing
        self._uj_prev = None
        if self.bias_track_s is not None:  # the tracked value's own variance (an EMA of white noise)
            al = min(1.0, 1.0 / (self.bias_track_s * self.sample_rate))
            self._trk_var = mdl.sigma[mdl._p0] ** 2 * self.window_gain[mdl._p0] * (al / (2.0 - al)) * mdl.real
        if self.window > 1:  # the window restarts with the set
            self._wr = np.zeros((self.window, mdl.n))
            self._wm = np.zeros((self.window,) + mdl._Ab.shape[:2] + (mdl._Ab.shape[1],))
            self._wi = self._wc = 0
            self._white = mdl.sigma[mdl._p0] ** 2 * self.window_gain[mdl._p0] * mdl.real
            self._const = mdl.extra_var[mdl._p0] * mdl.real

    def set_input(self, u: np.ndarray) -> None:
        u = np.array(u, dtype=float) - self.rest_level  # the rate: the common bias at rest is not motion
        self._du = (u - self._u_prev) * self.sample_rate if self._u_prev is not None else np.zeros(3)
        self._u_prev = u
        self._u = u

    def set_motion(self, rate: np.ndarray, angular_acceleration: np.ndarray) -> None:
        """Angular rate and acceleration of the unit for the next sample (accelerometer detectors)."""
        self._rate = np.asarray(rate, float)
        self._dgyro = np.asarray(angular_acceleration, float)

    def _solve(self, parity: np.ndarray) -> float:
        mdl = self.model
        d = self._dof
        r = self._s2 * (parity[:d] @ self._V)  # WLS residual of the outputs (0 on inactive sensors)
        if self.bias_track_s is not None:
            self._r_raw = r
            r = r - self.tracked_bias * self._act_n
        self._r_last = r
        rate = dg = None
        if not self.input_is_rate:
            rate = self._rate if self._rate is not None else np.zeros(3)
            dg = self._dgyro if self._dgyro is not None else np.zeros(3)
        if self.window == 1:
            B = mdl.blocks(self._u, self._du, rate, dg)
        else:  # the window mean: white noise / c (times its gain), the motion part's mean (a bound: module doc)
            i = self._wi
            self._wr[i] = r
            self._wm[i] = mdl.blocks(self._u, self._du, rate, dg, white=False)
            self._wi = (i + 1) % self.window
            self._wc = c = min(self.window, self._wc + 1)
            r = self._wr.sum(axis=0) / c
            B = self._wm.sum(axis=0) / c
            B[mdl._diag] += self._white / c + self._const
        if self.bias_track_s is not None:
            B[mdl._diag] += self._trk_var
        # inactive slots: identity rows and columns, zero residual and zero axis
        if not self._all:
            B *= self._pair
            B[mdl._diag] += self._pad
        rhs = self._rhs
        rb = r[mdl._p0] * self._act
        rhs[..., 0] = rb
        X = np.linalg.solve(B, rhs)  # (k, g, 4): Sigma^-1 [r, A] per block
        Sir, SiA = X[..., 0], X[..., 1:]
        Ab = self._Ab
        M = Ab.reshape(-1, 3).T @ SiA.reshape(-1, 3)
        b = Ab.reshape(-1, 3).T @ Sir.reshape(-1)
        try:
            Minv_b = np.linalg.solve(M, b)
        except np.linalg.LinAlgError:
            # a direction seen by no redundant sensor (e.g. two triads, one axis lost): those sensors carry no
            # parity and b has no component there; the minimum-norm solution gives the same statistic
            Minv_b = np.linalg.lstsq(M, b, rcond=None)[0]
        self._last = (B, Sir, SiA, M, Minv_b)
        return float(rb.reshape(-1) @ Sir.reshape(-1) - b @ Minv_b)

    def motion(self) -> tuple[float, float]:
        """|rate| (rad/s) and |angular acceleration| (rad/s^2) of the last sample as most sub-units see them.

        The median over the sub-units with an active sensor of the magnitude of each one's own rate
        ``x + A_j^+ r_j`` (its outputs where it measures, the fused rate x along what it does not: a triad with
        a sensor isolated still counts) and of its backward difference: a fault on one sensor moves its
        sub-unit's rate and the fused rate, not the median of three or more, so it is never taken for motion
        beyond the envelope (a 1 deg/s bias on one of four triads moves the fused rate by 0.25 deg/s). The
        fused rate where fewer than two sub-units can say (one block, or before the first parity)."""
        P, r = self._Pj, self._r_last
        if P is None or len(P) < 2 or r is None:
            return float(np.linalg.norm(self._u)), float(np.linalg.norm(self._du))
        mdl = self.model
        rb = (r[mdl._p0] * self._act)[self._pj_rows]
        uj = self._u + np.einsum("jag,jg->ja", P, rb)
        acc = 0.0 if self._uj_prev is None else float(np.median(np.linalg.norm(uj - self._uj_prev, axis=1))) * \
            self.sample_rate
        self._uj_prev = uj
        return float(np.median(np.linalg.norm(uj, axis=1))), acc

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        env = self.envelope
        if env is not None and not self.input_is_rate:  # accelerometers: the unit's motion from the gyros
            w = self._rate if self._rate is not None else np.zeros(3)  # (set_motion); unknown is beyond
            a = self._dgyro if self._dgyro is not None else np.zeros(3)
            self.model_exceeded = not (float(np.linalg.norm(w)) <= env[0] and float(np.linalg.norm(a)) <= env[1])
        if self._dof < 1:
            if env is not None and self.input_is_rate:
                self.model_exceeded = bool(np.linalg.norm(self._u) > env[0] or np.linalg.norm(self._du) > env[1])
            return 0.0, float("inf")
        stat = self._solve(parity)
        if env is not None and self.input_is_rate:
            w, dw = self.motion()
            self.model_exceeded = bool(w > env[0] or dw > env[1])
        if self.bias_track_s is not None and stat <= self._thr and self._at_rest():
            al = min(1.0, 1.0 / (self.bias_track_s * self.sample_rate))  # at rest, no alarm: follow the drift
            a = self._act_n
            self.tracked_bias[a] += al * (self._r_raw[a] - self.tracked_bias[a])
        return stat, self._thr

    def _at_rest(self) -> bool:
        """The unit turns slower than ``rest_rate``: its estimate (gyros), or the rate :meth:`set_motion` gave
        (accelerometers; unknown is not rest)."""
        if self.input_is_rate:
            return float(np.linalg.norm(self._u)) < self.rest_rate
        return self._rate is not None and float(np.linalg.norm(self._rate)) < self.rest_rate

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        """Bias likelihood ratio of each active sensor for the last sample (after an alarm)."""
        mdl = self.model
        ratios = np.zeros(mdl.n)
        if self._dof < 2:
            return -1, ratios
        B, Sir, SiA, M, Minv_b = self._last
        act, p0 = self._act, mdl._p0
        Si_diag = np.linalg.inv(B)[mdl._diag]  # only after an alarm
        Sirt = Sir - SiA @ Minv_b
        den = Si_diag - np.einsum("jga,ab,jgb->jg", SiA, np.linalg.pinv(M), SiA)
        ok = act & (den > 1e-300)
        vals = np.where(ok, Sirt**2 / np.where(ok, den, 1.0), 0.0)
        ratios[p0[ok]] = vals[ok]
        return int(np.argmax(ratios)), ratios

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int, U: np.ndarray | None = None
              ) -> tuple[np.ndarray, float, np.ndarray]:
        """N samples of one active set, inputs U (N, 3) (the estimates x); loops over the samples."""
        if U is None:
            raise ValueError("the motion-aware test needs the input of every sample (U)")
        self.configure(Vz, dof)
        stat = np.zeros(len(P))
        iso = np.full(len(P), -1)
        for t in range(len(P)):
            self.set_input(U[t])
            stat[t], thr = self.update(P[t])
            if stat[t] > thr and dof >= 2:
                iso[t] = self.isolate(P[t])[0]
        return stat, self._thr, iso


_FIT_TERMS = ("white", "scale", "misalignment", "time_offset", "rate", "accel")


def fit_motion_terms(model: MotionNoiseModel, residuals: np.ndarray, G: np.ndarray, rate: np.ndarray,
                     angular_acceleration: np.ndarray, u: np.ndarray | None = None, du: np.ndarray | None = None,
                     terms: tuple[str, ...] = _FIT_TERMS[1:], margin: float = 1.0,
                     max_samples: int | None = None) -> MotionNoiseModel:
    """Fit motion terms of the model (variances, non-negative) on fault-free data with every sensor active.

    The WLS residual ``r = Q z``, ``Q = I - A G``, has ``E[r_i^2] = (Q Sigma(t) Q^T)_ii``, and every term of
    Sigma(t) is linear in its variance parameter, so the expected squared residual of each sensor and sample is
    a linear function of the parameters: per sensor ``extra_var_i`` (white, feature ``Q_ik^2``), ``s_i^2`` (scale, feature ``Q_ik^2 (a_k.u)^2``), ``q_w,i``
    (``Q_ik^2 |w|^2``), ``q_a,i`` (``Q_ik^2 |dw/dt|^2``); per sub-unit ``m_j^2`` (misalignment,
    ``|u|^2 (Q_j A_j A_j^T Q_j^T)_ii - (Q_j A_j u)_i^2``) and ``t_j^2`` (time offset, ``(Q_j A_j du)_i^2``).
    The parameters named in ``terms`` are the non-negative least-squares fit of ``r_i(t)^2`` minus the white noise
    and the stated (not fitted) terms, over samples and sensors (normal equations accumulated in chunks).

    Parameters
    ----------
    model : MotionNoiseModel
        White noise and the stated values of the terms not fitted (without ``calibration_covariance``).
    residuals : ndarray (N, n)
        Output residuals of fault-free samples: ``sigma^2 * (parity @ Vz)`` of the full set.
    G : ndarray (3, n)
        The full set's projection (``table.G[0]``).
    rate, angular_acceleration : ndarray (N, 3)
        Angular rate and acceleration of each sample (e.g. the gyro estimate and its difference).
    u, du : ndarray (N, 3), optional
        The instrument's input and its derivative (default: rate and angular acceleration, i.e. gyros).
    terms : tuple of str
        Which of ``white``, ``scale``, ``misalignment``, ``time_offset``, ``rate``, ``accel`` to fit. Default: all
        but ``white`` (the noise at rest is the calibration's; a fitted constant variance would also blunt the test
        at rest). Add ``white`` where vibration does not follow the rate (rotors) and no still data exist.
    margin : float
        Factor on the fitted variances (1: the least-squares fit; a fit is a mean, and a real unit's residual
        errors are fixed rather than random, so a margin of 2-4 buys robustness at the cost of sensitivity in
        motion).
    max_samples : int, optional
        Samples used (evenly spaced); default ``min(4000, max(500, 100000 // n))`` (the normal equations cost
        about ``9 N n^3``).

    Returns
    -------
    MotionNoiseModel with the fitted terms.
    """
    if model.cal_blocks is not None:
        raise ValueError("fit the motion terms with a model without calibration_covariance, then add it")
    bad = [t for t in terms if t not in _FIT_TERMS]
    if bad:
        raise ValueError(f"unknown terms {bad}; choose from {_FIT_TERMS}")
    R = np.asarray(residuals, float)
    N, n = R.shape
    k = model.k
    u = rate if u is None else u
    du = angular_acceleration if du is None else du
    A = model.axes
    Q = np.eye(n) - A @ G
    Q2 = Q**2
    Gm = np.zeros((n, k))  # sub-unit membership
    for j in range(k):
        Gm[model.pos[j][model.real[j]], j] = 1.0
    AAt = np.zeros((n, n))
    for j in range(k):
        idx = model.pos[j][model.real[j]]
        AAt[np.ix_(idx, idx)] = A[idx] @ A[idx].T
    Dm = np.stack([np.einsum("ia,ab,ib->i", Q * Gm[:, j], AAt, Q * Gm[:, j]) for j in range(k)], axis=1)
    sizes = {"white": n, "scale": n, "misalignment": k, "time_offset": k, "rate": n, "accel": n}
    stated = {"white": model.extra_var, "scale": model.scale_rel**2, "misalignment": model.misalignment_rad**2,
              "time_offset": model.time_offset_s**2, "rate": model.rate_var, "accel": model.accel_var}
    order = list(_FIT_TERMS)
    fit = [t in terms for t in order]
    p = sum(sizes[t] for t, f in zip(order, fit) if f)
    XtX = np.zeros((p, p))
    Xty = np.zeros(p)
    if max_samples is None:
        max_samples = min(4000, max(500, 100_000 // n))
    sel = np.unique(np.linspace(0, N - 1, min(N, int(max_samples))).astype(int))
    white = Q2 @ model.sigma**2
    for c0 in range(0, len(sel), 64):
        t = sel[c0:c0 + 64]
        Au, Adu = u[t] @ A.T, du[t] @ A.T  # (c, n)
        w2 = np.einsum("ta,ta->t", rate[t], rate[t])
        a2 = np.einsum("ta,ta->t", angular_acceleration[t], angular_acceleration[t])
        u2 = np.einsum("ta,ta->t", u[t], u[t])
        feats = {
            "white": np.broadcast_to(Q2, (len(t), n, n)),
            "scale": Q2[None] * (Au**2)[:, None, :],
            "misalignment": u2[:, None, None] * Dm[None] - np.einsum("ia,ta,aj->tij", Q, Au, Gm) ** 2,
            "time_offset": np.einsum("ia,ta,aj->tij", Q, Adu, Gm) ** 2,
            "rate": Q2[None] * w2[:, None, None],
            "accel": Q2[None] * a2[:, None, None],
        }
        y = R[t] ** 2 - white[None]
        for name, f in zip(order, fit):
            if not f:
                y -= feats[name] @ stated[name]
        X = np.concatenate([feats[name] for name, f in zip(order, fit) if f], axis=2)
        X2 = X.reshape(-1, p)
        XtX += X2.T @ X2
        Xty += X2.T @ y.reshape(-1)
    scale = np.sqrt(np.clip(np.diag(XtX), 1e-300, None))  # column scaling: the terms differ by many decades
    XtXs = XtX / np.outer(scale, scale) + 1e-10 * np.eye(p)
    c, low = cho_factor(XtXs)
    U = np.triu(c) if not low else np.tril(c).T
    d = solve_triangular(U, Xty / scale, trans="T")
    from scipy.optimize import nnls  # imported where used: scipy.optimize is ~18 MB
    q = nnls(U, d, maxiter=50 * p)[0] / scale * float(margin)
    out: dict[str, np.ndarray] = {}
    pos = 0
    for name, f in zip(order, fit):
        if f:
            out[name] = q[pos:pos + sizes[name]]
            pos += sizes[name]
    kw = {}
    if "white" in out:
        kw["extra_var"] = out["white"]
    if "scale" in out:
        kw["scale_rel"] = np.sqrt(out["scale"])
    if "misalignment" in out:
        kw["misalignment_rad"] = np.sqrt(out["misalignment"])
    if "time_offset" in out:
        kw["time_offset_s"] = np.sqrt(out["time_offset"])
    if "rate" in out:
        kw["rate_var"] = out["rate"]
    if "accel" in out:
        kw["accel_var"] = out["accel"]
    return model.with_terms(**kw)


def fit_motion_detector(calibration: InstrumentCalibration, raw: np.ndarray, valid: np.ndarray | None,
                        sample_rate: float, margin: float = 3.0, p_fa: float = 1e-3,
                        terms: tuple[str, ...] = _FIT_TERMS[1:], min_samples: int = 50,
                        envelope: float | None = 1.0, window: int = 1,
                        bias_track_s: float | str | None = None, still: np.ndarray | None = None,
                        rate: np.ndarray | None = None, extra_var: Any = 0.0) -> MotionAwareGlt:
    """A gyro (or, with ``rate``, accelerometer) :class:`MotionAwareGlt` whose motion terms are fitted on
    fault-free raw data of the unit.

    The data go through the runtime pipeline with every sensor active; the samples where every sensor is valid
    give the residuals ``sigma^2 (parity @ Vz)``, the estimate is the angular rate and its central difference
    the angular acceleration (:func:`fit_motion_terms`).

    Parameters
    ----------
    calibration : InstrumentCalibration
        Of the gyros (with a noise sigma).
    raw, valid : ndarray (N, n)
        Raw outputs and validity flags (None: all valid) of a fault-free span, N samples at ``sample_rate`` Hz.
    margin : float
        Factor on the fitted variances (see :func:`fit_motion_terms`).

    envelope : float or None
        The detector's :attr:`MotionAwareGlt.envelope` is ``envelope`` times the largest |angular rate| and
        |angular acceleration| of the fit samples, as most sub-units see them (:meth:`MotionAwareGlt.motion`: a
        fault on one sensor is not motion): beyond it the fitted terms are an extrapolation and an alarm is
        reported as ``model_exceeded`` (the unit DEGRADED, nothing isolated). None: no envelope. A fit span with fewer than ``min_samples``
        samples in motion (|rate| of at least ``MOTION_RATE``, 0.05 rad/s; a static recording, where every term
        would be fitted on noise) fits no term: the test is the plain GLT, and the envelope is the motion of
        the samples at rest (what the noise was measured on).
    window : int
        Samples of the detector's window mean (:class:`MotionAwareGlt`, module docstring); with more than one,
        each sensor's ``window_gain`` is measured on the fit span's rest (rate below 0.02 rad/s, in runs of at
        least four windows, each run's mean removed): the variance of an L-sample mean of its residual over
        1/L of its variance, at least 1.
    bias_track_s : float, "auto" or None
        Time constant of the detector's relative-bias tracker at rest (:class:`MotionAwareGlt`); None: none;
        ``"auto"``: ``N / K`` of the residuals' white noise density N and bias random walk K measured on the
        span's poses at rest (:func:`rimu.fdi.bias_drift.bias_drift`; the detector's ``bias_drift`` says them),
        none where the span has fewer than three poses at rest (``bias_drift`` then says why).
    still : ndarray (N,) of bool, optional
        The samples at rest (e.g. :attr:`rimu.calibration.multi_imu.MultiImuSetup.still`); default: the estimate
        within 0.02 rad/s of zero. Given, their median estimate is the detector's ``rest_level`` (the array's
        common bias, which no parity sees): the motion terms are fitted and evaluated on the rate from it.
    rate : ndarray (N, 3), optional
        For accelerometers: the unit's angular rate at the same samples (the gyros' estimate, rad/s). The
        instrument's input is then the specific force (scale and misalignment act on it, its difference is the
        time-offset term), the vibration terms and the envelope follow the rate and its difference (the
        accelerometers' lever-arm terms grow with both), and the detector takes them per sample by
        ``set_motion`` (:class:`rimu.fdi.Runtime` feeds the gyros' estimate); the relative-bias tracker follows
        the accelerometers' residuals where that rate is below ``rest_rate``.
    extra_var : float or ndarray (n,)
        A constant variance of each sensor's output (output units^2) the calibration states beside its noise (e.g.
        the offset at a new pose of gains fitted on poses, :func:`rimu.calibration.multi_imu.pose_uncertainty`,
        squared): in the test's covariance, not fitted, not averaged down by the window.

    Returns
    -------
    MotionAwareGlt, with ``fit_samples``: the number of samples (every sensor valid) the terms were fitted on,
    and ``envelope``.

    Raises
    ------
    ShapeError
        Fewer than ``min_samples`` samples with every sensor valid: a longer fault-free span is needed.
    """
    if not sample_rate > 0:
        raise ValueError(f"sample_rate must be positive (Hz), got {sample_rate}")
    pipe = InstrumentPipeline(calibration)
    blk = pipe.process(np.asarray(raw, float), valid)
    full = np.asarray(blk.validity) == Validity.NOMINAL
    if int(full.sum()) < min_samples:
        raise ShapeError(f"only {int(full.sum())} samples with every gyro valid to fit the motion terms; give a "
                         f"longer fault-free span (at least {min_samples} samples)")
    res = pipe.table.sigma**2 * (blk.parity @ pipe.table.Vz[0])
    x = np.where(np.isfinite(blk.x), blk.x, 0.0)
    level = np.zeros(3)
    if still is None:  # rest: the estimate within 0.02 rad/s of zero
        rest = full & (np.linalg.norm(x, axis=1) < 0.02)
    else:  # the estimate at rest is the common bias no parity sees (the reference triad's): not a rate
        rest = full & np.asarray(still, bool)
        level = np.median(x[rest], axis=0) if rest.any() else level
    if rate is not None:  # accelerometers: input = specific force, motion = the gyros' rate
        w = np.asarray(rate, dtype=float)
        if w.shape != (len(x), 3):
            raise ShapeError(f"rate must be (N, 3) with N = {len(x)} (the accelerometer samples), got {w.shape}")
        full = full & np.isfinite(w).all(axis=1)
        w = np.where(np.isfinite(w), w, 0.0)
        if int(full.sum()) < min_samples:
            raise ShapeError(f"only {int(full.sum())} samples with every accelerometer valid and a rate to fit the "
                             f"motion terms; give a longer fault-free span (at least {min_samples} samples)")
        rest = full & (np.asarray(still, bool) if still is not None else np.linalg.norm(w, axis=1) < 0.02)
        du = np.gradient(x, 1.0 / sample_rate, axis=0)
        alpha = np.gradient(w, 1.0 / sample_rate, axis=0)
        model = fit_motion_terms(MotionNoiseModel(calibration, sigma=pipe.table.sigma, extra_var=extra_var), res[full],
                                 pipe.table.G[0],
                                 w[full], alpha[full], u=x[full], du=du[full], terms=terms, margin=margin)
        gain = _window_gain(res, rest, int(window)) if window > 1 else 1.0
        bias_track_s, drift = _track(bias_track_s, res, rest, sample_rate)
        det = MotionAwareGlt(model, p_fa, sample_rate=sample_rate, input_is_rate=False, window=window,
                             window_gain=gain, bias_track_s=bias_track_s)
        det.fit_samples = int(full.sum())
        det.bias_drift = drift
        det.moving_samples = int((full & (np.linalg.norm(w, axis=1) >= MOTION_RATE)).sum())
        if envelope is not None:  # the gyros' motion over the fit samples (set_motion gives it at runtime)
            det.envelope = (float(envelope * np.linalg.norm(w[full], axis=1).max()),
                            float(envelope * np.linalg.norm(alpha[full], axis=1).max()))
        return det
    x = x - level
    alpha = np.gradient(x, 1.0 / sample_rate, axis=0)
    model = MotionNoiseModel(calibration, sigma=pipe.table.sigma, extra_var=extra_var)
    moving = int((full & (np.linalg.norm(x, axis=1) >= MOTION_RATE)).sum())  # as the setup counts motion
    if moving >= min_samples:
        model = fit_motion_terms(model, res[full], pipe.table.G[0], x[full], alpha[full], terms=terms, margin=margin)
    gain = _window_gain(res, rest, int(window)) if window > 1 else 1.0
    bias_track_s, drift = _track(bias_track_s, res, rest, sample_rate)
    det = MotionAwareGlt(model, p_fa, sample_rate=sample_rate, window=window, window_gain=gain,
                         bias_track_s=bias_track_s, rest_level=level)
    det.fit_samples = int(full.sum())
    det.bias_drift = drift
    det.moving_samples = moving
    if envelope is not None:  # the motion as the runtime judges it (MotionAwareGlt.motion), over the fit samples
        w, dw = _subunit_motion(model, x, res, full, sample_rate)
        seen = full if moving >= min_samples or not rest.any() else rest  # no terms: the rest the noise came from
        det.envelope = (float(envelope * w[seen].max()), float(envelope * dw[seen].max()))
    return det


def _track(bias_track_s: float | str | None, res: np.ndarray, rest: np.ndarray, sample_rate: float
           ) -> tuple[float | None, Any]:
    """The tracker's time constant (s, or None) and the drift it was measured from (``"auto"``:
    :func:`rimu.fdi.bias_drift.bias_drift` on the residuals at rest; where none can be measured, no tracker and
    the reason as a string)."""
    if not isinstance(bias_track_s, str):
        return bias_track_s, None
    if bias_track_s != "auto":
        raise ValueError(f"bias_track_s must be a time (s), 'auto' or None, got {bias_track_s!r}")
    from .bias_drift import bias_drift

    try:
        drift = bias_drift(res, rest, sample_rate)
    except ShapeError as exc:  # no drift can be measured: no tracker, and the reason said
        return None, f"no bias tracker: {exc}"
    return drift.tau_s, drift


def _subunit_motion(model: MotionNoiseModel, x: np.ndarray, res: np.ndarray, ok: np.ndarray,
                    sample_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the median over the sub-units of |x + A_j^+ r_j| and of its backward difference
    times the rate (0 after a sample that is not ``ok``); the fused rate with fewer than two such sub-units (as
    :meth:`MotionAwareGlt.motion`)."""
    blocks = [model.pos[j][model.real[j]] for j in range(model.k)]
    if len(blocks) < 2:
        U = x[:, None, :]
    else:
        U = np.stack([x + res[:, b] @ np.linalg.pinv(model.axes[b]).T for b in blocks], axis=1)
    w = np.median(np.linalg.norm(U, axis=2), axis=1)
    dw = np.zeros(len(x))
    dw[1:] = np.median(np.linalg.norm(np.diff(U, axis=0), axis=2), axis=1) * sample_rate
    dw[1:][~ok[:-1]] = 0.0
    return w, dw


def envelope_text(envelope: tuple[float, float] | None) -> str:
    """The envelope in the field's units, "any" where it sets no limit (an infinite bound).

    >>> envelope_text((np.radians(100.0), np.inf))
    '|rate| up to 100 deg/s and any |angular acceleration|'
    """
    if envelope is None:
        return "any motion"
    r, a = envelope
    rt = f"|rate| up to {np.degrees(r):.4g} deg/s" if np.isfinite(r) else "any |rate|"
    at = f"|angular acceleration| up to {np.degrees(a):.4g} deg/s^2" if np.isfinite(a) else "any |angular acceleration|"
    return f"{rt} and {at}"


#: the least window gain used (a guard: a residual whose window means barely vary would otherwise get no noise; the
#: MIMU4444's measured gains are 0.29-1.44)
MIN_WINDOW_GAIN = 0.1


def _window_gain(res: np.ndarray, rest: np.ndarray, L: int) -> np.ndarray:
    """Per sensor: the variance of an L-sample mean of its residual ``res`` (N, n) over ``var / L``, measured
    in the runs of ``rest`` of at least ``4 L`` samples with each run's mean removed; 1 where there is no rest
    (white noise assumed). Below 1 where neighbouring samples are anti-correlated (noise near the Nyquist
    frequency: the MIMU4444's imu4 x accelerometer, 0.29 at 62.5 Hz, its per-sample noise 3.4 times the variance
    of its 0.1 s means over 6): clamped at 1, a 0.3 m/s^2 bias on it was not confirmed within 1 s; at least
    :data:`MIN_WINDOW_GAIN`."""
    n = res.shape[1]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(np.int8), [0]])))
    num, den = np.zeros(n), np.zeros(n)
    for a, b in zip(edges[::2], edges[1::2]):
        if b - a < 4 * L:
            continue
        x = res[a:b] - res[a:b].mean(axis=0)
        c = np.cumsum(np.vstack([np.zeros(n), x]), axis=0)
        m = (c[L:] - c[:-L]) / L
        num += (m * m).sum(axis=0) / len(m) * (b - a)
        den += (x * x).mean(axis=0) * (b - a)
    if not den.any():
        return np.ones(n)
    return np.maximum(MIN_WINDOW_GAIN, L * num / np.where(den > 0, den, 1.0))


#: rad/s: a sample of the fit span whose rate (from the rest level) reaches this is motion (the setup's threshold,
#: :func:`rimu.calibration.multi_imu.setup_multi_imu` ``min_rate_rad_s``)
MOTION_RATE = 0.05

#: what a fault-free fit span may need: extra white noise up to 4 times a sensor's calibrated variance (its noise
#: at most sqrt(5) = 2.2 times what the calibration states), a scale-factor spread up to 5 %
EXTRA_VAR_LIMIT = 4.0
SCALE_LIMIT = 0.05


def check_fit_span(calibration: InstrumentCalibration, detector: MotionAwareGlt, t: np.ndarray, raw: np.ndarray,
                   valid: np.ndarray | None, what: str = "the fit span", confirm: int = 3) -> None:
    """Refuse a motion fit whose span holds a fault: the fitted detector, run over the span it was fitted on,
    must not isolate a sensor, and no sensor's residual may carry most of the fitted excess variance.

    A step or drift inside the span is partly absorbed into the fitted terms (they grow until the statistic
    fits), but what the terms cannot explain (a bias on one sensor is not a motion term of all) still alarms on
    that span, and one sensor's residual then dominates.

    Raises
    ------
    NotApplicableError
        Naming the sensor, the time of the first isolation, and what to do.
    """
    import copy

    from ..errors import NotApplicableError
    from .manager import RedundancyManager

    model = detector.model
    ratio = np.asarray(model.extra_var, float) / np.asarray(model.sigma, float) ** 2
    scale = np.atleast_1d(np.asarray(model.scale_rel, float))
    if np.max(ratio) > EXTRA_VAR_LIMIT or np.max(np.abs(scale)) > SCALE_LIMIT:
        i = int(np.argmax(ratio))
        names = list(calibration.geometry.names)
        raise NotApplicableError(
            f"{what}: the span the motion terms are fitted on is not fault-free: the fit needs "
            + (f"{ratio[i]:.3g} times the calibrated noise variance of {names[i]} as extra white noise (at most "
               f"{EXTRA_VAR_LIMIT:g})" if np.max(ratio) > EXTRA_VAR_LIMIT else
               f"a scale-factor spread of {100 * float(np.max(np.abs(scale))):.3g} % (at most {100 * SCALE_LIMIT:g} %)")
            + "; a fault inside the span is absorbed by the fit: give a shorter --motion-fit that ends before it, or "
            "fit on a fault-free recording")
    pipe = InstrumentPipeline(calibration)
    res = RedundancyManager(pipe, copy.deepcopy(detector), p_fa=detector.p_fa, confirm=confirm,
                            readmit_after=None).run(np.asarray(raw, float), valid, np.asarray(t, float))
    found = [ev for ev in res.events if ev.kind in ("isolated", "detected_not_isolable")]
    if found:
        ev = found[0]
        raise NotApplicableError(f"{what}: the span the motion terms are fitted on is not fault-free (the fitted "
                                 f"detector, run over it, {ev.kind.replace('_', ' ')} {ev.sensor or ''} at t = "
                                 f"{ev.t:.4g} s); give a shorter --motion-fit that ends before the fault, or fit on "
                                 "a fault-free recording")


def motion_detector_to_dict(detector: MotionAwareGlt) -> dict[str, Any]:
    """The fitted motion terms and envelope of a gyro :class:`MotionAwareGlt` as plain lists (SI: rad, s,
    (rad/s)^2 per (rad/s)^2, ...), for a unit file (``rimu setup --motion-fit``); the noise and axes stay in the
    calibration. :func:`motion_detector_from_dict` makes the same detector again.

    Examples
    --------
    >>> from rimu.geometry import triads
    >>> cal = InstrumentCalibration.nominal("gyro", triads(3), 1.0, noise_sigma=0.01)
    >>> det = MotionAwareGlt(MotionNoiseModel(cal, scale_rel=0.01, rate_var=1e-6), sample_rate=100.0)
    >>> det.envelope = (3.0, 50.0)
    >>> d = motion_detector_to_dict(det)
    >>> again = motion_detector_from_dict(cal, d, p_fa=1e-3)
    >>> again.envelope, float(again.model.rate_var[0]), again.sample_rate
    ((3.0, 50.0), 1e-06, 100.0)
    """
    m = detector.model
    out: dict[str, Any] = {k: np.asarray(getattr(m, k), float).tolist() for k in _STORED_TERMS}
    out["sample_rate_hz"] = float(detector.sample_rate)
    out["window"] = int(detector.window)
    out["bias_track_s"] = detector.bias_track_s
    out["rest_level"] = np.asarray(detector.rest_level, float).tolist()
    out["window_gain"] = np.asarray(detector.window_gain, float).tolist()
    out["fit_samples"] = int(detector.fit_samples)
    out["envelope"] = None if detector.envelope is None else [  # no limit (inf): null
        float(v) if np.isfinite(v) else None for v in detector.envelope]
    if not detector.input_is_rate:
        out["input_is_rate"] = False
    return out


def motion_detector_from_dict(calibration: InstrumentCalibration, stored: dict[str, Any], p_fa: float = 1e-3,
                              sample_rate: float | None = None) -> MotionAwareGlt:
    """The gyro :class:`MotionAwareGlt` of stored motion terms (:func:`motion_detector_to_dict`) on
    ``calibration`` (its noise and axes); ``sample_rate`` defaults to the stored one (the rate the terms were
    fitted at: the angular acceleration is a difference of successive samples)."""
    try:
        terms = {k: np.asarray(stored[k], float) for k in _STORED_TERMS}
        fs = float(stored["sample_rate_hz"]) if sample_rate is None else float(sample_rate)
        env = stored.get("envelope")
    except (KeyError, TypeError, ValueError) as exc:
        raise ShapeError(f"stored motion terms are incomplete or malformed ({exc}); fit them again "
                         "(rimu setup --motion-fit)") from None
    det = MotionAwareGlt(MotionNoiseModel(calibration, **terms), p_fa, sample_rate=fs,
                         input_is_rate=bool(stored.get("input_is_rate", True)),
                         window=int(stored.get("window", 1)), window_gain=stored.get("window_gain", 1.0),
                         bias_track_s=stored.get("bias_track_s"), rest_level=stored.get("rest_level"))
    det.fit_samples = int(stored.get("fit_samples", 0))
    det.envelope = None if env is None else tuple(np.inf if v is None else float(v) for v in env)  # type: ignore
    return det
