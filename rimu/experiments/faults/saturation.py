"""Saturation (clipping): the raw output clipped to +/- ``limit`` (raw); without one, to the median magnitude
inside the window minus ``size`` (SI), so that the clipped part is about ``size``."""

from __future__ import annotations

import numpy as np

from .base import Fault


class Saturation(Fault):
    name = "saturation"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        limit = self.params.get("limit")
        if limit is None:
            limit = max(float(np.median(np.abs(y[m]))) - abs(self.size / scale), 0.0)
        y[m] = np.clip(y[m], -float(limit), float(limit))
