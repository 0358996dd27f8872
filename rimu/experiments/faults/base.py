"""The fault interface: one class per fault type, applied to one sensor's raw column over a time window."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

__all__ = ["Fault"]


class Fault:
    """A fault on one sensor from ``start`` (s) for ``duration`` (s, None: to the end).

    Parameters
    ----------
    size : float
        Size in SI units of the compensated output (rad/s, m/s^2); each type says what it means.
    start, duration : float
        Window, s.
    params : dict
        Type-specific settings.

    Subclasses implement :meth:`_apply` on the raw column inside the window; ``scale`` is the sensor's scale
    factor (SI per raw unit), used to express SI sizes in raw units.
    """

    name: ClassVar[str] = "fault"
    #: the fault shows as isolated samples or gaps, not a lasting change (campaigns count it as transient)
    transient: ClassVar[bool] = False

    def __init__(self, size: float = 0.0, start: float = 0.0, duration: float | None = None, **params: Any) -> None:
        self.size = float(size)
        self.start = float(start)
        self.duration = None if duration is None else float(duration)
        self.params = params

    def window(self, t: np.ndarray) -> np.ndarray:
        """Boolean mask of the samples the fault acts on."""
        m = t >= self.start
        if self.duration is not None:
            m &= t < self.start + self.duration
        return m

    def apply(self, t: np.ndarray, y: np.ndarray, valid: np.ndarray, scale: float,
              rng: np.random.Generator) -> None:
        """Modify one sensor's raw column ``y`` and validity ``valid`` (both (N,)) in place."""
        m = self.window(t)
        if m.any():
            self._apply(t, y, valid, m, float(scale), rng)

    def _apply(self, t: np.ndarray, y: np.ndarray, valid: np.ndarray, m: np.ndarray, scale: float,
               rng: np.random.Generator) -> None:
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}(size={self.size:g}, start={self.start:g}, duration={self.duration})"
