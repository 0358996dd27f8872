"""Generic least squares on an effect model, sensor by sensor, with honest uncertainties.

For each sensor the raw-domain model is linear, ``y = X beta + e`` with X stacked from every usable segment
(see :mod:`rimu.calibration.model`). The estimate is ordinary least squares, which is the minimum-variance
unbiased estimate for white noise of one level per sensor; its covariance is ``sigma^2 (X^T X)^-1`` with
sigma the known noise (raw units per sample) or, if not given, the residual estimate. Physical parameters
(SF, misalignment angles, bias and every further effect in SI) follow by the map of the model module, and
their covariance by its Jacobian (checked against finite differences in the tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError
from ..session import Segment, Session
from .effects.scale_misalignment import ScaleMisalignment
from .model import ErrorModel, ParamSpec, SensorContext, axes_from_w, contexts
from .result import InstrumentCalibration

__all__ = ["BaseArrays", "LazyResiduals", "LsqResult", "SensorFit", "central_jacobian", "check_identifiable_gram", "fit_lsq", "physical_from_beta",
           "rss_from_statistics", "sensor_segments"]

#: why a segment is left out of a sensor's fit (``skipped[label]``)
SKIP_REASON = "the segment lacks inputs the model needs (a known rate, attitude or temperature)"


@dataclass
class SensorFit:
    """Fit of one sensor."""

    ctx: SensorContext
    beta_names: list[str]
    beta: np.ndarray
    beta_cov: np.ndarray
    theta_names: list[str]
    theta_specs: list[ParamSpec]
    theta: np.ndarray
    theta_cov: np.ndarray
    sigma: float
    sigma_known: bool
    n_obs: int
    rss: float
    residuals: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    @property
    def name(self) -> str:
        return self.ctx.name

    @property
    def dof(self) -> int:
        return self.n_obs - len(self.beta)

    @property
    def chi2_dof(self) -> float:
        """Residual chi-square per degree of freedom against the noise level (1 when sigma is estimated)."""
        return float(self.rss / (self.sigma**2 * max(self.dof, 1)))

    def value(self, local: str) -> float:
        return float(self.theta[self.theta_names.index(f"{self.name}.{local}")])

    def std(self, local: str) -> float:
        k = self.theta_names.index(f"{self.name}.{local}")
        return float(np.sqrt(self.theta_cov[k, k]))


@dataclass(eq=False)
class BaseArrays:
    """The base model's (scale/misalignment + bias) fit of every sensor of one instrument as arrays, rows in the
    geometry's order: what :meth:`LsqResult.to_calibration` and :attr:`LsqResult.chi2_dof` read, so that a fit of
    the base model needs no :class:`SensorFit` object unless one is asked for.

    Attributes
    ----------
    geometry : Geometry
    theta : ndarray (n, 4)
        Physical values: scale (SI per raw unit), the two misalignment angles (rad), bias (SI).
    theta_cov : ndarray (n, 4, 4)
        Their covariance, per sensor.
    misalignment : ndarray (n, 3)
        The unit misalignment rows ``m_i = C_i w_i / |w_i|`` in each sensor's sub-unit basis, from the raw-domain
        axis coefficients ``w_i`` (Cho & Park 2005, Eq. 5, 10).
    sigma : list of float
        Noise level per sample, raw units.
    rss : list of float
        Residual sum of squares, raw units squared.
    dof : int
        Observations less parameters (the same for every sensor).
    """

    geometry: Any
    theta: np.ndarray
    theta_cov: np.ndarray
    misalignment: np.ndarray
    sigma: list[float]
    rss: list[float]
    dof: int

    def theta_names(self) -> list[str]:
        """``"<sensor>.scale"``, its two off-axis misalignment names, ``"<sensor>.bias"`` for every sensor (the names
        of :meth:`~rimu.calibration.effects.scale_misalignment.ScaleMisalignment.physical_parameters` and
        :class:`~rimu.calibration.effects.bias.Bias`)."""
        g = self.geometry
        P = g.off_axis_projections()  # (a constant of the geometry's axes, shared by every Geometry with them)
        key = (g.names, id(P))
        hit = _THETA_NAMES.get(key)
        if hit is None or hit[0] is not P:
            if len(_THETA_NAMES) >= 256:
                _THETA_NAMES.clear()
            hit = _THETA_NAMES[key] = (P, [f"{nm}.{x}" for i, nm in enumerate(g.names)
                                           for x in ("scale", *g.off_axis_basis(i)[1], "bias")])
        return list(hit[1])


#: :meth:`BaseArrays.theta_names` per sensor names and off-axis constants (held with them, so that an id is not reused)
_THETA_NAMES: dict[tuple, tuple[np.ndarray, list[str]]] = {}


class LsqResult:
    """Result of :func:`fit_lsq` for one instrument: per-sensor fits (``sensors``), the segments used and those left
    out (``skipped``, label -> why).

    A fit of the base model over all the sensors at once (:class:`~rimu.calibration.estimate.LeastSquares`) gives
    its numbers as :class:`BaseArrays` (``base``) with a function that makes the :class:`SensorFit` list
    (``make_sensors``), called on the first read of ``sensors``."""

    def __init__(self, instrument: str, model: ErrorModel, sensors: list[SensorFit] | None, segments: list[str],
                 skipped: dict[str, str], base: BaseArrays | None = None,
                 make_sensors: Callable[[], list[SensorFit]] | None = None) -> None:
        if sensors is None and make_sensors is None:
            raise ValueError("an LsqResult needs its sensors' fits or a function that makes them")
        self.instrument = instrument
        self.model = model
        self._sensors = sensors
        self._make_sensors = make_sensors
        self.segments = segments
        self.skipped = skipped
        self.base = base

    @property
    def sensors(self) -> list[SensorFit]:
        """Per-sensor fits, in the geometry's order (made on first use where the fit gave :class:`BaseArrays`)."""
        if self._sensors is None:
            self._sensors = self._make_sensors()  # type: ignore[misc]
        return self._sensors

    def __repr__(self) -> str:
        return (f"LsqResult(instrument={self.instrument!r}, model={self.model!r}, segments={self.segments!r}, "
                f"skipped={self.skipped!r})")

    @property
    def chi2_dof(self) -> float:
        b = self.base
        if self._sensors is None and b is not None:  # the same sums as over the sensors' fits
            return float(sum(r / s**2 for r, s in zip(b.rss, b.sigma)) / (max(b.dof, 1) * len(b.rss)))
        rss = sum(s.rss / s.sigma**2 for s in self.sensors)
        dof = sum(max(s.dof, 1) for s in self.sensors)
        return float(rss / dof)

    def to_calibration(self) -> InstrumentCalibration:
        """The result as an :class:`InstrumentCalibration` (needs scale/misalignment and bias in the model)."""
        if self.base is not None:  # (a fit of the base model itself)
            return self._from_base(self.base)
        if "scale_misalignment" not in self.model or "bias" not in self.model:
            raise IdentifiabilityError(
                "a calibration needs the scale_misalignment and bias effects in the model; "
                f"this model is {self.model.label}"
            )
        g = self.sensors[0].ctx.geometry
        n = g.n
        if [e.name for e in self.model.effects] == ["scale_misalignment", "bias"] and len(self.sensors) == n:
            return self._base_calibration(g)
        scale, bias, sig = np.empty(n), np.empty(n), np.empty(n)
        mis = np.empty((n, 3))
        names: list[str] = []
        blocks: list[np.ndarray] = []
        effects: dict[str, dict[str, float]] = {}
        sm = ScaleMisalignment()
        for s in self.sensors:
            i = s.ctx.index
            scale[i] = s.value("scale")
            bias[i] = s.value("bias")
            sig[i] = s.sigma * scale[i]
            k = [s.beta_names.index(f"{s.name}.w_{a}") for a in "xyz"]
            mis[i] = sm.misalignment_row(s.beta[k], s.ctx)
            names += s.theta_names
            blocks.append(s.theta_cov)
            for e in self.model.effects_for(s.ctx):
                if e.name in ("bias", "scale_misalignment"):
                    continue
                for p in e.physical_parameters(s.ctx):
                    effects.setdefault(e.name, {})[f"{s.name}.{p.name}"] = s.value(p.name)
        cov = _block_diag(blocks)
        return InstrumentCalibration(self.instrument, g, scale, mis, bias, sig, cov, names, effects)


    def _from_base(self, b: BaseArrays) -> InstrumentCalibration:
        """:meth:`to_calibration` from :class:`BaseArrays`: the numbers of :meth:`_base_calibration`, without a
        :class:`SensorFit` per sensor."""
        g = b.geometry
        theta = b.theta
        scale = theta[:, 0]
        return InstrumentCalibration(self.instrument, g, scale, b.misalignment, theta[:, 3], np.array(b.sigma) * scale,
                                     _block_diag_stack(b.theta_cov), b.theta_names(), {})

    def _base_calibration(self, g: "object") -> InstrumentCalibration:
        """:meth:`to_calibration` of the base model (every sensor's theta is scale, two misalignment angles, bias;
        beta is w_x, w_y, w_z, c), as array operations over the sensors: the same numbers as the per-sensor path."""
        sensors = self.sensors
        n = len(sensors)
        order = [s.ctx.index for s in sensors]
        ordered = sensors if order == list(range(n)) else sorted(sensors, key=lambda s: s.ctx.index)
        theta = np.array([s.theta for s in ordered])  # (n, 4)
        W = np.array([s.beta[:3] for s in ordered])
        sig = np.array([s.sigma for s in ordered])
        names = [x for s in sensors for x in s.theta_names]  # the covariance follows the sensors' order
        cov = _block_diag([s.theta_cov for s in sensors])
        scale = theta[:, 0]
        C = g.subunit_rotations()  # type: ignore[attr-defined]
        mis = np.einsum("nij,nj->ni", C, W / np.sqrt(np.einsum("ni,ni->n", W, W))[:, None])
        return InstrumentCalibration(self.instrument, g, scale, mis, theta[:, 3], sig * scale, cov, names, {})  # type: ignore[arg-type]


def physical_from_beta(model: ErrorModel, ctx: SensorContext, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[ParamSpec]]:
    """Physical parameters theta from raw-domain beta, with the Jacobian d theta / d beta.

    The scale/misalignment block maps by :meth:`ScaleMisalignment.physical`; every other effect by
    theta = beta * SF with SF = 1/|w|. Without a scale block, theta = beta (raw units).
    """
    effs = model.effects_for(ctx)
    offs = [0]
    for e in effs:
        offs.append(offs[-1] + len(e.parameters(ctx)))
    p = offs[-1]
    theta = np.zeros(p)
    J = np.zeros((p, p))
    specs: list[ParamSpec] = []
    w_slice = None
    for e, a, b in zip(effs, offs[:-1], offs[1:]):
        if isinstance(e, ScaleMisalignment):
            w_slice = slice(a, b)
    if w_slice is not None:
        w = beta[w_slice]
        nw = math.sqrt(float(w @ w))
        if not nw > 0:
            raise IdentifiabilityError("a sensor's output does not respond to its input (zero scale-misalignment "
                                       "vector): a dead sensor or an unconnected channel; remove it from the geometry")
        sf = 1.0 / nw
        d_sf = -w / nw**3
    for e, a, b in zip(effs, offs[:-1], offs[1:]):
        if isinstance(e, ScaleMisalignment):
            th, jac = e.physical(beta[a:b], ctx)
            theta[a:b] = th
            J[a:b, a:b] = jac
            specs += e.physical_parameters(ctx)
        elif w_slice is not None:
            theta[a:b] = beta[a:b] * sf
            J[a:b, a:b] = np.eye(b - a) * sf
            J[a:b, w_slice] = np.outer(beta[a:b], d_sf)
            specs += e.physical_parameters(ctx)
        else:
            theta[a:b] = beta[a:b]
            J[a:b, a:b] = np.eye(b - a)
            specs += e.parameters(ctx)
    return theta, J, specs


def fit_lsq(
    session: Session,
    model: ErrorModel | None = None,
    instrument: str = "gyro",
    sigma: float | Sequence[float] | None = None,
    segments: Sequence[str] | None = None,
) -> LsqResult:
    """Fit ``model`` to ``session`` for one instrument by least squares, sensor by sensor.

    Parameters
    ----------
    session : Session
    model : ErrorModel, optional
        Default: scale/misalignment + bias.
    instrument : str
    sigma : float or sequence, optional
        Known per-sample noise of the raw outputs (raw units), per sensor or common. Default: estimated
        from the residuals.
    segments : sequence of str, optional
        Labels of the segments to use (default all that carry the inputs the model needs).

    Raises
    ------
    IdentifiabilityError
        The usable segments cannot identify some parameters; they are named.
    """
    model = model or ErrorModel.base()
    segs = [session.segment(x) for x in segments] if segments is not None else list(session.segments)
    ctxs = contexts(session, instrument)
    sig = None if sigma is None else np.broadcast_to(np.asarray(sigma, dtype=float), (len(ctxs),))
    if on_calibrated_axes(model):
        # the effects of the input along an axis act on what the sensor really senses: fit them on the axes a
        # first fit of scale, misalignment and bias calibrates (whose bias by the other effects enters the
        # effects' columns to second order only)
        ctxs = contexts(session, instrument, axes=first_axes(session, model, instrument, segs, sig))
    fits, used, skipped = _fit_sensors(session, model, instrument, ctxs, segs, sig)
    return LsqResult(instrument, model, fits, used, skipped)


def on_calibrated_axes(model: ErrorModel) -> bool:
    """Whether a model's further effects are fitted on the calibrated axes (it has the scale/misalignment block
    and some effect beyond scale, misalignment and bias)."""
    return "scale_misalignment" in model and any(e.name not in ("bias", "scale_misalignment") for e in model)


def first_axes(session: Session, model: ErrorModel, instrument: str, segs: list, sig: np.ndarray | None,
               ctxs: list[SensorContext] | None = None) -> np.ndarray:
    """Calibrated axes from a fit of the model's scale/misalignment and bias alone on the nominal axes
    (``ctxs``: the nominal contexts, default :func:`contexts` of the session)."""
    base = ErrorModel([e for e in model if e.name in ("scale_misalignment", "bias")])
    fits, _, _ = _fit_sensors(session, base, instrument, ctxs or contexts(session, instrument), segs, sig)
    return calibrated_axes(base, fits)


def calibrated_axes(model: ErrorModel, fits: Sequence["SensorFit"]) -> np.ndarray:
    """The calibrated axes (n, 3) in MB, a_i = w_i / |w_i|, from per-sensor fits of ``model``."""
    W = np.empty((len(fits), 3))
    for s in fits:
        k = [s.beta_names.index(f"{s.name}.w_{a}") for a in "xyz"]
        W[s.ctx.index] = s.beta[k]
    return axes_from_w(W)


def _fit_sensors(session: Session, model: ErrorModel, instrument: str, ctxs: list[SensorContext],
                 segs: list, sig: np.ndarray | None) -> tuple[list[SensorFit], list[str], dict[str, str]]:
    fits: list[SensorFit] = []
    skipped: dict[str, str] = {}
    used: list[str] = []
    for ctx in ctxs:
        # sufficient statistics per segment: X^T X, X^T y, y^T y (the design is never stacked over the session)
        p_ = len(model.parameter_names(ctx))
        G, h, q, n_obs = np.zeros((p_, p_)), np.zeros(p_), 0.0, 0
        labels = []
        for seg, X, y in sensor_segments(model, ctx, segs, instrument, skipped):
            G += X.T @ X
            h += X.T @ y
            q += float(y @ y)
            n_obs += len(y)
            labels.append(seg.label)
        if not labels:
            raise IdentifiabilityError(f"no segment of the session carries the inputs the model {model.label} needs")
        names = model.parameter_names(ctx)
        check_identifiable_gram(G, n_obs, names, instrument)
        XtX_inv = np.linalg.inv(G)
        beta = XtX_inv @ h
        rss = rss_from_statistics(q, h, G, beta)
        if rss < 1e-8 * q:  # cancellation in q - 2 b.h + b.G.b: a second exact pass, segment by segment
            rss = sum(float(np.sum(_design_residual(model, ctx, session.segment(lab), instrument, beta)() ** 2))
                      for lab in labels)
        dof = max(n_obs - len(beta), 1)
        known = sig is not None
        s = float(sig[ctx.index]) if known else float(np.sqrt(rss / dof))
        bcov = s**2 * XtX_inv
        theta, J, specs = physical_from_beta(model, ctx, beta)
        tcov = J @ bcov @ J.T
        res = LazyResiduals({lab: _design_residual(model, ctx, session.segment(lab), instrument, beta)
                             for lab in labels})
        fits.append(SensorFit(ctx, names, beta, bcov, [f"{ctx.name}.{p.name}" for p in specs], specs,
                              theta, tcov, s, known, n_obs, rss, res))
        used = labels
    return fits, used, skipped


def sensor_segments(model: ErrorModel, ctx: SensorContext, segs: Iterable[Segment], instrument: str,
                    skipped: dict[str, str]) -> Iterator[tuple[Segment, np.ndarray, np.ndarray]]:
    """The design of one sensor, segment by segment: ``(segment, X, y)`` with ``X`` the model's regressor
    matrix (n, p) on the segment and ``y`` the sensor's raw output (n,). Segments that lack an input the model
    needs are left out and recorded in ``skipped`` (label -> reason). Every per-sensor fit (the estimators'
    sufficient statistics, the diagnosis' stacked design) collects its design here."""
    for seg in segs:
        X = model.design(seg, ctx)
        if X is None:
            skipped[seg.label] = SKIP_REASON
            continue
        yield seg, X, seg.raw[instrument][:, ctx.index]


def central_jacobian(f: Callable[[np.ndarray], np.ndarray], p: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Jacobian of ``f`` at ``p`` by central differences with steps ``h`` (one per parameter)."""
    f0 = f(p)
    J = np.empty((f0.size, p.size))
    for k in range(p.size):
        d = np.zeros_like(p)
        d[k] = h[k]
        J[:, k] = (f(p + d) - f(p - d)) / (2 * h[k])
    return J


def rss_from_statistics(q: float, h: np.ndarray, G: np.ndarray, beta: np.ndarray) -> float:
    """Residual sum of squares ``|y - X beta|^2 = y.y - 2 beta.X^T y + beta.X^T X.beta`` from the statistics."""
    return max(float(q) - 2.0 * float(beta @ h) + float(beta @ G @ beta), 0.0)


def _design_residual(model: ErrorModel, ctx: SensorContext, seg, instrument: str,
                     beta: np.ndarray) -> Callable[[], np.ndarray]:
    """A function returning the segment's residual ``y - X beta`` (the design rebuilt when asked for)."""
    def make() -> np.ndarray:
        return seg.raw[instrument][:, ctx.index] - model.design(seg, ctx) @ beta

    return make


def _check_identifiable(X: np.ndarray, names: list[str], instrument: str) -> None:
    """Raise IdentifiabilityError naming the parameters whose design columns ``X`` are linearly dependent."""
    check_identifiable_gram(X.T @ X, X.shape[0], names, instrument)


def check_identifiable_gram(G: np.ndarray, n_rows: int, names: list[str], instrument: str) -> None:
    """The identifiability check on the Gram matrix ``G = X^T X`` of ``n_rows`` observations (the sufficient
    statistic the estimators accumulate segment by segment, so no per-sample design is ever held).

    Columns are scaled to unit norm; a direction whose scaled eigenvalue is below 1e-12 of the largest (a
    singular value ratio of 1e-6: a variance inflation of 1e12) cannot be identified and its parameters are
    named.
    """
    p = G.shape[0]
    if n_rows < p:
        raise IdentifiabilityError(f"{instrument}: {n_rows} observations for {p} parameters; add segments", names)
    scale = np.sqrt(np.clip(np.diag(G), 0.0, None))
    scale[scale == 0] = 1.0
    lam, V = np.linalg.eigh(G / np.outer(scale, scale))
    null = V[:, lam <= 1e-12 * max(lam[-1], 1e-300)].T
    if null.size:
        involved = [names[k] for k in range(len(names)) if np.abs(null[:, k]).max() > 1e-6]
        raise IdentifiabilityError(
            f"{instrument}: the segments cannot separate these parameters (their columns are linearly dependent): "
            f"{involved}. Add segments whose inputs differ in the directions involved (more attitudes or rotation axes)",
            involved,
        )


class LazyResiduals(Mapping):
    """Per-segment residuals ``y - X beta`` (raw units), computed when asked for, never all held at once.

    A fit keeps memory proportional to the number of segments, not of samples: each entry is recomputed from
    the segment's samples on access (``residuals["P1"]``). Entries set explicitly (``residuals[label] =
    array``) are stored as given.
    """

    def __init__(self, makers: dict[str, Callable[[], np.ndarray]] | None = None, *,
                 labels: Iterable[str] = (), compute: Callable[[str], np.ndarray] | None = None) -> None:
        self._makers: dict[str, Callable[[], np.ndarray]] = dict(makers or {})
        #: segments whose residual is ``compute(label)`` (one function for all of them: no closure per segment)
        self._labels: tuple[str, ...] = ((tuple(k for k in labels if k not in self._makers) if self._makers
                                          else tuple(labels)) if compute else ())
        self._compute = compute
        self._given: dict[str, np.ndarray] = {}

    def __getitem__(self, label: str) -> np.ndarray:
        if label in self._given:
            return self._given[label]
        mk = self._makers.get(label)
        if mk is not None:
            return mk()
        if label in self._labels:
            return self._compute(label)  # type: ignore[misc]
        raise KeyError(label)

    def __setitem__(self, label: str, value: np.ndarray) -> None:
        self._given[label] = np.asarray(value)
        self._makers.pop(label, None)

    def __iter__(self) -> Iterator[str]:
        yield from self._makers
        yield from self._labels
        yield from (k for k in self._given if k not in self._makers and k not in self._labels)

    def __len__(self) -> int:
        return len(set(self._makers) | set(self._labels) | set(self._given))

    def __repr__(self) -> str:
        return f"LazyResiduals({list(self)})"


def _block_diag_stack(blocks: np.ndarray) -> np.ndarray:
    """The block-diagonal matrix (n m, n m) of ``blocks`` (n, m, m), in one assignment."""
    n, m, _ = blocks.shape
    if n <= 8:  # (a few sensors: a slice each is cheaper than the index arrays)
        out = np.zeros((n * m, n * m))
        for i in range(n):
            out[i * m:(i + 1) * m, i * m:(i + 1) * m] = blocks[i]
        return out
    out = np.zeros((n, m, n, m))
    k = np.arange(n)
    out[k, :, k, :] = blocks
    return out.reshape(n * m, n * m)


def _block_diag(blocks: list[np.ndarray]) -> np.ndarray:
    p = sum(b.shape[0] for b in blocks)
    out = np.zeros((p, p))
    k = 0
    for b in blocks:
        m = b.shape[0]
        out[k:k + m, k:k + m] = b
        k += m
    return out
