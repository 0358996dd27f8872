"""Ramp (drift): an offset growing linearly, reaching ``size`` (SI) after ``ramp_time`` s (default 1 s)."""

from __future__ import annotations

from .base import Fault


class Ramp(Fault):
    name = "ramp"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        ramp_time = float(self.params.get("ramp_time", 1.0))
        y[m] += self.size * (t[m] - self.start) / ramp_time / scale
