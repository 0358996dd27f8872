"""Runtime compensation of every further effect of a calibration (the stage before the projection).

The calibrated output model of sensor i (:mod:`rimu.calibration.model`; Cho & Park 2005, Eq. 1-3 extended) is::

    SF_i y_i = a_i . u + b_i + sum_e phi_e(inputs, s_i) . theta_e,i + v_i,      s_i = a_i . u

with a_i the calibrated axis (effects of the input along an axis act on what the sensor really senses; the
estimators fit them there) and the regressors phi of each effect declared by the effect itself
(:meth:`rimu.calibration.model.Effect.runtime_columns`, compiled from its
:class:`~rimu.calibration.model.RuntimeForm`). Effects whose regressors depend only on the epoch's other
inputs (time, temperature, specific force, angular rate) are *exogenous*: their contribution is computed and
subtracted. Effects that depend on the sensor's own input s_i (nonlinearity, asymmetry, scale temperature
coefficients, cross coupling) are *output-side*: the stage solves ::

    q_i + c_i(q) = z_i,     z_i = SF_i y_i - b_i - (exogenous terms)

for q_i = a_i . u by Newton's method, sensor by sensor (cross coupling enters the Jacobian to first order).
That is the exact inverse of the model, not a first-order correction: two steps from q = z leave less than
1e-12 of the input (tested against the forward model with every effect at once, up to 460 deg/s and 3 g). The
result is handed on as the raw output of an ideal scale/misalignment/bias sensor, ``(q + b) / SF``, so
projection, parity and FDI downstream are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..calibration.model import MONOMIALS, RUNTIME_INPUTS, Effect, RuntimeInputs, SensorContext, effect, unit_axes
from ..calibration.result import InstrumentCalibration
from ..errors import CalibrationFileError, MissingInputError, NotCompensableError

__all__ = ["BASE_EFFECTS", "EffectCompensation", "compensable_effects", "monomial_values"]

#: inputs the stage makes itself (each sensor's own input, the instrument's MB input)
_INTERNAL = ("axis_input", "input")
_T0 = np.zeros(1)

#: Effects the projection itself undoes (folded into its matrices); not part of this stage.
BASE_EFFECTS = ("bias", "scale_misalignment")


def compensable_effects() -> list[str]:
    """Names of the registered effects that declare a runtime compensation.

    >>> "sf_quadratic" in compensable_effects(), "earth_rate" in compensable_effects()
    (True, False)
    """
    from ..calibration.model import EFFECTS

    names = []
    for name, cls in EFFECTS.items():
        if name != cls.name or name in BASE_EFFECTS:
            continue
        if cls.runtime_columns is not Effect.runtime_columns:
            names.append(name)
    return sorted(names)


class _Term:
    """One effect of one instrument: the effect, its coefficients (n, k) and whether it is output-side."""

    def __init__(self, eff: Effect, theta: np.ndarray) -> None:
        self.effect = eff
        self.theta = theta
        self.output_side = "axis_input" in eff.runtime_needs or "input" in eff.runtime_needs


_PAIRS = [(a, b) for a in range(3) for b in range(a, 3)]
_PA = np.array([a for a, _ in _PAIRS])
_PB = np.array([b for _, b in _PAIRS])


def monomial_values(inputs: RuntimeInputs, reference_temperature: float) -> np.ndarray:
    """All of :data:`~rimu.calibration.model.MONOMIALS` for N samples, (N, M); absent inputs give zeros (the
    compiled stage only reads the monomials its effects use, whose inputs are checked to be present)."""
    t = np.asarray(inputs.t, dtype=float)
    N = t.shape[0]
    cols = [np.ones(N), t]
    if inputs.temperature is not None:
        dT = np.asarray(inputs.temperature, dtype=float) - reference_temperature
        cols += [dT, dT * dT]
    else:
        cols += [np.zeros(N), np.zeros(N)]
    out = np.column_stack(cols)
    parts = [out]
    for v in (inputs.specific_force, inputs.angular_rate):
        if v is None:
            parts.append(np.zeros((N, 9)))
        else:
            v = np.asarray(v, dtype=float)
            parts += [v, v[:, _PA] * v[:, _PB]]
    return np.concatenate(parts, axis=1)


def _monomials_one(t: float, dT: float, f: list[float] | None, w: list[float] | None) -> list[float]:
    """:func:`monomial_values` of one sample in Python floats (the same products, so the same numbers)."""
    out = [1.0, t, dT, dT * dT]
    for v in (f, w):
        if v is None:
            out += [0.0] * 9
        else:
            x, y, z = v
            out += [x, y, z, x * x, x * y, x * z, y * y, y * z, z * z]
    return out


class EffectCompensation:
    """Compensation of the further effects of one instrument's calibration.

    Each effect is compiled from its :class:`~rimu.calibration.model.RuntimeForm` into a few matrices (the
    exogenous error and the output-side polynomial coefficients are one matrix-vector product with the epoch's
    monomials; cross coupling is one n x n matrix); an effect without a form is evaluated through its
    ``runtime_columns`` (same numbers, slower).

    Parameters
    ----------
    calibration : InstrumentCalibration
        Its ``effects`` (``{effect: {"sensor.param": value}}``, SI) are compensated; scale, misalignment and
        bias are the projection's.
    reference_temperature : float
        T_ref of the temperature effects, degC (the calibration's, 25 degC by default).
    latitude, gravity : float, optional
        For the sensor contexts (as in the calibration).
    newton_steps : int
        Newton steps of the output-side inversion (see the module docstring); 3 where cross coupling needs the
        instrument's estimate, which lags one step.

    Raises
    ------
    NotCompensableError
        An effect of the calibration declares no runtime compensation (named).
    CalibrationFileError
        An effect parameter names a sensor or parameter the effect does not have.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.5)
    >>> cal.effects = {"sf_quadratic": {"x1.k2": 1e-3}}
    >>> comp = EffectCompensation(cal)
    >>> comp.needs, [t.effect.name for t in comp.terms]
    ((), ['sf_quadratic'])
    """

    def __init__(self, calibration: InstrumentCalibration, reference_temperature: float = 25.0,
                 latitude: float | None = None, gravity: float = 9.80665, newton_steps: int = 2) -> None:
        cal = calibration
        g = cal.geometry
        self.calibration = cal
        self.instrument = cal.instrument
        self.n = g.n
        self.reference_temperature = float(reference_temperature)
        A = unit_axes(cal.axes_mb())
        self.ctxs = [SensorContext(cal.instrument, i, g, latitude, gravity, reference_temperature, axes=A)
                     for i in range(g.n)]
        self.newton_steps = int(newton_steps)
        self.terms: list[_Term] = []
        for name, params in cal.effects.items():
            if name in BASE_EFFECTS:
                continue
            eff = effect(name)
            if type(eff).runtime_columns is Effect.runtime_columns:
                raise NotCompensableError(
                    f"{cal.instrument}: the calibration holds effect {name!r}, which has no runtime compensation "
                    f"({eff.description}). Recalibrate without it, or drop it from the file's 'effects' to run "
                    "the pipeline without it")
            theta = self._coefficients(eff, params)
            if np.any(theta):
                self.terms.append(_Term(eff, theta))
        self.exogenous = [t for t in self.terms if not t.output_side]
        self.output_side = [t for t in self.terms if t.output_side]
        needs: list[str] = []
        for t in self.terms:
            needs += [x for x in t.effect.runtime_needs if x not in _INTERNAL and x not in needs]
        #: inputs from the stream this stage needs, in the order of :data:`RUNTIME_INPUTS`
        self.needs: tuple[str, ...] = tuple(x for x in RUNTIME_INPUTS if x in needs)
        self._scale = cal.scale.copy()
        self._bias = cal.bias.copy()
        self._compile()

    # ------------------------------------------------------------------ compilation
    def _compile(self) -> None:
        n, M = self.n, len(MONOMIALS)
        blocks = {"exo": np.zeros((n, M)), 1: np.zeros((n, M)), 2: np.zeros((n, M)), 3: np.zeros((n, M)),
                  "abs": np.zeros((n, M))}
        Hx = np.zeros((n, 3))
        self._generic_exo: list[_Term] = []
        self._generic_out: list[_Term] = []
        for t in self.terms:
            form = t.effect.runtime_form(self.ctxs)
            key: Any = None
            if form is not None:
                if form.kind == "exogenous" and not t.output_side:
                    key = "exo"
                elif form.kind == "power" and form.power in (1, 2, 3) and t.output_side:
                    key = form.power
                elif form.kind == "absolute" and t.output_side:
                    key = "abs"
                elif form.kind == "pair" and t.output_side and not np.any(form.F[:, :, 1:]):
                    k = form.F.shape[1]
                    Hx += np.einsum("ik,ikj->ij", form.F[:, :, 0] * t.theta[:, :k], form.directions)
                    continue
            if key is None:
                (self._generic_out if t.output_side else self._generic_exo).append(t)
                continue
            blocks[key] += np.einsum("ikm,ik->im", form.F, t.theta[:, :form.F.shape[1]])
        used = [k for k, B in blocks.items() if np.any(B)]
        #: blocks that depend on the epoch's monomials: one matrix-vector product (the constant column included,
        #: mono[0] = 1) gives them all; the others are constant vectors
        self._dyn_keys = [k for k in used if np.any(blocks[k][:, 1:])]
        self._const = {k: blocks[k][:, 0].copy() for k in used if k not in self._dyn_keys}
        self._dyn = np.ascontiguousarray(np.vstack([blocks[k] for k in self._dyn_keys]) if self._dyn_keys
                                         else np.zeros((0, M)))
        #: cross coupling: (h_i . u)(Hx u)_i (u the instrument's MB input, h_i the nominal axes)
        self._Hx = Hx if np.any(Hx) else None
        self._H = self.calibration.geometry.H
        self._needs_u = self._Hx is not None or any("input" in t.effect.runtime_needs for t in self._generic_out)
        if self._needs_u and self.newton_steps == 2:
            self.newton_steps = 3  # the estimate of u lags one step: one more to reach the rounding level
        #: exogenous-only instruments: y' = y - mono . E / SF (one product in the raw domain)
        self._raw_exo = None
        if not self.output_side and not self._generic_exo and "exo" in blocks:
            self._raw_exo = np.ascontiguousarray(blocks["exo"] / self.calibration.scale[:, None])

    def _coefficient_arrays(self, mono: np.ndarray | None) -> dict[Any, np.ndarray]:
        """Per block (exogenous error, k1, k2, k3, k_abs): (N, n), (n,) for one sample, or (n,) constants."""
        out: dict[Any, np.ndarray] = dict(self._const)
        if self._dyn_keys and mono is not None:
            V = mono @ self._dyn.T
            n = self.n
            for j, k in enumerate(self._dyn_keys):
                out[k] = V[..., j * n:(j + 1) * n]
        return out

    def __bool__(self) -> bool:
        return bool(self.terms)

    @property
    def has_generic(self) -> bool:
        """Whether some effect is evaluated through ``runtime_columns`` (no compiled form)."""
        return bool(self._generic_exo or self._generic_out)


    def effects_needing(self, name: str) -> list[str]:
        """Names of the effects that need input ``name``."""
        return [t.effect.name for t in self.terms if name in t.effect.runtime_needs]

    def _coefficients(self, eff: Effect, params: dict[str, float]) -> np.ndarray:
        specs = [eff.physical_parameters(c) if eff.applies_to(c) else [] for c in self.ctxs]
        k = max([len(s) for s in specs] + [1])
        theta = np.zeros((self.n, k))
        used = set()
        for i, (c, sp) in enumerate(zip(self.ctxs, specs)):
            for j, p in enumerate(sp):
                key = f"{c.name}.{p.name}"
                if key in params:
                    theta[i, j] = float(params[key])
                    used.add(key)
        unknown = sorted(set(params) - used)
        if unknown:
            raise CalibrationFileError(
                f"{self.instrument}: effect {eff.name!r} has parameters {unknown} that name no sensor/parameter of "
                f"this geometry ({self.calibration.geometry.name}); the file does not belong to this model")
        if not np.all(np.isfinite(theta)):
            raise CalibrationFileError(f"{self.instrument}: effect {eff.name!r} has non-finite coefficients")
        return theta

    # ------------------------------------------------------------------ evaluation (reference: runtime_columns)
    def _sum(self, terms: Sequence[_Term], inputs: RuntimeInputs, slope: bool = False) -> np.ndarray | float:
        out: np.ndarray | float = 0.0
        for t in terms:
            cols = t.effect.runtime_slope(inputs, self.ctxs) if slope else t.effect.runtime_columns(inputs, self.ctxs)
            out = out + np.einsum("nik,ik->ni", cols, t.theta)
        return out

    def exogenous_error(self, inputs: RuntimeInputs) -> np.ndarray | float:
        """Sum of the exogenous effects' output errors, (N, n), SI, through every effect's ``runtime_columns``
        (the reference the compiled path is tested against)."""
        return self._sum(self.exogenous, inputs)

    def output_error(self, inputs: RuntimeInputs) -> np.ndarray | float:
        """Sum of the output-side effects' errors at ``inputs.axis_input``, (N, n), SI (reference path)."""
        return self._sum(self.output_side, inputs)

    # ------------------------------------------------------------------ compiled evaluation
    def _output_poly(self, s: np.ndarray, K: dict[Any, np.ndarray], inputs: RuntimeInputs
                     ) -> tuple[np.ndarray, np.ndarray]:
        """c(s) and dc/ds_i of the output-side effects (compiled blocks plus any generic ones):
        ``c = (k1 + (k2 + k3 s) s) s + ka |s| + (h . u)(Hx u)``, ``dc = k1 + (2 k2 + 3 k3 s) s + ka sign(s)``
        with the cross coupling from the current MB estimate u, held within a step."""
        k1, k2, k3, ka = K.get(1), K.get(2), K.get(3), K.get("abs")
        lin = k1 if k1 is not None else 0.0
        xc = None
        if self._Hx is not None:  # cross coupling (h_i . u)(Hx u)_i: from the estimate u, held within a step
            u = inputs.input
            xc = (u @ self._H.T) * (u @ self._Hx.T) if u.ndim > 1 else (self._H @ u) * (self._Hx @ u)
        if k3 is not None:
            a = k3 * s
            quad = a + k2 if k2 is not None else a
            slope2 = 2.0 * k2 + 3.0 * a if k2 is not None else 3.0 * a
        elif k2 is not None:
            quad, slope2 = k2, 2.0 * k2
        else:
            quad, slope2 = 0.0, 0.0
        c = (lin + quad * s) * s
        dc = lin + slope2 * s
        if ka is not None:
            c = c + ka * np.abs(s)
            dc = dc + ka * np.sign(s)
        if xc is not None:
            c = c + xc
        if self._generic_out:
            inputs.axis_input = s
            c += self._sum(self._generic_out, inputs)
            dc += self._sum(self._generic_out, inputs, slope=True)
            inputs.axis_input = None
        return c, dc

    def solve(self, Y: np.ndarray, inputs: RuntimeInputs, mono: np.ndarray | None = None,
              estimate: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """Effect-free compensated outputs ``q = a . u + v`` (N, n), SI, from raw outputs Y (N, n).

        Non-finite raw values stay non-finite (the projection routes around them), and leave the other sensors
        alone. ``mono``: the inputs' :func:`monomial_values`, if already computed; ``estimate(Q)``: the MB
        estimate (N, 3) of compensated outputs on the active sensors (for the cross coupling).
        """
        self._check(inputs)
        if mono is None and self._dyn_keys:
            mono = monomial_values(inputs, self.reference_temperature)
        K = self._coefficient_arrays(mono)
        with np.errstate(invalid="ignore", over="ignore"):
            z = Y * self._scale - self._bias
            exo = K.get("exo")
            if exo is not None:
                z = z - exo
            if self._generic_exo:
                z = z - self._sum(self._generic_exo, inputs)
            if not self.output_side:
                return z
            return self._newton(z, K, inputs, estimate)

    def solve_one(self, y: np.ndarray, mono: list[float] | None, inputs: RuntimeInputs | None = None,
                  estimate: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """:meth:`solve` for one sample (n,): the same arithmetic on 1-D arrays, for the per-sample path.
        ``mono``: the sample's monomials (:func:`monomial_values` of one sample, as a list); ``inputs`` only
        where an effect has no compiled form."""
        if self._generic_exo or self._generic_out:  # effects without a compiled form: the general path
            if inputs is None:
                raise ValueError("solve_one needs the RuntimeInputs where an effect has no compiled form")
            one = None if estimate is None else (lambda Q: estimate(Q[0])[None])
            return self.solve(y[None], inputs, None if mono is None else np.array(mono)[None], one)[0]
        K = self._coefficient_arrays(None if mono is None else np.array(mono))
        z = y * self._scale - self._bias
        exo = K.get("exo")
        if exo is not None:
            z = z - exo
        if not self.output_side:
            return z
        inp = RuntimeInputs(_T0)
        s = sum(z.tolist())
        if s - s != 0.0:  # a non-finite output: keep it from warning, as the block path does
            with np.errstate(invalid="ignore", over="ignore"):
                return self._newton(z, K, inp, estimate)
        return self._newton(z, K, inp, estimate)

    def _newton(self, z: np.ndarray, K: dict[Any, np.ndarray], inputs: RuntimeInputs,
                estimate: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray:
        """Solve ``q + c(q) = z`` for q by Newton steps on each sensor's own input; the instrument's MB input u
        of the cross coupling is re-estimated from q before each step (``estimate``: the projection on the
        active sensors). Each step leaves ~(c'' e + |dc/du| |G|) e of the error e (|dc/du| ~ 1e-4 at
        grade-typical cross coupling), so two steps from q = z reach the rounding level."""
        if self._needs_u and estimate is None:
            raise ValueError("the cross coupling needs the instrument's estimate: pass estimate=")
        q = z
        for _ in range(self.newton_steps):
            if self._needs_u:
                inputs.input = estimate(q)
            c, dc = self._output_poly(q, K, inputs)
            q = q - (q + c - z) / (1.0 + dc)
        inputs.input = None
        return q

    def raw(self, Y: np.ndarray, inputs: RuntimeInputs,
            estimate: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """Raw outputs with every effect removed: those of an ideal scale/misalignment/bias sensor, (N, n)."""
        if self._raw_exo is not None:
            self._check(inputs)
            return Y - monomial_values(inputs, self.reference_temperature) @ self._raw_exo.T
        return self.equivalent_raw(self.solve(Y, inputs, estimate=estimate))

    def raw_one(self, y: np.ndarray, mono: list[float], inputs: RuntimeInputs | None = None,
                estimate: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
        """:meth:`raw` for one sample (n,), ``mono`` its monomials as a list; ``estimate(q)`` (3,) of one."""
        if self._raw_exo is not None:
            return y - self._raw_exo @ np.array(mono)
        return self.equivalent_raw(self.solve_one(y, mono, inputs, estimate))

    def equivalent_raw(self, Q: np.ndarray) -> np.ndarray:
        """Raw outputs of an ideal scale/misalignment/bias sensor giving compensated outputs Q: ``(Q + b) / SF``."""
        return (Q + self._bias) / self._scale

    def forward(self, U: np.ndarray, inputs: RuntimeInputs) -> np.ndarray:
        """Noise-free raw outputs (N, n) for true inputs U (N, 3) in MB: the calibrated model itself."""
        U = np.asarray(U, dtype=float)
        z = U @ self.calibration.axes_mb().T + self._bias
        if self.exogenous:
            z = z + self.exogenous_error(inputs)
        if self.output_side:
            inputs.axis_input = U @ np.stack([c.axis for c in self.ctxs]).T
            inputs.input = U
            z = z + self.output_error(inputs)
            inputs.axis_input = inputs.input = None
        return z / self._scale

    def _check(self, inputs: RuntimeInputs) -> None:
        for t in self.exogenous + self.output_side:
            for name in t.effect.runtime_needs:
                if name not in _INTERNAL and getattr(inputs, "t" if name == "time" else name) is None:
                    raise MissingInputError(
                        f"{self.instrument}: effect {t.effect.name!r} needs the {name.replace('_', ' ')}, and this "
                        "sample has none", t.effect.name, name)
