"""What every estimator of rimu returns, and the pieces they share.

An estimator (:class:`~rimu.calibration.cho_park.ChoPark`, :class:`~rimu.calibration.oliveira.Oliveira`,
:class:`~rimu.calibration.zhang.Zhang`, :class:`LeastSquares`) stores its settings in its constructor and
does the work in ``fit(session)``, which returns a :class:`CalibrationResult`: one
:class:`~rimu.calibration.lsq.LsqResult` per instrument (per-sensor values, covariance, residuals per segment,
chi-square per degree of freedom), a coefficient table in the field's units, and
:meth:`CalibrationResult.to_calibration` for the versioned calibration file.

Everything here works on the raw-domain linear model of :mod:`rimu.calibration.model` (Cho & Park 2005,
Eq. 5): ``y_i = u . w_i + c_i + ...`` with ``SF_i = 1/|w_i|`` (Eq. 10).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError
from ..session import Segment, Session
from .lsq import (
    LsqResult,
    SensorFit,
    _check_identifiable,
    first_axes,
    on_calibrated_axes,
    physical_from_beta,
)
from .model import ErrorModel, SensorContext, contexts
from .result import Calibration, InstrumentCalibration

__all__ = [
    "CalibrationResult",
    "LeastSquares",
    "estimate_noise_sigma",
    "field_value",
    "make_sensor_fit",
    "segment_residuals",
]


def estimate_noise_sigma(session: Session, instrument: str) -> np.ndarray:
    """Per-sample white-noise standard deviation of each sensor's raw output (raw units).

    Pooled first-difference estimate ``var(y[k+1] - y[k]) / 2`` over the static segments (all segments if
    there is none): insensitive to the (slow) signal, exact for white noise.
    """
    segs = [s for s in session.segments if s.kind in ("static", "static_unknown")] or list(session.segments)
    n = session.geometries[instrument].n
    acc = np.zeros(n)
    cnt = 0
    for s in segs:
        y = s.raw[instrument]
        if y.shape[0] < 3:
            continue
        d = np.diff(y, axis=0)
        acc += np.sum((d - d.mean(axis=0)) ** 2, axis=0)
        cnt += d.shape[0] - 1
    if cnt == 0:
        raise IdentifiabilityError(f"{instrument}: no segment has enough samples to estimate the noise level")
    sig = np.sqrt(acc / cnt / 2.0)
    if np.any(sig <= 0):
        sig = np.where(sig > 0, sig, np.max(sig) if np.max(sig) > 0 else 1.0)
    return sig


def segment_residuals(model: ErrorModel, ctx: SensorContext, segments: Sequence[Segment], beta: np.ndarray,
                      instrument: str, cache: dict[str, np.ndarray | None] | None = None) -> dict[str, np.ndarray]:
    """Per-sample residuals ``y - X beta`` (raw units) of every segment whose inputs the model knows.

    For the base model (scale/misalignment + bias) the known input of a segment is the same for every sensor
    of an instrument; pass one ``cache`` dict for all sensors to compute it once per segment.
    """
    out: dict[str, np.ndarray] = {}
    base = [e.name for e in model.effects_for(ctx)] == ["scale_misalignment", "bias"]
    for seg in segments:
        if base and cache is not None:
            if seg.label not in cache:
                cache[seg.label] = _known_input(ctx, seg)
            u = cache[seg.label]
            if u is None:
                continue
            out[seg.label] = seg.raw[instrument][:, ctx.index] - (u @ beta[:3] + beta[3])
            continue
        X = model.design(seg, ctx)
        if X is None:
            continue
        out[seg.label] = seg.raw[instrument][:, ctx.index] - X @ beta
    return out


def _known_input(ctx: SensorContext, seg: Segment) -> np.ndarray | None:
    """``ctx.input(seg)``, without building a rotation matrix per sample when the segment is static."""
    if seg.kind == "static" and not np.any(seg.table_rate()):
        if ctx.instrument == "gyro":
            if seg.mat_ln_mb is not None and ctx.latitude is not None:
                from ..session import earth_rate_ln

                return np.broadcast_to(seg.mat_ln_mb.T @ earth_rate_ln(ctx.latitude), (seg.n_samples, 3))
            return np.zeros((seg.n_samples, 3))
        if seg.specific_force_mb is None and seg.mat_ln_mb is not None:
            return np.broadcast_to(seg.mat_ln_mb.T @ np.array([0.0, 0.0, ctx.gravity]), (seg.n_samples, 3))
    return ctx.input(seg)


def make_sensor_fit(model: ErrorModel, ctx: SensorContext, beta: np.ndarray, beta_cov: np.ndarray, sigma: float,
                    sigma_known: bool, n_obs: int, chi2: float, residuals: dict[str, np.ndarray]) -> SensorFit:
    """A :class:`SensorFit` from raw-domain coefficients and their covariance (physical values by the Jacobian
    of :func:`~rimu.calibration.lsq.physical_from_beta`). ``chi2`` is the weighted residual sum of squares in
    units of the noise variance."""
    theta, J, specs = physical_from_beta(model, ctx, beta)
    names = model.parameter_names(ctx)
    return SensorFit(ctx, names, np.asarray(beta, float), np.asarray(beta_cov, float),
                     [f"{ctx.name}.{p.name}" for p in specs], specs, theta, J @ beta_cov @ J.T, float(sigma),
                     sigma_known, int(n_obs), float(chi2) * float(sigma) ** 2, residuals)


def field_value(name: str, value: float, std: float, spec_unit: str, to_report: float) -> tuple[float, float, str]:
    """(value, std, unit) in the field's units. Scale factors are reported as a value in SI and a relative
    standard deviation in ppm."""
    if name.endswith(".scale"):
        return value, abs(std / value) * 1e6, "ppm"
    return value * to_report, std * to_report, spec_unit


@dataclass
class CalibrationResult:
    """Result of an estimator's ``fit``.

    Attributes
    ----------
    method : str
        Which estimator and paper.
    instruments : dict[str, LsqResult]
        Per instrument: per-sensor values, covariance, residuals per segment, chi-square per dof.
    raw_unit : str
    notes : list of str
        What the estimator did that a user should know (Earth rate subtracted or not, segments skipped, ...).
    extra : dict
        Method-specific results (e.g. Zhang's inter-triad misalignment, de Oliveira's parity check).
    """

    method: str
    instruments: dict[str, LsqResult]
    raw_unit: str = "count"
    notes: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, instrument: str) -> LsqResult:
        return self.instruments[instrument]

    @property
    def chi2_dof(self) -> dict[str, float]:
        """Residual chi-square per degree of freedom against the noise level, per instrument."""
        return {k: r.chi2_dof for k, r in self.instruments.items()}

    def values(self, instrument: str) -> dict[str, float]:
        """Physical parameter values (SI) by name."""
        return {n: float(v) for s in self.instruments[instrument].sensors for n, v in zip(s.theta_names, s.theta)}

    def covariance(self, instrument: str) -> tuple[list[str], np.ndarray]:
        """(names, covariance) of the physical parameters (SI), block diagonal over sensors."""
        r = self.instruments[instrument]
        names = [n for s in r.sensors for n in s.theta_names]
        p = len(names)
        C = np.zeros((p, p))
        k = 0
        for s in r.sensors:
            m = len(s.theta_names)
            C[k:k + m, k:k + m] = s.theta_cov
            k += m
        return names, C

    def std(self, instrument: str) -> dict[str, float]:
        """Standard deviations (SI) by name."""
        return {n: float(np.sqrt(max(s.theta_cov[i, i], 0.0))) for s in self.instruments[instrument].sensors
                for i, n in enumerate(s.theta_names)}

    def std_field(self, instrument: str) -> dict[str, tuple[float, str]]:
        """Standard deviations in the field's units: ppm (scale, relative), arcsec, micro-g, deg/h."""
        out = {}
        for s in self.instruments[instrument].sensors:
            for i, (n, sp) in enumerate(zip(s.theta_names, s.theta_specs)):
                _, sd, unit = field_value(n, s.theta[i], np.sqrt(max(s.theta_cov[i, i], 0.0)), sp.report_unit,
                                          sp.to_report)
                out[n] = (sd, unit)
        return out

    def residuals(self, instrument: str) -> dict[str, dict[str, np.ndarray]]:
        """Residuals (raw units) per segment label, per sensor name."""
        out: dict[str, dict[str, np.ndarray]] = {}
        for s in self.instruments[instrument].sensors:
            for lab, r in s.residuals.items():
                out.setdefault(lab, {})[s.name] = r
        return out

    def to_calibration(self) -> Calibration:
        """An :class:`~rimu.calibration.result.Calibration` with the covariance of every instrument."""
        insts: dict[str, InstrumentCalibration] = {k: r.to_calibration() for k, r in self.instruments.items()}
        meta = {"chi2_dof": self.chi2_dof, "notes": list(self.notes)}
        for k, v in self.extra.items():
            try:
                meta[k] = _jsonable(v)
            except TypeError:
                pass
        return Calibration(insts, raw_unit=self.raw_unit, method=self.method, metadata=meta)

    def table(self) -> str:
        """A readable coefficient table with standard deviations in the field's units."""
        lines = [f"calibration by {self.method}"]
        for inst, r in self.instruments.items():
            lines.append(f"\n{inst}: chi2/dof = {r.chi2_dof:.3f}")
            lines.append(f"  {'parameter':<16} {'value':>16} {'std':>12}  unit")
            for s in r.sensors:
                for i, (n, sp) in enumerate(zip(s.theta_names, s.theta_specs)):
                    v, sd, unit = field_value(n, s.theta[i], np.sqrt(max(s.theta_cov[i, i], 0.0)), sp.report_unit,
                                              sp.to_report)
                    vs = f"{v:.8g}" if n.endswith(".scale") else f"{v:.4f}"
                    unit_s = f"{sp.unit} (std ppm)" if n.endswith(".scale") else unit
                    lines.append(f"  {n:<16} {vs:>16} {sd:>12.4g}  {unit_s}")
        for note in self.notes:
            lines.append(f"note: {note}")
        return "\n".join(lines)


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    raise TypeError(type(v))


# ---------------------------------------------------------------------- generic least squares
class LeastSquares:
    """Generic least squares on an effect model, per sensor, weighted by the noise level.

    Per-sample rows for every segment whose inputs the model knows (``y = X beta``, the raw-domain model of
    Cho & Park 2005, Eq. 5, extended by further effects); for segments of kind ``"angle"`` (a known total
    rotation with unknown rate profile: Zhang et al. 2010, Eq. 16-17; hand turns) one integrated row
    ``integral(y) dt = w . angle + c T`` weighted by its noise ``sigma sqrt(N) dt`` (only with the base
    effects, whose columns integrate to the angle and the duration).

    Parameters
    ----------
    model : ErrorModel, optional
        Default: scale/misalignment + bias.
    sigma : dict[str, float or array], optional
        Known per-sample noise (raw units) per instrument; default from :func:`estimate_noise_sigma`.
    instruments : sequence of str, optional
        Default: every instrument of the session.
    segments : sequence of str, optional
        Labels of the segments to use (default all).
    """

    method = "lsq"

    def __init__(self, model: ErrorModel | None = None, sigma: dict[str, Any] | None = None,
                 instruments: Sequence[str] | None = None, segments: Sequence[str] | None = None) -> None:
        self.model = model
        self.sigma = sigma
        self.instruments = instruments
        self.segments = segments

    def fit(self, session: Session) -> CalibrationResult:
        """Fit every instrument. Raises IdentifiabilityError naming what the segments cannot identify."""
        model = self.model or ErrorModel.base()
        insts = list(self.instruments or session.instruments)
        segs = [session.segment(x) for x in self.segments] if self.segments is not None else list(session.segments)
        base_only = all(e.name in ("bias", "scale_misalignment") for e in model.effects)
        out: dict[str, LsqResult] = {}
        notes: list[str] = []
        for inst in insts:
            sig = _sigma_for(self.sigma, session, inst)
            fits = []
            skipped: dict[str, str] = {}
            cache: dict[str, np.ndarray | None] = {}
            base = [e.name for e in model.effects] == ["scale_misalignment", "bias"]
            axes = None
            if on_calibrated_axes(model):  # effects along an axis act on the calibrated axis: fit them there
                axes = first_axes(session, model, inst, segs, sig)
            for ctx in contexts(session, inst, axes=axes):
                Xs, ys, labels = [], [], []
                for seg in segs:
                    if base:  # the known input is the same for every sensor of the instrument: compute it once
                        if seg.label not in cache:
                            cache[seg.label] = _known_input(ctx, seg)
                        u = cache[seg.label]
                        X = None if u is None else np.column_stack([u, np.ones(seg.n_samples)])
                    else:
                        X = model.design(seg, ctx)
                    y = seg.raw[inst][:, ctx.index]
                    if X is not None:
                        Xs.append(X)
                        ys.append(y)
                        labels.append(seg.label)
                    elif seg.kind == "angle" and inst == "gyro" and base_only and seg.n_samples > 1:
                        Xs.append(_angle_row(seg, model, ctx))
                        ys.append(np.array([y.sum() / np.sqrt(seg.n_samples)]))
                        labels.append(seg.label)
                    else:
                        skipped[seg.label] = "the segment lacks inputs an effect needs (known rate, attitude or angle)"
                if not Xs:
                    raise IdentifiabilityError(f"{inst}: no segment carries the inputs the model {model.label} needs",
                                               model.parameter_names(ctx))
                X = np.vstack(Xs)
                y = np.concatenate(ys)
                names = model.parameter_names(ctx)
                try:
                    _check_identifiable(X, names, inst)
                except IdentifiabilityError as exc:
                    raise IdentifiabilityError(str(exc), _physical_names(model, ctx, exc.parameters)) from None
                beta, *_ = np.linalg.lstsq(X, y, rcond=None)
                r = y - X @ beta
                s = float(sig[ctx.index])
                cov = s**2 * np.linalg.inv(X.T @ X)
                res, k = {}, 0
                for lab, yy in zip(labels, ys):
                    res[lab] = r[k:k + len(yy)]
                    k += len(yy)
                fits.append(make_sensor_fit(model, ctx, beta, cov, s, self.sigma is not None, len(y),
                                            float(r @ r) / s**2, res))
            out[inst] = LsqResult(inst, model, fits, [x.label for x in segs if x.label not in skipped], skipped)
            if skipped:
                notes.append(f"{inst}: segments not used: {sorted(skipped)}")
        return CalibrationResult(f"least squares ({model.label})", out, session.raw_unit, notes)


def _physical_names(model: ErrorModel, ctx: SensorContext, raw_names: Sequence[str]) -> list[str]:
    """Physical parameter names for raw-domain ones: an involved axis coefficient ``w_*`` means the scale factor
    and both misalignment angles; every other effect's parameters keep their names."""
    out: list[str] = []
    for n in raw_names:
        local = n.split(".", 1)[1] if "." in n else n
        if local.startswith("w_"):
            _, mis = ctx.geometry.off_axis_basis(ctx.index)
            for x in ("scale", *mis):
                if f"{ctx.name}.{x}" not in out:
                    out.append(f"{ctx.name}.{x}")
        elif n not in out:
            out.append(n)
    return out


def _angle_row(seg: Segment, model: ErrorModel, ctx: SensorContext) -> np.ndarray:
    """The integrated row of an 'angle' segment for the base effects, scaled to the per-sample noise."""
    dt = seg.duration / (seg.n_samples - 1)
    row = []
    for e in model.effects_for(ctx):
        if e.name == "scale_misalignment":
            row += list(np.asarray(seg.angle_mb, float).reshape(-1, 3)[-1] if seg.angle_mb.ndim == 2 else seg.angle_mb)
        elif e.name == "bias":
            row.append(seg.n_samples * dt)
    return np.array(row)[None, :] / (dt * np.sqrt(seg.n_samples))


def _sigma_for(sigma: dict[str, Any] | None, session: Session, inst: str) -> np.ndarray:
    n = session.geometries[inst].n
    if sigma is not None and inst in sigma and sigma[inst] is not None:
        return np.broadcast_to(np.asarray(sigma[inst], dtype=float), (n,)).copy()
    return estimate_noise_sigma(session, inst)
