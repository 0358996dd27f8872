"""Zero output: the sensor reports 0 (raw) but claims to be valid."""

from __future__ import annotations

from .base import Fault


class ZeroOutput(Fault):
    name = "zero"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        y[m] = 0.0
