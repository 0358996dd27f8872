"""Stuck-at: the output freezes at its last value before ``start``, plus ``size`` (SI; 0 = frozen in place)."""

from __future__ import annotations

import numpy as np

from .base import Fault


class StuckAt(Fault):
    name = "stuck"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        k = int(np.argmax(m))
        last = y[k - 1] if k > 0 else y[k]
        y[m] = last + self.size / scale
