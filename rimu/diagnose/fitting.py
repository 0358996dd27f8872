"""Per-sensor least squares for diagnostics: the model's design, its residuals, and the columns of candidate
effects orthogonalised against it.

The raw-domain model of a sensor is linear (Cho & Park 2005, Eq. 5 extended by further columns, see
:mod:`rimu.calibration.model`), ``y = X beta + e``. Everything here works on one QR factorisation of the
model's (column-scaled) design per sensor: the fit, the residual, and for every candidate effect its columns
with the model's span projected out (``C_perp = C - Q Q^T C``), from which the nested F-tests, the
identifiability checks and the confounding tests follow without refitting.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..calibration.lsq import physical_from_beta, sensor_segments
from ..calibration.model import Effect, ErrorModel, ParamSpec, SensorContext, axes_from_w, contexts
from ..errors import IdentifiabilityError
from ..session import Segment, Session
from .series import autocorrelation

__all__ = [
    "RANK_TOL",
    "ModelFit",
    "calibrated_axes_of",
    "SensorFit",
    "cached",
    "candidate_columns",
    "candidate_design",
    "fit_model",
    "noise_from_differences",
    "noise_inflation",
    "noise_level",
    "within_segment",
]

class _CachedSegment(Segment):
    """A segment whose attitude history and inputs (the costly part of every column) are computed once."""

    def attitude(self) -> np.ndarray | None:
        c = self.__dict__.get("_att_cache", False)
        if c is False:
            c = Segment.attitude(self)
            self.__dict__["_att_cache"] = c
        return c

    def specific_force(self, gravity: float = 9.80665) -> np.ndarray | None:
        key = ("_f_cache", gravity)
        if key not in self.__dict__:
            self.__dict__[key] = Segment.specific_force(self, gravity)
        return self.__dict__[key]

    def earth_rate(self, latitude: float | None) -> np.ndarray | None:
        key = ("_we_cache", latitude)
        if key not in self.__dict__:
            self.__dict__[key] = Segment.earth_rate(self, latitude)
        return self.__dict__[key]

    def angular_rate(self, latitude: float | None = None, include_earth: bool = True) -> np.ndarray:
        # the gyros' input, asked for by every effect of every sensor: held once, read-only (shared)
        key = ("_w_cache", latitude, include_earth)
        if key not in self.__dict__:
            w = Segment.angular_rate(self, latitude, include_earth)
            w.flags.writeable = False
            self.__dict__[key] = w
        return self.__dict__[key]


def cached(session: Session) -> Session:
    """The same session with segments that compute their attitude history once (inputs of many effects
    for many sensors derive from it). The samples are shared, not copied."""
    if session.meta.get("_rimu_cached"):
        return session
    segs = []
    for seg in session.segments:
        c = copy.copy(seg)
        c.__class__ = _CachedSegment
        segs.append(c)
    meta = dict(session.meta)
    meta["_rimu_cached"] = True
    return Session(segs, dict(session.geometries), session.sample_rate, session.latitude, session.gravity,
                   session.raw_unit, meta)


#: relative singular-value tolerance below which columns count as linearly dependent
RANK_TOL = 1e-7


def within_segment(r: np.ndarray, seg_index: np.ndarray) -> np.ndarray:
    """The residual minus its mean on each segment (what no segment-constant error can explain)."""
    cnt = np.maximum(np.bincount(seg_index), 1)
    return r - (np.bincount(seg_index, weights=r) / cnt)[seg_index]


def noise_level(r: np.ndarray, seg_index: np.ndarray, within: np.ndarray | None = None) -> float:
    """White-noise level from the residual about its segment means: ``sum (r - mean_seg)^2 / (N - n_seg)``.

    Errors that are constant over a segment (most missing effects on static and constant-rate segments) do
    not enter; coloured noise is counted with its full variance (unlike first differences). ``within``: the
    residual's :func:`within_segment` part, when already computed.
    """
    w = within_segment(r, seg_index) if within is None else within
    nseg = int(np.count_nonzero(np.bincount(seg_index)))
    return float(np.sqrt((w @ w) / max(r.size - nseg, 1)))


def noise_inflation(r: np.ndarray, seg_index: np.ndarray, max_lag: int = 50,
                    within: np.ndarray | None = None) -> tuple[float, float]:
    """(variance inflation factor, lag-1 autocorrelation) of the within-segment residual.

    The factor is the long-run variance over the variance, ``1 + 2 sum_k (1 - k/(L+1)) rho_k`` (Bartlett
    weights, Newey & West 1987), computed only when the lag-1 autocorrelation is significant
    (``rho_1 sqrt(N) > 4``); else 1. Statistics built on averages of many samples are divided by it.
    """
    w = within_segment(r, seg_index) if within is None else within
    rho = autocorrelation(w, seg_index, 1)
    r1 = float(rho[0])
    if r1 * np.sqrt(r.size) <= 4.0:
        return 1.0, r1
    L = int(min(max_lag, max(r.size // 50, 1)))
    rho = autocorrelation(w, seg_index, L)
    k = np.arange(1, L + 1)
    c = 1.0 + 2.0 * float(np.sum((1 - k / (L + 1)) * rho))
    return max(c, 1.0), r1


def noise_from_differences(r: np.ndarray, seg_index: np.ndarray) -> float:
    """White-noise level from first differences within segments: ``sigma^2 = mean(diff(r)^2) / 2``.

    Slow systematic errors (a missing effect, constant over a segment or smooth in time) cancel in the
    differences, so the estimate does not depend on the model being complete. Relative variance of the
    variance estimate for white noise: 3 / N.
    """
    same = seg_index[1:] == seg_index[:-1]
    d = np.diff(r)[same]
    if d.size < 2:
        return float(np.std(r)) if r.size > 1 else 0.0
    return float(np.sqrt(np.mean(d**2) / 2.0))


@dataclass
class SensorFit:
    """The fit of one sensor and what diagnostics need of its data."""

    ctx: SensorContext
    names: list[str]
    beta: np.ndarray
    beta_cov: np.ndarray
    theta: np.ndarray
    theta_cov: np.ndarray
    specs: list[ParamSpec]
    y: np.ndarray = field(repr=False)
    X: np.ndarray = field(repr=False)
    Q: np.ndarray = field(repr=False)
    r: np.ndarray = field(repr=False)
    seg_index: np.ndarray = field(repr=False)
    t: np.ndarray = field(repr=False)
    temperature: np.ndarray | None = field(repr=False)
    axis_input: np.ndarray | None = field(repr=False)
    sigma: float = 1.0
    sigma_known: bool = False
    #: variance inflation of the noise for averages over many samples (1 + 2 sum of Bartlett-weighted
    #: within-segment autocorrelations; 1 for white noise): coloured noise makes segment means noisier
    inflation: float = 1.0
    lag1_within: float = 0.0
    #: scale factor SI/raw where the model has no scale block: from the declared raw unit (deg/s, g) or a
    #: calibration; None for counts without one (their residual then has no SI value)
    known_scale: float | None = None

    @property
    def name(self) -> str:
        return self.ctx.name

    @property
    def n_obs(self) -> int:
        return int(self.y.size)

    @property
    def n_par(self) -> int:
        return int(self.beta.size)

    @property
    def dof(self) -> int:
        return max(self.n_obs - self.n_par, 1)

    @property
    def rss(self) -> float:
        v = self.__dict__.get("_rss")
        if v is None:
            v = self.__dict__["_rss"] = float(self.r @ self.r)
        return v

    @property
    def scale(self) -> float | None:
        """Scale factor SI/raw: from the model's scale block, else :attr:`known_scale` (the declared raw unit or
        a calibration), else None (raw counts: no SI value)."""
        k = [i for i, nm in enumerate(self.names) if nm.endswith((".w_x", ".w_y", ".w_z"))]
        if len(k) == 3:
            return 1.0 / float(np.linalg.norm(self.beta[k]))
        return self.known_scale

    @property
    def chi2_dof(self) -> float:
        """Residual chi-square per degree of freedom against the noise level."""
        return float(self.rss / (self.sigma**2 * self.dof))

    def aic(self) -> float:
        """Akaike information criterion of the Gaussian fit with the variance profiled out."""
        n = self.n_obs
        return float(n * np.log(self.rss / n) + 2 * self.n_par)

    def bic(self) -> float:
        """Bayesian (Schwarz) information criterion, ``N ln(RSS/N) + p ln N``."""
        n = self.n_obs
        return float(n * np.log(self.rss / n) + self.n_par * np.log(n))

    def parameter(self, local: str) -> tuple[float, float, ParamSpec]:
        """(value SI, 1-sigma SI, spec) of a physical parameter by local name (``"gsens_x"``)."""
        names = [p.name for p in self.specs]
        if local not in names:
            raise KeyError(f"{self.name} has no parameter {local!r} in this model; parameters: {names}")
        k = names.index(local)
        return float(self.theta[k]), float(np.sqrt(self.theta_cov[k, k])), self.specs[k]


@dataclass
class ModelFit:
    """The fit of one model to one instrument of a session, sensor by sensor."""

    instrument: str
    model: ErrorModel
    sensors: list[SensorFit]
    segment_labels: list[str]
    skipped: dict[str, str]
    contexts: list[SensorContext]
    #: the contexts are on the calibrated axes of the model's own first fit (not given by the caller): a refit
    #: of the model plus further effects would find the same axes
    own_axes: bool = False
    #: the declared unit of the raw outputs ("count" unless the session says otherwise)
    raw_unit: str = "count"

    @property
    def chi2_dof(self) -> float:
        rss = sum(s.rss / s.sigma**2 for s in self.sensors)
        dof = sum(s.dof for s in self.sensors)
        return float(rss / dof)

    @property
    def bic(self) -> float:
        return float(sum(s.bic() for s in self.sensors))

    @property
    def aic(self) -> float:
        return float(sum(s.aic() for s in self.sensors))

    def rms_si(self) -> np.ndarray:
        """Residual rms per sensor in SI (raw residual times the scale factor; NaN where the scale is unknown)."""
        return np.array([np.sqrt(s.rss / s.n_obs) * (np.nan if s.scale is None else s.scale) for s in self.sensors])

    def display(self, unit: str | None = None) -> tuple[str, np.ndarray]:
        """(unit, factor per sensor from a raw residual to that unit) in which this fit's residuals are printed:
        the field unit that reads best (``rimu.units.field_unit``) when every sensor's scale factor is known,
        else the raw unit: counts are never shown as SI. ``unit`` forces a field unit (a comparison's)."""
        from ..units import FIELD_UNITS, field_unit

        scales = [s.scale for s in self.sensors]
        if any(sc is None for sc in scales) or not scales:
            return self.raw_unit, np.ones(len(scales))
        sc = np.abs(np.array(scales, dtype=float))
        if unit is None or unit == self.raw_unit:
            unit, f = field_unit(self.instrument, float(np.max(self.rms_raw() * sc)))
        else:
            f = dict(FIELD_UNITS["rate" if self.instrument == "gyro" else "specific_force"])[unit]
        return unit, sc * f

    def rms_raw(self) -> np.ndarray:
        """Residual rms per sensor in the raw unit (:attr:`raw_unit`)."""
        return np.array([np.sqrt(s.rss / s.n_obs) for s in self.sensors])

    def sensor(self, name: str) -> SensorFit:
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(f"no sensor {name!r}; sensors: {[s.name for s in self.sensors]}")


def _sigma_vector(sigma: float | Sequence[float] | None, n: int) -> np.ndarray | None:
    if sigma is None:
        return None
    out = np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(out)) or np.any(out <= 0):
        raise ValueError(f"noise sigma must be positive and finite, got {out}")
    return out


def fit_model(
    session: Session,
    model: ErrorModel,
    instrument: str,
    sigma: float | Sequence[float] | None = None,
    include_earth_rate: bool = True,
    reference_temperature: float = 25.0,
    ctxs: list[SensorContext] | None = None,
    _beta_only: bool = False,
    scale: float | Sequence[float] | None = None,
) -> ModelFit:
    """Least-squares fit of ``model`` to one instrument, keeping what the diagnostics need.

    The estimate is the same as :func:`rimu.calibration.lsq.fit_lsq` (ordinary least squares per sensor, the
    raw-domain model of Cho & Park 2005 Eq. 5 with further effect columns); this version also keeps the QR
    factor of the design, the residual per sample and the sample's segment, time, temperature and input.

    Parameters
    ----------
    sigma : float or sequence, optional
        Known white-noise level per sample, raw units, per sensor. Default: estimated from the residual about
        its segment means (:func:`noise_level`).
    include_earth_rate : bool
        Whether the gyros' known input includes the Earth rate (False to test the ``earth_rate`` effect).
    scale : float or sequence, optional
        Known scale factor SI/raw per sensor for a model without a scale block (a calibration's). Default: the
        factor of the session's declared raw unit (deg/s, g), none for counts (residuals then stay raw).

    Raises
    ------
    IdentifiabilityError
        No segment carries the inputs the model needs, or the usable segments cannot separate its parameters.
    """
    if instrument not in session.geometries:
        raise IdentifiabilityError(f"the session has no {instrument} data; instruments: {list(session.geometries)}")
    session = cached(session)
    own_axes = False
    if ctxs is None:
        ctxs = contexts(session, instrument, reference_temperature, include_earth_rate)
        own_axes = "scale_misalignment" in model
        if own_axes:
            # candidates and effects along an axis are evaluated on the calibrated axes (what each sensor really
            # senses), taken from a first fit of scale, misalignment and bias on the nominal ones
            base = ErrorModel([e for e in model if e.name in ("scale_misalignment", "bias")])
            # the model is the first fit's own (its design, the input and a constant, does not depend on the
            # axes): the first fit is the fit, only seen from the calibrated axes
            only_base = len(base.effects) == len(model.effects)
            first = fit_model(session, base if not only_base else model, instrument, sigma, include_earth_rate,
                              reference_temperature, ctxs, _beta_only=not only_base, scale=scale)
            ctxs = contexts(session, instrument, reference_temperature, include_earth_rate, calibrated_axes_of(first))
            if only_base:
                return _on_axes(session, first, ctxs)
    sig = _sigma_vector(sigma, len(ctxs))
    skipped: dict[str, str] = {}
    fits: list[SensorFit] = []
    labels_used: list[str] = []
    for ctx in ctxs:
        Xs, ys, idx, ts, Ts, ss, labels = [], [], [], [], [], [], []
        have_T = True
        for seg, X, y in sensor_segments(model, ctx, session.segments, instrument, skipped):
            Xs.append(X)
            ys.append(y)
            idx.append(np.full(seg.n_samples, len(labels)))
            ts.append(seg.t)
            if seg.temperature is None:
                have_T = False
            else:
                Ts.append(seg.temperature)
            u = ctx.input(seg)
            ss.append(np.full(seg.n_samples, np.nan) if u is None else np.asarray(u) @ ctx.axis)
            labels.append(seg.label)
        if not Xs:
            raise IdentifiabilityError(f"{instrument}: no segment of the session carries the inputs the model "
                                       f"{model.label} needs" + _skip_note(session, skipped))
        X = np.vstack(Xs)
        y = np.concatenate(ys)
        names = model.parameter_names(ctx)
        norms = np.linalg.norm(X, axis=0)
        if X.shape[0] <= X.shape[1] or np.any(norms == 0):
            bad = [names[k] for k in np.flatnonzero(norms == 0)]
            raise IdentifiabilityError(f"{instrument} {ctx.name}: the segments do not excite {bad or names}"
                                       + _skip_note(session, skipped), bad or names)
        Xn = X / norms
        Q, R = _orthonormalise(Xn)
        d = np.abs(np.diag(R))
        if d.min() < RANK_TOL * d.max():
            _, sv, Vt = np.linalg.svd(Xn, full_matrices=False)
            null = Vt[sv < RANK_TOL * sv[0]]
            involved = [names[k] for k in range(len(names)) if np.abs(null[:, k]).max() > 1e-6]
            raise IdentifiabilityError(
                f"{instrument} {ctx.name}: the segments cannot separate {involved} (linearly dependent columns); "
                "add segments whose inputs differ in the directions involved", involved)
        Rinv = np.linalg.inv(R)
        beta = (Rinv @ (Q.T @ y)) / norms
        if _beta_only:  # the first fit on the nominal axes: only beta is read (calibrated_axes_of); no residual
            none = np.empty(0)
            fits.append(SensorFit(ctx, names, beta, beta_cov=none, theta=none, theta_cov=none, specs=[], y=y, X=X,
                                  Q=Q, r=none, seg_index=none, t=none, temperature=None, axis_input=None))
            continue
        r = y - X @ beta
        seg_index = np.concatenate(idx)
        w = within_segment(r, seg_index)
        s_est = noise_level(r, seg_index, w)
        infl, rho1 = noise_inflation(r, seg_index, within=w)
        known = sig is not None
        s = float(sig[ctx.index]) if known else max(s_est, np.finfo(float).tiny)
        # covariance of beta: sigma^2 (X^T X)^-1 = sigma^2 D^-1 R^-1 R^-T D^-1 (D = column norms)
        B = Rinv / norms[:, None]
        s_par = s if known else float(np.sqrt((r @ r) / max(len(y) - len(beta), 1)))
        bcov = s_par**2 * (B @ B.T)
        theta, J, specs = physical_from_beta(model, ctx, beta)
        fits.append(SensorFit(ctx, names, beta, bcov, theta, J @ bcov @ J.T, specs, y, X, Q, r, seg_index,
                              np.concatenate(ts), np.concatenate(Ts) if have_T and Ts else None,
                              np.concatenate(ss), s, known, infl, rho1))
        labels_used = labels
    from ..session.checks import raw_unit_of
    from ..units import raw_to_si

    unit = raw_unit_of(session, instrument)
    known = _sigma_vector(scale, len(ctxs)) if scale is not None else None
    for s_fit in fits:
        s_fit.known_scale = float(known[s_fit.ctx.index]) if known is not None else raw_to_si(instrument, unit)
    return ModelFit(instrument, model, fits, labels_used, skipped, list(ctxs), own_axes, unit)


def _on_axes(session: Session, fit: ModelFit, ctxs: list[SensorContext]) -> ModelFit:
    """The same fit with its sensors' contexts on other axes: the physical parameters and the input along the
    axis follow the new axis; the design, estimate and residual do not depend on it (models of scale,
    misalignment and bias only)."""
    for s in fit.sensors:
        ctx = ctxs[s.ctx.index]
        theta, J, specs = physical_from_beta(fit.model, ctx, s.beta)
        ss = []
        for lab in fit.segment_labels:
            seg = session.segment(lab)
            u = ctx.input(seg)
            ss.append(np.full(seg.n_samples, np.nan) if u is None else np.asarray(u) @ ctx.axis)
        s.ctx, s.theta, s.theta_cov, s.specs, s.axis_input = ctx, theta, J @ s.beta_cov @ J.T, specs, np.concatenate(ss)
    fit.contexts, fit.own_axes = list(ctxs), True
    return fit


def calibrated_axes_of(fit: ModelFit) -> np.ndarray:
    """The calibrated axes (n, 3) in MB of a fit with the scale/misalignment block: a_i = w_i / |w_i|."""
    W = np.empty((len(fit.sensors), 3))
    for s in fit.sensors:
        W[s.ctx.index] = [s.beta[s.names.index(f"{s.name}.w_{a}")] for a in "xyz"]
    return axes_from_w(W)


def _orthonormalise(Xn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Thin QR of a column-scaled design: by Cholesky of the Gram matrix (two passes over the data) when it
    is well conditioned, else Householder QR."""
    G = Xn.T @ Xn
    try:
        L = np.linalg.cholesky(G)
    except np.linalg.LinAlgError:
        return np.linalg.qr(Xn)
    d = np.diag(L)
    if d.min() < 1e-4 * d.max():  # cond(Xn) > ~1e4: the Gram route would lose too many digits
        return np.linalg.qr(Xn)
    R = L.T
    Q = Xn @ np.linalg.inv(R)
    return Q, R


def _skip_note(session: Session, skipped: dict[str, str]) -> str:
    if not skipped:
        return ""
    kinds = sorted({session.segment(lab).kind for lab in skipped})
    note = f"; segments skipped: {', '.join(list(skipped)[:6])}{'...' if len(skipped) > 6 else ''} (kind {', '.join(kinds)})"
    if "angle" in kinds:
        note += (": 'angle' segments know only the total angle turned, not the rate sample by sample, so the "
                 "sample-level diagnostics cannot use them (an integrated-angle estimator can)")
    return note


def candidate_design(session: Session, fit: ModelFit, effects: Sequence[Effect],
                     sensor: int) -> tuple[np.ndarray, dict[str, slice], dict[str, str]]:
    """The shared design of one sensor's candidate effects, built in one pass over the segments the fit used.

    Returns ``(B, slices, reasons)``: the columns of every effect that applies to the sensor and can be built on
    every segment, side by side in one array B (N, K) (each column centred when the model has a bias, see
    below), their column slices by effect name, and for the applicable effects left out why. Effects that do
    not apply to the sensor are in neither.
    """
    ctx = fit.contexts[sensor]
    use = [e for e in effects if e.applies_to(ctx)]
    widths = [len(e.parameters(ctx)) for e in use]
    offs = np.concatenate([[0], np.cumsum(widths)]).astype(int)
    B = np.empty((fit.sensors[sensor].n_obs, int(offs[-1])), order="F")  # filled and reduced column by column
    missing: dict[str, list[str]] = {e.name: [] for e in use}
    row = 0
    for lab in fit.segment_labels:
        seg = session.segment(lab)
        n = seg.n_samples
        for e, a, b in zip(use, offs[:-1], offs[1:]):
            c = e.columns(seg, ctx)
            if c is None:
                missing[e.name].append(lab)
            else:
                B[row:row + n, a:b] = np.asarray(c, dtype=float).reshape(n, b - a)
        row += n
    reasons: dict[str, str] = {}
    slices: dict[str, slice] = {}
    keep: list[int] = []
    for e, a, b in zip(use, offs[:-1], offs[1:]):
        miss = missing[e.name]
        if miss:
            reasons[e.name] = (f"segments {miss[:4]}{'...' if len(miss) > 4 else ''} lack the inputs it needs"
                               if len(miss) < len(fit.segment_labels) else "no segment carries the inputs it needs")
            continue
        slices[e.name] = slice(len(keep), len(keep) + b - a)
        keep += range(a, b)
    if len(keep) < B.shape[1]:
        B = B[:, keep]
    if "bias" in fit.model:
        # a constant shift lies in the model's span (its bias column): removing the mean changes nothing
        # in the tests but keeps digits (time stamps far from zero, temperatures far from T_ref)
        B -= B.mean(axis=0)
    return B, slices, reasons


def candidate_columns(session: Session, fit: ModelFit, effect: Effect, sensor: int) -> tuple[np.ndarray | None, str]:
    """Columns of ``effect`` for one sensor over the segments the fit used, or (None, reason)."""
    ctx = fit.contexts[sensor]
    if not effect.applies_to(ctx):
        return None, f"does not apply to {fit.instrument} {ctx.name}"
    B, slices, reasons = candidate_design(session, fit, [effect], sensor)
    return (B, "") if effect.name in slices else (None, reasons[effect.name])
