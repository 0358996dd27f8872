"""Relative calibration of an array's gyro triads from ordinary motion, and the ranking of missing terms.

Model, body frame, triad j (Carlsson, Skog & Jalden 2021 model the same gain/bias structure; the sampling
offset, angular-acceleration sensitivity, g-sensitivity and rate nonlinearity are the candidate terms of the issue)::

    z_j(t) = (I + F_j) w(t + tau_j) + c_j + sum_terms X_term(t) theta_term,j + noise

The array rate ``w`` is unknown in every sample and is estimated with the parameters (it is the nuisance of a
separable least-squares problem). What the parity space makes observable is everything *relative*: the common
mode of every parameter (the array-mean gain F, mean bias c, mean offset tau, ...) is indistinguishable from a
different true rate and is fixed to zero in the array mean. Concretely the result satisfies
``mean_j (I + F_j) = I``, ``mean_j c_j = 0``, ``mean_j tau_j = 0`` (and zero mean of every other term): the
array-mean gyro defines the frame. Absolute scale, absolute misalignment to the case, common bias and common
delay need an external reference (turntable, static poses, another sensor).

Estimation: compensate every triad with the current parameters (inverse gain, bias and terms, and a cubic-spline
time shift by ``-tau_j``), form the array mean, regress each triad's difference from it on the terms' columns
(common to all triads, so one Gram matrix serves all of them), compose, repeat (with backtracking on the parity
criterion) until the update is a small fraction of its standard deviation. With the regressors built from the
array mean, the estimates centred on the mean do not depend on the noise weights; their covariance is
``S^-1 [sigma_j^2 (1 - 2/k) + mean(sigma^2)/k]`` with ``S`` the Gram matrix of the columns
(``RelativeFit.covariance``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.interpolate import CubicSpline

from ..errors import GeometryError, IdentifiabilityError, NonFiniteError, ShapeError
from ..units import RAD_TO_ARCSEC, RAD_TO_DEG, RS_TO_DH
from .layout import ArrayLayout
from .terms import GYRO_TERMS, Signals, Term

__all__ = ["DERIVATIVE_CUTOFF_HZ", "RelativeFit", "CandidateScore", "fit_relative_gyro", "rank_candidates",
           "derivative", "time_shift", "to_array_gauge", "BASE_TERMS", "CANDIDATE_TERMS"]

BASE_TERMS = ("scale_misalignment", "bias")
CANDIDATE_TERMS = ("sampling_offset", "aa_sensitivity", "g_sensitivity", "rate_nonlinearity")
#: Largest predicted standard deviation at which a term counts as identified (SI, per parameter).
_MAX_SIGMA = {"scale_misalignment": 0.05, "bias": 1.0, "sampling_offset": 0.01, "aa_sensitivity": 0.01,
              "g_sensitivity": 0.01, "rate_nonlinearity": 0.05}


#: Angular acceleration is the derivative of the array rate low-passed here [Hz]: hand-held and vehicle motion
#: lies well below it, while the noise of a differentiated rate grows with frequency.
DERIVATIVE_CUTOFF_HZ = 30.0


def derivative(t: np.ndarray, x: np.ndarray, cutoff_hz: "float | None" = DERIVATIVE_CUTOFF_HZ) -> np.ndarray:
    """Time derivative of ``x`` (N, ...) sampled at ``t``.

    Fourth-order central differences on a uniform grid, second-order (``np.gradient``) otherwise, after a
    zero-phase low-pass at ``cutoff_hz`` when that is below 0.4 times the sampling rate (None: no filter).
    """
    x = np.asarray(x, dtype=float)
    dt = np.diff(t)
    fs = 1.0 / float(np.median(dt))
    if cutoff_hz is not None and cutoff_hz < 0.4 * fs and x.shape[0] > 30:
        from scipy.signal import butter, sosfiltfilt

        # odd extension over a few time constants: the filter's start-up transient stays in the padding
        x = sosfiltfilt(butter(4, cutoff_hz, fs=fs, output="sos"), x, axis=0,
                        padlen=min(x.shape[0] - 1, int(4 * fs / cutoff_hz)))
    if x.shape[0] >= 5 and np.allclose(dt, dt.mean(), rtol=1e-6, atol=0):
        h = dt.mean()
        d = np.gradient(x, h, axis=0, edge_order=2)
        d[2:-2] = (x[:-4] - 8 * x[1:-3] + 8 * x[3:-1] - x[4:]) / (12 * h)
        return d
    return np.gradient(x, t, axis=0, edge_order=2)


def time_shift(t: np.ndarray, x: np.ndarray, shift_s: float) -> np.ndarray:
    """``x(t + shift_s)`` by a cubic spline through the samples (N, 3); ends are held (mark them invalid)."""
    if shift_s == 0.0:
        return x
    tt = np.clip(t + shift_s, t[0], t[-1])
    return CubicSpline(t, x, axis=0)(tt)


def to_array_gauge(D: np.ndarray, c: np.ndarray, tau: np.ndarray, extra: "dict[str, np.ndarray] | None" = None,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Express body-frame gains ``D`` (k,3,3), biases ``c`` (k,3), offsets ``tau`` (k,) and additive terms relative
    to the array mean, the frame in which :func:`fit_relative_gyro` reports them (exactly, not to first order).

    With ``A = mean_j D_j``: ``D_j <- D_j A^-1``, ``c_j <- c_j - D_j A^-1 mean(c)``, ``tau_j <- tau_j - mean(tau)``,
    and every additive term ``X_j <- X_j - D_j A^-1 mean(X)`` (its parameters must be linear in a matrix form:
    pass them as (k, 3, m) matrices).
    """
    A = D.mean(axis=0)
    DA = D @ np.linalg.inv(A)
    c2 = c - DA @ c.mean(axis=0)
    out = {}
    for name, X in (extra or {}).items():
        out[name] = X - DA @ X.mean(axis=0)
    return DA, c2, tau - tau.mean(), out


@dataclass(frozen=True)
class CandidateScore:
    """One candidate term tested against the current model (nested F-test on the parity residual)."""

    name: str
    n_params: int
    f_stat: float
    log10_p: float
    explained: float
    excitation_ok: bool

    @property
    def significant(self) -> bool:
        return bool(self.log10_p < -3.0)

    def to_dict(self) -> dict:
        return {"name": self.name, "n_params": self.n_params, "F": self.f_stat, "log10_p": self.log10_p,
                "explained_share": self.explained}


@dataclass
class RelativeFit:
    """Result of :func:`fit_relative_gyro` (body-frame parameters, relative to the array mean).

    Attributes
    ----------
    layout : ArrayLayout
    terms : tuple of str
        Terms in the model (base ones first).
    gain : ndarray (k, 3, 3)
        ``I + F_j`` in the body frame (mean over triads = I).
    bias_rad_s : ndarray (k, 3)
    sampling_offset_s : ndarray (k,)
        Zero when the term is not in the model.
    extra : dict of name -> ndarray (k, p)
        Parameters of the additive terms.
    sigma_rad_s : ndarray (k,)
        White-noise standard deviation per sample of each triad, estimated from the residual.
    gram_inv : ndarray (P, P)
        Inverse Gram matrix of the columns at the solution (common to all triads).
    labels : tuple of str
        Parameter labels of one triad, in column order.
    parity_rms_rad_s : dict
        ``"before"``/``"after"``: per-triad rms of the difference from the array mean, in motion.
    iterations : int
    converged : bool
        False when ``max_iter`` ended the iterations before the update fell below 2 % of its standard deviation.
    candidates : list of CandidateScore
        Missing terms ranked by the share of the residual they explain (largest first).
    """

    layout: ArrayLayout
    terms: tuple[str, ...]
    gain: np.ndarray
    bias_rad_s: np.ndarray
    sampling_offset_s: np.ndarray
    extra: dict[str, np.ndarray]
    sigma_rad_s: np.ndarray
    gram_inv: np.ndarray
    labels: tuple[str, ...]
    parity_rms_rad_s: dict[str, np.ndarray]
    iterations: int
    candidates: list[CandidateScore] = field(default_factory=list)
    n_used: int = 0
    converged: bool = True

    def vector(self) -> np.ndarray:
        """Parameters per triad in column order, (k, P): F (row-major), c, tau, extra terms."""
        parts = []
        for name in self.terms:
            if name == "scale_misalignment":
                parts.append((self.gain - np.eye(3)).reshape(-1, 9))
            elif name == "bias":
                parts.append(self.bias_rad_s)
            elif name == "sampling_offset":
                parts.append(self.sampling_offset_s[:, None])
            else:
                parts.append(self.extra[name])
        return np.hstack(parts)

    def covariance(self) -> np.ndarray:
        """Covariance of every triad's parameters, (k, P, P), in the array-mean gauge.

        With ``S`` the Gram matrix and the estimates ``theta_j = S^-1 X^T (u_j - sum_l a_l u_l)`` (a_l the noise
        weights), centring to the plain mean gives
        ``Cov(theta_j) = S^-1 [sigma_j^2 (1 - 2/k) + mean(sigma^2)/k]``.
        """
        s2 = self.sigma_rad_s**2
        fac = s2 * (1 - 2 / self.layout.k) + s2.mean() / self.layout.k
        return fac[:, None, None] * self.gram_inv[None]

    def std(self) -> np.ndarray:
        """Standard deviation of every parameter, (k, P)."""
        return np.sqrt(np.einsum("kii->ki", self.covariance()))

    def limiting_term(self, min_share: float = 0.1) -> str:
        """The candidate that explains most of what is left, or ``"noise"`` when none is significant.

        A significant candidate that explains less than ``min_share`` of the residual does not limit anything
        (with many samples a term explaining 0.1 % is significant): then ``"unexplained"`` with the share each
        candidate explains."""
        sig = [c for c in self.candidates if c.significant]
        if not sig:
            return "noise"
        if sig[0].explained >= min_share:
            return sig[0].name
        return "unexplained (" + ", ".join(f"{c.name} {100 * c.explained:.2g} %" for c in self.candidates) + ")"

    def apply(self, t: np.ndarray, gyro: np.ndarray, specific_force: "np.ndarray | None" = None) -> np.ndarray:
        """Compensate raw triad outputs (N, k, 3, own axes) -> body-frame rates with the relative errors removed.

        Additive terms (angular-acceleration sensitivity, g-sensitivity, nonlinearity) are evaluated on the
        array-mean signals of a first pass (``specific_force`` (N, 3) is needed for g-sensitivity).
        """
        t = np.asarray(t, dtype=float)
        z = self.layout.to_body(np.asarray(gyro, dtype=float))
        u = _compensate(t, z, self.gain, self.bias_rad_s, self.sampling_offset_s, {}, None)
        if not self.extra:
            return u
        if "g_sensitivity" in self.extra and specific_force is None:
            raise IdentifiabilityError("this calibration has a g_sensitivity term: pass specific_force (N, 3)",
                                       parameters=["g_sensitivity"])
        sig = _signals(t, u, self.sigma_rad_s, specific_force)
        return _compensate(t, z, self.gain, self.bias_rad_s, self.sampling_offset_s, self.extra, sig)

    def to_dict(self) -> dict:
        """Plain dictionary (JSON-ready): body-frame parameters and standard deviations, SI units."""
        return {"type": "rimu.array.RelativeFit", "version": 1, "triads": list(self.layout.names),
                "terms": list(self.terms), "labels": list(self.labels),
                "gain": self.gain.tolist(), "bias_rad_s": self.bias_rad_s.tolist(),
                "sampling_offset_s": self.sampling_offset_s.tolist(),
                "extra": {k: v.tolist() for k, v in self.extra.items()},
                "std": self.std().tolist(), "sigma_rad_s": self.sigma_rad_s.tolist(),
                "parity_rms_rad_s": {k: v.tolist() for k, v in self.parity_rms_rad_s.items()},
                "limiting_term": self.limiting_term(), "candidates": [c.to_dict() for c in self.candidates],
                "iterations": self.iterations, "converged": self.converged,
                "gauge": "relative to the plain array mean: mean gain I, mean bias 0, mean offset 0"}

    def triad_frame(self) -> dict[str, np.ndarray]:
        """Gain, bias and g-sensitivity in each triad's own axes (``R^T X R``)."""
        R = self.layout.rotations
        out = {"gain": np.einsum("kji,kjl,klm->kim", R, self.gain, R),
               "bias_rad_s": np.einsum("kji,kj->ki", R, self.bias_rad_s)}
        return out

    def table(self) -> str:
        """Per triad: relative scale [ppm], misalignment [arcsec], bias [deg/h], offset [us], noise [deg/s]."""
        g = self.triad_frame()
        F = g["gain"] - np.eye(3)
        sd = self.std()
        lines = [f"{'triad':>6} {'scale x/y/z [ppm]':>26} {'max misal. [arcsec]':>20} {'bias x/y/z [deg/h]':>28}"
                 f" {'tau [us]':>16} {'noise [deg/s]':>14}"]
        ti = self.labels.index("tau") if "tau" in self.labels else None
        for j, name in enumerate(self.layout.names):
            sc = np.diag(F[j]) * 1e6
            mis = np.abs(F[j] - np.diag(np.diag(F[j]))).max() * RAD_TO_ARCSEC
            b = g["bias_rad_s"][j] * RS_TO_DH
            tau = f"{self.sampling_offset_s[j] * 1e6:8.1f}+-{sd[j, ti] * 1e6:5.1f}" if ti is not None else "-"
            lines.append(f"{name:>6} {sc[0]:8.0f} {sc[1]:8.0f} {sc[2]:8.0f} {mis:20.0f} {b[0]:9.0f} {b[1]:9.0f} "
                         f"{b[2]:9.0f} {tau:>16} {self.sigma_rad_s[j] * RAD_TO_DEG:14.4f}")
        return "\n".join(lines)


def _compensate(t, z, gain, bias, tau, extra, signals) -> np.ndarray:
    k = z.shape[1]
    u = np.empty_like(z)
    Ginv = np.linalg.inv(gain)
    cols = {}
    if signals is not None:
        for name in extra:
            cols[name] = GYRO_TERMS[name].columns(signals)
    for j in range(k):
        zj = time_shift(t, z[:, j], -tau[j])
        add = bias[j]
        for name, th in extra.items():
            if name in cols:
                add = add + cols[name] @ th[j]
        u[:, j] = (zj - add) @ Ginv[j].T
    return u


def _noise_from_differences(y: np.ndarray) -> np.ndarray:
    """White-noise sigma per triad from second differences of its difference from the array mean."""
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    v = np.median(np.abs(d2), axis=(0, 2)) / 0.6745
    return np.maximum(v / np.sqrt(6.0), 1e-12)


def _sigma_from_residual_var(v: np.ndarray) -> np.ndarray:
    """Triad noise from the variance of (triad - weighted mean): v_j = s_j^2 - 1/sum(1/s^2); fixed point."""
    s2 = v.copy()
    for _ in range(50):
        h = 1 / np.sum(1 / s2)
        s2 = np.maximum(v + h, 1e-30)
    return np.sqrt(s2)


def _check_identifiable(terms: Sequence[Term], S: np.ndarray, sigma: float, sig: Signals) -> None:
    sizes = [t.n_cols for t in terms]
    idx = np.cumsum([0] + sizes)
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    Sn = S / np.outer(d, d)
    ev, V = np.linalg.eigh(Sn)
    bad = []
    if ev[0] < 1e-10 * ev[-1]:
        # which terms carry the null directions
        null = V[:, ev < 1e-10 * ev[-1]]
        for i, t in enumerate(terms):
            if np.linalg.norm(null[idx[i]:idx[i + 1]]) > 0.3:
                bad.append(t)
    else:
        Sinv = np.linalg.inv(S)
        sd = sigma * np.sqrt(np.diag(Sinv))
        for i, t in enumerate(terms):
            if np.any(sd[idx[i]:idx[i + 1]] > _MAX_SIGMA.get(t.name, np.inf)):
                bad.append(t)
    if bad:
        msg = "; ".join(f"{t.name} needs {t.excitation_report(sig)}" for t in bad)
        raise IdentifiabilityError(f"the motion cannot identify {', '.join(t.name for t in bad)}: {msg}; "
                                   "record more of that motion or leave the term out",
                                   parameters=[t.name for t in bad])


def _signals(t, u, sigma, specific_force) -> Signals:
    # plain mean: the estimates centred on it do not depend on the weights (see RelativeFit.covariance), and a
    # triad with coloured (vibration) residuals does not drag the reference
    w = u.mean(axis=1)
    return Signals(w, derivative(t, w), specific_force)


def fit_relative_gyro(
    layout: ArrayLayout, t: np.ndarray, gyro: np.ndarray, terms: Sequence[str] = BASE_TERMS,
    specific_force: "np.ndarray | None" = None, candidates: "Sequence[str] | None" = CANDIDATE_TERMS,
    motion_threshold_deg_s: float = 30.0, max_iter: int = 30,
) -> RelativeFit:
    """Relative calibration of the gyro triads from a recording with motion.

    Parameters
    ----------
    layout : ArrayLayout
        Triad rotations (positions are not needed for the gyros).
    t : ndarray (N,)
        Sample times [s], increasing.
    gyro : ndarray (N, k, 3)
        Raw gyro outputs in each triad's own axes [rad/s].
    terms : sequence of str
        Terms to estimate: ``scale_misalignment`` and ``bias`` always, plus any of ``sampling_offset``,
        ``aa_sensitivity``, ``g_sensitivity``, ``rate_nonlinearity``.
    specific_force : ndarray (N, 3), optional
        The array's specific force (body frame), needed by ``g_sensitivity``.
    candidates : sequence of str, optional
        Terms to test against the fitted model (the missing-term ranking); None to skip.
    motion_threshold_deg_s : float
        Samples with a larger array rate count as "in motion" for the parity rms figures.

    Returns
    -------
    RelativeFit

    Raises
    ------
    IdentifiabilityError
        The motion cannot identify a requested term; the message names the excitation it needs.
    ShapeError, NonFiniteError
        Bad input.
    """
    t = np.asarray(t, dtype=float)
    z = layout.to_body(np.asarray(gyro, dtype=float))
    N, k = z.shape[:2]
    if t.shape != (N,) or np.any(np.diff(t) <= 0):
        raise ShapeError(f"t must be ({N},) and strictly increasing")
    if not np.all(np.isfinite(z)):
        bad = np.argwhere(~np.isfinite(z).all(axis=2))
        raise NonFiniteError(f"{len(bad)} triad samples are not finite (first: sample {bad[0, 0]}, triad "
                             f"{layout.names[bad[0, 1]]}); cut them out or interpolate before calibrating")
    terms = tuple(dict.fromkeys(list(BASE_TERMS) + [x for x in terms if x not in BASE_TERMS]))
    for x in terms:
        if x not in GYRO_TERMS:
            raise ShapeError(f"unknown term {x!r}; known: {', '.join(GYRO_TERMS)}")
    if "g_sensitivity" in terms and specific_force is None:
        raise IdentifiabilityError("g_sensitivity needs the array's specific force: pass specific_force (N, 3)",
                                   parameters=["g_sensitivity"])
    T = [GYRO_TERMS[x] for x in terms]
    labels = tuple(lbl for tt in T for lbl in tt.labels)
    P = len(labels)
    gain = np.repeat(np.eye(3)[None], k, axis=0)
    bias = np.zeros((k, 3))
    tau = np.zeros(k)
    extra = {x: np.zeros((k, GYRO_TERMS[x].n_cols)) for x in terms if x not in ("scale_misalignment", "bias",
                                                                                  "sampling_offset")}
    sigma = _noise_from_differences(z - z.mean(axis=1, keepdims=True))
    dt_max = float(np.max(np.diff(t)))
    sig = _signals(t, z, sigma, specific_force)
    before = _parity_rms(z, sigma, sig.omega, motion_threshold_deg_s)
    it = 0
    u = _compensate(t, z, gain, bias, tau, extra, None)
    sig = _signals(t, u, sigma, specific_force)
    converged = False
    for it in range(1, max_iter + 1):
        m = int(np.ceil(np.abs(tau).max() / dt_max)) + 3
        use = slice(m, N - m)
        X = np.concatenate([tt.columns(sig) for tt in T], axis=2)[use]
        y = (u - sig.omega[:, None, :])[use]
        S = np.einsum("nap,naq->pq", X, X)
        if it == 1:
            _check_identifiable(T, S, float(np.sqrt(np.mean(sigma**2))), sig)
        Sinv = np.linalg.inv(S)
        b = np.einsum("nap,nka->kp", X, y)
        th = b @ Sinv.T
        rss = np.einsum("nka,nka->k", y, y) - np.einsum("kp,kp->k", b, th)
        n_used = y.shape[0]
        sigma = _sigma_from_residual_var(rss / (3 * n_used - P))
        sd = np.sqrt(np.diag(Sinv))[None] * sigma[:, None]
        if np.all(np.abs(th) <= 0.02 * sd):
            converged = True
            break
        # compose, with backtracking on the parity criterion: the linearised step can overshoot when the
        # recording barely excites a term (large offsets, vibration-dominated rates)
        j_old = _criterion(u, use)
        lam = 1.0
        for _ in range(8):
            cand = _compose(T, th * lam, gain, bias, tau, extra)
            u_new = _compensate(t, z, *cand, sig if extra else None)
            if _criterion(u_new, use) <= j_old * (1 + 1e-9):
                break
            lam *= 0.5
        else:
            converged = True   # no step lowers the criterion: as far as the data goes
            break
        gain, bias, tau, extra = cand
        u = u_new
        sig = _signals(t, u, sigma, specific_force)
        if extra:
            u = _compensate(t, z, gain, bias, tau, extra, sig)
            sig = _signals(t, u, sigma, specific_force)
    D, c, tau, _ = to_array_gauge(gain, bias, tau)
    _check_mounting(layout, D)
    # additive terms: centred (their common mode times the array-mean gain is second order)
    extra = {n: v - v.mean(axis=0) for n, v in extra.items()}
    u = _compensate(t, z, D, c, tau, extra, sig if extra else None)
    sig = _signals(t, u, sigma, specific_force)
    after = _parity_rms(u, sigma, sig.omega, motion_threshold_deg_s)
    fit = RelativeFit(layout, terms, D, c, tau, extra, sigma, Sinv, labels, {"before": before, "after": after}, it,
                      n_used=n_used, converged=converged)
    if candidates:
        fit.candidates = rank_candidates(fit, t, u, sig, [x for x in candidates if x not in terms])
    return fit


#: A relative gain this far from I (Frobenius norm) is a mounting error, not a calibration
_MAX_RELATIVE_GAIN = 0.3


def _check_mounting(layout: ArrayLayout, D: np.ndarray) -> None:
    """Refuse relative gains that are really a wrong rotation (or sign) of a triad in the layout.

    The gains are compared with their element-wise median over the triads (robust: one wrong triad drags the
    array mean, not the median)."""
    D = D @ np.linalg.inv(np.median(D, axis=0))
    dev = np.linalg.norm(D - np.eye(3), axis=(1, 2))
    bad = np.flatnonzero(dev > _MAX_RELATIVE_GAIN)
    if not bad.size:
        return
    parts = []
    for j in bad[:4]:
        U, sv, Vt = np.linalg.svd(D[j])
        Q = U @ Vt
        if np.linalg.det(Q) < 0:
            parts.append(f"{layout.names[j]}: its axes are a reflection of the array's (a sign flipped), "
                         f"scale {sv.mean():.3g}")
            continue
        ang = np.degrees(np.arccos(np.clip((np.trace(Q) - 1) / 2, -1, 1)))
        ev, V = np.linalg.eig(Q)
        ax = np.real(V[:, np.argmin(np.abs(ev - 1))])
        ax = ax * np.sign(ax[np.argmax(np.abs(ax))])
        parts.append(f"{layout.names[j]}: turned {ang:.0f} deg about body [{ax[0]:+.2f} {ax[1]:+.2f} {ax[2]:+.2f}] "
                     f"from the array, scale {sv.mean():.3g}")
    raise GeometryError(
        f"{bad.size} triad(s) disagree with the array by more than a calibration can: " + "; ".join(parts)
        + ". Check their rotations in the layout (triad axes -> body) and that every gyro is in rad/s"
    )


def _criterion(u: np.ndarray, use: slice) -> float:
    """The parity criterion: every triad's squared difference from the array mean, summed."""
    y = u[use] - u[use].mean(axis=1, keepdims=True)
    return float(np.einsum("nka,nka->", y, y))


def _compose(T, th, gain, bias, tau, extra):
    """Apply a regression step ``th`` (k, P) to the parameters (exact composition of gain, bias and offset)."""
    k = gain.shape[0]
    pos = 0
    gain_new, bias_new, tau_new, extra_new = gain, bias, tau, dict(extra)
    for tt in T:
        d = th[:, pos:pos + tt.n_cols]
        pos += tt.n_cols
        if tt.name == "scale_misalignment":
            gain_new = gain @ (np.eye(3) + d.reshape(k, 3, 3))
        elif tt.name == "bias":
            bias_new = bias + np.einsum("kij,kj->ki", gain, d)
        elif tt.name == "sampling_offset":
            tau_new = tau + d[:, 0]
        else:
            extra_new[tt.name] = extra[tt.name] + d
    return gain_new, bias_new, tau_new, extra_new


def _parity_rms(u: np.ndarray, sigma: np.ndarray, omega: np.ndarray, thr_deg_s: float) -> np.ndarray:
    moving = np.linalg.norm(omega, axis=1) > np.radians(thr_deg_s)
    if moving.sum() < 10:
        moving = np.ones(len(omega), bool)
    y = u[moving] - u[moving].mean(axis=1, keepdims=True)   # plain mean: the same yardstick before and after
    return np.sqrt(np.mean(y**2, axis=(0, 2)))


def rank_candidates(fit: RelativeFit, t: np.ndarray, u: np.ndarray, sig: Signals, names: Sequence[str],
                    ) -> list[CandidateScore]:
    """Nested F-test of every candidate term on the parity residual of ``fit`` (compensated rates ``u``).

    For candidate columns ``X_c`` the test uses their part orthogonal to the model's columns ``X``; the
    residual sum of squares it removes, summed over triads weighted by their noise, against the remaining one:
    ``F = (dRSS / (p_c (k-1))) / ((RSS - dRSS) / ((k-1)(3N - P - p_c)))``. Ranked by the share of the residual
    each explains (what limits the agreement first), with the F-test's p-value.
    """
    k = fit.layout.k
    T = [GYRO_TERMS[x] for x in fit.terms]
    m = int(np.ceil(np.abs(fit.sampling_offset_s).max() / np.max(np.diff(t)))) + 3
    use = slice(m, len(t) - m)
    X = np.concatenate([tt.columns(sig) for tt in T], axis=2)[use]
    y = (u - sig.omega[:, None, :])[use]
    n = y.shape[0]
    S = np.einsum("nap,naq->pq", X, X)
    Sinv = np.linalg.inv(S)
    w = 1 / fit.sigma_rad_s**2
    b = np.einsum("nap,nka->kp", X, y)
    rss_j = np.einsum("nka,nka->k", y, y) - np.einsum("kp,pq,kq->k", b, Sinv, b)
    rss_w = float(np.sum(w * rss_j))
    P = X.shape[2]
    out = []
    for name in names:
        tt = GYRO_TERMS[name]
        if name == "g_sensitivity" and sig.specific_force is None:
            continue
        Xc = tt.columns(sig)[use]
        Sc = np.einsum("nap,naq->pq", Xc, Xc) - np.einsum("nap,naq->pq", Xc, X) @ Sinv @ np.einsum(
            "nap,naq->pq", X, Xc)
        bc = np.einsum("nap,nka->kp", Xc, y) - b @ Sinv @ np.einsum("nap,naq->pq", X, Xc)
        ev = np.linalg.eigvalsh(Sc)
        ok = bool(ev[0] > 1e-9 * max(ev[-1], 1e-300))
        d_j = np.einsum("kp,pq,kq->k", bc, np.linalg.pinv(Sc), bc)
        d_w = float(np.sum(w * d_j))
        pc = tt.n_cols
        dof2 = (k - 1) * (3 * n - P - pc)
        F = (d_w / (pc * (k - 1))) / max((rss_w - d_w) / dof2, 1e-300)
        lp = float(stats.f.logsf(F, pc * (k - 1), dof2)) / np.log(10)
        out.append(CandidateScore(name, pc, float(F), lp, float(d_j.sum() / max(rss_j.sum(), 1e-300)), ok))
    out.sort(key=lambda c: (not c.significant, -c.explained))
    return out
