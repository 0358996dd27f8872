"""Scale-factor asymmetry: a different scale factor for positive and negative inputs."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...session import Segment
from ...units import PPM
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial
from ._common import axis_input

__all__ = ["ScaleAsymmetry"]


class ScaleAsymmetry(Effect):
    name = "sf_asymmetry"
    runtime_needs = ("axis_input",)
    description = "scale-factor asymmetry: the scale for positive inputs differs from the scale for negative inputs"
    physics = ("Unequal gains of the two halves of a push-pull pick-off or of the two torquer polarities. "
               "Error = ka * |s|: the scale is SF(1 + ka) for s > 0 and SF(1 - ka) for s < 0; reported in ppm.")
    excited_by = "equal inputs of both signs along the sensing axis (+w / -w rate pairs, axis up / axis down)"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec("k_asym", "1", "ppm", 1.0 / PPM)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        s = axis_input(segment, ctx)
        return None if s is None else np.abs(s)[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``|s_i|``, (N, n, 1): output-side; the inversion picks the scale of the input's sign exactly."""
        return np.abs(inputs.axis_input)[:, :, None]

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        return np.sign(inputs.axis_input)[:, :, None]

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("absolute", len(ctxs), 1)
        form.F[:, 0, monomial("1")] = 1.0
        return form
