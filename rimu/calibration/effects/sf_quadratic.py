"""Scale-factor nonlinearity, quadratic: an output error proportional to the square of the input."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import axis_input, per_input_power

__all__ = ["ScaleQuadratic"]


class ScaleQuadratic(Effect):
    name = "sf_quadratic"
    runtime_needs = ("axis_input",)
    description = "scale-factor nonlinearity: output error proportional to the input squared (even in the input)"
    physics = ("Second-order terms of the pick-off and of the rebalance loop (MEMS electrostatic springs, "
               "torquer nonlinearity). Error = k2 * s^2 with s the input along the sensing axis; reported as "
               "ppm of the input per unit of input.")
    excited_by = ("inputs of several magnitudes along the sensing axis: a rate sweep for gyros "
                  "(e.g. +-10, 50, 100, 200 deg/s), tilts putting cos(angle)*g on the axis for accelerometers")

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        unit, rep, f = per_input_power(ctx, 1)
        return [ParamSpec("k2", unit, rep, f)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        s = axis_input(segment, ctx)
        return None if s is None else (s**2)[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``s_i^2``, (N, n, 1): output-side, inverted exactly (Newton on the sensor's own input)."""
        s = inputs.axis_input
        return (s * s)[:, :, None]

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        return (2.0 * inputs.axis_input)[:, :, None]

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("power", len(ctxs), 1, power=2)
        form.F[:, 0, monomial("1")] = 1.0
        return form
