"""What flows from a data source into the runtime pipeline: epochs of raw samples.

An :class:`Epoch` is one synchronised sample of every sensor of the unit; an :class:`EpochBlock` is many
of them as arrays (replay). Raw values are in the device's raw unit (counts); ``valid`` marks, per sensor,
whether that value arrived intact. A sensor that is not valid has its raw value set to 0.0 by the source
(never NaN), so that nothing downstream can be poisoned.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import ShapeError

__all__ = ["INSTRUMENTS", "Epoch", "EpochBlock"]

#: The instrument kinds of a unit, in the order rimu uses them everywhere.
INSTRUMENTS = ("gyro", "accel")


@dataclass
class Epoch:
    """One sample time of a redundant IMU.

    Attributes
    ----------
    t : float
        Time of the sample, s (device or receive time; sources say which).
    raw : dict[str, ndarray]
        Raw outputs per instrument (``"gyro"``, ``"accel"``), shape (n_instrument,), raw units.
    valid : dict[str, ndarray of bool]
        Per sensor: the value arrived intact. Missing keys mean all valid.
    temperature : float or None
        Unit temperature, degC, where sent.
    counters : dict[str, int]
        Device counters (sample counter, frame counter, ...), as sent.
    """

    t: float
    raw: dict[str, np.ndarray]
    valid: dict[str, np.ndarray] = field(default_factory=dict)
    temperature: float | None = None
    counters: dict[str, int] = field(default_factory=dict)

    def valid_mask(self, instrument: str) -> np.ndarray:
        y = self.raw[instrument]
        v = self.valid.get(instrument)
        return np.ones(y.shape, dtype=bool) if v is None else np.asarray(v, dtype=bool)


@dataclass
class EpochBlock:
    """Many epochs as arrays (for replay and block processing).

    Attributes
    ----------
    t : ndarray, shape (N,)
    raw : dict[str, ndarray (N, n_instrument)]
    valid : dict[str, ndarray of bool (N, n_instrument)]
    temperature : ndarray (N,) or None
    meta : dict
    """

    t: np.ndarray
    raw: dict[str, np.ndarray]
    valid: dict[str, np.ndarray] = field(default_factory=dict)
    temperature: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        N = self.t.shape[0]
        for k, y in self.raw.items():
            y = np.asarray(y, dtype=float)
            if y.ndim != 2 or y.shape[0] != N:
                raise ShapeError(f"raw[{k!r}] must have shape (N={N}, n); got {y.shape}")
            self.raw[k] = y
        if self.valid is None:  # None: every sample valid (as the pipeline's own valid=None)
            self.valid = {}
        for k, v in self.valid.items():
            if np.shape(v) != self.raw[k].shape:
                raise ShapeError(f"valid[{k!r}] has shape {np.shape(v)}, raw has {self.raw[k].shape}")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def epochs(self):
        """Iterate as :class:`Epoch` objects (copies)."""
        for k in range(len(self)):
            yield Epoch(
                t=float(self.t[k]),
                raw={i: y[k].copy() for i, y in self.raw.items()},
                valid={i: v[k].copy() for i, v in self.valid.items()},
                temperature=None if self.temperature is None else float(self.temperature[k]),
            )

    @classmethod
    def from_epochs(cls, epochs: "list[Epoch]") -> "EpochBlock":
        if not epochs:
            raise ShapeError("no epochs to stack")
        keys = list(epochs[0].raw)
        temps = [e.temperature for e in epochs]
        return cls(
            t=np.array([e.t for e in epochs]),
            raw={k: np.vstack([e.raw[k] for e in epochs]) for k in keys},
            valid={k: np.vstack([e.valid_mask(k) for e in epochs]) for k in keys},
            temperature=None if any(x is None for x in temps) else np.array(temps, dtype=float),
        )
