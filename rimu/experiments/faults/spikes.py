"""Spikes: single-sample outliers of +/- ``size`` (SI) at random instants, ``rate`` per second (default 1)."""

from __future__ import annotations

import numpy as np

from .base import Fault


class Spikes(Fault):
    name = "spikes"
    transient = True

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        idx = np.flatnonzero(m)
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
        p = min(1.0, float(self.params.get("rate", 1.0)) * dt)
        hit = idx[rng.random(len(idx)) < p]
        y[hit] += rng.choice([-1.0, 1.0], len(hit)) * self.size / scale
