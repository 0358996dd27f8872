"""Scale-factor change: the raw output multiplied by ``factor``; without one, the factor that moves the
output by ``size`` (SI) at its median level inside the window."""

from __future__ import annotations

import numpy as np

from .base import Fault


class ScaleChange(Fault):
    name = "scale"

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        factor = self.params.get("factor")
        if factor is None:
            level = float(np.median(np.abs(y[m] * scale)))
            factor = 1.0 + (self.size / level if level > 0 else 0.0)
        y[m] *= float(factor)
