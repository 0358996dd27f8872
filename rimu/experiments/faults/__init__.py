"""Fault types for injection. Adding one is a new file in this folder plus one line in ``FAULTS``.

Each fault acts on one sensor's raw column over a time window; :func:`inject` applies a list of
:class:`Injection` s to an :class:`rimu.epoch.EpochBlock` (simulated or recorded) and returns a new block.

Injection specification (CLI ``--inject``): ``TYPE:INSTRUMENT:SENSOR:START[:SIZE[:DURATION]]`` with SIZE in SI
or with the suffix ``sigma`` (times the sensor's noise level), e.g. ``bias:gyro:y2:15:10sigma``.

>>> sorted(FAULTS)
['bias', 'dropout', 'noise', 'nonfinite', 'ramp', 'saturation', 'scale', 'spikes', 'stuck', 'zero']
>>> parse_injection("bias:gyro:y2:15:10sigma")
Injection(fault='bias', instrument='gyro', sensor='y2', start=15.0, size=10.0, in_sigma=True, duration=None, params={})
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...calibration.result import Calibration
from ...epoch import EpochBlock
from ...errors import ShapeError
from .base import Fault
from .bias import StepBias
from .dropout import Dropout
from .noise import NoiseIncrease
from .nonfinite import NonFinite
from .ramp import Ramp
from .saturation import Saturation
from .scale import ScaleChange
from .spikes import Spikes
from .stuck import StuckAt
from .zero import ZeroOutput

__all__ = ["FAULTS", "Fault", "Injection", "parse_injection", "inject"]

#: name -> fault class
FAULTS: dict[str, type[Fault]] = {
    "bias": StepBias,
    "ramp": Ramp,
    "stuck": StuckAt,
    "scale": ScaleChange,
    "noise": NoiseIncrease,
    "spikes": Spikes,
    "dropout": Dropout,
    "zero": ZeroOutput,
    "saturation": Saturation,
    "nonfinite": NonFinite,
}


@dataclass
class Injection:
    """One fault to inject: type, where, when, how big."""

    fault: str
    instrument: str
    sensor: str | int
    start: float
    size: float = 0.0
    in_sigma: bool = False
    duration: float | None = None
    params: dict[str, Any] = field(default_factory=dict)

    def build(self, sigma: float) -> Fault:
        if self.fault not in FAULTS:
            raise ShapeError(f"unknown fault type {self.fault!r}; known: {sorted(FAULTS)}")
        size = self.size * sigma if self.in_sigma else self.size
        return FAULTS[self.fault](size, self.start, self.duration, **self.params)


def parse_injection(spec: str) -> Injection:
    """Parse ``TYPE:INSTRUMENT:SENSOR:START[:SIZE[:DURATION]]`` (SIZE in SI, or ``10sigma``)."""
    parts = spec.split(":")
    if len(parts) < 4 or len(parts) > 6:
        raise ShapeError(f"injection {spec!r}: expected TYPE:INSTRUMENT:SENSOR:START[:SIZE[:DURATION]], "
                         "e.g. bias:gyro:y2:15:10sigma")
    kind, inst, sensor, start = parts[:4]
    if kind not in FAULTS:
        raise ShapeError(f"injection {spec!r}: unknown fault type {kind!r}; known: {sorted(FAULTS)}")
    size, in_sigma = 0.0, False
    try:
        if len(parts) >= 5 and parts[4]:
            s = parts[4].strip()
            if s.endswith("sigma"):
                size, in_sigma = float(s[:-5]), True
            else:
                size = float(s)
        duration = float(parts[5]) if len(parts) == 6 and parts[5] else None
        start_f = float(start)
    except ValueError as exc:
        raise ShapeError(f"injection {spec!r}: {exc}") from exc
    return Injection(kind, inst, sensor, start_f, size, in_sigma, duration)


def inject(block: EpochBlock, injections: Sequence[Injection], calibration: Calibration,
           sigma: dict[str, Any] | None = None, seed: int = 0) -> EpochBlock:
    """A copy of ``block`` with the faults applied.

    Parameters
    ----------
    calibration : Calibration
        Gives each sensor's scale factor (SI sizes -> raw units), names and, for sizes in sigma, the noise.
    sigma : dict, optional
        Noise per instrument (scalar or (n,)), overriding the calibration's ``noise_sigma``.
    seed : int
        For the random fault types (noise, spikes).
    """
    raw = {k: np.array(v, dtype=float) for k, v in block.raw.items()}
    valid = {k: (np.array(block.valid[k], dtype=bool) if k in block.valid else np.ones(v.shape, bool))
             for k, v in raw.items()}
    rng = np.random.default_rng(seed)
    for inj in injections:
        if inj.instrument not in raw:
            raise ShapeError(f"injection on {inj.instrument!r}, but the data hold {sorted(raw)}")
        cal = calibration[inj.instrument]
        names = list(cal.geometry.names)
        if isinstance(inj.sensor, str) and not inj.sensor.isdigit():
            if inj.sensor not in names:
                raise ShapeError(f"no {inj.instrument} sensor named {inj.sensor!r}; sensors: {names}")
            i = names.index(inj.sensor)
        else:
            i = int(inj.sensor)
            if not 0 <= i < cal.geometry.n:
                raise ShapeError(f"no {inj.instrument} sensor {i}: indices run 0..{cal.geometry.n - 1} ({names})")
        s = (sigma or {}).get(inj.instrument, cal.noise_sigma)
        if inj.in_sigma and s is None:
            raise ShapeError(f"size in sigma for {inj.instrument}, but no noise level is known; give it in SI")
        s_i = float(np.broadcast_to(np.asarray(s if s is not None else 1.0, dtype=float), (cal.geometry.n,))[i])
        inj.build(s_i).apply(block.t, raw[inj.instrument][:, i], valid[inj.instrument][:, i], cal.scale[i], rng)
    return EpochBlock(block.t.copy(), raw, valid, None if block.temperature is None else block.temperature.copy(),
                      dict(block.meta))
