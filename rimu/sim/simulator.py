"""The truth simulator: raw outputs of a redundant IMU on a turntable, in raw units.

For sensor i (Cho & Park 2005, Eq. 1 solved for the output)::

    y_i = (a_i . u + b_i + sum_e phi_e . theta_e + v_i) / SF_i

with u the true input in MB: for gyros the table rate plus the Earth rate at the true attitude; for
accelerometers the specific force at the true attitude plus the centripetal acceleration of a lever arm and
an optional random perturbing acceleration. ``v_i`` is white noise of the given density (ARW, VRW) plus an
optional bias random walk and an optional flicker bias (bias instability, :mod:`rimu.sim.noise`). Turntable
imperfections: a random attitude error per position, a relative rate error per step, and a constant mounting error of the unit on the table. The session reports only what the
procedure says the rig knows (commanded values), never the truth.

Deterministic for a given seed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calibration.model import Effect, SensorContext, unit_axes
from ..calibration.result import Calibration, InstrumentCalibration
from ..epoch import INSTRUMENTS, EpochBlock
from ..geometry import Geometry, cone6
from ..noise.model import InstrumentNoise
from ..session import Segment, Session, rotation_matrix
from ..units import (
    ARCSEC_TO_RAD,
    ARW_DSQH_TO_RSQS,
    DEG_TO_RAD,
    DH_TO_RS,
    G0,
    PPM,
    UG_TO_MS2,
    white_noise_sigma,
)
from .noise import FlickerSource
from .procedures import SegmentSpec
from .truth import default_truth

__all__ = ["Simulator", "SimRun", "TruthEffect"]


@dataclass
class TruthEffect:
    """A further effect present in the simulated sensors: ``effect`` with physical values ``theta``
    (SI, in the order of ``effect.physical_parameters``) per sensor index."""

    effect: Effect
    theta: dict[int, Sequence[float]]


@dataclass
class SimRun:
    """What a simulation returns.

    Attributes
    ----------
    session : Session
        Segments with raw samples and what the rig reports.
    block : EpochBlock
        All samples back to back (continuous time), for the runtime pipeline.
    truth_inputs : dict[str, ndarray (N, 3)]
        True input of each instrument in MB for every sample of ``block``.
    truth : Calibration
        The coefficients the data were made with (noise_sigma set to the simulated white noise).
    segment_index : ndarray (N,)
        Segment number of each sample of ``block``.
    """

    session: Session
    block: EpochBlock
    truth_inputs: dict[str, np.ndarray]
    truth: Calibration
    segment_index: np.ndarray
    truth_segments: list[Segment] = field(repr=False, default_factory=list)


@dataclass(eq=False, repr=False)
class Simulator:
    """Settings of a simulated unit and rig; :meth:`run` makes the data.

    Parameters
    ----------
    geometries : dict[str, Geometry], optional
        Default: a cone6 unit for both gyros and accelerometers.
    truth : Calibration, optional
        True coefficients. Default: Cho & Park Table 3 for cone6, random (seeded) otherwise.
    arw_deg_sqrt_h : float
        Gyro angle random walk, deg/sqrt(h) (white rate noise density).
    vrw_ug_sqrt_hz : float
        Accelerometer white noise density, micro-g/sqrt(Hz).
    gyro_bias_rw_deg_h_sqrt_h, accel_bias_rw_ug_sqrt_h : float
        Bias random walk densities ((deg/h)/sqrt(h) and micro-g/sqrt(h)); 0 disables.
    gyro_bias_instability_deg_h, accel_bias_instability_ug : float
        Bias instability B (flicker bias, :class:`rimu.sim.noise.FlickerSource`; the Allan deviation is flat
        at 0.664 B), deg/h and micro-g; 0 disables.
    flicker_band_s : (float, float), optional
        Shortest and longest time constant of the flicker source, s (default ``(0.2 / sample_rate, 1e5)``).
    sample_rate : float
        Hz.
    latitude_deg : float or None
        Latitude for the Earth rate; None switches the Earth rate off.
    gravity : float
        m/s^2.
    table_angle_error_arcsec : float
        1-sigma attitude error of each commanded position, and of each rotation's total angle.
    table_rate_error_ppm : float
        1-sigma relative error of each commanded rate.
    mount_error_rad : array_like (3,), optional
        Rotation vector of the unit's true MB frame against the table's nominal one (constant).
    lever_arm_m : array_like (3,) or (n_accel, 3), optional
        Position of the accelerometers relative to the rotation centre, MB, m.
    perturbation_ug : float
        1-sigma white perturbing acceleration common to all accelerometers, micro-g.
    temperature : float or callable
        degC, constant or a function of time (s from the start).
    effects : dict[str, list[TruthEffect]], optional
        Further effects per instrument.
    quantize : bool
        Round raw outputs to whole counts.
    seed : int or None
    """

    geometries: dict[str, Geometry] | None = None
    truth: Calibration | None = None
    arw_deg_sqrt_h: float = 3.0
    vrw_ug_sqrt_hz: float = 200.0
    gyro_bias_rw_deg_h_sqrt_h: float = 0.0
    accel_bias_rw_ug_sqrt_h: float = 0.0
    gyro_bias_instability_deg_h: float = 0.0
    accel_bias_instability_ug: float = 0.0
    flicker_band_s: tuple[float, float] | None = None
    sample_rate: float = 100.0
    latitude_deg: float | None = 36.37
    gravity: float = G0
    table_angle_error_arcsec: float = 0.0
    table_rate_error_ppm: float = 0.0
    mount_error_rad: Sequence[float] | None = None
    lever_arm_m: Any = None
    perturbation_ug: float = 0.0
    temperature: float | Callable[[np.ndarray], np.ndarray] = 25.0
    effects: dict[str, list[TruthEffect]] | None = None
    quantize: bool = False
    seed: int | None = 0

    def __post_init__(self) -> None:
        self.geometries = dict(self.geometries) if self.geometries is not None else {"gyro": cone6(), "accel": cone6()}
        self.flicker_band_s = None if self.flicker_band_s is None else tuple(self.flicker_band_s)
        self.effects = self.effects or {}

    # ------------------------------------------------------------------ helpers
    def noise_sigma(self, instrument: str) -> float:
        """Per-sample white-noise standard deviation in SI."""
        if instrument == "gyro":
            return white_noise_sigma(self.arw_deg_sqrt_h * ARW_DSQH_TO_RSQS, self.sample_rate)
        return white_noise_sigma(self.vrw_ug_sqrt_hz * UG_TO_MS2, self.sample_rate)

    def noise_model(self, instrument: str) -> InstrumentNoise | None:
        """The simulated noise terms (IEEE Std 952, SI) when bias instability or random walk are on, else None."""
        b, k = self._bias_instability(instrument), self._bias_rw_density(instrument)
        if b <= 0 and k <= 0:
            return None
        g = self.geometries[instrument]
        white = self.noise_sigma(instrument) / np.sqrt(self.sample_rate)
        return InstrumentNoise.from_terms(instrument, list(g.names), self.sample_rate, white=white,
                                          bias_instability=b, rate_random_walk=k)

    def truth_calibration(self) -> Calibration:
        base = self.truth or default_truth(self.geometries, seed=0 if self.seed is None else int(self.seed))
        out = {}
        for k, g in self.geometries.items():
            c = base[k]
            if c.geometry.fingerprint() != g.fingerprint():
                raise ValueError(f"the truth for {k} is for geometry {c.geometry.name!r}, the simulator has {g.name!r}")
            out[k] = InstrumentCalibration(k, g, c.scale, c.misalignment, c.bias, np.full(g.n, self.noise_sigma(k)),
                                           effects=dict(c.effects), noise=self.noise_model(k))
        return Calibration(out, method=base.method)

    # ------------------------------------------------------------------ run
    def run(self, procedure: Sequence[SegmentSpec]) -> SimRun:
        """Simulate a procedure. Returns a :class:`SimRun` (session, continuous block, truth)."""
        if not procedure:
            raise ValueError("the procedure has no segments")
        rng = np.random.default_rng(self.seed)
        truth = self.truth_calibration()
        fs = self.sample_rate
        lat = None if self.latitude_deg is None else self.latitude_deg * DEG_TO_RAD
        mount = rotation_matrix(np.zeros(3) if self.mount_error_rad is None else np.asarray(self.mount_error_rad, float))
        # further effects act on what each sensor really senses: its true axis
        ctxs = {k: [SensorContext(k, i, g, lat, self.gravity, axes=unit_axes(truth[k].axes_mb())) for i in range(g.n)]
                for k, g in self.geometries.items()}
        rw_state = {k: np.zeros(g.n) for k, g in self.geometries.items()}
        flicker = {k: FlickerSource(g.n, fs, self._bias_instability(k), self.flicker_band_s, rng=rng)
                   for k, g in self.geometries.items() if self._bias_instability(k) > 0}
        lever = None if self.lever_arm_m is None else np.asarray(self.lever_arm_m, dtype=float)
        segments, truth_segments, inputs_all, idx_all = [], [], {k: [] for k in self.geometries}, []
        t0 = 0.0
        for s_i, spec in enumerate(procedure):
            N = max(int(round(spec.duration * fs)), 1)
            t = t0 + np.arange(N) / fs
            t0 = t[-1] + 1.0 / fs
            # true attitude and rate
            d_att = rotation_matrix(rng.standard_normal(3) * self.table_angle_error_arcsec * ARCSEC_TO_RAD)
            att_true = d_att @ spec.mat_ln_mb @ mount
            rate_true = mount.T @ (spec.rate_mb * (1.0 + self.table_rate_error_ppm * PPM * rng.standard_normal()))
            if not spec.is_static and self.table_angle_error_arcsec > 0:
                total = np.linalg.norm(spec.rate_mb) * spec.duration
                rate_true = rate_true * (1.0 + rng.standard_normal() * self.table_angle_error_arcsec * ARCSEC_TO_RAD / total)
            temp = self._temperature(t)
            tseg = Segment(spec.label, "static" if spec.is_static else "rate", t, {}, temp,
                           rate_mb=None if spec.is_static else rate_true, mat_ln_mb=att_true)
            raw = {}
            for k, g in self.geometries.items():
                cal = truth[k]
                u = ctxs[k][0].input(tseg)
                if k == "accel":
                    u = np.array(u, dtype=float)
                    if lever is not None and not spec.is_static:
                        w = rate_true
                        cent = np.cross(w, np.cross(w, lever))  # (3,) or (n, 3)
                        u = u[:, None, :] + np.broadcast_to(cent, (g.n, 3))[None] if cent.ndim == 2 else u + cent
                    if self.perturbation_ug > 0:
                        pert = rng.standard_normal((N, 3)) * self.perturbation_ug * UG_TO_MS2
                        u = u + (pert[:, None, :] if u.ndim == 3 else pert)
                A = cal.axes_mb()
                z = np.einsum("nij,ij->ni", u, A) if u.ndim == 3 else u @ A.T
                z = z + cal.bias
                for te in self.effects.get(k, []):
                    for i, theta in te.theta.items():
                        cols = te.effect.columns(tseg, ctxs[k][i])
                        if cols is None:
                            raise ValueError(f"truth effect {te.effect.name} lacks inputs in segment {spec.label}")
                        z[:, i] += np.asarray(cols, dtype=float) @ np.asarray(theta, dtype=float)
                z = z + rng.standard_normal((N, g.n)) * cal.noise_sigma
                rw = self._bias_rw_density(k)
                if rw > 0:
                    steps = rng.standard_normal((N, g.n)) * rw / np.sqrt(fs)
                    walk = rw_state[k] + np.cumsum(steps, axis=0)
                    rw_state[k] = walk[-1]
                    z = z + walk
                if k in flicker:
                    z = z + flicker[k].draw(N)
                y = z / cal.scale
                if self.quantize:
                    y = np.round(y)
                raw[k] = y
                inputs_all[k].append(u if u.ndim == 2 else u.mean(axis=1))
            tseg.raw = raw
            truth_segments.append(tseg)
            idx_all.append(np.full(N, s_i))
            segments.append(self._reported(spec, t, raw, temp))
        session = Session(segments, dict(self.geometries), fs, lat, self.gravity, "count",
                          {"simulator": self.settings()})
        block = EpochBlock(
            t=np.concatenate([s.t for s in segments]),
            raw={k: np.vstack([s.raw[k] for s in segments]) for k in self.geometries},
            temperature=np.concatenate([s.temperature for s in segments]),
        )
        return SimRun(session, block, {k: np.vstack(v) for k, v in inputs_all.items()}, truth,
                      np.concatenate(idx_all), truth_segments)

    def session(self, procedure: Sequence[SegmentSpec]) -> Session:
        """Just the session of :meth:`run`."""
        return self.run(procedure).session

    def settings(self) -> dict[str, Any]:
        """The settings, JSON-friendly (kept in the session's meta)."""
        return {
            "geometries": {k: g.name for k, g in self.geometries.items()},
            "arw_deg_sqrt_h": self.arw_deg_sqrt_h,
            "vrw_ug_sqrt_hz": self.vrw_ug_sqrt_hz,
            "gyro_bias_rw_deg_h_sqrt_h": self.gyro_bias_rw_deg_h_sqrt_h,
            "accel_bias_rw_ug_sqrt_h": self.accel_bias_rw_ug_sqrt_h,
            "gyro_bias_instability_deg_h": self.gyro_bias_instability_deg_h,
            "accel_bias_instability_ug": self.accel_bias_instability_ug,
            "flicker_band_s": None if self.flicker_band_s is None else list(self.flicker_band_s),
            "sample_rate": self.sample_rate,
            "latitude_deg": self.latitude_deg,
            "table_angle_error_arcsec": self.table_angle_error_arcsec,
            "table_rate_error_ppm": self.table_rate_error_ppm,
            "perturbation_ug": self.perturbation_ug,
            "seed": self.seed,
        }

    def _temperature(self, t: np.ndarray) -> np.ndarray:
        if callable(self.temperature):
            return np.asarray(self.temperature(t), dtype=float).reshape(t.shape)
        return np.full(t.shape, float(self.temperature))

    def _bias_rw_density(self, instrument: str) -> float:
        """Bias random walk in SI per sqrt(s)."""
        if instrument == "gyro":
            return self.gyro_bias_rw_deg_h_sqrt_h * DH_TO_RS / 60.0
        return self.accel_bias_rw_ug_sqrt_h * UG_TO_MS2 / 60.0

    def _bias_instability(self, instrument: str) -> float:
        """Bias instability B in SI (rad/s, m/s^2)."""
        if instrument == "gyro":
            return self.gyro_bias_instability_deg_h * DH_TO_RS
        return self.accel_bias_instability_ug * UG_TO_MS2

    def _reported(self, spec: SegmentSpec, t: np.ndarray, raw: dict[str, np.ndarray], temp: np.ndarray) -> Segment:
        kind = spec.report
        att = spec.mat_ln_mb if spec.report_attitude else None
        sf = spec.specific_force_mb(self.gravity) if (kind == "static" and spec.report_attitude) else None
        angle = np.asarray(spec.meta["angle_mb"]) if kind == "angle" else None
        if kind == "angle" and angle is None:
            angle = spec.rate_mb * spec.duration
        rate = spec.rate_mb if kind == "rate" else None
        meta = dict(spec.meta)
        meta["commanded_rate_mb"] = spec.rate_mb.tolist()
        return Segment(spec.label, kind, t, dict(raw), temp, specific_force_mb=sf, rate_mb=rate, angle_mb=angle,
                       mat_ln_mb=att, meta=meta)


INSTRUMENT_NAMES = INSTRUMENTS
