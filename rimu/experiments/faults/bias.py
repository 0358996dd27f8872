"""Step bias: a constant offset of ``size`` (SI) from ``start``."""

from __future__ import annotations

from .base import Fault


class StepBias(Fault):
    name = "bias"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        y[m] += self.size / scale
