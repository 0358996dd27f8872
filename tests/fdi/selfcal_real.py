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


def first_half_calibration(cal, Y: np.ndarray, use: np.ndarray, iterations: int = 3):
    """The strongest fixed calibration the first half gives: ``cal`` with every gyro's bias and axis (relative scale
    and misalignment) refitted by least squares to the parity of the samples ``use`` (the first half's, every
    sensor valid).

    The recipe of docs/real-units.md fits one rotation per triad and the biases, not each gyro's scale and
    misalignment; the parity of the first half sees them (relative to the unit). Per gyro i the compensated output
    is modelled ``z_i = (a_i + c_i) . u + b_i`` (u the fused rate) and ``(b, c)`` is fitted in the normalised parity
    (minimum norm), its common mode removed (``Pi``: the fused estimate keeps its frame and scale), and folded in::

        a_i' = (a_i + c_i) / |a_i + c_i|,   SF_i' = SF_i / |a_i + c_i|,   B_i' = (B_i + b_i) / |a_i + c_i|

    (sigma scaled as the output). Repeated ``iterations`` times (the fused rate is that of the current
    calibration). Nothing of the second half is used."""
    from dataclasses import replace

    Y0 = np.where(np.isfinite(Y), Y, 0.0)[use]
    for _ in range(iterations):
        trk = SelfCalTracker(cal, settings())
        A, n = trk.axes, trk.n
        z = cal.compensate(Y0)
        Vz = trk.parity_rows()
        u = z @ trk.G.T
        X = np.concatenate([Vz[None].repeat(len(z), 0)] + [Vz[None] * u[:, c, None, None] for c in range(3)], axis=2)
        X = X.reshape(-1, 4 * n)
        th, *_ = np.linalg.lstsq(X.T @ X, X.T @ (z @ Vz.T).reshape(-1), rcond=None)  # the normal equations
        b = trk.Pi @ th[:n]
        C = trk.Pi @ th[n:].reshape(3, n).T                        # (n, 3) axis corrections in MB
        Anew = A + C
        nrm = np.linalg.norm(Anew, axis=1)
        mis = cal.misalignment.copy()
        for su in cal.geometry.subunits:
            idx = list(su.members)
            mis[idx] = (Anew[idx] / nrm[idx, None]) @ su.mat_sb_mb.T
        cal = replace(cal, scale=cal.scale / nrm, misalignment=mis, bias=(cal.bias + b) / nrm,
                      noise_sigma=None if cal.noise_sigma is None else cal.noise_sigma / nrm, covariance=None,
                      param_names=[])
    return cal


def _parity_rms(cal, Y: np.ndarray, V: np.ndarray, rows: np.ndarray, correction: np.ndarray | None = None) -> float:
    pipe = InstrumentPipeline(cal)
    Yc = Y if correction is None else Y - correction / cal.scale
    return float(np.sqrt(np.mean(pipe.process(np.where(np.isfinite(Yc), Yc, 0.0), V).parity[rows] ** 2)))


def compare(rec, p_fa: float = 1e-3, confirm: int = 3, refine: bool = True) -> dict:
    """Parity rms (normalised, sigma) over the second half: fixed first-half calibration vs online tracking.

    ``refine``: the fixed calibration is the recipe's with every gyro's bias, scale and misalignment refitted on the
    first half (:func:`first_half_calibration`: the strongest fixed reference the first half gives); the tracker
    starts from it. Off: the recipe's calibration alone (``rms_recipe``, always reported, is its fixed rms)."""
    split = 0.5 * max(u.t[-1] for u in rec.units)      # s: the setup fits on t <= split, the second half is t > split
    su = setup_multi_imu(rec, average_s=0.1, fit_window_s=(-np.inf, split))
    recipe = su.calibration["gyro"]
    blk = su.block
    Y, V, t = blk.raw["gyro"], blk.valid["gyro"], blk.t
    ok = np.all(V, axis=1) & np.all(np.isfinite(Y), axis=1)
    second = (t > split) & ok
    cal = first_half_calibration(recipe, Y, ok & (t <= split)) if refine else recipe
    trk = SelfCalTracker(cal, settings())
    mgr = RedundancyManager(InstrumentPipeline(cal), TrackedGltWindow(1, p_fa), p_fa=p_fa, confirm=confirm,
                            common_cause=True)
    run = SelfCalibratingRun(mgr, trk)
    res = run.run(Y, V, t)
    mgr0 = RedundancyManager(InstrumentPipeline(cal), TrackedGltWindow(1, p_fa), p_fa=p_fa, confirm=confirm,
                            common_cause=True)
    res0 = mgr0.run(Y, V, t)
    iso = [e for e in res.replay.events if e.kind in ("isolated", "invalid_isolated")]
    iso0 = [e for e in res0.events if e.kind in ("isolated", "invalid_isolated")]
    return {"n": cal.geometry.n, "samples": int(second.sum()), "rate_hz": 1.0 / float(np.median(np.diff(t))),
            "rms_fixed": _parity_rms(cal, Y, V, second), "rms_tracked": _parity_rms(cal, Y, V, second, res.correction),
            "rms_recipe": _parity_rms(recipe, Y, V, second),
            "isolations_tracked": len(iso), "isolations_fixed": len(iso0),
            "invalid_isolations_tracked": sum(e.kind == "invalid_isolated" for e in iso),
            "invalid_isolations_fixed": sum(e.kind == "invalid_isolated" for e in iso0),
            "alarms_tracked": float(res.replay.alarm.mean()), "alarms_fixed": float(res0.alarm.mean()),
            "result": res, "guard": run.loop.guard(), "tracker": trk, "t": t, "second": second, "z_second": cal.compensate(
                np.where(np.isfinite(Y), Y, 0.0))[second], "z": cal.compensate(np.where(np.isfinite(Y), Y, 0.0)),
            "first": ok & (t <= split), "still": _padded(su.still, len(t)) & ok}


def _padded(mask, n: int) -> np.ndarray:
    """``mask`` (the setup's epochs at rest: whole blocks only) as n epochs, False past its end."""
    out = np.zeros(n, bool)
    m = np.asarray(mask, bool)[:n]
    out[:len(m)] = m
    return out


def _longest(mask: np.ndarray) -> slice:
    e = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    if not len(e):
        return slice(0, 0)
    a, b = e[::2], e[1::2]
    k = int(np.argmax(b - a))
    return slice(int(a[k]), int(b[k]))


def parity_drift(c: dict, rest: bool = False, p_fa: float = 1e-3, min_tau_s: float = 1.0) -> dict:
    """Is there slow drift in the parity, left by the fixed calibration (``compare(refine=True)``: the first half's
    constant terms removed)? The overlapping Allan deviation (:func:`rimu.noise.allan.allan_deviation`) of every
    normalised parity component over the longest stretch of the first half with every sensor valid (``rest``: at
    rest), against white noise: ``adev sqrt(m) = 1`` at every tau, its upper bound from the chi-square of Greenhall's
    edf for white noise (NIST SP 1065, Eq. 45) at ``p_fa`` shared by every component and tau (Bonferroni). A random
    walk or any drift slow enough to track rises above it at long taus.

    Returns ``tau_s`` (the longest tau), ``median``/``max`` of the normalised deviation there over the components,
    ``bound`` (the white upper bound there), ``above`` (component-taus at ``tau >= min_tau_s`` above their bound),
    ``tested`` (how many were tested) and ``seconds`` (the stretch's length)."""
    from scipy.stats import chi2

    from rimu.noise.allan import allan_deviation, edf

    trk = c["tracker"]
    fs = c["rate_hz"]
    P = c["z"] @ trk.parity_rows().T
    sl = _longest(c["first"] & (c["still"] if rest else True))
    R = P[sl] - P[sl].mean(axis=0)
    ad = allan_deviation(R, fs, None, per_decade=4, max_fraction=0.25)
    nd = ad.adev * np.sqrt(ad.cluster)[None]
    dof = np.array([edf(0, int(m), len(R)) for m in ad.cluster])
    hi = np.sqrt(chi2.isf(p_fa / nd.size, dof) / dof)
    long = ad.tau >= min_tau_s
    return {"tau_s": float(ad.tau[-1]), "median": float(np.median(nd[:, -1])), "max": float(nd[:, -1].max()),
            "bound": float(hi[-1]), "above": int((nd[:, long] > hi[None, long]).sum()), "tested": int(nd[:, long].size),
            "seconds": (sl.stop - sl.start) / fs}


def random_walk_gain(c: dict, block_s: float = 2.0) -> dict:
    """What a random walk of the parity bias with its process noise MEASURED on the first half would do on the
    second (a local-level Kalman filter per normalised parity component, one-step-ahead predictions, on top of the
    fixed calibration). The variance growth ``K^2`` per second from the variogram of the first half's ``block_s``
    means, ``E[(m_j - m_i)^2] = c + K^2 |t_j - t_i|`` (the rule of :mod:`rimu.fdi.bias_drift`; negative: 0), the
    white variance from the first half. Returns the second half's parity rms ``fixed`` and ``random_walk`` (sigma)
    and the median ``K2`` (1/s, normalised units)."""
    trk = c["tracker"]
    fs = c["rate_hz"]
    ok = np.zeros(len(c["z"]), bool)
    ok[c["first"]] = True
    ok[np.flatnonzero(c["second"])] = True
    P = c["z"] @ trk.parity_rows().T
    Pf = P[c["first"]]
    L = max(1, int(round(block_s * fs)))
    nb = len(Pf) // L
    mb = Pf[:nb * L].reshape(nb, L, -1).mean(axis=1)
    lags = np.arange(1, max(2, nb // 3))
    vg = np.array([np.mean((mb[k:] - mb[:-k]) ** 2, axis=0) for k in lags])
    X = np.column_stack([np.ones(len(lags)), lags * L / fs])
    K2 = np.clip(np.linalg.lstsq(X, vg, rcond=None)[0][1], 0.0, None)
    r = np.mean(Pf ** 2, axis=0)
    x, v = Pf.mean(axis=0), r / len(Pf)
    e = np.zeros_like(P)
    for k in np.flatnonzero(ok):          # the filter runs over the valid samples, learning on the second half only
        v = v + K2 / fs
        e[k] = P[k] - x
        if c["second"][k]:
            g = v / (v + r)
            x, v = x + g * e[k], (1 - g) * v
    return {"fixed": float(np.sqrt(np.mean(P[c["second"]] ** 2))),
            "random_walk": float(np.sqrt(np.mean(e[c["second"]] ** 2))), "K2": float(np.median(K2))}


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
    scales (``s``: ``a_i . u``, u the fused rate), axes (``m``: the three components of u, scale and
    misalignment)."""
    n = trk.n
    u = z @ trk.G.T
    cols = []
    if "b" in blocks:
        cols.append(np.broadcast_to(np.eye(n), (len(z), n, n)))
    if "s" in blocks:
        cols.append(np.einsum("kn,nm->knm", u @ trk.axes.T, np.eye(n)))
    if "m" in blocks:       # each gyro's whole axis: scale and misalignment, three terms per gyro
        cols += [np.einsum("k,nm->knm", u[:, c], np.eye(n)) for c in range(3)]
    return np.concatenate(cols, axis=2)


def ceiling(c: dict, blocks: str = "b", batches: int = 10) -> dict:
    """The ceiling of a tracker of constant terms on the second half: the hindsight-optimal constant correction
    (least squares in the parity space; ``blocks`` "b" biases, "bs" biases and relative scales, "bm" biases and
    axes) and what it gains
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
    # the normal equations of each batch, summed for the fits on all batches but one
    XtX = np.array([np.einsum("krp,krq->pq", X[o], X[o]) for o in idx])
    Xty = np.array([np.einsum("krp,kr->p", X[o], p[o]) for o in idx])
    for j, out in enumerate(idx):
        th, *_ = np.linalg.lstsq(XtX.sum(axis=0) - XtX[j], Xty.sum(axis=0) - Xty[j], rcond=None)
        g[j] = np.sum(p[out] ** 2) - np.sum((p[out] - X[out] @ th) ** 2)
    N = p.size
    ss0 = float(np.sum(p * p))
    rms0 = np.sqrt(ss0 / N)
    rms_c = np.sqrt(max(ss0 - g.sum(), 0.0) / N)
    se_ss = np.sqrt(batches) * g.std(ddof=1)
    return {"rms_fixed": float(rms0), "rms": float(rms_c), "gain": float(rms0 - rms_c),
            "se": float(se_ss / N / (2 * rms0)), "z": float(g.sum() / se_ss)}


def rest_parity(c: dict) -> dict:
    """The second half's parity at rest (``compare()``'s spans at rest after the split, every sensor valid): rms with
    the fixed calibration and with tracking (sigma), and the ceiling of a constant bias there, judged out of sample
    span by span (fitted as the mean parity of the other spans at rest; ``z``: the summed gain over its standard
    error from the spread of the spans' gains). Where the whole half's rms is made by violent motion (MIMU4444: 99.98 %
    of its sum of squares), this is where a change of the biases between the halves shows."""
    trk = c["tracker"]
    Vz = trk.parity_rows()
    P = c["z"] @ Vz.T
    Pt = (c["z"] - c["result"].correction) @ Vz.T
    rest = c["still"] & c["second"]
    e = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(np.int8), [0]])))
    spans = list(zip(e[::2], e[1::2]))
    if len(spans) < 2:
        return {"spans": len(spans), "seconds": float(rest.sum()) / c["rate_hz"]}
    g = np.empty(len(spans))
    for j, (a, b) in enumerate(spans):
        other = np.concatenate([np.arange(x, y) for k, (x, y) in enumerate(spans) if k != j])
        g[j] = np.sum(P[a:b] ** 2) - np.sum((P[a:b] - P[other].mean(axis=0)) ** 2)
    ss, N = float(np.sum(P[rest] ** 2)), P[rest].size
    return {"spans": len(spans), "seconds": float(rest.sum()) / c["rate_hz"], "fixed": float(np.sqrt(ss / N)),
            "tracked": float(np.sqrt(np.mean(Pt[rest] ** 2))), "ceiling": float(np.sqrt(max(ss - g.sum(), 0.0) / N)),
            "z": float(g.sum() / (np.sqrt(len(g)) * g.std(ddof=1)))}
