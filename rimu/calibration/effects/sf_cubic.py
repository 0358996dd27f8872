"""Scale-factor nonlinearity, cubic: an output error proportional to the cube of the input."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import axis_input, per_input_power

__all__ = ["ScaleCubic"]


class ScaleCubic(Effect):
    name = "sf_cubic"
    runtime_needs = ("axis_input",)
    description = "scale-factor nonlinearity: output error proportional to the input cubed (odd in the input)"
    physics = ("Third-order terms of a symmetric pick-off or a saturating rebalance loop: the gain falls (or "
               "rises) at large inputs in both directions. Error = k3 * s^3; reported as ppm of the input per "
               "(unit of input)^2.")
    excited_by = "inputs of several magnitudes along the sensing axis, the larger the better (a rate sweep up to full scale)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        unit, rep, f = per_input_power(ctx, 2)
        return [ParamSpec("k3", unit, rep, f)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        s = axis_input(segment, ctx)
        return None if s is None else (s * s * s)[:, None]  # not s**3: numpy's pow is ~100x slower

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``s_i^3``, (N, n, 1): output-side, inverted exactly (Newton on the sensor's own input)."""
        s = inputs.axis_input
        return (s * s * s)[:, :, None]

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        s = inputs.axis_input
        return (3.0 * s * s)[:, :, None]

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("power", len(ctxs), 1, power=3)
        form.F[:, 0, monomial("1")] = 1.0
        return form
