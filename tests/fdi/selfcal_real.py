"""The shared real multi-IMU recordings for the self-calibration tests and docs (skip cleanly when absent).

Each recording is set up by the recipe of docs/real-units.md from its first half (clock offsets, axes, biases and
noise from the triads' disagreement, 0.1 s block averages), then its gyros are replayed whole twice: on that fixed
calibration, and with the tracker of :mod:`rimu.fdi.selfcal` running from the start. The drift model is stated, not
fitted: consumer MEMS gyros (bias instability 20 deg/h, three times as fast; residual bias of the short fit
0.1 deg/s 1-sigma; relative scale 0.5 % 1-sigma, moving by 200 ppm in 2 h); no temperature terms (the logs read
here carry no temperature channel of every triad).

The MIMU4444 board is read by :mod:`rimu.io.formats.mimu4444` (its clipped samples invalid).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rimu.calibration.multi_imu import setup_multi_imu
from rimu.fdi import RedundancyManager
from rimu.fdi.selfcal import SelfCalibratingRun, SelfCalSettings, SelfCalTracker, TrackedGltWindow
from rimu.fusion import InstrumentPipeline
from rimu.io.formats import mimu4444
from rimu.io.multiimu import MultiImuRecording
from rimu.units import DEG_TO_RAD, PPM

XSENS = ("Horizontal/path_10", "Horizontal/path_11", "Vertical/path_1", "Vertical/path_8", "StraightLine/path_1")
MIMU = ("exp_5", "exp_6", "exp_7", "exp_8", "exp_9")


def read_mimu4444(path: Path) -> MultiImuRecording:
    """The MIMU4444 raw stream (``exp_k.bin.xz``) through rimu's reader (:func:`rimu.io.formats.mimu4444.read`):
    8 MPU-9150 triads, 62.5 Hz, each in its own axes, SI, NaN where clipped."""
    return mimu4444.read(path)


def recordings(shared: Path) -> list[tuple[str, object]]:
    """(label, loader) of every shared multi-IMU recording present under ``shared`` (the data folder)."""
    from rimu.io.pixhawk_dual import read_pixhawk_dual
    from rimu.io.xsens_dot import read_xsens_dot_run

    out = []
    if (shared / "pixhawk1_dual_imu_flight").exists():
        out.append(("pixhawk1_dual_imu_flight", lambda: read_pixhawk_dual(shared / "pixhawk1_dual_imu_flight")))
    for r in XSENS:
        d = shared / "quadrotor_4x_xsens_dot" / r
        if d.exists():
            out.append((f"quadrotor_4x_xsens_dot/{r}", lambda d=d: read_xsens_dot_run(d)))
    for e in MIMU:
        f = shared / "mimu4444_array" / f"{e}.bin.xz"
        if f.exists():
            out.append((f"mimu4444_array/{e}", lambda f=f: read_mimu4444(f)))
    return out


def settings() -> SelfCalSettings:
    return SelfCalSettings(bias_rw=(0.06 * DEG_TO_RAD) ** 2 / 60.0, bias_sigma0=0.1 * DEG_TO_RAD,
                           scale_rw=(200 * PPM) ** 2 / 7200.0, scale_sigma0=0.01, window_s=1.0, hold_s=1.0)


def compare(rec, p_fa: float = 1e-3, confirm: int = 3) -> dict:
    """Parity rms (normalised, sigma) over the second half: fixed first-half calibration vs online tracking."""
    t_end = max(u.t[-1] for u in rec.units)
    su = setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, 0.5 * t_end))
    cal = su.calibration["gyro"]
    blk = su.block
    Y, V, t = blk.raw["gyro"], blk.valid["gyro"], blk.t
    trk = SelfCalTracker(cal, settings())
    mgr = RedundancyManager(InstrumentPipeline(cal), TrackedGltWindow(1, p_fa), p_fa=p_fa, confirm=confirm,
                            common_cause=True)
    run = SelfCalibratingRun(mgr, trk)
    res = run.run(Y, V, t)
    mgr0 = RedundancyManager(InstrumentPipeline(cal), TrackedGltWindow(1, p_fa), p_fa=p_fa, confirm=confirm,
                            common_cause=True)
    res0 = mgr0.run(Y, V, t)
    second = (t >= t[0] + 0.5 * (t[-1] - t[0])) & np.all(V, axis=1) & np.all(np.isfinite(Y), axis=1)
    pipe = InstrumentPipeline(cal)
    P0 = pipe.process(np.where(np.isfinite(Y), Y, 0.0), V).parity[second]
    P1 = pipe.process(np.where(np.isfinite(Y), Y - res.correction / cal.scale, 0.0), V).parity[second]
    iso = [e for e in res.replay.events if e.kind in ("isolated", "invalid_isolated")]
    iso0 = [e for e in res0.events if e.kind in ("isolated", "invalid_isolated")]
    return {"n": cal.geometry.n, "samples": int(second.sum()), "rate_hz": 1.0 / float(np.median(np.diff(t))),
            "rms_fixed": float(np.sqrt(np.mean(P0**2))), "rms_tracked": float(np.sqrt(np.mean(P1**2))),
            "isolations_tracked": len(iso), "isolations_fixed": len(iso0),
            "invalid_isolations_tracked": sum(e.kind == "invalid_isolated" for e in iso),
            "invalid_isolations_fixed": sum(e.kind == "invalid_isolated" for e in iso0),
            "alarms_tracked": float(res.replay.alarm.mean()), "alarms_fixed": float(res0.alarm.mean()),
            "result": res, "guard": run.loop.guard(), "tracker": trk, "t": t, "second": second, "z_second": cal.compensate(
                np.where(np.isfinite(Y), Y, 0.0))[second]}


def hindsight(c: dict, scale: bool = True) -> dict:
    """What the drift model could do at best on the second half, with hindsight: constant biases (and relative
    scales) of every gyro fitted by least squares to the second half's own parity. Returns the parity rms left
    (sigma; ``dof_corrected``: divided by the observations minus the parameters fitted) and the sampling standard
    error of the fixed calibration's rms (``rms / sqrt(2 N)`` for N parity values)."""
    trk, z = c["tracker"], c["z_second"]
    Vz = trk.parity_rows()
    p = z @ Vz.T
    s = (z @ trk.G.T) @ trk.axes.T
    cols = [np.ones_like(s)] + ([s] if scale else [])
    K, r = p.shape
    X = np.concatenate([(Vz[None] * g[:, None, :]).reshape(K * r, -1) for g in cols], axis=1)
    th, *_ = np.linalg.lstsq(X, p.reshape(-1), rcond=None)
    res = p.reshape(-1) - X @ th
    dof = K * r - np.linalg.matrix_rank(X)
    return {"rms": float(np.sqrt(np.mean(res**2))), "dof_corrected": float(np.sqrt(np.sum(res**2) / dof)),
            "se": float(np.sqrt(np.mean(p**2)) / np.sqrt(2 * K * r))}
