"""Earth rate seen by the gyros."""

from __future__ import annotations

import numpy as np

from ...session import Segment
from ..model import Effect, ParamSpec, SensorContext

__all__ = ["EarthRate"]


class EarthRate(Effect):
    name = "earth_rate"
    instruments = ("gyro",)
    description = "the Earth's rotation (15.04 deg/h) seen by the gyros, in proportion k to its component along the axis"
    physics = ("The local level frame turns with the Earth; a gyro at rest reads h . C^T W_ie with "
               "W_ie = W (0, cos(lat), sin(lat)) in ENU. Error = k * h . W_ie(MB); k = 1 for a sensor that sees "
               "it (every gyro does; only a precise one shows it above its noise). Testable only when the "
               "model's input leaves the Earth rate out (SensorContext.include_earth_rate=False, "
               "rimu diagnose --no-earth-rate).")
    excited_by = "static positions or rotations with known attitude and latitude, the sensing axis pointing North/up and South/down"

    def applies_to(self, ctx: SensorContext) -> bool:
        return ctx.instrument == "gyro" and not ctx.include_earth_rate

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        return [ParamSpec("earth_k", "1", "", 1.0)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        we = segment.earth_rate(ctx.latitude)
        return None if we is None else (np.asarray(we, dtype=float) @ ctx.axis)[:, None]
