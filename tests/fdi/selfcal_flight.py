"""A simulated flight for the self-calibration tests: a unit whose calibration drifts with time and temperature.

Consumer MEMS gyros of the autopilots' class (MPU-6000 family: angle random walk 0.3 deg/sqrt(h), bias instability
20 deg/h), biases
drifting as a random walk three times as fast as that bias instability gives (:func:`rimu.fdi.selfcal.bias_random_walk`,
horizon 1 h), relative scale drifting as a random walk (200 ppm 1-sigma after 2 h), a 30 K temperature ramp
(10 to 40 degC, T_ref 25 degC) with first- to third-order bias coefficients drawn from their priors (10 (deg/h)/K,
0.3 (deg/h)/K^2, 0.01 (deg/h)/K^3), flight-like motion (sums of slow sines, about 20 deg/s rms per axis).
The truth is drawn from the tracker's own prior, so that its normalised errors can be checked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rimu.calibration import InstrumentCalibration
from rimu.fdi.selfcal import SelfCalSettings, bias_random_walk
from rimu.noise import InstrumentNoise
from rimu.units import ARW_DSQH_TO_RSQS, DEG_TO_RAD, DH_TO_RS, PPM

ARW = 0.3 * ARW_DSQH_TO_RSQS
BI = 20.0 * DH_TO_RS
TC_SIGMA = (10.0 * DH_TO_RS, 0.3 * DH_TO_RS, 0.01 * DH_TO_RS)
SCALE_RW = (200 * PPM) ** 2 / 7200.0


@dataclass
class Flight:
    cal: InstrumentCalibration
    settings: SelfCalSettings
    t: np.ndarray
    Y: np.ndarray
    temperature: np.ndarray
    bias: np.ndarray        # (N, n) true bias drift, rad/s
    scale: np.ndarray       # (N, n) true relative scale drift
    tc: np.ndarray          # (3, n) true temperature coefficients
    u: np.ndarray           # (N, 3) true rate, rad/s
    sigma: float


def unit(geometry, fs: float) -> tuple[InstrumentCalibration, SelfCalSettings]:
    n = geometry.n
    noise = InstrumentNoise.from_terms("gyro", list(geometry.names), fs, white=ARW, bias_instability=BI)
    sigma = float(noise.sample_sigma()[0])
    cal = InstrumentCalibration.nominal("gyro", geometry, 1.0, noise_sigma=np.full(n, sigma))
    st = SelfCalSettings(bias_rw=bias_random_walk(noise, 3.0, 3600.0), scale_rw=SCALE_RW,
                         temperature_sigma=TC_SIGMA, reference_temperature=25.0, window_s=2.0, hold_s=3.0)
    return cal, st


def flight(geometry, hours: float = 2.0, fs: float = 10.0, seed: int = 0, drift: bool = True) -> Flight:
    rng = np.random.default_rng(seed)
    cal, st = unit(geometry, fs)
    n = geometry.n
    N = int(round(hours * 3600 * fs))
    t = np.arange(N) / fs
    A = cal.axes_mb()
    u = np.zeros((N, 3))
    for ax in range(3):
        for _ in range(6):
            f = 10 ** rng.uniform(-2.0, -0.5)
            u[:, ax] += rng.normal(0, 12.0) * DEG_TO_RAD * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    T = 10.0 + 30.0 * t / t[-1]
    q = np.asarray(st.bias_rw)
    if drift:
        bias = np.cumsum(rng.standard_normal((N, n)) * np.sqrt(q / fs), axis=0)
        scale = np.cumsum(rng.standard_normal((N, n)) * np.sqrt(SCALE_RW / fs), axis=0)
        tc = np.array([rng.normal(0, s, n) for s in TC_SIGMA])
    else:
        bias, scale, tc = np.zeros((N, n)), np.zeros((N, n)), np.zeros((3, n))
    dT = T - 25.0
    s = u @ A.T
    sigma = float(cal.noise_sigma[0])
    Y = s * (1 + scale) + bias + sum(tc[k][None, :] * dT[:, None] ** (k + 1) for k in range(3)) \
        + sigma * rng.standard_normal((N, n))
    return Flight(cal, st, t, Y, T, bias, scale, tc, u, sigma)
