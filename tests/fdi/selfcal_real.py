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


def _regressors(trk, z: np.ndarray, blocks: str) -> np.ndarray:
    """Per-sample regressors (K, n, p) in sensor space of constant terms of every gyro: biases (``b``), relative
    scales (``s``: ``a_i . u``, u the fused rate)."""
    n = trk.n
    u = z @ trk.G.T
    cols = []
    if "b" in blocks:
        cols.append(np.broadcast_to(np.eye(n), (len(z), n, n)))
    if "s" in blocks:
        cols.append(np.einsum("kn,nm->knm", u @ trk.axes.T, np.eye(n)))
    return np.concatenate(cols, axis=2)


def ceiling(c: dict, blocks: str = "b", batches: int = 10) -> dict:
    """The ceiling of a tracker of constant terms on the second half: the hindsight-optimal constant correction
    (least squares in the parity space; ``blocks`` "b" biases, "bs" biases and relative scales) and what it gains
    over the fixed calibration, judged out of sample so that fitting the noise does not count as a gain.

    The second half is cut into ``batches`` contiguous batches; the terms are fitted on all batches but one and
    the gain (sum of squares of the normalised parity removed) is measured on the one left out. The gains of the
    batches are summed; their standard error is ``sqrt(B) std(g_j)`` (the batches as independent replicates: the
    parity's own correlation, vibration and manoeuvres, is inside each batch). For the biases alone the fit is the
    mean parity of the other batches. Returns the parity rms fixed and at the ceiling (sigma), the ``gain`` (rms
    fixed minus ceiling, sigma; negative: constant terms fitted on the rest of the half make each batch worse) and
    its standard error ``se`` (sigma)."""
    trk, z = c["tracker"], c["z_second"]
    Vz = trk.parity_rows()
    p = z @ Vz.T
    K = p.shape[0]
    X = np.einsum("rn,knp->krp", Vz, _regressors(trk, z, blocks))
    idx = np.array_split(np.arange(K), batches)
    g = np.empty(batches)
    for j, out in enumerate(idx):
        fit = np.setdiff1d(np.arange(K), out)
        th, *_ = np.linalg.lstsq(X[fit].reshape(-1, X.shape[2]), p[fit].reshape(-1), rcond=None)
        g[j] = np.sum(p[out] ** 2) - np.sum((p[out] - X[out] @ th) ** 2)
    N = p.size
    ss0 = float(np.sum(p * p))
    rms0 = np.sqrt(ss0 / N)
    rms_c = np.sqrt(max(ss0 - g.sum(), 0.0) / N)
    se_ss = np.sqrt(batches) * g.std(ddof=1)
    return {"rms_fixed": float(rms0), "rms": float(rms_c), "gain": float(rms0 - rms_c),
            "se": float(se_ss / N / (2 * rms0)), "z": float(g.sum() / se_ss)}
