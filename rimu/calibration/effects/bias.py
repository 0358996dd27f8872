"""Bias: a constant offset of the output (Cho & Park 2005, Eq. 1, B)."""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ...units import MS2_TO_UG, RS_TO_DH
from ..model import Effect, ParamSpec, SensorContext


class Bias(Effect):
    name = "bias"
    description = "constant offset of the output"
    physics = ("Electronics offsets and, for MEMS, asymmetries of the proof mass; seen in every segment, "
               "identified by any set of segments with different inputs.")

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        if ctx.instrument == "gyro":
            return [ParamSpec("bias", "rad/s", "deg/h", RS_TO_DH)]
        return [ParamSpec("bias", "m/s^2", "ug", MS2_TO_UG)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray:
        return np.ones((segment.n_samples, 1))
