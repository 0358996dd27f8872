"""Non-finite values: NaN (and +/- inf on every third sample) where the sensor still claims validity."""

from __future__ import annotations

import numpy as np

from .base import Fault


class NonFinite(Fault):
    name = "nonfinite"
    transient = True

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        idx = np.flatnonzero(m)
        y[idx] = np.nan
        y[idx[::3]] = np.inf
