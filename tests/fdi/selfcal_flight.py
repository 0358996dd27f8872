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


# ---------------------------------------------------------------------------------------------- the step Monte-Carlo
def step_trials(geometry, seed: int = 11, tail_s: float = 30.0, onsets=(8, 10, 12, 14, 16, 18, 20, 22),
                sensors: int | None = None, window: int = 20, p_fa: float = 1e-6, confirm: int = 3) -> dict:
    """The isolation delays (s) of a step of the drift's final size applied within 1 s, after 2 h of tracking, for
    every onset (s into the tail) on ``sensors`` sensors (default all): the unit that keeps flying (the flown run,
    copied per trial), a loop restarted from the state after 2 h, a fresh unit (the same samples with the true drift
    taken out) with today's window GLT, and a fresh unit with the tracked unit's detector (window GLT at p_fa / 2 and
    the CUSUM bank, no tracker covariance). ``inf``: not isolated within the tail, or a wrong sensor first."""
    import copy

    from rimu.fdi import GltWindow, RedundancyManager
    from rimu.fdi.selfcal import SelfCalibratingRun, SelfCalTracker, TrackedGltWindow
    from rimu.fusion import InstrumentPipeline

    fs = 10.0

    def manager(cal, det):
        return RedundancyManager(InstrumentPipeline(cal), det, p_fa=p_fa, confirm=confirm)

    F = flight(geometry, hours=2.0 + tail_s / 3600.0, fs=fs, seed=seed)
    N2 = int(round(2 * 3600 * fs))
    trk = SelfCalTracker(F.cal, F.settings)
    run = SelfCalibratingRun(manager(F.cal, TrackedGltWindow(window, p_fa, cusum=True)), trk)
    for a in range(0, N2, 12000):
        run.run(F.Y[a:min(a + 12000, N2)], None, F.t[a:min(a + 12000, N2)], F.temperature[a:min(a + 12000, N2)])
    s = run.state
    dT = F.temperature[N2 - 1] - 25.0
    size = float(np.sqrt(np.mean((F.bias[N2 - 1] + sum(F.tc[k] * dT ** (k + 1) for k in range(3))) ** 2)))
    u = F.u[N2:] @ F.cal.axes_mb().T
    dTs = F.temperature[N2:, None] - 25.0
    true_drift = F.bias[N2:] + F.scale[N2:] * u + sum(F.tc[k][None, :] * dTs ** (k + 1) for k in range(3))
    t, T = F.t[N2:], F.temperature[N2:]
    n = F.cal.geometry.n
    out: dict = {"size": size, "continuing": [], "restarted": [], "fresh": [], "fresh_same_detector": []}
    for onset in onsets:
        for j in range(0, n, max(1, n // (sensors or n))):
            Y = F.Y[N2:].copy()
            on = t[0] + float(onset)
            Y[:, j] += size * np.clip(t - on, 0.0, 1.0)
            reps = {"continuing": copy.deepcopy(run).run(Y, None, t, T).replay,
                    "restarted": SelfCalibratingRun(manager(F.cal, TrackedGltWindow(window, p_fa, cusum=True)), trk, s)
                    .run(Y, None, t, T).replay,
                    "fresh": manager(F.cal, GltWindow(window, p_fa)).run(Y - true_drift, None, t),
                    "fresh_same_detector": manager(F.cal, TrackedGltWindow(window, p_fa, cusum=True)).run(Y - true_drift, None, t)}
            for k, rep in reps.items():
                ev = [e for e in rep.events if e.kind == "isolated"]
                ok = bool(ev) and ev[0].sensor == F.cal.geometry.names[j]
                out[k].append(ev[0].t - on if ok else float("inf"))
    return out


def _main() -> None:
    import argparse

    from rimu.geometry import cone6
    from rimu.sim.multitriad import triad_array
    from rimu.units import DH_TO_RS

    ap = argparse.ArgumentParser(description="step delays after 2 h of tracking against a fresh unit (s)")
    ap.add_argument("--geometry", choices=["cone6", "triads8"], default="triads8")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--sensors", type=int, default=None)
    a = ap.parse_args()
    geo = cone6() if a.geometry == "cone6" else triad_array(8)
    r = step_trials(geo, a.seed, sensors=a.sensors)
    fresh = np.array(r["fresh"])
    print(f"{a.geometry}, seed {a.seed}: step of {r['size'] / DH_TO_RS:.0f} deg/h, {len(fresh)} trials")
    for k in ("continuing", "restarted", "fresh", "fresh_same_detector"):
        d = np.array(r[k])
        ok = np.isfinite(d) & np.isfinite(fresh)
        diff = d[ok] - fresh[ok]
        print(f"  {k:20s} median {np.median(d):.2f} s, not isolated in the tail {int(np.sum(~np.isfinite(d)))}; "
              f"minus fresh {np.mean(diff):+.3f} +- {np.std(diff, ddof=1) / np.sqrt(len(diff)):.3f} s (mean +- se)")


if __name__ == "__main__":
    _main()
