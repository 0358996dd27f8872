"""Simulated sessions for the diagnostics tests: procedures that excite every effect of the library, effect
sizes a real sensor of the stated grade shows, and the sensors they sit on."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rimu.calibration.model import effect as make_effect
from rimu.geometry import preset
from rimu.sim import Simulator, TruthEffect
from rimu.sim.procedures import SegmentSpec, rotation, static
from rimu.units import DEG_TO_RAD, DH_TO_RS, G0, PPM, UG_TO_MS2

__all__ = ["SCENARIOS", "Scenario", "known_sigma", "rich_procedure", "simulate"]


def rich_procedure(static_s: float = 5.0, rate_s: float = 5.0, rates_dps: tuple[float, ...] = (50.0, 200.0),
                   n_static: int = 26) -> list[SegmentSpec]:
    """26 static attitudes (axes, face and body diagonals up) and rotations about 7 MB directions (axes,
    face diagonals, one body diagonal), each at +-the given rates. Excites every effect of the library except
    temperature (which needs a temperature profile) and the Earth rate (which needs a precise gyro)."""
    dirs = []
    for v in [(1, 0, 0), (0, 1, 0), (0, 0, 1)]:
        dirs += [v, tuple(-x for x in v)]
    for a, b in [(0, 1), (0, 2), (1, 2)]:
        for sa in (1, -1):
            for sb in (1, -1):
                v = [0.0, 0.0, 0.0]
                v[a], v[b] = sa, sb
                dirs.append(tuple(v))
    for sx in (1, -1):
        for sy in (1, -1):
            for sz in (1, -1):
                dirs.append((sx, sy, sz))
    out = [static(f"S{k + 1}", np.array(d) / np.linalg.norm(d), static_s) for k, d in enumerate(dirs[:n_static])]
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)]
    for k, a in enumerate(axes):
        a = np.array(a, dtype=float) / np.linalg.norm(a)
        for r in rates_dps:
            for sgn in (1, -1):
                out.append(rotation(f"R{k + 1}{'p' if sgn > 0 else 'm'}{int(r)}", sgn * r * DEG_TO_RAD * a, rate_s))
    return out


@dataclass
class Scenario:
    """A hidden effect: which instrument, its true values (SI) on which sensors, and the simulation."""

    effect: str
    instrument: str
    theta: Callable[[int], list[float]]   # sensor index -> true physical values, SI
    sensors: Callable[[Any], list[int]]   # geometry -> affected sensor indices
    sim: dict[str, Any]
    diagnose: dict[str, Any]
    truth_in_sim: bool = True             # False: the simulator makes the effect physically (Earth rate)


def _ends(g) -> list[int]:
    return [0, g.n - 1]


def _first_two(g) -> list[int]:
    return [0, 1]


def _temp(t: np.ndarray) -> np.ndarray:
    """A thermal profile: 25 degC, a soak up to about 45 and back down to about 15 degC over the session
    (not monotonic in time, so temperature and time effects separate)."""
    return 30.0 + 15.0 * np.sin(2 * math.pi * t / 500.0)


TACTICAL = {"arw_deg_sqrt_h": 0.15, "vrw_ug_sqrt_hz": 50.0}
NAVIGATION = {"arw_deg_sqrt_h": 0.01, "vrw_ug_sqrt_hz": 20.0}

SCENARIOS: dict[str, Scenario] = {
    # scale-factor nonlinearity of a tactical MEMS gyro: about 300 ppm at 300 deg/s
    "sf_quadratic": Scenario("sf_quadratic", "gyro", lambda i: [(1.0 + 0.5 * i) * PPM / DEG_TO_RAD], _ends, TACTICAL, {}),
    "sf_cubic": Scenario("sf_cubic", "gyro", lambda i: [(4e-3 - 1e-3 * i) * PPM / DEG_TO_RAD**2], _ends, TACTICAL, {}),
    "sf_asymmetry": Scenario("sf_asymmetry", "gyro", lambda i: [(200.0 + 20 * i) * PPM], _ends, TACTICAL, {}),
    # g-sensitivity of MEMS gyros: tens of (deg/h)/g; anisoelastic tens of (deg/h)/g^2
    "g_sensitivity": Scenario("g_sensitivity", "gyro", lambda i: [x * DH_TO_RS / G0 for x in (40.0, -25.0, 30.0 + i)],
                              _ends, TACTICAL, {}),
    "g2_sensitivity": Scenario("g2_sensitivity", "gyro", lambda i: [x * DH_TO_RS / G0**2 for x in (30.0, -20.0)],
                               _ends, TACTICAL, {}),
    # temperature coefficients over a 30 K swing
    "bias_temperature": Scenario("bias_temperature", "gyro", lambda i: [(3.0 + i) * DH_TO_RS], _ends,
                                 {**TACTICAL, "temperature": _temp}, {}),
    "bias_temperature2": Scenario("bias_temperature2", "accel", lambda i: [(1.0 + 0.2 * i) * UG_TO_MS2], _ends,
                                  {**TACTICAL, "temperature": _temp}, {}),
    "scale_temperature": Scenario("scale_temperature", "gyro", lambda i: [(20.0 + i) * PPM], _ends,
                                  {**TACTICAL, "temperature": _temp}, {}),
    "scale_temperature2": Scenario("scale_temperature2", "gyro", lambda i: [(2.0 + 0.1 * i) * PPM], _ends,
                                   {**TACTICAL, "temperature": _temp}, {}),
    # warm-up drift of a MEMS gyro: a few hundred (deg/h)/h in the first minutes
    "bias_drift": Scenario("bias_drift", "gyro", lambda i: [(300.0 + 10 * i) * DH_TO_RS / 3600.0], _ends, TACTICAL, {}),
    # accelerometers a few mm off the rotation centre
    "size_effect": Scenario("size_effect", "accel", lambda i: [0.004, -0.003, 0.005 + 0.001 * i], _ends, TACTICAL, {}),
    # a navigation-grade gyro sees the Earth rate (k = 1); the model leaves it out of the input
    "earth_rate": Scenario("earth_rate", "gyro", lambda i: [1.0], lambda g: list(range(g.n)), NAVIGATION,
                           {"include_earth_rate": False}, truth_in_sim=False),
    "cross_coupling": Scenario("cross_coupling", "gyro", lambda i: [2.0 * PPM / DEG_TO_RAD, -1.5 * PPM / DEG_TO_RAD],
                               _first_two, TACTICAL, {}),
}


def known_sigma(run, instrument: str) -> np.ndarray:
    """The simulated white-noise level per sample in raw units."""
    c = run.truth[instrument]
    return c.noise_sigma / c.scale


def simulate(name: str, geometry: str = "cone6", seed: int = 0, sample_rate: float = 20.0,
             procedure: list[SegmentSpec] | None = None, hidden: bool = True):
    """Simulate scenario ``name`` (hidden effect present unless ``hidden`` is False). Returns (run, truth dict
    sensor index -> theta, scenario)."""
    sc = SCENARIOS[name]
    g = preset(geometry)
    eff = make_effect(sc.effect)
    ctx_sensors = sc.sensors(g)
    if sc.effect == "cross_coupling":
        ctx_sensors = [i for i in ctx_sensors if len(g.subunit_of(i).members) > 1]
    truth = {i: sc.theta(i)[: len(eff.physical_parameters(_ctx(sc.instrument, g, i)))] for i in ctx_sensors}
    effects = {sc.instrument: [TruthEffect(eff, truth)]} if (hidden and sc.truth_in_sim) else {}
    sim_kw = dict(sc.sim)
    if not hidden and "temperature" in sim_kw:
        pass
    sim = Simulator({sc.instrument: g}, sample_rate=sample_rate, effects=effects, seed=seed, **sim_kw)
    run = sim.run(procedure or rich_procedure())
    return run, truth, sc


def _ctx(instrument, g, i):
    from rimu.calibration.model import SensorContext

    return SensorContext(instrument, i, g, 0.6)
