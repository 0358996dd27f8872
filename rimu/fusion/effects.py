"""Runtime compensation of every further effect of a calibration (the stage before the projection).

The calibrated output model of sensor i (:mod:`rimu.calibration.model`; Cho & Park 2005, Eq. 1-3 extended) is::

    SF_i y_i = a_i . u + b_i + sum_e phi_e(inputs, s_i) . theta_e,i + v_i,      s_i = h_i . u

with a_i the calibrated axis, h_i the nominal one, and the regressors phi of each effect declared by the effect
itself (:meth:`rimu.calibration.model.Effect.runtime_columns`). Effects whose regressors depend only on the
epoch's other inputs (time, temperature, specific force, angular rate) are *exogenous*: their contribution is
computed and subtracted. Effects that depend on the sensor's own input s_i (nonlinearity, asymmetry, scale
temperature coefficients, cross coupling) are *output-side*: the stage solves ::

    q_i + c_i(q_i + d_i) = z_i,     z_i = SF_i y_i - b_i - (exogenous terms),   d_i = (h_i - a_i) . u

for q_i = a_i . u by Newton's method on each sensor's own input (the slope from
:meth:`~rimu.calibration.model.Effect.runtime_slope`), with u the least-squares estimate of q on the active
sensors. That is the exact inverse of the model, not a first-order correction: with grade-typical sizes
(|dc/ds| ~ 1e-3, misalignment ~ 1e-2 rad) two refinements of two Newton steps leave less than 1e-12 of the
input (tested against the forward model). The result is handed on as the raw output of an ideal
scale/misalignment/bias sensor, ``(q + b) / SF``, so projection, parity and FDI downstream are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..calibration.model import RUNTIME_INPUTS, Effect, RuntimeInputs, SensorContext, effect
from ..calibration.result import InstrumentCalibration
from ..errors import CalibrationFileError, MissingInputError, NotCompensableError

__all__ = ["EffectCompensation", "BASE_EFFECTS", "compensable_effects"]

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
        self.output_side = "axis_input" in eff.runtime_needs


class EffectCompensation:
    """Compensation of the further effects of one instrument's calibration.

    Parameters
    ----------
    calibration : InstrumentCalibration
        Its ``effects`` (``{effect: {"sensor.param": value}}``, SI) are compensated; scale, misalignment and
        bias are the projection's.
    reference_temperature : float
        T_ref of the temperature effects, degC (the calibration's, 25 degC by default).
    latitude, gravity : float, optional
        For the sensor contexts (as in the calibration).
    newton_iterations, refinements : int
        Newton steps per refinement, and refinements of the axis correction d (see the module docstring).

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
                 latitude: float | None = None, gravity: float = 9.80665, newton_iterations: int = 2,
                 refinements: int = 2) -> None:
        cal = calibration
        g = cal.geometry
        self.calibration = cal
        self.instrument = cal.instrument
        self.n = g.n
        self.ctxs = [SensorContext(cal.instrument, i, g, latitude, gravity, reference_temperature) for i in range(g.n)]
        self.newton_iterations = int(newton_iterations)
        self.refinements = int(refinements)
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
            needs += [x for x in t.effect.runtime_needs if x != "axis_input" and x not in needs]
        #: inputs from the stream this stage needs, in the order of :data:`RUNTIME_INPUTS`
        self.needs: tuple[str, ...] = tuple(x for x in RUNTIME_INPUTS if x in needs)
        self._scale = cal.scale.copy()
        self._bias = cal.bias.copy()
        #: (h_i - a_i) as rows: s = q + D u
        self.D = np.stack([c.axis for c in self.ctxs]) - cal.axes_mb()

    def __bool__(self) -> bool:
        return bool(self.terms)

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

    # ------------------------------------------------------------------ evaluation
    @staticmethod
    def _sum(terms: Sequence[_Term], inputs: RuntimeInputs, ctxs: list[SensorContext], slope: bool = False
             ) -> np.ndarray | float:
        out: np.ndarray | float = 0.0
        for t in terms:
            cols = t.effect.runtime_slope(inputs, ctxs) if slope else t.effect.runtime_columns(inputs, ctxs)
            out = out + np.einsum("nik,ik->ni", cols, t.theta)
        return out

    def exogenous_error(self, inputs: RuntimeInputs) -> np.ndarray | float:
        """Sum of the exogenous effects' output errors, (N, n), SI (0.0 without such effects)."""
        return self._sum(self.exogenous, inputs, self.ctxs)

    def output_error(self, inputs: RuntimeInputs) -> np.ndarray | float:
        """Sum of the output-side effects' errors at ``inputs.axis_input``, (N, n), SI."""
        return self._sum(self.output_side, inputs, self.ctxs)

    def solve(self, Y: np.ndarray, inputs: RuntimeInputs, project: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Effect-free compensated outputs ``q = a . u + v`` (N, n), SI, from raw outputs Y (N, n).

        ``project(Q)`` returns the MB estimate (N, 3) of compensated outputs Q on the active sensors (non-finite
        entries excluded). Non-finite raw values stay non-finite (the projection routes around them).
        """
        self._check(inputs)
        with np.errstate(invalid="ignore", over="ignore"):
            z = Y * self._scale - self._bias
            if self.exogenous:
                z = z - self.exogenous_error(inputs)
            if not self.output_side:
                return z
            q = z
            for _ in range(self.refinements):
                d = project(q) @ self.D.T
                for _ in range(self.newton_iterations):
                    inputs.axis_input = q + d
                    c = self._sum(self.output_side, inputs, self.ctxs)
                    dc = self._sum(self.output_side, inputs, self.ctxs, slope=True)
                    q = q - (q + c - z) / (1.0 + dc)
            inputs.axis_input = None
        return q

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
            z = z + self.output_error(inputs)
            inputs.axis_input = None
        return z / self._scale

    def _check(self, inputs: RuntimeInputs) -> None:
        for t in self.exogenous + self.output_side:
            for name in t.effect.runtime_needs:
                if name != "axis_input" and getattr(inputs, "t" if name == "time" else name) is None:
                    raise MissingInputError(
                        f"{self.instrument}: effect {t.effect.name!r} needs the {name.replace('_', ' ')}, and this "
                        "sample has none", t.effect.name, name)
