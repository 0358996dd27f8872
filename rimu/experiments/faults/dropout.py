"""Dropout: no data (``valid`` False, raw value 0 as the Epoch contract says) inside the window."""

from __future__ import annotations

from .base import Fault


class Dropout(Fault):
    name = "dropout"
    transient = True

    def _apply(self, t, y, valid, m, scale, rng):  # type: ignore[no-untyped-def]
        valid[m] = False
        y[m] = 0.0
