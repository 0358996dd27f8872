"""Small sessions in SI units for the bad-input tests: a cone6 unit at rest in six attitudes and turning at known
rates, raw outputs ``H u + noise`` in the unit the test declares."""

from __future__ import annotations

import numpy as np

from rimu.geometry import preset
from rimu.session import Segment, Session
from rimu.units import DEG_TO_RAD, G0

UPS = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)
RATES_DPS = np.array([[30, 0, 0], [-30, 0, 0], [0, 30, 0], [0, -30, 0], [0, 0, 30], [0, 0, -30]], float)


def si_session(seed: int = 0, n: int = 200, fs: float = 100.0, accel_factor: float = 1.0, gyro_factor: float = 1.0,
               raw_unit="count", geometry: str = "cone6", dt: float | None = None) -> Session:
    """Raw accelerometer outputs = specific force in m/s^2 times ``accel_factor``; gyro outputs = rate in rad/s
    times ``gyro_factor``; ``dt`` overrides the time step of the samples (default 1/fs)."""
    rng = np.random.default_rng(seed)
    g = preset(geometry)
    H = g.H
    step = 1.0 / fs if dt is None else dt
    segs = []
    t0 = 0.0
    for k, up in enumerate(UPS):
        t = t0 + np.arange(n) * step
        f = G0 * up
        raw = {"accel": (f @ H.T + 1e-3 * rng.standard_normal((n, g.n))) * accel_factor,
               "gyro": (1e-4 * rng.standard_normal((n, g.n))) * gyro_factor}
        segs.append(Segment(f"P{k}", "static", t, raw, specific_force_mb=f))
        t0 = t[-1] + 1.0
    for k, w_dps in enumerate(RATES_DPS):
        t = t0 + np.arange(n) * step
        w = w_dps * DEG_TO_RAD
        raw = {"accel": (G0 * UPS[0] @ H.T + 1e-3 * rng.standard_normal((n, g.n))) * accel_factor,
               "gyro": (w @ H.T + 1e-4 * rng.standard_normal((n, g.n))) * gyro_factor}
        segs.append(Segment(f"R{k}", "rate", t, raw, rate_mb=w))
        t0 = t[-1] + 1.0
    return Session(segs, {"gyro": g, "accel": g}, fs, None, G0, raw_unit)
