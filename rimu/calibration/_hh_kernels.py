"""Compiled kernels (numba) of the hand-held calibration (:mod:`rimu.calibration.handheld`): the one pass over
an instrument's samples (segment sums, peaks, the noise level's third differences), the sums of the motion windows and the integration of the motions. The numpy code of
handheld.py is the reference; these give its numbers to rounding (another summation order; tested in
tests/calibration/test_handheld_numba.py).

Imported only when numba is installed (``pip install rimu[fast]``) and the backend is not ``"numpy"``
(:mod:`rimu._backend`). Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError as exc:  # pragma: no cover - the caller checks availability first
    raise ImportError("the compiled hand-held kernels need numba: pip install rimu[fast]") from exc

__all__ = ["accel_triad_batch", "gauss_newton_model", "integrate_motions", "motion_rotations", "rotation_model",
           "segment_stats", "window_sums"]

#: IEEE arithmetic as numpy's (no exceptions, no fast-math)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def segment_stats(Y, starts, counts, ref, sums, hi, lo, d3):  # pragma: no cover - compiled
    """One pass over the samples Y (N, n) of every segment back to back (rows as stored): per segment j and
    column i of ``x = Y - ref``, the sum, largest and smallest value and the sum of the squared third differences
    inside the segment (``x_t - 3 x_t-1 + 3 x_t-2 - x_t-3``, t >= 3), into row j of sums, hi, lo, d3. Two
    interleaved partial sums (even and odd t), so that the additions do not wait on each other."""
    n = Y.shape[1]
    for j in range(starts.shape[0]):
        a = starts[j]
        k = counts[j]
        for i in range(n):
            r = ref[i]
            s0 = 0.0
            s1 = 0.0
            p0 = 0.0
            p1 = 0.0
            h = -np.inf
            lw = np.inf
            x3 = x2 = x1 = 0.0
            t = 0
            while t + 1 < k:
                xa = Y[a + t, i] - r
                xb = Y[a + t + 1, i] - r
                s0 += xa
                s1 += xb
                if xa > h:
                    h = xa
                if xa < lw:
                    lw = xa
                if xb > h:
                    h = xb
                if xb < lw:
                    lw = xb
                if t >= 3:
                    e = xa - 3.0 * x1 + 3.0 * x2 - x3
                    p0 += e * e
                if t >= 2:
                    e = xb - 3.0 * xa + 3.0 * x1 - x2
                    p1 += e * e
                x3 = x1
                x2 = xa
                x1 = xb
                t += 2
            if t < k:
                xa = Y[a + t, i] - r
                s0 += xa
                if xa > h:
                    h = xa
                if xa < lw:
                    lw = xa
                if t >= 3:
                    e = xa - 3.0 * x1 + 3.0 * x2 - x3
                    p0 += e * e
            sums[j, i] = s0 + s1
            hi[j, i] = h
            lo[j, i] = lw
            d3[j, i] = p0 + p1


@_jit
def integrate_motions(YD, DM, Gm, c):  # pragma: no cover - compiled
    """The motions' rotations and pre-integration sums, sample by sample (handheld.fit_gyro's ``integrate``).

    YD (n, M, L): dt-weighted raw samples of each motion (zero-padded); DM (M, L): their dt; the rate of sample t
    is ``omega_t dt = G (YD_t - c DM_t)``, its rotation the exact quaternion ``exp``. Returns the total
    quaternion of every motion (M, 4) (not normalised) and ``S[m, k] = sum_t w_kt C_mid,t`` (M, n + 1, 3, 3), the
    weights ``w = (YD_i - c_i DM, DM)`` and ``C_mid,t`` the attitude at the middle of sample t relative to the
    start, ``(P_t-1 q_t + P_t-1) / sqrt(2 (1 + q_t,w))`` as the numpy reference forms it."""
    n, M, L = YD.shape
    tot = np.empty((M, 4))
    S = np.zeros((M, n + 1, 3, 3))
    wk = np.empty(n + 1)
    for m in range(M):
        ew, ex, ey, ez = 1.0, 0.0, 0.0, 0.0
        for t in range(L):
            dm = DM[m, t]
            ox = 0.0
            oy = 0.0
            oz = 0.0
            for i in range(n):
                yi = YD[i, m, t] - c[i] * dm
                wk[i] = yi
                ox += Gm[0, i] * yi
                oy += Gm[1, i] * yi
                oz += Gm[2, i] * yi
            wk[n] = dm
            th = np.sqrt(ox * ox + oy * oy + oz * oz)
            half = 0.5 * th
            kk = np.sin(half) / th if th > 1e-12 else 0.5 - th * th / 48.0
            qw, qx, qy, qz = np.cos(half), ox * kk, oy * kk, oz * kk
            # P_t-1 q_t
            pw = ew * qw - ex * qx - ey * qy - ez * qz
            px = ew * qx + ex * qw + ey * qz - ez * qy
            py = ew * qy - ex * qz + ey * qw + ez * qx
            pz = ew * qz + ex * qy - ey * qx + ez * qw
            den = np.sqrt(max(2.0 * (1.0 + qw), 1e-300))
            w = (pw + ew) / den
            x = (px + ex) / den
            y = (py + ey) / den
            z = (pz + ez) / den
            c00 = 1 - 2 * (y * y + z * z)
            c01 = 2 * (x * y - w * z)
            c02 = 2 * (x * z + w * y)
            c10 = 2 * (x * y + w * z)
            c11 = 1 - 2 * (x * x + z * z)
            c12 = 2 * (y * z - w * x)
            c20 = 2 * (x * z - w * y)
            c21 = 2 * (y * z + w * x)
            c22 = 1 - 2 * (x * x + y * y)
            for k in range(n + 1):
                v = wk[k]
                if v != 0.0:
                    S[m, k, 0, 0] += v * c00
                    S[m, k, 0, 1] += v * c01
                    S[m, k, 0, 2] += v * c02
                    S[m, k, 1, 0] += v * c10
                    S[m, k, 1, 1] += v * c11
                    S[m, k, 1, 2] += v * c12
                    S[m, k, 2, 0] += v * c20
                    S[m, k, 2, 1] += v * c21
                    S[m, k, 2, 2] += v * c22
            ew, ex, ey, ez = pw, px, py, pz
        tot[m, 0] = ew
        tot[m, 1] = ex
        tot[m, 2] = ey
        tot[m, 3] = ez
    return tot, S


@_jit
def window_sums(Y, ref, dt_all, c0s, c1s, nas, nbs, SA_w, SB_w, Tw, SA_y, SB_y, YD, Yint):  # pragma: no cover
    """handheld.fit_gyro's ``sums()`` from the samples Y (N, n) back to back (``x = Y - ref``), every window in
    one call.

    Window m spans columns c0 .. c1-1 (at least two): pose k (na samples), the motion, pose k+1 (nb samples);
    ``dt_t = t_t+1 - t_t`` (``dt_all``), the last sample's the one before it. Pose weights ``wa_t = dt_t (t + 1)
    / na`` and ``wb_j = dt_j (nb - 1 - j) / nb`` (j from the start of pose k+1); SA_y, SB_y the weighted pose sums,
    YD (n, M, L) the dt-weighted motion samples, Yint the window integral (``ref`` added back through SA_w, SB_w,
    dt and Tw)."""
    n = Y.shape[1]
    for m in range(c0s.shape[0]):
        c0 = c0s[m]
        N = c1s[m] - c0
        na = nas[m]
        nb = nbs[m]
        nm = N - na - nb
        for i in range(n):
            r = ref[i]
            # three loops without branches or divisions (the pose weights' 1 / na and 1 / nb applied once)
            sa = 0.0
            si = 0.0
            sa2 = 0.0
            si2 = 0.0
            for t in range(0, na - 1, 2):  # two partial sums each (t even, t odd): the additions overlap
                xd = (Y[c0 + t, i] - r) * dt_all[c0 + t]
                xd2 = (Y[c0 + t + 1, i] - r) * dt_all[c0 + t + 1]
                si += xd
                sa += xd * (t + 1.0)
                si2 += xd2
                sa2 += xd2 * (t + 2.0)
            if na % 2:
                t = na - 1
                xd = (Y[c0 + t, i] - r) * dt_all[c0 + t]
                si += xd
                sa += xd * (t + 1.0)
            si += si2
            sa += sa2
            sm = 0.0
            for t in range(na, na + nm):
                d = dt_all[c0 + t]
                xd = (Y[c0 + t, i] - r) * d
                sm += xd
                YD[i, m, t - na] = xd + r * d
            sb = 0.0
            sj = 0.0
            sb2 = 0.0
            sj2 = 0.0
            t = na + nm
            while t + 1 < N - 1:
                xd = (Y[c0 + t, i] - r) * dt_all[c0 + t]
                xd2 = (Y[c0 + t + 1, i] - r) * dt_all[c0 + t + 1]
                sj += xd
                sb += xd * (N - 1.0 - t)
                sj2 += xd2
                sb2 += xd2 * (N - 2.0 - t)
                t += 2
            if t < N - 1:
                xd = (Y[c0 + t, i] - r) * dt_all[c0 + t]
                sj += xd
                sb += xd * (N - 1.0 - t)
            sj += sj2
            sb += sb2
            xd = (Y[c0 + N - 1, i] - r) * dt_all[c0 + N - 2]  # the last sample: weight 0 in the pose sum
            sj += xd
            SA_y[m, i] = sa / na + r * SA_w[m]
            SB_y[m, i] = sb / nb + r * SB_w[m]
            Yint[m, i] = (si + sm + sj) + r * Tw[m]


@_jit
def _rod(x, y, z, series, out):  # pragma: no cover - compiled
    """handheld._rodrigues of one rotation vector into out (3, 3); ``series``: every angle of the batch is tiny."""
    th2 = x * x + y * y + z * z
    if series:
        a = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
        b = 0.5 - th2 / 24.0 + th2 * th2 / 720.0
    else:
        th = np.sqrt(th2)
        if th > 1e-4:
            a = np.sin(th) / th
            b = (1.0 - np.cos(th)) / (th * th)
        else:
            a = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
            b = 0.5 - th2 / 24.0 + th2 * th2 / 720.0
    bx, by = b * x, b * y
    ax, ay, az = a * x, a * y, a * z
    out[0, 0] = 1.0 - b * (y * y + z * z)
    out[1, 1] = 1.0 - b * (x * x + z * z)
    out[2, 2] = 1.0 - b * (x * x + y * y)
    out[0, 1] = bx * y - az
    out[1, 0] = bx * y + az
    out[0, 2] = bx * z + ay
    out[2, 0] = bx * z - ay
    out[1, 2] = by * z - ax
    out[2, 1] = by * z + ax


@_jit
def rotation_model(Gm, c, Rl, DG, Qc, G_l, c_l, SA_y, SB_y, SA_w, SB_w, u_a, u_b, T):  # pragma: no cover
    """handheld.fit_gyro's ``rot_parts`` (the rotation residuals (M, 2) and their Jacobian (M, 2, 4n) with the
    motions from a pre-integration), motion by motion; the same formulas, named there."""
    n = c.shape[0]
    M = Rl.shape[0]
    p = 4 * n
    v = np.zeros(3)
    for a in range(3):
        for i in range(n):
            v[a] += Gm[a, i] * (c[i] - c_l[i])
    dGv = np.empty(3 * n)
    for a in range(3):
        for i in range(n):
            dGv[a * n + i] = Gm[a, i] - G_l[a, i]
    x = np.zeros((M, 3))
    psi = np.zeros((M, 3))
    phi = np.zeros((M, 3))
    big = 0.0
    xmax = 0.0
    for m in range(M):
        for r in range(3):
            s = 0.0
            for k in range(3 * n):
                s += DG[m, r, k] * dGv[k]
            for b in range(3):
                s -= Qc[m, r, b] * v[b]
            x[m, r] = s
            xmax = max(xmax, abs(s))
            sa = 0.0
            sb = 0.0
            for i in range(n):
                sa -= Gm[r, i] * (SA_y[m, i] - c[i] * SA_w[m])
                sb += Gm[r, i] * (SB_y[m, i] - c[i] * SB_w[m])
            psi[m, r] = sa
            phi[m, r] = sb
        for q in (x[m], psi[m], phi[m]):
            big = max(big, q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    series = big < 1e-8
    rr = np.empty((M, 2))
    Jr = np.empty((M, 2, p))
    Rx = np.empty((3, 3))
    Eb = np.empty((3, 3))
    Ca = np.empty((3, 3))
    Dth = np.empty((3, p))
    Dth2 = np.empty((3, p))
    Dpsi = np.empty((3, p))
    Dbeta = np.empty((3, p))
    Cb = np.empty((3, 3))
    Rm = np.empty((3, 3))
    dpred = np.empty((3, p))
    cv = np.empty((3, p))
    QG = np.empty((3, n))
    vv = np.empty(3)
    pred = np.empty(3)
    for m in range(M):
        # d x / d theta (model_x)
        for r in range(3):
            for i in range(n):
                s = 0.0
                for b in range(3):
                    s += Qc[m, r, b] * Gm[b, i]
                QG[r, i] = s
        for r in range(3):
            for i in range(n):
                for j in range(3):
                    s = 0.0
                    for a in range(3):
                        xa = 0.0
                        for k in range(n):
                            xa += DG[m, r, a * n + k] * Gm[j, k]
                        s += Gm[a, i] * xa
                    Dth[r, 3 * i + j] = -s + QG[r, i] * v[j]
                Dth[r, 3 * n + i] = -QG[r, i]
        _rod(x[m, 0], x[m, 1], x[m, 2], series, Rx)
        _rod(phi[m, 0], phi[m, 1], phi[m, 2], series, Eb)
        _rod(psi[m, 0], psi[m, 1], psi[m, 2], series, Ca)
        if xmax > 1e-3:  # Dth = Jr(x) Dth (handheld._right_jacobian)
            x0, x1, x2 = x[m, 0], x[m, 1], x[m, 2]
            t2 = x0 * x0 + x1 * x1 + x2 * x2
            t = np.sqrt(t2)
            if t > 1e-4:
                ca = (1.0 - np.cos(t)) / t**2
                cb = (t - np.sin(t)) / t**3
            else:
                ca = 0.5 - t2 / 24.0
                cb = 1.0 / 6.0 - t2 / 120.0
            Jx = np.empty((3, 3))
            xs = (x0, x1, x2)
            for r in range(3):
                for k in range(3):
                    Jx[r, k] = cb * (xs[r] * xs[k])
            d = 1.0 - cb * t2
            Jx[0, 0] += d
            Jx[1, 1] += d
            Jx[2, 2] += d
            Jx[0, 1] += ca * x2
            Jx[1, 0] -= ca * x2
            Jx[0, 2] -= ca * x1
            Jx[2, 0] += ca * x1
            Jx[1, 2] += ca * x0
            Jx[2, 1] -= ca * x0
            for r in range(3):
                for k in range(p):
                    Dth2[r, k] = Jx[r, 0] * Dth[0, k] + Jx[r, 1] * Dth[1, k] + Jx[r, 2] * Dth[2, k]
            Dth[:, :] = Dth2
        for r in range(3):
            for k in range(3):
                Rm[r, k] = Rl[m, r, 0] * Rx[0, k] + Rl[m, r, 1] * Rx[1, k] + Rl[m, r, 2] * Rx[2, k]
        for r in range(3):
            for k in range(3):
                Cb[r, k] = Rm[r, 0] * Eb[0, k] + Rm[r, 1] * Eb[1, k] + Rm[r, 2] * Eb[2, k]
        for r in range(3):
            vv[r] = Ca[r, 0] * u_a[m, 0] + Ca[r, 1] * u_a[m, 1] + Ca[r, 2] * u_a[m, 2]
        for r in range(3):
            pred[r] = Cb[0, r] * vv[0] + Cb[1, r] * vv[1] + Cb[2, r] * vv[2]
        for a in range(3):
            for i in range(n):
                for j in range(3):
                    Dpsi[a, 3 * i + j] = -Gm[a, i] * psi[m, j]
                    Dbeta[a, 3 * i + j] = -Gm[a, i] * phi[m, j]
                Dpsi[a, 3 * n + i] = SA_w[m] * Gm[a, i]
                Dbeta[a, 3 * n + i] = -SB_w[m] * Gm[a, i]
        for r in range(3):  # Dbeta = Eb^T Dth + Dphi
            for k in range(p):
                Dbeta[r, k] += Eb[0, r] * Dth[0, k] + Eb[1, r] * Dth[1, k] + Eb[2, r] * Dth[2, k]
        for k in range(p):  # v x Dpsi, pred x Dbeta
            cv[0, k] = vv[1] * Dpsi[2, k] - vv[2] * Dpsi[1, k]
            cv[1, k] = vv[2] * Dpsi[0, k] - vv[0] * Dpsi[2, k]
            cv[2, k] = vv[0] * Dpsi[1, k] - vv[1] * Dpsi[0, k]
            dpred[0, k] = pred[1] * Dbeta[2, k] - pred[2] * Dbeta[1, k]
            dpred[1, k] = pred[2] * Dbeta[0, k] - pred[0] * Dbeta[2, k]
            dpred[2, k] = pred[0] * Dbeta[1, k] - pred[1] * Dbeta[0, k]
        for r in range(3):
            for k in range(p):
                dpred[r, k] -= Cb[0, r] * cv[0, k] + Cb[1, r] * cv[1, k] + Cb[2, r] * cv[2, k]
        for e in range(2):
            rr[m, e] = (T[m, e, 0] * (pred[0] - u_b[m, 0]) + T[m, e, 1] * (pred[1] - u_b[m, 1])
                        + T[m, e, 2] * (pred[2] - u_b[m, 2]))
            for k in range(p):
                Jr[m, e, k] = T[m, e, 0] * dpred[0, k] + T[m, e, 1] * dpred[1, k] + T[m, e, 2] * dpred[2, k]
    return rr, Jr


@_jit
def accel_triad_batch(theta, free_pos, ybar, sd, gravity, keep, typ):  # pragma: no cover - compiled
    """handheld._accel_triad_batch (the norm residuals of a triad's accelerometer fit and their Jacobian, for B
    parameter vectors at once; the formulas of handheld._accel_problem), pose by pose, and the Gauss-Newton
    normal equations of each: residuals ``r`` (B, K) times ``keep`` (B, K), the Jacobians scaled by ``typ``
    ``Js`` (B, K, p), ``A = Js^T Js`` (B, p, p) and ``g = Js^T r`` (B, p). ``free_pos`` (9,): the parameter
    index of each entry ``W[i, a]`` (row-major), -1 where it is fixed at zero; the biases follow the free
    entries."""
    B, p = theta.shape
    K = ybar.shape[0]
    nfree = p - 3
    r = np.zeros((B, K))
    Js = np.zeros((B, K, p))
    A = np.zeros((B, p, p))
    g = np.zeros((B, p))
    W = np.zeros((3, 3))
    info = np.empty((3, 3))
    S = np.empty((3, 3))
    rhs = np.empty(3)
    f = np.empty(3)
    u = np.empty(3)
    Su = np.empty(3)
    res = np.empty(3)
    rho = np.empty(3)
    w = np.empty(3)
    SW = np.empty((3, 3))
    df = np.empty((3, p))
    dnf = np.empty(p)
    ds2 = np.empty(p)
    SuW = np.empty(3)
    for b in range(B):
        for q in range(9):
            W[q // 3, q % 3] = theta[b, free_pos[q]] if free_pos[q] >= 0 else 0.0
        for k in range(K):
            if keep[b, k] == 0.0:
                continue
            for i in range(3):
                w[i] = 1.0 / (sd[k, i] * sd[k, i])
                res[i] = ybar[k, i] - theta[b, nfree + i]
            for a in range(3):
                s = 0.0
                for i in range(3):
                    s += w[i] * W[i, a] * res[i]
                rhs[a] = s
                for c in range(3):
                    s = 0.0
                    for i in range(3):
                        s += w[i] * W[i, a] * W[i, c]
                    info[a, c] = s
            # inverse of the symmetric 3 x 3 information (cofactors)
            c00 = info[1, 1] * info[2, 2] - info[1, 2] * info[2, 1]
            c01 = info[1, 2] * info[2, 0] - info[1, 0] * info[2, 2]
            c02 = info[1, 0] * info[2, 1] - info[1, 1] * info[2, 0]
            det = info[0, 0] * c00 + info[0, 1] * c01 + info[0, 2] * c02
            S[0, 0] = c00 / det
            S[1, 0] = c01 / det
            S[2, 0] = c02 / det
            S[0, 1] = (info[0, 2] * info[2, 1] - info[0, 1] * info[2, 2]) / det
            S[1, 1] = (info[0, 0] * info[2, 2] - info[0, 2] * info[2, 0]) / det
            S[2, 1] = (info[0, 1] * info[2, 0] - info[0, 0] * info[2, 1]) / det
            S[0, 2] = (info[0, 1] * info[1, 2] - info[0, 2] * info[1, 1]) / det
            S[1, 2] = (info[0, 2] * info[1, 0] - info[0, 0] * info[1, 2]) / det
            S[2, 2] = (info[0, 0] * info[1, 1] - info[0, 1] * info[1, 0]) / det
            for a in range(3):
                f[a] = S[a, 0] * rhs[0] + S[a, 1] * rhs[1] + S[a, 2] * rhs[2]
            for i in range(3):
                rho[i] = res[i] - (W[i, 0] * f[0] + W[i, 1] * f[1] + W[i, 2] * f[2])
            nf = np.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            for a in range(3):
                u[a] = f[a] / nf
            for a in range(3):
                Su[a] = S[a, 0] * u[0] + S[a, 1] * u[1] + S[a, 2] * u[2]
            den = np.sqrt(u[0] * Su[0] + u[1] * Su[1] + u[2] * Su[2])
            d = nf - gravity
            rk = d / den
            r[b, k] = rk * keep[b, k]
            for a in range(3):
                for i in range(3):
                    SW[a, i] = (S[a, 0] * W[i, 0] + S[a, 1] * W[i, 1] + S[a, 2] * W[i, 2]) * w[i]
            for o in range(3):
                for q in range(9):
                    if free_pos[q] >= 0:
                        i = q // 3
                        a = q % 3
                        df[o, free_pos[q]] = S[o, a] * w[i] * rho[i] - SW[o, i] * f[a]
                for i in range(3):
                    df[o, nfree + i] = -SW[o, i]
            for i in range(3):
                SuW[i] = Su[0] * W[i, 0] + Su[1] * W[i, 1] + Su[2] * W[i, 2]
            for q in range(p):
                dnf[q] = u[0] * df[0, q] + u[1] * df[1, q] + u[2] * df[2, q]
                s = 0.0
                for o in range(3):
                    s += Su[o] * (df[o, q] - u[o] * dnf[q]) / nf
                ds2[q] = 2.0 * s
            for q in range(9):
                if free_pos[q] >= 0:
                    i = q // 3
                    a = q % 3
                    ds2[free_pos[q]] -= 2.0 * w[i] * Su[a] * SuW[i]
            for q in range(p):
                Js[b, k, q] = (dnf[q] / den - 0.5 * (d / den**3) * ds2[q]) * typ[q] * keep[b, k]
        for q in range(p):
            s = 0.0
            for k in range(K):
                s += Js[b, k, q] * r[b, k]
            g[b, q] = s
            for q2 in range(q, p):
                s = 0.0
                for k in range(K):
                    s += Js[b, k, q] * Js[b, k, q2]
                A[b, q, q2] = s
                A[b, q2, q] = s
    return r, Js, A, g


@_jit
def _model_x_max(theta, DG, Qc, G_l, c_l):  # pragma: no cover - compiled
    """handheld.fit_gyro's ``reach``: the largest |x| of ``model_x`` (a triad, G = W^-1) at theta."""
    Gm = np.linalg.inv(theta[:9].reshape(3, 3).copy())
    n = 3
    v = np.zeros(3)
    for a in range(3):
        for i in range(n):
            v[a] += Gm[a, i] * (theta[3 * n + i] - c_l[i])
    big = 0.0
    for m in range(DG.shape[0]):
        for r in range(3):
            s = 0.0
            for a in range(3):
                for i in range(n):
                    s += DG[m, r, a * n + i] * (Gm[a, i] - G_l[a, i])
            for b in range(3):
                s -= Qc[m, r, b] * v[b]
            big = max(big, abs(s))
    return big


@_jit
def _model_residual(phi, Bm, full, Rl, DG, Qc, G_l, c_l, SA_y, SB_y, SA_w, SB_w, u_a, u_b, T, Lws, ybar, sd, w_st,
                    J_st):  # pragma: no cover - compiled
    """handheld.fit_gyro's ``reduced(model_fun(pre))`` of a triad: the weighted residuals and their Jacobian
    with respect to phi (theta = Bm phi)."""
    theta = phi.copy() if full else Bm @ phi
    Gm = np.linalg.inv(theta[:9].reshape(3, 3).copy())
    c = theta[9:].copy()
    rr, Jr = rotation_model(Gm, c, Rl, DG, Qc, G_l, c_l, SA_y, SB_y, SA_w, SB_w, u_a, u_b, T)
    M = rr.shape[0]
    K = ybar.shape[0]
    r = np.empty(2 * M + 3 * K)
    J = np.empty((2 * M + 3 * K, 12))
    rf = rr.reshape(2 * M)
    Jf = Jr.reshape(2 * M, 12)
    r[:2 * M] = Lws @ rf
    J[:2 * M] = Lws @ Jf
    for k in range(K):
        for i in range(3):
            r[2 * M + 3 * k + i] = (ybar[k, i] - c[i]) / sd[k, i] * w_st
    J[2 * M:] = J_st
    if full:
        return r, J
    return r, J @ Bm


@_jit
def _huber(r, robust, f_scale):  # pragma: no cover - compiled
    """handheld._huber_cost and handheld._huber_weights."""
    w = np.ones(r.shape[0])
    if not robust:
        return 0.5 * np.sum(r * r), w
    cost = 0.0
    for j in range(r.shape[0]):
        z = (r[j] / f_scale) ** 2
        cost += z if z <= 1.0 else 2.0 * np.sqrt(z) - 1.0
        a = abs(r[j])
        if a > f_scale:
            w[j] = f_scale / max(a, 1e-300)
    return 0.5 * f_scale**2 * cost, w


@_jit
def gauss_newton_model(phi, typ, robust, xtol, max_iter, radius, Bm, full, Rl, DG, Qc, G_l, c_l, SA_y, SB_y, SA_w,
                       SB_w, u_a, u_b, T, Lws, ybar, sd, w_st, J_st):  # pragma: no cover - compiled
    """handheld._gauss_newton (f_scale 3) on handheld.fit_gyro's model of a pre-integration, for a triad, with the
    reach of the model (``_model_x_max``) against ``radius``: the same steps, compiled. Returns (phi, edge)."""
    f_scale = 3.0
    args = (Bm, full, Rl, DG, Qc, G_l, c_l, SA_y, SB_y, SA_w, SB_w, u_a, u_b, T, Lws, ybar, sd, w_st, J_st)
    theta = phi.copy()
    r, J = _model_residual(theta, *args)
    cost, w = _huber(r, robust, f_scale)
    lam = 0.0
    near = False
    p = theta.shape[0]
    for _ in range(max_iter):
        cost_w = _huber(r, robust, f_scale)
        w = cost_w[1]
        Js = J * typ
        hw = w.copy()
        if robust and near:
            for j in range(w.shape[0]):
                hw[j] = 1e-6 if w[j] < 1.0 else 1.0
        A = Js.T @ (Js * hw.reshape(-1, 1))
        g = Js.T @ (w * r)
        dA = np.diag(A).copy()
        here = _model_x_max(theta if full else Bm @ theta, DG, Qc, G_l, c_l)
        while True:
            Ad = A.copy()
            for j in range(p):
                Ad[j, j] += lam * dA[j]
            try:
                step = -np.linalg.solve(Ad, g)
            except Exception:  # singular: the least-squares step, as handheld._gauss_newton
                step = -np.linalg.lstsq(Ad, g)[0]
            small = np.max(np.abs(step)) <= xtol
            th_new = theta + step * typ
            edge = False
            far = _model_x_max(th_new if full else Bm @ th_new, DG, Qc, G_l, c_l)
            if far > radius:
                th_new = theta + step * typ * max(radius - here, 0.0) / max(far - here, 1e-300)
                edge = True
            r_new, J_new = _model_residual(th_new, *args)
            c_new = _huber(r_new, robust, f_scale)[0]
            if c_new <= cost * (1 + 1e-9) or small:
                lam = lam / 10.0 if lam > 1e-6 else 0.0
                break
            lam = max(lam * 10.0, 1e-4)
            if lam > 1e8:
                return theta, False
        theta, r, J, cost = th_new, r_new, J_new, c_new
        near = lam == 0.0 and np.max(np.abs(step)) < 1e-3
        if small or edge:
            return theta, edge
    return theta, False


@_jit
def motion_rotations(YD, DM, Gm, c):  # pragma: no cover - compiled
    """The total quaternion of every motion (M, 4) (not normalised), sample by sample as ``integrate_motions``
    forms it, without the pre-integration sums (handheld.fit_gyro's ``integrate`` without ``jac``)."""
    n, M, L = YD.shape
    tot = np.empty((M, 4))
    for m in range(M):
        ew, ex, ey, ez = 1.0, 0.0, 0.0, 0.0
        for t in range(L):
            dm = DM[m, t]
            ox = 0.0
            oy = 0.0
            oz = 0.0
            for i in range(n):
                yi = YD[i, m, t] - c[i] * dm
                ox += Gm[0, i] * yi
                oy += Gm[1, i] * yi
                oz += Gm[2, i] * yi
            th = np.sqrt(ox * ox + oy * oy + oz * oz)
            half = 0.5 * th
            kk = np.sin(half) / th if th > 1e-12 else 0.5 - th * th / 48.0
            qw, qx, qy, qz = np.cos(half), ox * kk, oy * kk, oz * kk
            pw = ew * qw - ex * qx - ey * qy - ez * qz
            px = ew * qx + ex * qw + ey * qz - ez * qy
            py = ew * qy - ex * qz + ey * qw + ez * qx
            pz = ew * qz + ex * qy - ey * qx + ez * qw
            ew, ex, ey, ez = pw, px, py, pz
        tot[m, 0] = ew
        tot[m, 1] = ex
        tot[m, 2] = ey
        tot[m, 3] = ez
    return tot
