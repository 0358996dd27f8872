"""What is left of the MIMU4444 gyros' disagreement in the fast rotation, looked at as a user of the array would.

``python examples/mimu4444_residual.py [RUN]`` (RUN 5..9 of ``../shared/data/mimu4444_array``, default 5):

1. the triads in the array frame (the board's geometry), a full affine relative calibration of each triad
   against the mean of the others (gain and misalignment matrix and bias: 12 parameters per triad) fitted on the
   first half of the fast rotation, the residual judged on the second half (held out);
2. where the residual sits: against the distance to the nearest clipped sample, against the angular
   acceleration, per triad, per axis, between triads (independent errors correlate at -1/(k-1));
3. the share of the residual each deterministic candidate explains, fitted on the first half and judged on the
   second (a negative share: the candidate adds only noise): angular acceleration (a time offset), jerk,
   quadratic and cubic rate terms (nonlinearity), the triad's own specific force (g-sensitivity), and any FIR
   of a triad's own rates or of the array mean over +-2 samples (digital low-pass or delay differences);
4. the spectrum of the residual against the rate's and its lag-1 autocorrelation.

The figures of the five runs are in docs/real-units.md ("A board of eight raw triads").
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.signal import welch

from rimu.io.formats import mimu4444

D = np.degrees


def main(run: int = 5) -> dict[str, float]:
    f = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mimu4444_array" / f"exp_{run}.bin.xz"
    rec = mimu4444.read(f)
    geo = mimu4444.geometry()
    t = rec.units[0].t
    fs = rec.meta["sample_rate_hz"]
    G = np.stack([u.gyro @ su.mat_sb_mb for u, su in zip(rec.units, geo.subunits)], axis=1)   # (N, 8, 3)
    A = np.stack([u.accel @ su.mat_sb_mb for u, su in zip(rec.units, geo.subunits)], axis=1)
    ok = np.isfinite(G).all(axis=(1, 2)) & np.isfinite(A).all(axis=(1, 2))
    with warnings.catch_warnings():        # samples where every triad clipped: all-NaN rows
        warnings.simplefilter("ignore", RuntimeWarning)
        spin = np.convolve(np.nanmax(np.abs(G), axis=(1, 2)) > np.radians(200), np.ones(63), "same") > 0
        w = np.nan_to_num(np.nanmean(G, axis=1))
    idx = np.flatnonzero(spin & ok)
    fit, test = idx[: len(idx) // 2], idx[len(idx) // 2:]
    E = np.zeros_like(G)
    for j in range(8):
        others = np.delete(G, j, axis=1).mean(axis=1)
        X = np.column_stack([G[:, j], np.ones(len(G))])
        B = np.linalg.lstsq(X[fit], others[fit], rcond=None)[0]
        E[:, j] = X @ B - others
    E = np.nan_to_num(E)
    alpha = np.gradient(w, 1 / fs, axis=0)
    jerk = np.gradient(alpha, 1 / fs, axis=0)
    pos = np.flatnonzero(~np.isfinite(G).all(axis=(1, 2)))
    k = np.searchsorted(pos, np.arange(len(t)))
    dist = np.minimum(np.abs(np.arange(len(t)) - pos[np.clip(k - 1, 0, len(pos) - 1)]),
                      np.abs(pos[np.clip(k, 0, len(pos) - 1)] - np.arange(len(t)))) if len(pos) else np.full(len(t), 10**6)
    e2 = (E**2).mean(axis=(1, 2))
    out = {"residual_rms_deg_s": float(D(np.sqrt(e2[test].mean())))}
    print(f"run {run}: {len(idx) / fs:.0f} s of fast rotation, residual after a full affine relative calibration "
          f"{out['residual_rms_deg_s']:.2f} deg/s rms (held-out half)")
    for lo, hi in ((1, 2), (3, 8), (9, 20), (21, 10**7)):
        s = test[(dist[test] >= lo) & (dist[test] <= hi)]
        if len(s):
            print(f"  {lo}-{hi} samples from a clipped sample: {D(np.sqrt(e2[s].mean())):.2f} deg/s rms, "
                  f"{e2[s].sum() / e2[test].sum():.0%} of the residual")
    sel = test[dist[test] > 2]
    an = np.linalg.norm(alpha, axis=1)
    q = np.quantile(an[sel], [0, 0.25, 0.5, 0.75, 1])
    print("  by |angular acceleration| quartile: " + ", ".join(
        f"{D(np.sqrt(e2[s].mean())):.1f}" for s in (sel[(an[sel] >= a) & (an[sel] <= b)] for a, b in zip(q, q[1:])))
        + " deg/s rms (a time offset would grow in proportion)")
    print(f"  per triad: {np.round(D(np.sqrt((E[sel] ** 2).mean(axis=(0, 2)))), 1).tolist()} deg/s rms")
    C = np.corrcoef(E[sel][:, :, 2].T)
    print(f"  correlation between triads (z): mean {C[~np.eye(8, dtype=bool)].mean():+.3f} "
          f"(independent errors: {-1 / 7:+.3f})")
    fit2 = fit[dist[fit] > 2]

    def share(build) -> float:
        tot = res = 0.0
        for j in range(8):
            R = build(j)
            Bj = np.linalg.lstsq(R[fit2], E[fit2, j], rcond=None)[0]
            tot += float((E[sel, j] ** 2).sum())
            res += float(((E[sel, j] - R[sel] @ Bj) ** 2).sum())
        return 1 - res / tot

    def gj(j):
        return np.nan_to_num(G[:, j])

    cands = {
        "angular acceleration (time offset)": lambda j: alpha,
        "jerk": lambda j: jerk,
        "rate^2 and products (nonlinearity)": lambda j: np.column_stack(
            [gj(j) ** 2, gj(j)[:, [0]] * gj(j)[:, [1]], gj(j)[:, [1]] * gj(j)[:, [2]], gj(j)[:, [0]] * gj(j)[:, [2]]]),
        "rate^3 (nonlinearity)": lambda j: gj(j) ** 3,
        "own specific force (g-sensitivity)": lambda j: np.nan_to_num(A[:, j]),
        "FIR of own rates, +-2 samples (filter, delay)": lambda j: np.column_stack(
            [np.roll(gj(j), s, 0) for s in (-2, -1, 1, 2)]),
        "FIR of the array mean, +-2 samples": lambda j: np.column_stack([np.roll(w, s, 0) for s in (-2, -1, 0, 1, 2)]),
    }
    for name, build in cands.items():
        out[name] = share(build)
        print(f"  {name}: explains {out[name]:+.1%} of the residual (held out)")
    runs, s0 = [], None
    for i in range(len(t)):
        if spin[i] and ok[i]:
            s0 = i if s0 is None else s0
        elif s0 is not None:
            runs.append((s0, i))
            s0 = None
    Pe = Pw = 0.0
    n = 0
    ac = []
    for a, b in runs:
        if b - a < 64:
            continue
        fr, pe = welch(E[a:b].reshape(b - a, -1), fs=fs, nperseg=64, axis=0)
        _, pw = welch(w[a:b], fs=fs, nperseg=64, axis=0)
        Pe, Pw, n = Pe + pe.mean(axis=1) * (b - a), Pw + pw.mean(axis=1) * (b - a), n + b - a
        x = E[a:b].reshape(b - a, -1) - E[a:b].reshape(b - a, -1).mean(axis=0)
        ac.append((x[1:] * x[:-1]).sum(axis=0) / (x * x).sum(axis=0))
    if n:
        ratio = np.sqrt(Pe / Pw)
        print("  residual / rate amplitude spectrum: " + ", ".join(
            f"{fr[i]:.0f} Hz {ratio[i]:.3f}" for i in range(1, len(fr), 5)))
        out["lag1"] = float(np.median(np.concatenate(ac)))
        print(f"  lag-1 autocorrelation of the residual: {out['lag1']:.2f}")
    return out


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
