"""Noise increase: white noise of standard deviation ``size`` (SI) added to the output."""

from __future__ import annotations

from .base import Fault


class NoiseIncrease(Fault):
    name = "noise"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        y[m] += rng.standard_normal(int(m.sum())) * self.size / scale
