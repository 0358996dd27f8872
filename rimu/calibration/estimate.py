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

import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from .._backend import import_once
from .._backend import resolve_loaded as _resolve_loaded
from ..errors import IdentifiabilityError
from ..session import Segment, Session, SessionStatistics
from ..units import raw_unit_for, scale_unit
from .lsq import (
    BaseArrays,
    LazyResiduals,
    LsqResult,
    SensorFit,
    check_identifiable_gram,
    first_axes,
    on_calibrated_axes,
    physical_from_beta,
    rss_from_statistics,
)
from .model import ErrorModel, SensorContext, contexts
from .result import Calibration, InstrumentCalibration

__all__ = [
    "CalibrationResult",
    "LeastSquares",
    "estimate_noise_sigma",
    "bias_magnitudes",
    "field_value",
    "make_sensor_fit",
    "segment_residuals",
]


def estimate_noise_sigma(session: Session, instrument: str, stats: SessionStatistics | None = None) -> np.ndarray:
    """Per-sample white-noise standard deviation of each sensor's raw output (raw units).

    Pooled first-difference estimate ``var(y[k+1] - y[k]) / 2`` over the static segments (all segments if
    there is none): insensitive to the (slow) signal, exact for white noise. ``stats``: the fit's
    :class:`~rimu.session.SessionStatistics` (whose first-difference sums are then shared), default a new one.
    """
    stats = stats or SessionStatistics(session)
    # each segment's sum of squared deviations of the differences from their mean (y[-1] - y[0]) / m, with the
    # sums and squares the fit reads next (one pass, or a few numpy calls for all short segments together)
    return _noise_sigma_from(stats.sums_of(_noise_segments(session), instrument, full=True),
                             session.geometries[instrument].n, instrument)


def _noise_sigma_from(sums: Sequence[Any], n: int, instrument: str) -> np.ndarray:
    """:func:`estimate_noise_sigma` from the :class:`~rimu.session.SegmentSums` of its segments."""
    parts = [st.diff for st in sums]
    used = [ss for ss, dof in parts if dof]
    cnt = sum(dof for _, dof in parts)
    if cnt == 0:
        raise IdentifiabilityError(f"{instrument}: no segment has enough samples to estimate the noise level")
    acc = np.add.reduce(np.array(used), axis=0)  # row by row: the segments' sums added in turn
    sig = np.sqrt(acc / cnt / 2.0)
    if np.logical_or.reduce(sig <= 0):
        sig = np.where(sig > 0, sig, np.max(sig) if np.max(sig) > 0 else 1.0)
    return sig


_DEAD_SENSOR = ("a sensor's output does not respond to its input (zero scale-misalignment vector): a dead sensor or "
                "an unconnected channel; remove it from the geometry")
_LSQ_KERNELS: list = []


def _lsq_kernel(backend: str | None) -> Any:
    """The compiled base-model kernel (:mod:`rimu.calibration._lsq_kernels`) where numba is loaded in the process
    already and the backend allows it, or numba is asked for by name; else None
    (:func:`rimu._backend.resolve_loaded`: no calibration pays for importing numba unasked). The answer for the same
    request, ``RIMU_BACKEND`` and state of the process (numba loaded or not, the kernel importable or not) is kept."""
    key = (backend, os.environ.get("RIMU_BACKEND"), "numba" in sys.modules, tuple(_LSQ_KERNELS))
    hit = _LSQ_RESOLVED.get(key, False)
    if hit is not False:
        return hit
    if _resolve_loaded(backend, lambda: import_once(_LSQ_KERNELS, "rimu.calibration._lsq_kernels") is not None,
                       "the compiled least-squares kernel") != "numba":
        out = None
    else:
        out = import_once(_LSQ_KERNELS, "rimu.calibration._lsq_kernels")
    if len(_LSQ_RESOLVED) < 64:
        _LSQ_RESOLVED[(backend, os.environ.get("RIMU_BACKEND"), "numba" in sys.modules, tuple(_LSQ_KERNELS))] = out
    return out


#: :func:`_lsq_kernel`'s answers (an error is raised again each time, never kept)
_LSQ_RESOLVED: dict[tuple, Any] = {}


def _noise_sigma_of(rows: list[int], ns: list[int], M: np.ndarray, instrument: str) -> np.ndarray:
    """:func:`estimate_noise_sigma` from the rows ``rows`` (its segments, in order) of a
    :meth:`~rimu.session.SessionStatistics.moments` array ``M`` (``ns``: their samples): the same sums in the same
    order as :func:`_noise_sigma_from`."""
    dofs = [ns[j] - 2 if ns[j] >= 3 else 0 for j in rows]
    cnt = sum(dofs)
    if cnt == 0:
        raise IdentifiabilityError(f"{instrument}: no segment has enough samples to estimate the noise level")
    used = [j for j, d in zip(rows, dofs) if d]
    a = used[0]
    # row by row: added in turn (a slice where the rows follow each other, as the static positions of a session)
    acc = np.add.reduce(M[a:a + len(used), 2] if used == list(range(a, a + len(used))) else M[used, 2], axis=0)
    sig = np.sqrt(acc / cnt / 2.0)
    if np.logical_or.reduce(sig <= 0):
        sig = np.where(sig > 0, sig, np.max(sig) if np.max(sig) > 0 else 1.0)
    return sig


def _input_forms(session: Session, inst: str, segs: Sequence[Segment]) -> list[tuple[str | None, Any]]:
    """:func:`_input_form` of every segment for ``inst`` (its nominal contexts': the base model's), the common
    cases without a context: a gyro at rest without a known Earth rate reads zero, an accelerometer with one known
    specific force reads it, one at rest in a known attitude reads gravity in MB, a gyro on a segment of neither
    known rate nor rest reads nothing, an accelerometer without a known specific force or attitude reads nothing."""
    out: list[tuple[str | None, Any]] = []
    ctx = None
    gyro = inst == "gyro"
    for seg in segs:
        if gyro:
            if seg.kind not in ("rate", "static"):
                out.append((None, None))
                continue
            if seg.kind == "static" and seg.rate_mb is None and (seg.mat_ln_mb is None or session.latitude is None):
                out.append(("constant", np.zeros(3)))
                continue
        else:
            f = seg.specific_force_mb
            if f is not None and f.ndim == 1:
                out.append(("constant", f))
                continue
            if f is None:
                if seg.mat_ln_mb is None:
                    out.append((None, None))
                    continue
                if seg.rate_mb is None:  # at rest in a known attitude (or turning about it): gravity seen in MB
                    g = seg.mat_ln_mb.T @ np.array([0.0, 0.0, session.gravity])
                    out.append(("constant", g) if seg.fixed_under_turn(g) else (None, None))
                    continue
        if ctx is None:
            ctx = contexts(session, inst)[0]
        out.append(_input_form(ctx, seg))
    return out


def _base_sensor_fits(session: Session, model: ErrorModel, inst: str, parts: list[tuple], Bt: np.ndarray,
                      beta_cov: np.ndarray, arrays: BaseArrays, sigma_known: bool, n_obs: int) -> list[SensorFit]:
    """The :class:`SensorFit` of every sensor of ``inst`` from the base model's arrays (rows in the geometry's
    order): raw coefficients ``Bt`` (n, 4) and their covariance, physical values and theirs, each sensor's residuals
    per segment computed when asked for (:class:`~rimu.calibration.lsq.LazyResiduals`)."""
    ctxs = contexts(session, inst)
    effs = model.effects_for(ctxs[0])
    local = [x.name for e in effs for x in e.parameters(ctxs[0])]  # w_x, w_y, w_z, bias: every sensor's
    by_label = {lab: (seg, u) for lab, seg, u in parts}
    fits = []
    for i, ctx in enumerate(ctxs):
        name = ctx.name
        res = LazyResiduals(labels=by_label, compute=partial(_base_residual_of, by_label, inst, ctx, Bt[i]))
        specs = _base_physical_specs(effs, ctx)
        fits.append(SensorFit(ctx, [f"{name}.{x}" for x in local], Bt[i], beta_cov[i],
                              [f"{name}.{x.name}" for x in specs], specs, arrays.theta[i], arrays.theta_cov[i],
                              arrays.sigma[i], sigma_known, n_obs, arrays.rss[i], res))
    return fits


def _base_statistics_numpy(M: np.ndarray, Z: list, G0: np.ndarray | None, H0: np.ndarray | None, n_obs: int,
                           labels: list[str], parts: list) -> tuple:
    """The base model's normal equations ``G`` (4, 4), ``H`` (4, n), ``q`` (n,) of one instrument from the rows of
    :meth:`LeastSquares._base_rows` by numpy (the reference of
    :func:`rimu.calibration._lsq_kernels.base_statistics`): every row's terms in two products, the outputs' sums of
    squares added segment by segment (row by row, in order). Returns ``G, H, q, n_obs, labels, parts``."""
    n = M.shape[2]
    G = np.zeros((4, 4)) if G0 is None else G0
    H = np.zeros((4, n)) if H0 is None else H0
    if not Z:
        return G, H, np.zeros(n), n_obs, labels, parts
    R = np.array(Z, dtype=float)
    j = R[:, 5].astype(np.intp)
    kind = R[:, 7]
    fit = kind != 2.0
    T = M[j[fit], 0] / R[fit, 6][:, None]  # each row's totals (an angle row's over sqrt(N))
    Q = M[j, 1]
    Q[kind == 1.0] = T[kind[fit] == 1.0] ** 2
    q = np.add.reduce(Q, axis=0)
    X = R[fit, :4]
    G += (X.T * R[fit, 4]) @ X
    H += X.T @ T
    return G, H, q, n_obs, labels, parts


def _base_statistics_compiled(kern: Any, rows: list[tuple]) -> tuple[list[tuple], tuple]:
    """The base model's normal equations and noise level of every instrument in one compiled call
    (:func:`rimu.calibration._lsq_kernels.base_statistics`) from :meth:`LeastSquares._base_rows`' rows; returns
    ``per``: instrument, ``(G, H, q, n_obs, labels, parts)``, noise level, skipped segments; and every instrument's
    ``G`` (K, 4, 4), ``H`` (4, p), ``q``, noise level (p,) in one array each (whose views ``per`` holds), ``G^-1``
    and the bound ``tr`` of :meth:`LeastSquares._base_check` (None where a G is exactly singular)."""
    counts = [M.shape[2] for _, M, *_ in rows]
    p = sum(counts)
    G = np.zeros((len(rows), 4, 4))
    H = np.zeros((4, p))
    q, sig = np.empty(p), np.empty(p)
    Z, Nz, est = [], [], []
    a = 0
    for k, (_, _, _, nz, sg, _, (Zk, G0, H0, *_)) in enumerate(rows):
        b = a + counts[k]
        if G0 is not None:
            G[k] = G0
            H[:, a:b] = H0
        if nz is None:
            sig[a:b] = sg
        else:
            Nz += [(j, d, k) for j, d in nz]
        Z += [(*z, k) for z in Zk]
        est.append(nz is not None)
        a = b
    Ginv, tr = np.empty((len(rows), 4, 4)), np.empty(len(rows))
    try:
        kern.base_statistics(rows[0][1], rows[-1][1], np.array(Z, dtype=float).reshape(-1, 9),
                             np.array(Nz, dtype=float).reshape(-1, 3), np.array(est), G, H, q, sig, Ginv, tr)
    except np.linalg.LinAlgError:  # an exactly singular G: the check names what is missing
        Ginv = tr = None
    out: list[tuple] = []
    a = 0
    for k, (inst, _, _, _, _, skipped, (_, _, _, n_obs, labels, parts)) in enumerate(rows):
        b = a + counts[k]
        out.append((inst, (G[k], H[:, a:b], q[a:b], n_obs, labels, parts), sig[a:b], skipped))
        a = b
    return out, (G, H, q, sig, Ginv, tr)


_BASE_MODEL: list[ErrorModel] = []


def _base_model() -> ErrorModel:
    """:meth:`ErrorModel.base` (scale/misalignment + bias), made once: a model holds no state a fit changes."""
    if not _BASE_MODEL:
        _BASE_MODEL.append(ErrorModel.base())
    return _BASE_MODEL[0]


def _noise_segments(session: Session) -> list[Segment]:
    """The segments :func:`estimate_noise_sigma` reads: the static ones, or every segment where none is."""
    return [s for s in session.segments if s.kind in ("static", "static_unknown")] or list(session.segments)


def _is_turn(seg: Segment, inst: str) -> bool:
    """Whether the base model reads ``seg`` of ``inst`` as one integrated row (a gyro's turn of known angle)."""
    return inst == "gyro" and seg.kind == "angle" and seg.n_samples > 1


def segment_residuals(model: ErrorModel, ctx: SensorContext, segments: Sequence[Segment], beta: np.ndarray,
                      instrument: str, cache: dict[str, bool] | None = None) -> LazyResiduals:
    """Residuals ``y - X beta`` (raw units) of every segment whose inputs the model knows, computed per segment
    when asked for (a :class:`~rimu.calibration.lsq.LazyResiduals`: memory proportional to the segments).

    ``cache`` (one dict for all sensors of an instrument) remembers which segments have a known input.
    """
    base = [e.name for e in model.effects_for(ctx)] == ["scale_misalignment", "bias"]
    makers: dict[str, Any] = {}
    for seg in segments:
        if base:
            if cache is None or seg.label not in cache:  # whether the segment's input is known (not the input)
                known = _input_known(ctx, seg)
                if cache is not None:
                    cache[seg.label] = known
            else:
                known = cache[seg.label]
            if known:
                makers[seg.label] = _bind(_base_residual(seg, instrument, ctx, None), beta)
        elif model.design(seg, ctx) is not None:
            makers[seg.label] = _bind(_model_residual(seg, instrument, ctx, model), beta)
    return LazyResiduals(makers)


def _input_known(ctx: SensorContext, seg: Segment) -> bool:
    """Whether ``ctx.input(seg)`` is not None, without computing the input."""
    if ctx.instrument == "gyro":
        return seg.kind in ("rate", "static")
    return seg.specific_force_mb is not None or seg.mat_ln_mb is not None


def _known_input(ctx: SensorContext, seg: Segment) -> np.ndarray | None:
    """``ctx.input(seg)``, without building a rotation matrix per sample when the segment is static."""
    if seg.kind == "static" and not np.any(seg.table_rate()):
        if ctx.instrument == "gyro":
            if seg.mat_ln_mb is not None and ctx.latitude is not None and ctx.include_earth_rate:
                from ..session import earth_rate_ln

                return np.broadcast_to(seg.mat_ln_mb.T @ earth_rate_ln(ctx.latitude), (seg.n_samples, 3))
            return np.zeros((seg.n_samples, 3))
        if seg.specific_force_mb is None and seg.mat_ln_mb is not None:
            return np.broadcast_to(seg.mat_ln_mb.T @ np.array([0.0, 0.0, ctx.gravity]), (seg.n_samples, 3))
    return ctx.input(seg)


def _input_form(ctx: SensorContext, seg: Segment) -> tuple[str | None, Any]:
    """How the known input ``ctx.input(seg)`` of the base model varies over a segment, without evaluating it per
    sample: ``("constant", u (3,))``; ``("basis", P (3, 3))`` with ``u = [1, cos(theta), sin(theta)] P`` on a
    segment turning at a constant rate with known attitude (:class:`~rimu.session.RotationMoments`);
    ``("samples", u (N, 3))`` for an input given sample by sample; ``(None, None)`` when it is not known."""
    w = seg.table_rate()
    turning = seg.rate_mb is not None and bool(np.any(w))
    if ctx.instrument == "gyro":
        if seg.kind not in ("rate", "static"):
            return None, None
        earth = seg.mat_ln_mb is not None and ctx.latitude is not None and ctx.include_earth_rate
        if not earth:
            return "constant", np.asarray(w, dtype=float)
        from ..session import earth_rate_ln

        x = seg.mat_ln_mb.T @ earth_rate_ln(ctx.latitude)
        if not turning:
            return "constant", x
        P = _basis_coefficients(w, x)
        P[0] += w
        return "basis", P
    if seg.specific_force_mb is not None:
        f = seg.specific_force_mb
        return ("constant", f) if f.ndim == 1 else ("samples", seg.specific_force(ctx.gravity))
    if seg.mat_ln_mb is None:
        return None, None
    x = seg.mat_ln_mb.T @ np.array([0.0, 0.0, ctx.gravity])
    if not seg.fixed_under_turn(x):  # an 'angle' turn about a non-vertical axis at an unstated rate
        return None, None
    return ("basis", _basis_coefficients(w, x)) if turning else ("constant", x)


def _basis_coefficients(w: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rows ``a, b, c`` of an LN-fixed vector ``x = C0^T v`` seen in MB while turning at ``w``:
    ``a + b cos(theta) + c sin(theta)`` (:meth:`rimu.session.RotationMoments.coefficients`)."""
    k = w / np.linalg.norm(w)
    a = k * float(k @ x)
    return np.vstack([a, x - a, -np.cross(k, x)])


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


#: report units of a parameter that are a rate or a specific force: the one formatter's field unit is chosen by the
#: magnitude of the table (deg/h for a tactical gyro bias, deg/s for a MEMS one; ug, mg or m/s^2)
_MAGNITUDE_UNITS = {"deg/h": "rate", "ug": "specific_force"}


def field_value(name: str, value: float, std: float, spec_unit: str, to_report: float,
                magnitude: float | None = None) -> tuple[float, float, str]:
    """(value, std, unit) in the field's units. Scale factors are reported as a value in SI and a relative
    standard deviation in ppm. A bias (rate or specific force) reads in the field unit the ``magnitude`` (SI, the
    largest of its table; :func:`rimu.units.field_unit`) calls for, or in its parameter's report unit without it.

    >>> field_value("x.bias", 3.33, 0.01, "deg/h", 1.0, magnitude=3.33)[2]     # a MEMS gyro bias: deg/s
    'deg/s'
    >>> field_value("x.bias", 3e-5, 1e-6, "deg/h", 1.0, magnitude=3e-5)[2]     # a tactical one: deg/h
    'deg/h'
    """
    if name.endswith(".scale"):
        return value, abs(std / value) * 1e6, "ppm"
    if magnitude is not None and spec_unit in _MAGNITUDE_UNITS:
        from ..units import field_unit

        unit, f = field_unit(_MAGNITUDE_UNITS[spec_unit], magnitude)
        return value * f, std * f, unit
    return value * to_report, std * to_report, spec_unit


def bias_magnitudes(result: "LsqResult") -> dict[str, float]:
    """Per report unit that is a rate or a specific force (:data:`_MAGNITUDE_UNITS`): the largest magnitude (SI)
    of the parameters of one instrument in that unit, so that one table reads in one unit."""
    out: dict[str, float] = {}
    for s in result.sensors:
        for v, sp in zip(s.theta, s.theta_specs):
            if sp.report_unit in _MAGNITUDE_UNITS and np.isfinite(v):
                out[sp.report_unit] = max(out.get(sp.report_unit, 0.0), abs(float(v)))
    return out


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
        mag = bias_magnitudes(self.instruments[instrument])
        for s in self.instruments[instrument].sensors:
            for i, (n, sp) in enumerate(zip(s.theta_names, s.theta_specs)):
                _, sd, unit = field_value(n, s.theta[i], np.sqrt(max(s.theta_cov[i, i], 0.0)), sp.report_unit,
                                          sp.to_report, mag.get(sp.report_unit))
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
            mag = bias_magnitudes(r)
            for s in r.sensors:
                for i, (n, sp) in enumerate(zip(s.theta_names, s.theta_specs)):
                    v, sd, unit = field_value(n, s.theta[i], np.sqrt(max(s.theta_cov[i, i], 0.0)), sp.report_unit,
                                              sp.to_report, mag.get(sp.report_unit))
                    vs = f"{v:.8g}" if n.endswith(".scale") else f"{v:.4f}"
                    unit_s = (f"{scale_unit(inst, raw_unit_for(self.raw_unit, inst))} (std ppm)" if n.endswith(".scale")
                              else unit)
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
    backend : {"auto", "numpy", "numba"}, optional
        Implementation of the one pass over a long segment's samples (sums, squares, first differences;
        :class:`~rimu.session.SessionStatistics`, :mod:`rimu._backend`). Default: ``RIMU_BACKEND``, else auto.
    """

    method = "lsq"

    def __init__(self, model: ErrorModel | None = None, sigma: dict[str, Any] | None = None,
                 instruments: Sequence[str] | None = None, segments: Sequence[str] | None = None,
                 backend: str | None = None) -> None:
        self.model = model
        self.sigma = sigma
        self.instruments = instruments
        self.segments = segments
        self.backend = backend

    def fit(self, session: Session) -> CalibrationResult:
        """Fit every instrument. Raises IdentifiabilityError naming what the segments cannot identify."""
        model = self.model or _base_model()
        insts = list(self.instruments or session.instruments)
        segs = [session.segment(x) for x in self.segments] if self.segments is not None else list(session.segments)
        if [e.name for e in model.effects] == ["scale_misalignment", "bias"]:
            return self._fit_base(session, model, insts, segs)  # every sensor of every instrument at once
        base_only = all(e.name in ("bias", "scale_misalignment") for e in model.effects)
        out: dict[str, LsqResult] = {}
        notes: list[str] = []
        # each segment's sums (with their squares and first differences, in one pass) and rotation moments once for
        # every instrument and step of the fit
        sstats = SessionStatistics(session, self.backend)
        for inst in insts:
            sig = _sigma_for(self.sigma, session, inst, sstats)
            skipped: dict[str, str] = {}
            # effects along an axis act on the calibrated axis: fit them there
            axes = first_axes(session, model, inst, segs, sig) if on_calibrated_axes(model) else None
            ctxs = contexts(session, inst, axes=axes)
            fits = []
            for ctx in ctxs:
                names = model.parameter_names(ctx)
                G, h, q, n_obs, labels, makers = self._model_statistics(segs, inst, ctx, model, base_only, skipped)
                if not labels:
                    raise IdentifiabilityError(f"{inst}: no segment carries the inputs the model {model.label} needs",
                                               model.parameter_names(ctx))
                try:
                    check_identifiable_gram(G, n_obs, names, inst)
                except IdentifiabilityError as exc:
                    raise IdentifiabilityError(str(exc), _physical_names(model, ctx, exc.parameters)) from None
                Ginv = np.linalg.inv(G)
                beta = Ginv @ h
                rss = rss_from_statistics(q, h, G, beta)
                res = LazyResiduals({lab: _bind(mk, beta) for lab, mk in makers.items()})
                if rss < 1e-8 * q:  # cancellation in the statistics: an exact second pass
                    rss = sum(float(np.sum(res[lab] ** 2)) for lab in res)
                s = float(sig[ctx.index])
                fits.append(make_sensor_fit(model, ctx, beta, s**2 * Ginv, s, self.sigma is not None, n_obs,
                                            rss / s**2, res))
            out[inst] = LsqResult(inst, model, fits, [x.label for x in segs if x.label not in skipped], skipped)
            if skipped:
                notes.append(f"{inst}: segments not used: {sorted(skipped)}")
        return CalibrationResult(f"least squares ({model.label})", out, session.raw_unit, notes)

    def _fit_base(self, session: Session, model: ErrorModel, insts: list[str],
                  segs: list[Segment]) -> CalibrationResult:
        """The base model (scale/misalignment + bias) of every sensor of every instrument at once: per instrument the
        sums of every segment it reads in one array (:meth:`~rimu.session.SessionStatistics.moments`) and one row per
        segment of what the normal equations take from them (:meth:`_base_rows`); the normal equations and the noise
        level of every instrument from these (one compiled call where numba is loaded, else a few array operations);
        then every sensor solved together (:meth:`_base_solve`). The result holds the numbers as arrays
        (:class:`~rimu.calibration.lsq.BaseArrays`); a sensor's :class:`SensorFit` is made when asked for."""
        kern = _lsq_kernel(self.backend)
        # the statistics take the compiled pass where the fit's kernel is used (one resolution of the backend)
        sstats = SessionStatistics(session, "numba" if kern is not None else "numpy")
        known = self.sigma is not None
        noise = _noise_segments(session)
        notes: list[str] = []
        rows = []
        for inst in insts:
            forms = _input_forms(session, inst, segs)
            # the segments whose sums the fit and the noise level read, each once (of a turn read as one integrated
            # row, its column sums: the compiled pass gives them with the rest, as fast as numpy's sums alone)
            todo = {id(x): x for x, f in zip(segs, forms) if f[0] is not None or _is_turn(x, inst)}
            given = known and self.sigma.get(inst) is not None  # type: ignore[union-attr]
            if not given:
                todo.update((id(x), x) for x in noise)
            ns, M = sstats.moments(list(todo.values()), inst)
            pos = dict(zip(todo, range(len(todo))))
            if given:
                sig, nz = _sigma_for(self.sigma, session, inst, sstats), None
            else:
                nz = [(j, ns[j] - 2 if ns[j] >= 3 else 0) for j in (pos[id(x)] for x in noise)]
                if not any(d for _, d in nz):
                    raise IdentifiabilityError(f"{inst}: no segment has enough samples to estimate the noise level")
                sig = None
            skipped: dict[str, str] = {}
            rows.append((inst, M, ns, nz, sig, skipped,
                         self._base_rows(sstats, segs, inst, forms, pos, ns, M, skipped, tuple(insts))))
            if skipped:
                notes.append(f"{inst}: segments not used: {sorted(skipped)}")
        whole = None  # every instrument's G (K, 4, 4), H (4, p), q and sigma (p,) as the compiled call leaves them
        if kern is not None and len(rows) <= 2:
            per, whole = _base_statistics_compiled(kern, rows)
        else:
            per = [(inst, _base_statistics_numpy(M, *st), sig if nz is None else
                    _noise_sigma_of([j for j, _ in nz], ns, M, inst), skipped)
                   for inst, M, ns, nz, sig, skipped, st in rows]
        Ginv = self._base_check(session, model, per, *(() if whole is None else (whole[0], whole[4], whole[5])))
        out = self._base_solve(session, model, per, known, segs, Ginv, kern, whole)
        return CalibrationResult(f"least squares ({model.label})", out, session.raw_unit, notes)

    @staticmethod
    def _base_check(session: Session, model: ErrorModel, per: list[tuple], G: np.ndarray | None = None,
                    Ginv: np.ndarray | None = None, tr: np.ndarray | None = None) -> np.ndarray:
        """Refuse the first instrument (in order) whose base statistics identify no parameter set: no usable
        segment, or a Gram matrix with a direction the segments do not excite
        (:func:`~rimu.calibration.lsq.check_identifiable_gram`), naming the physical parameters involved. Returns
        every instrument's ``G^-1`` (K, 4, 4), one call for all.

        The check's criterion is an eigenvalue of the scaled Gram matrix ``S = D^-1 G D^-1`` (unit diagonal) below
        1e-12 of the largest. ``tr S = 4`` bounds the largest from above and ``1 / tr S^-1`` the smallest from
        below, and ``S^-1 = D G^-1 D`` comes from the inverse the fit needs anyway: where ``1 / tr S^-1 > 4e-12``
        no eigenvalue can fail, and only otherwise are the eigenvalues computed (by the check itself, which names
        the parameters). ``G``: the instruments' Gram matrices stacked (K, 4, 4), if they are already; ``Ginv``,
        ``tr``: their inverses and ``tr S^-1``, if they are known (the compiled statistics give them)."""
        G = np.stack([st[0] for _, st, _, _ in per]) if G is None else G
        try:
            if Ginv is None or tr is None:
                Ginv = np.linalg.inv(G)
                # tr S^-1 = sum_i G_ii (G^-1)_ii; a zero column (G_ii = 0) makes G singular: an error, inf or nan here
                tr = np.einsum("kii,kii->k", Ginv, G)
            # (an inverse of a Gram matrix has a positive diagonal; nan fails)
            ok = [0.0 < t and t * 4e-12 < 1.0 for t in tr.tolist()]
        except np.linalg.LinAlgError:  # exactly singular: the check below names what is missing
            Ginv, ok = None, [False] * len(per)
        for k, (inst, st, _, _) in enumerate(per):
            if st[4] and st[3] >= G.shape[1] and ok[k]:
                continue
            ctx = contexts(session, inst)[0]
            names = model.parameter_names(ctx)
            if not st[4]:
                raise IdentifiabilityError(f"{inst}: no segment carries the inputs the model {model.label} needs",
                                           names)
            try:
                check_identifiable_gram(st[0], st[3], names, inst)
            except IdentifiabilityError as exc:
                raise IdentifiabilityError(str(exc), _physical_names(model, ctx, exc.parameters)) from None
        if Ginv is None:  # (singular, yet not refused: cannot happen, the check refuses a rank-deficient G)
            Ginv = np.linalg.inv(G)
        return Ginv

    @staticmethod
    def _base_solve(session: Session, model: ErrorModel, per: list[tuple], sigma_known: bool, segs: list[Segment],
                    Ginv_k: np.ndarray | None = None, kern: Any = None,
                    whole: tuple | None = None) -> dict[str, LsqResult]:
        """The base model (scale/misalignment + bias) of every sensor of every instrument from the shared
        statistics (``per``: instrument, statistics, noise level, skipped segments; each checked by
        :meth:`_base_check`), as array operations over all the sensors at once: ``B = G^-1 H`` (4, n) per
        instrument, the residual sums of squares from the statistics, and the physical values with their Jacobian
        (:func:`~rimu.calibration.lsq.physical_from_beta` and
        :meth:`~rimu.calibration.effects.scale_misalignment.ScaleMisalignment.physical`, Cho & Park 2005, Eq. 10:
        ``SF = 1/|w|``, ``m = C w/|w|``, ``b = c SF``). The same numbers as the per-sensor path
        (:func:`make_sensor_fit`, to rounding; tested to 1e-10). Each instrument's :class:`LsqResult` holds them as
        :class:`~rimu.calibration.lsq.BaseArrays`, its :class:`SensorFit` list made on first use. ``whole``: every
        instrument's ``G`` (K, 4, 4), ``H`` (4, p), ``q`` and noise level (p,) in one array each, if they are
        already."""
        if Ginv_k is None:  # (K, 4, 4): one call for all
            Ginv_k = np.linalg.inv(np.stack([st[0] for _, st, _, _ in per]))
        geos = [session.geometries[inst] for inst, _, _, _ in per]
        counts = [g.n for g in geos]

        def cat(xs: list, axis: int = 0) -> np.ndarray:
            return np.concatenate(xs, axis=axis) if len(xs) > 1 else xs[0]

        EC = cat([g.off_axis_projections() for g in geos])  # (p, 2, 3): E_i C_i
        Cs = cat([g.subunit_rotations() for g in geos])  # (p, 3, 3): C_i
        if whole is None:
            H = cat([st[1] for _, st, _, _ in per], 1)
            q, sig = cat([st[2] for _, st, _, _ in per]), cat([x[2] for x in per])
        else:
            H, q, sig = whole[1], whole[2], whole[3]
        s2 = sig**2
        if kern is not None:  # numba loaded: every sensor's numbers in one compiled call (the same to rounding)
            p = H.shape[1]
            Bt, theta, rss = np.empty((p, 4)), np.empty((p, 4)), np.empty(p)
            tcov, beta_cov = np.empty((p, 4, 4)), np.empty((p, 4, 4))
            which = np.array([k for k, c in enumerate(counts) for _ in range(c)], dtype=np.intp)
            G = np.stack([st[0] for _, st, _, _ in per]) if whole is None else whole[0]
            mis = np.empty((p, 3))
            if not kern.base_solve(Ginv_k, G, H, q, s2, which, EC, Cs, Bt, theta, tcov, beta_cov, rss, mis):
                raise IdentifiabilityError(_DEAD_SENSOR)
        else:
            Bs, GB = [], []
            for k, (_, st, _, _) in enumerate(per):
                Bk = Ginv_k[k] @ st[1]  # (4, n_k): w_x, w_y, w_z, c of every sensor of instrument k
                Bs.append(Bk)
                GB.append(st[0] @ Bk)
            B, GB = cat(Bs, 1), cat(GB, 1)
            Gi = Ginv_k[np.repeat(np.arange(len(per)), counts)]  # (p, 4, 4): each sensor's G^-1
            rss = np.maximum(q - 2.0 * np.einsum("pn,pn->n", B, H) + np.einsum("pn,pn->n", B, GB), 0.0)
            W = np.ascontiguousarray(B[:3].T)
            nw = np.sqrt(np.einsum("ni,ni->n", W, W))
            if not np.all(nw > 0):
                raise IdentifiabilityError(_DEAD_SENSOR)
            U = W / nw[:, None]
            sf = 1.0 / nw
            p = W.shape[0]
            J = np.zeros((p, 4, 4))
            d_sf = -W * (sf**3)[:, None]
            J[:, 0, :3] = d_sf
            d_u = (np.eye(3)[None] - U[:, :, None] * U[:, None, :]) * sf[:, None, None]
            J[:, 1:3, :3] = EC @ d_u
            J[:, 3, 3] = sf
            J[:, 3, :3] = B[3][:, None] * d_sf
            theta = np.empty((p, 4))
            theta[:, 0] = sf
            theta[:, 1:3] = np.einsum("nij,nj->ni", EC, U)
            theta[:, 3] = B[3] * sf
            mis = np.matmul(Cs, U[:, :, None])[:, :, 0]  # m_i = C_i w_i / |w_i|
            tcov = (J @ Gi @ J.transpose(0, 2, 1)) * s2[:, None, None]
            beta_cov = s2[:, None, None] * Gi
            Bt = np.ascontiguousarray(B.T)
        s2_l, rss0 = s2.tolist(), rss.tolist()
        chi2_l = [r / v for r, v in zip(rss0, s2_l)]  # (Python floats: the IEEE operations of numpy's, fewer calls)
        small = [i for i, (r, qq) in enumerate(zip(rss0, q.tolist())) if r < 1e-8 * qq]
        if small:  # cancellation in the statistics: an exact second pass over those sensors' samples
            starts = np.cumsum([0, *counts]).tolist()
            for i in small:
                k = int(np.searchsorted(starts, i, side="right")) - 1
                inst, st = per[k][0], per[k][1]
                by_label = {lab: (seg, u) for lab, seg, u in st[5]}
                ctx = contexts(session, inst)[i - starts[k]]
                chi2_l[i] = sum(float(np.sum(_base_residual_of(by_label, inst, ctx, Bt[i], lab) ** 2))
                                for lab in by_label) / s2_l[i]
        sig_l = sig.tolist()
        rss_l = [c * v for c, v in zip(chi2_l, s2_l)]
        out: dict[str, LsqResult] = {}
        a = 0
        for (inst, st, _, skipped), g, n in zip(per, geos, counts):
            b = a + n
            arrays = BaseArrays(g, theta[a:b], tcov[a:b], mis[a:b], sig_l[a:b], rss_l[a:b], int(st[3]) - 4)
            make = partial(_base_sensor_fits, session, model, inst, st[5], Bt[a:b], beta_cov[a:b], arrays,
                           sigma_known, int(st[3]))
            out[inst] = LsqResult(inst, model, None, [x.label for x in segs if x.label not in skipped], skipped,
                                  base=arrays, make_sensors=make)
            a = b
        return out

    @staticmethod
    def _base_rows(sstats: SessionStatistics, segs: list[Segment], inst: str, forms: list, pos: dict[int, int],
                   ns: list[int], M: np.ndarray, skipped: dict[str, str], instruments: tuple[str, ...] = ()) -> tuple:
        """What the base model's normal equations take from each segment ``inst`` reads: the known input u of a
        segment is the same for every sensor, so ``X = [u, 1]`` and ``X^T X`` are shared, ``X^T Y`` is one product
        for all sensors, and every term comes from the segments' sums (``M``, rows ``pos[id(segment)]``, of
        :meth:`~rimu.session.SessionStatistics.moments`). Returns ``(Z, G0, H0, n_obs, labels, parts)``: ``Z`` one row
        per segment read, in order (:func:`rimu.calibration._lsq_kernels.base_statistics`: the design row, its weight,
        its row of ``M``, the divisor of its totals, its kind): a static segment's constant input (weight N, its
        column sums), a turn of known angle as one integrated row (Zhang et al. 2010, Eq. 16-17: its totals over
        ``sqrt(N)``, in units of the per-sample noise); ``G0``, ``H0`` the terms of the segments turning at a
        constant rate with known attitude, whose input is ``B P`` in the basis ``B = [1, cos(theta), sin(theta)]`` of
        its angle, from ``B^T B`` and ``B^T Y`` (``X^T X = Q^T (B^T B) Q``, ``X^T Y = Q^T (B^T Y)``, ``Q = [P, e_1]``),
        and of an input given sample by sample (``specific_force_mb`` of shape (N, 3), built per sample); ``parts``:
        label, segment, and an angle row's ``("angle", x, y)``."""
        G0 = H0 = None
        n_obs, labels, parts, Z = 0, [], [], []
        for seg, (kind, u) in zip(segs, forms):
            if kind is None:
                if _is_turn(seg, inst):  # one row: the integral in units of the per-sample noise
                    x = _base_angle_row(seg)
                    j = pos[id(seg)]
                    div = math.sqrt(ns[j])
                    Z.append((*x, 1.0, j, div, 1.0))
                    n_obs += 1
                    labels.append(seg.label)
                    parts.append((seg.label, seg, ("angle", x, M[j, 0] / div)))
                else:
                    skipped[seg.label] = "the segment lacks inputs an effect needs (known rate, attitude or angle)"
                continue
            j = pos[id(seg)]
            N = ns[j]
            if kind == "constant":  # one input for every sample (a static position): N x x^T, x total^T
                Z.append((*u.tolist(), 1.0, N, j, 1.0, 0.0))
            else:
                if G0 is None:
                    G0, H0 = np.zeros((4, 4)), np.zeros((4, M.shape[2]))
                if kind == "basis":  # u = B P on a turning segment: from the moments of its angle
                    rm = sstats.rotation(seg)
                    Q = np.zeros((3, 4))
                    Q[:, :3] = u
                    Q[0, 3] = 1.0
                    G0 += Q.T @ rm.gram @ Q
                    H0 += Q.T @ sstats.basis_products(seg, tuple(dict.fromkeys((inst, *instruments))))[inst]
                else:
                    X = np.column_stack([u, np.ones(N)])
                    G0 += X.T @ X
                    H0 += X.T @ seg.raw[inst]
                Z.append((0.0, 0.0, 0.0, 0.0, 0.0, j, 1.0, 2.0))
            n_obs += N
            labels.append(seg.label)
            parts.append((seg.label, seg, None))
        return Z, G0, H0, n_obs, labels, parts

    @staticmethod
    def _model_statistics(segs: list[Segment], inst: str, ctx: SensorContext, model: ErrorModel, base_only: bool,
                          skipped: dict[str, str]) -> tuple:
        p = len(model.parameter_names(ctx))
        G, h, q, n_obs = np.zeros((p, p)), np.zeros(p), 0.0, 0
        labels: list[str] = []
        makers: dict[str, Any] = {}
        for seg in segs:
            X = model.design(seg, ctx)
            y = seg.raw[inst][:, ctx.index]
            if X is not None:
                makers[seg.label] = _model_residual(seg, inst, ctx, model)
                n_obs += len(y)
            elif seg.kind == "angle" and inst == "gyro" and base_only and seg.n_samples > 1:
                X = _angle_row(seg, model, ctx)
                y = np.array([y.sum() / np.sqrt(seg.n_samples)])
                makers[seg.label] = ("angle", X[0], y[0])
                n_obs += 1
            else:
                skipped[seg.label] = "the segment lacks inputs an effect needs (known rate, attitude or angle)"
                continue
            G += X.T @ X
            h += X.T @ y
            q += float(y @ y)
            labels.append(seg.label)
        return G, h, q, n_obs, labels, makers


def _base_residual(seg: Segment, inst: str, ctx: SensorContext, u: Any) -> Any:
    """Residual function of the base model; the known input is recomputed when asked for, not kept."""
    if isinstance(u, tuple):  # an angle row: (tag, x, y for all sensors)
        return ("angle", u[1], float(u[2][ctx.index]))

    def make(beta: np.ndarray) -> np.ndarray:
        uu = _known_input(ctx, seg)
        return seg.raw[inst][:, ctx.index] - (uu @ beta[:3] + beta[3])

    return make


def _base_residual_of(parts: dict[str, tuple[Segment, Any]], inst: str, ctx: SensorContext, beta: np.ndarray,
                      label: str) -> np.ndarray:
    """The base model's residual of sensor ``ctx`` on the segment ``label`` (:func:`_base_residual`, bound)."""
    seg, u = parts[label]
    if isinstance(u, tuple):  # an angle row: its one integrated value
        return np.array([float(float(u[2][ctx.index]) - np.asarray(u[1], dtype=float) @ beta)])
    return seg.raw[inst][:, ctx.index] - (_known_input(ctx, seg) @ beta[:3] + beta[3])


def _model_residual(seg: Segment, inst: str, ctx: SensorContext, model: ErrorModel) -> Any:
    def make(beta: np.ndarray) -> np.ndarray:
        return seg.raw[inst][:, ctx.index] - model.design(seg, ctx) @ beta

    return make


def _bind(maker: Any, beta: np.ndarray) -> Any:
    """A residual function of the fitted beta; an angle row's residual is its one integrated value."""
    if isinstance(maker, tuple):
        _, x, y = maker
        r = np.array([float(y - x @ beta)])
        return lambda: r
    return lambda: maker(beta)


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


def _base_angle_row(seg: Segment) -> tuple[float, float, float, float]:
    """:func:`_angle_row` of the base model (scale/misalignment, then bias): ``[angle, N dt] / (dt sqrt(N))``
    (in Python floats: the same IEEE operations, without numpy calls)."""
    t = seg.t
    N = t.shape[0]
    dt = float(t[-1] - t[0]) / (N - 1)
    w = dt * math.sqrt(N)
    a = (seg.angle_mb if seg.angle_mb.ndim == 1 else seg.angle_mb[-1]).tolist()
    return (a[0] / w, a[1] / w, a[2] / w, N * dt / w)


#: physical parameters of the base model per (effect types, instrument, off-axis names): ParamSpec is frozen, so
#: every fit shares these few lists instead of making 4 per sensor
_BASE_SPECS: dict[tuple, list] = {}


def _base_physical_specs(effs: Sequence[Any], ctx: SensorContext) -> list:
    """The physical parameters of the base model's ``effs`` (scale/misalignment, bias) for one sensor: what their
    :meth:`~rimu.calibration.model.Effect.physical_parameters` give, which depends only on the instrument and the
    names of the sensor's off-axis basis."""
    key = (tuple(type(e) for e in effs), ctx.instrument, ctx.geometry.off_axis_basis(ctx.index)[1])
    specs = _BASE_SPECS.get(key)
    if specs is None:
        specs = _BASE_SPECS[key] = [x for e in effs for x in e.physical_parameters(ctx)]
    return specs


def _sigma_for(sigma: dict[str, Any] | None, session: Session, inst: str,
               stats: SessionStatistics | None = None) -> np.ndarray:
    n = session.geometries[inst].n
    if sigma is not None and inst in sigma and sigma[inst] is not None:
        return np.broadcast_to(np.asarray(sigma[inst], dtype=float), (n,)).copy()
    return estimate_noise_sigma(session, inst, stats)
