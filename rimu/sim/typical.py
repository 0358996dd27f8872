"""Grade-typical coefficients of every compensable effect, for tests, benchmarks and examples of the runtime.

Sizes a tactical MEMS unit shows (the diagnosis scenarios' sizes, ``docs/effects.md``), varied a little from
sensor to sensor so that no two sensors are alike.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..calibration.model import SensorContext, effect
from ..calibration.result import Calibration, InstrumentCalibration
from ..units import DEG_TO_RAD, DH_TO_RS, G0, PPM
from .procedures import SegmentSpec, rotation, static

__all__ = ["TYPICAL_EFFECTS", "effect_parameters", "validation_procedure", "with_effects"]

#: instrument -> effect -> sensor index -> physical values (SI, in the order of ``physical_parameters``)
TYPICAL_EFFECTS: dict[str, dict[str, Callable[[int], list[float]]]] = {
    "gyro": {
        "sf_quadratic": lambda i: [(1.0 + 0.5 * i) * PPM / DEG_TO_RAD],
        "sf_cubic": lambda i: [(4e-3 - 1e-3 * i) * PPM / DEG_TO_RAD**2],
        "sf_asymmetry": lambda i: [(200.0 - 60 * i) * PPM],
        "g_sensitivity": lambda i: [x * DH_TO_RS / G0 for x in (40.0, -25.0, 30.0 + i)],
        "g2_sensitivity": lambda i: [x * DH_TO_RS / G0**2 for x in (30.0, -20.0 + i)],
        "bias_temperature": lambda i: [(3.0 + i) * DH_TO_RS],
        "bias_temperature2": lambda i: [(0.1 + 0.02 * i) * DH_TO_RS],
        "scale_temperature": lambda i: [(20.0 + i) * PPM],
        "scale_temperature2": lambda i: [(2.0 - 0.5 * i) * PPM],
        "bias_drift": lambda i: [(300.0 + 10 * i) * DH_TO_RS / 3600.0],
        "cross_coupling": lambda i: [(2.0 - i) * PPM / DEG_TO_RAD, (-1.5 + 0.3 * i) * PPM / DEG_TO_RAD],
    },
    "accel": {
        "sf_quadratic": lambda i: [(20.0 + 5 * i) * PPM / G0],
        "sf_cubic": lambda i: [(10.0 - 3 * i) * PPM / G0**2],
        "sf_asymmetry": lambda i: [(150.0 - 40 * i) * PPM],
        "bias_temperature": lambda i: [(20.0 + 3 * i) * 1e-6 * G0],
        "bias_temperature2": lambda i: [(1.0 + 0.2 * i) * 1e-6 * G0],
        "scale_temperature": lambda i: [(30.0 - 2 * i) * PPM],
        "scale_temperature2": lambda i: [(1.0 + 0.1 * i) * PPM],
        "bias_drift": lambda i: [(100.0 - 10 * i) * 1e-6 * G0 / 3600.0],
        "size_effect": lambda i: [0.004, -0.003 + 0.001 * i, 0.005],
        "cross_coupling": lambda i: [(30.0 - 5 * i) * PPM / G0, (-20.0 + 3 * i) * PPM / G0],
    },
}


def effect_parameters(name: str, cal: InstrumentCalibration, theta: Callable[[int], Sequence[float]],
                      sensors: Iterable[int] | None = None) -> dict[str, float]:
    """``{"sensor.param": value}`` of effect ``name`` for ``cal``'s sensors, as ``InstrumentCalibration.effects``
    holds them, from values per sensor index (SI, in the order of ``physical_parameters``)."""
    eff = effect(name)
    g = cal.geometry
    out: dict[str, float] = {}
    for i in range(g.n) if sensors is None else sensors:
        ctx = SensorContext(cal.instrument, i, g)
        if not eff.applies_to(ctx):
            continue
        for p, v in zip(eff.physical_parameters(ctx), theta(i)):
            out[f"{g.names[i]}.{p.name}"] = float(v)
    return out


def with_effects(cal: Calibration, names: dict[str, Iterable[str]] | None = None) -> Calibration:
    """A copy of ``cal`` holding the typical coefficients of the named effects (default: every compensable
    effect of :data:`TYPICAL_EFFECTS`) on every sensor.

    >>> from rimu.sim import cho_park_table3
    >>> c = with_effects(cho_park_table3(), {"gyro": ["sf_quadratic"], "accel": []})
    >>> sorted(c["gyro"].effects), round(c["gyro"].effects["sf_quadratic"]["x1.k2"] * DEG_TO_RAD / PPM, 6)
    (['sf_quadratic'], 1.0)
    """
    out = {}
    for k in cal.instruments:
        c = cal[k]
        chosen = TYPICAL_EFFECTS[k] if names is None else {e: TYPICAL_EFFECTS[k][e] for e in names.get(k, ())}
        effects = {e: effect_parameters(e, c, th) for e, th in chosen.items()}
        out[k] = InstrumentCalibration(k, c.geometry, c.scale, c.misalignment, c.bias,
                                       None if c.noise_sigma is None else np.array(c.noise_sigma),
                                       effects=effects)
    return Calibration(out, cal.raw_unit, cal.method, cal.created, dict(cal.metadata))


def validation_procedure(tilt_deg: float = 30.0, rate_dps: float = 100.0, duration: float = 5.0) -> list[SegmentSpec]:
    """A short session with known inputs for validating a calibration: static positions with gravity along
    +-x, +-y, +-z and tilted by ``tilt_deg`` towards the next axis, and rotations at ``rate_dps`` about the three
    axes in both senses (``duration`` s each). Two tilts give two different sessions of the same unit.

    >>> len(validation_procedure()), validation_procedure()[1].label
    (18, 'T0')
    """
    out = []
    t = np.radians(tilt_deg)
    for k, v in enumerate(np.vstack([np.eye(3), -np.eye(3)])):
        out.append(static(f"S{k}", v, duration))
        out.append(static(f"T{k}", np.cos(t) * v + np.sin(t) * np.roll(v, 1), duration))
    for k, a in enumerate(np.eye(3)):
        for sgn in (1, -1):
            out.append(rotation(f"R{k}{'p' if sgn > 0 else 'm'}", sgn * rate_dps * DEG_TO_RAD * a, duration))
    return out
