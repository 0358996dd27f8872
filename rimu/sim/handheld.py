"""A hand-held calibration recording: random poses held by hand, hand rotations between them, tremor.

The unit (default: a MEMS triad of gyros and accelerometers in raw counts, MPU-6050-like) is held in
``n_poses`` random attitudes for ``static_s`` seconds each and turned by hand from one to the next: the
body turns about the axis of the relative rotation with a minimum-jerk angle profile (peak rate
``peak_rate_deg_s``, every turn at least 0.8 s). During the whole recording the hand adds

* tremor: band-limited angular oscillation around 8-12 Hz (``tremor_deg`` rms) and a linear acceleration of
  the same band (``tremor_ms2`` rms);
* sway: a slow wander of the attitude below 0.5 Hz (``sway_deg`` rms), so a "static" pose is never quite
  static.

The body rate is integrated exactly on a grid ``oversample`` times finer than the output rate (one quaternion
per fine step, combined by a prefix product); the gyro outputs the mean rate over each sample interval (an
integrating sensor), the accelerometer the mean specific force. The Earth rate is left out (below a MEMS
gyro's resolution). Noise: white (ARW, VRW), outputs rounded to counts.

>>> run = handheld_run(n_poses=12, seed=1)
>>> [s.kind for s in run.session.segments[:3]]
['static_unknown', 'motion', 'static_unknown']
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..calibration.handheld import _prefix_product, quat_exp, quat_to_matrix
from ..calibration.result import Calibration, InstrumentCalibration
from ..geometry import Geometry, triad3
from ..session import Segment, Session
from ..units import ARW_DSQH_TO_RSQS, DEG_TO_RAD, G0, UG_TO_MS2, white_noise_sigma
from .truth import random_truth

__all__ = ["HandHeldRun", "handheld_run", "mems_truth"]


@dataclass
class HandHeldRun:
    """A simulated hand-held recording.

    Attributes
    ----------
    session : Session
        Poses (``static_unknown``, labelled P1..) and the motions between them (``motion``, M1..).
    truth : Calibration
    t : ndarray (N,)
    raw : dict[str, ndarray (N, n)]
        The continuous raw record (what a logger writes; input of ``rimu detect``).
    mat_nav_body : ndarray (N, 3, 3)
        True attitude at each sample.
    rate : ndarray (N, 3)
        True mean body rate over each sample interval, rad/s.
    specific_force : ndarray (N, 3)
        True mean specific force, m/s^2.
    pose_slices : list of slice
        Samples of each nominal pose in the continuous record.
    """

    session: Session
    truth: Calibration
    t: np.ndarray
    raw: dict[str, np.ndarray]
    mat_nav_body: np.ndarray
    rate: np.ndarray
    specific_force: np.ndarray
    pose_slices: list[slice]
    settings: dict[str, Any]


def mems_truth(geometries: dict[str, Geometry], seed: int = 0) -> Calibration:
    """Random coefficients of a consumer MEMS unit in counts: accelerometer 16384 count/g +-3 %, bias
    ~0.3 m/s^2, gyro 131 count/(deg/s) +-3 %, bias ~2 deg/s, misalignments ~5 mrad (MPU-6050 class)."""
    rng = np.random.default_rng(seed)
    out = {}
    for k, g in geometries.items():
        if k == "accel":
            out[k] = random_truth(g, k, rng, scale=G0 / 16384, misalignment_sigma=5e-3, bias_sigma=0.3,
                                  scale_spread=0.03)
        else:
            out[k] = random_truth(g, k, rng, scale=DEG_TO_RAD / 131.0, misalignment_sigma=5e-3,
                                  bias_sigma=2.0 * DEG_TO_RAD, scale_spread=0.03)
    return Calibration(out, method="MEMS truth (random)")


def _random_rotations(rng: np.random.Generator, k: int) -> np.ndarray:
    q = rng.standard_normal((k, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q


def _shaped_noise(rng: np.random.Generator, n: int, dt: float, f_lo: float, f_hi: float, rms: float) -> np.ndarray:
    """(n, 3) noise with a flat spectrum between f_lo and f_hi (Hz), scaled to the given rms per axis."""
    if rms <= 0:
        return np.zeros((n, 3))
    X = np.fft.rfft(rng.standard_normal((n, 3)), axis=0)
    f = np.fft.rfftfreq(n, dt)
    X[(f < f_lo) | (f > f_hi)] = 0.0
    x = np.fft.irfft(X, n, axis=0)
    s = x.std(axis=0)
    return x * (rms / np.where(s > 0, s, 1.0))


def _quat_log(q: np.ndarray) -> np.ndarray:
    q = q * np.sign(q[0]) if q[0] != 0 else q
    v = q[1:]
    s = np.linalg.norm(v)
    if s < 1e-15:
        return 2 * v
    return 2 * np.arctan2(s, q[0]) * v / s


def handheld_run(n_poses: int = 30, static_s: float = 3.0, geometries: dict[str, Geometry] | None = None,
                 truth: Calibration | None = None, sample_rate: float = 100.0, arw_deg_sqrt_h: float = 0.3,
                 vrw_ug_sqrt_hz: float = 300.0, tremor_deg: float = 0.03, sway_deg: float = 0.1,
                 tremor_ms2: float = 0.02, peak_rate_deg_s: float = 150.0, initial_still_s: float = 0.0,
                 quantize: bool = True, gravity: float = G0, oversample: int = 8, seed: int = 0,
                 up_mb: Any = None, gyro_g_sensitivity: Any = None) -> HandHeldRun:
    """Simulate a hand-held calibration recording (module docstring).

    Parameters
    ----------
    n_poses : int
        Number of static poses (random attitudes).
    static_s : float
        Seconds per pose (the first lasts ``initial_still_s`` if that is longer).
    geometries : dict, optional
        Default: a triad of gyros and a triad of accelerometers.
    truth : Calibration, optional
        Default: :func:`mems_truth` (seeded).
    arw_deg_sqrt_h, vrw_ug_sqrt_hz : float
        White noise densities.
    tremor_deg, sway_deg, tremor_ms2 : float
        Hand tremor (8-12 Hz, angle rms), sway (< 0.5 Hz, angle rms), tremor linear acceleration rms.
    gyro_g_sensitivity : array_like (3, 3), optional
        A hidden gyro g-sensitivity (rad/s per m/s^2, MB): the gyros also see ``G @ f`` (for diagnosis tests).
    up_mb : array_like (K, 3), optional
        Body directions to hold up, one per pose (random heading); default: random attitudes.
    peak_rate_deg_s : float
        Peak rate of a turn (minimum-jerk: 1.875 times the mean rate); every turn lasts at least 0.8 s.
    """
    rng = np.random.default_rng(seed)
    geometries = dict(geometries) if geometries is not None else {"gyro": triad3(), "accel": triad3()}
    truth = truth or mems_truth(geometries, seed=seed + 1000)
    fs = float(sample_rate)
    dtf = 1.0 / (fs * oversample)
    poses = _random_rotations(rng, n_poses)
    if up_mb is not None:
        up = np.asarray(up_mb, dtype=float).reshape(-1, 3)
        n_poses = len(up)
        poses = np.array([_pose_with_up(u, rng.uniform(0, 2 * np.pi)) for u in up])
    # nominal body rate on the fine grid: pose k still, then a minimum-jerk turn to pose k+1
    pieces, labels, bounds = [], [], []
    n0 = 0
    for k in range(n_poses):
        dur = max(static_s, initial_still_s) if k == 0 else static_s
        ns = round(dur * fs) * oversample
        pieces.append(np.zeros((ns, 3)))
        bounds.append(("static_unknown", f"P{k + 1}", n0, n0 + ns))
        n0 += ns
        if k == n_poses - 1:
            break
        qa, qb = poses[k], poses[k + 1]
        qrel = _qmul_conj(qa, qb)  # body-frame relative rotation
        phi = _quat_log(qrel)
        ang = float(np.linalg.norm(phi))
        T = max(0.8, 1.875 * ang / (peak_rate_deg_s * DEG_TO_RAD))
        T *= 1.0 + 0.2 * rng.random()
        nm = round(T * fs) * oversample
        tau = (np.arange(nm) + 0.5) / nm
        sdot = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T  # minimum-jerk profile, integrates to 1
        pieces.append(sdot[:, None] * phi[None, :])
        bounds.append(("motion", f"M{k + 1}", n0, n0 + nm))
        n0 += nm
        labels.append(k)
    w_nom = np.vstack(pieces)
    nf = len(w_nom)
    # hand: tremor and sway as angle processes; their rate is the derivative
    ang_tremor = _shaped_noise(rng, nf, dtf, 8.0, 12.0, tremor_deg * DEG_TO_RAD)
    ang_sway = _shaped_noise(rng, nf, dtf, 0.0, 0.5, sway_deg * DEG_TO_RAD)
    w_hand = np.gradient(ang_tremor + ang_sway, dtf, axis=0)
    w = w_nom + w_hand
    q = _prefix_product(quat_exp(w * dtf), np.zeros(nf, int))
    q = quat_mul_left(poses[0], q)
    C = quat_to_matrix(q)
    f_nav = np.array([0.0, 0.0, gravity])
    f_fine = np.einsum("nji,j->ni", C, f_nav) + _shaped_noise(rng, nf, dtf, 8.0, 12.0, tremor_ms2)
    # per output sample: mean over the fine steps
    N = nf // oversample
    rate = w[:N * oversample].reshape(N, oversample, 3).mean(axis=1)
    sf = f_fine[:N * oversample].reshape(N, oversample, 3).mean(axis=1)
    att = C[::oversample][:N]
    t = np.arange(N) / fs
    raw = {}
    for k, g in geometries.items():
        cal = truth[k]
        u = rate if k == "gyro" else sf
        if k == "gyro" and gyro_g_sensitivity is not None:
            u = u + sf @ np.asarray(gyro_g_sensitivity, dtype=float).T
        sig = (white_noise_sigma(arw_deg_sqrt_h * ARW_DSQH_TO_RSQS, fs) if k == "gyro"
               else white_noise_sigma(vrw_ug_sqrt_hz * UG_TO_MS2, fs))
        z = u @ cal.axes_mb().T + cal.bias + rng.standard_normal((N, g.n)) * sig
        y = z / cal.scale
        raw[k] = np.round(y) if quantize else y
        truth.instruments_cal[k] = InstrumentCalibration(k, g, cal.scale, cal.misalignment, cal.bias,
                                                         np.full(g.n, sig) if sig > 0 else None,
                                                         effects=dict(cal.effects))
    segs, slices = [], []
    for kind, lab, a, b in bounds:
        sl = slice(a // oversample, b // oversample)
        segs.append(Segment(lab, kind, t[sl], {k: v[sl] for k, v in raw.items()}))
        if kind == "static_unknown":
            slices.append(sl)
    settings = {"n_poses": n_poses, "static_s": static_s, "arw_deg_sqrt_h": arw_deg_sqrt_h,
                "vrw_ug_sqrt_hz": vrw_ug_sqrt_hz, "tremor_deg": tremor_deg, "sway_deg": sway_deg,
                "tremor_ms2": tremor_ms2, "peak_rate_deg_s": peak_rate_deg_s, "seed": seed}
    session = Session(segs, geometries, fs, None, gravity, "count", {"simulator": {"handheld": settings}})
    return HandHeldRun(session, truth, t, raw, att, rate, sf, slices, settings)


def _pose_with_up(u: np.ndarray, yaw: float) -> np.ndarray:
    """Quaternion (body -> nav) with body direction u pointing up (nav z), then turned by ``yaw`` about up."""
    from ..calibration.handheld import quat_mul

    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    s = np.linalg.norm(axis)
    ang = np.arctan2(s, u @ z)
    axis = axis / s if s > 1e-12 else np.array([1.0, 0.0, 0.0])
    q = np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis])
    qz = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    return quat_mul(qz, q)


def _qmul_conj(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """conj(qa) * qb."""
    from ..calibration.handheld import quat_mul

    return quat_mul(qa * np.array([1, -1, -1, -1]), qb)


def quat_mul_left(q0: np.ndarray, q: np.ndarray) -> np.ndarray:
    from ..calibration.handheld import quat_mul

    return quat_mul(np.broadcast_to(q0, q.shape), q)
