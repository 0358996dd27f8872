"""Compiled kernel (numba) of LeastSquares' base model (:meth:`rimu.calibration.estimate.LeastSquares._base_fit`):
every sensor's coefficients, residual sum of squares, physical values and their covariance from its instrument's
normal equations, in one call instead of some sixty small numpy operations. The numpy code of estimate.py is the
reference; this gives its numbers to rounding (another summation order; tested to 1e-10 in
tests/calibration/test_base_fast_path.py).

Used where numba is loaded in the process already and the backend allows it, or where ``"numba"`` is asked for by
name (:func:`rimu._backend.resolve_loaded`), so that no calibration pays for importing numba unasked. Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError as exc:  # pragma: no cover - the caller checks availability first
    raise ImportError("the compiled least-squares kernel needs numba: pip install rimu[fast]") from exc

__all__ = ["base_solve", "base_statistics"]

#: IEEE arithmetic as numpy's (no exceptions, no reassociation)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def base_solve(Ginv, G, H, q, s2, which, EC, C, B, theta, tcov, bcov, rss, mis):  # pragma: no cover - compiled
    """For every sensor i (column of ``H`` (4, p), instrument ``which[i]`` with ``G``/``Ginv`` (K, 4, 4)): the raw
    coefficients ``B[i] = G^-1 h`` (w_x, w_y, w_z, c), the residual sum of squares ``q - 2 b.h + b.G.b`` (at least
    0), the physical values (Cho & Park 2005, Eq. 10: ``SF = 1/|w|``, misalignment ``E C w/|w|`` with
    ``EC[i] = E_i C_i``, bias ``c SF``) and their covariance ``J (s2 G^-1) J^T`` with J the Jacobian of that map,
    and ``bcov[i] = s2 G^-1``, and the unit misalignment row ``mis[i] = C_i w / |w|`` (``C[i]``: the sensor's sub-unit
    rotation). Returns False where a sensor's ``w`` is zero (nothing written past it)."""
    p = H.shape[1]
    Jm = np.zeros((4, 4))
    for i in range(p):
        k = which[i]
        b0 = 0.0
        b1 = 0.0
        b2 = 0.0
        b3 = 0.0
        for r in range(4):
            h = H[r, i]
            b0 += Ginv[k, 0, r] * h
            b1 += Ginv[k, 1, r] * h
            b2 += Ginv[k, 2, r] * h
            b3 += Ginv[k, 3, r] * h
        b = (b0, b1, b2, b3)
        bh = 0.0
        bgb = 0.0
        for r in range(4):
            bh += b[r] * H[r, i]
            g = 0.0
            for c in range(4):
                g += G[k, r, c] * b[c]
            bgb += b[r] * g
        rs = q[i] - 2.0 * bh + bgb
        rss[i] = rs if rs > 0.0 else 0.0
        for r in range(4):
            B[i, r] = b[r]
        nw = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        if not nw > 0.0:
            return False
        sf = 1.0 / nw
        u0 = b0 / nw
        u1 = b1 / nw
        u2 = b2 / nw
        u = (u0, u1, u2)
        sf3 = sf**3
        d0 = -b0 * sf3
        d1 = -b1 * sf3
        d2 = -b2 * sf3
        theta[i, 0] = sf
        for a in range(2):
            theta[i, 1 + a] = EC[i, a, 0] * u0 + EC[i, a, 1] * u1 + EC[i, a, 2] * u2
        theta[i, 3] = b3 * sf
        for r in range(3):
            mis[i, r] = C[i, r, 0] * u0 + C[i, r, 1] * u1 + C[i, r, 2] * u2
        Jm[:, :] = 0.0
        Jm[0, 0] = d0
        Jm[0, 1] = d1
        Jm[0, 2] = d2
        for a in range(2):
            for c in range(3):
                acc = 0.0
                for m in range(3):
                    e = (1.0 if m == c else 0.0) - u[m] * u[c]
                    acc += EC[i, a, m] * (e * sf)
                Jm[1 + a, c] = acc
        Jm[3, 3] = sf
        Jm[3, 0] = b3 * d0
        Jm[3, 1] = b3 * d1
        Jm[3, 2] = b3 * d2
        s = s2[i]
        for r in range(4):
            for c in range(4):
                bcov[i, r, c] = s * Ginv[k, r, c]
        for r in range(4):
            for c in range(4):
                acc = 0.0
                for m in range(4):
                    jg = 0.0
                    for n in range(4):
                        jg += Jm[r, n] * Ginv[k, n, m]
                    acc += jg * Jm[c, m]
                tcov[i, r, c] = acc * s
    return True


@_jit
def base_statistics(M0, M1, Z, Nz, est, G, H, q, sig, Ginv, tr):  # pragma: no cover - compiled
    """The normal equations and noise level of the base model for one or two instruments k at once (the numpy code
    of :func:`rimu.calibration.estimate._base_statistics_numpy` and :func:`~rimu.calibration.estimate._noise_sigma_of`
    is the reference). ``M0``, ``M1`` (S, 3, n): every segment's column sums, sums of squares and first-difference
    sums of instrument 0 and 1 (:meth:`rimu.session.SessionStatistics.moments`; one instrument: ``M1`` is not read).
    ``Z`` (R, 9), one row per segment a fit reads, in order: the design row ``x`` (4), its weight, its row j of ``M``,
    the divisor of its totals, its kind (0: a constant input, ``G += w x x^T``, ``H += x t^T``, ``q += M[j, 1]``
    with ``t = M[j, 0]``; 1: an angle row, the same with ``t = M[j, 0] / div`` and ``q += t^2``; 2: the sums of
    squares alone, ``q += M[j, 1]``) and its instrument k. ``Nz`` (m, 3): the noise level's rows j of ``M``, their
    degrees of freedom and instrument; where ``est[k]``, ``sig`` (the instrument's columns) becomes
    ``sqrt(sum M[j, 2] / sum dof / 2)`` (a zero replaced by the largest, or 1). ``G`` (K, 4, 4) and ``H`` (4, p)
    hold the segments' terms added before (turning segments), ``q``, ``sig`` (p,) the sensors' columns of every
    instrument in turn. Then ``Ginv[k] = G[k]^-1`` (LAPACK's LU, as numpy's; raises numpy's LinAlgError where a G is
    exactly singular) and ``tr[k] = sum_i G_ii (G^-1)_ii`` (the identifiability bound of
    :meth:`rimu.calibration.estimate.LeastSquares._base_check`)."""
    K = est.shape[0]
    a = 0
    for k in range(K):
        M = M0 if k == 0 else M1
        n = M.shape[2]
        for j in range(n):
            q[a + j] = 0.0
        for r in range(Z.shape[0]):
            if Z[r, 8] != k:
                continue
            kind = Z[r, 7]
            m = int(Z[r, 5])
            if kind == 2.0:
                for j in range(n):
                    q[a + j] += M[m, 1, j]
                continue
            w = Z[r, 4]
            for c in range(4):
                xc = Z[r, c] * w
                for d in range(4):
                    G[k, c, d] += xc * Z[r, d]
            div = Z[r, 6]
            for j in range(n):
                t = M[m, 0, j] / div
                for c in range(4):
                    H[c, a + j] += Z[r, c] * t
                if kind == 1.0:
                    q[a + j] += t * t
                else:
                    q[a + j] += M[m, 1, j]
        if est[k]:
            cnt = 0.0
            for j in range(n):
                sig[a + j] = 0.0
            for r in range(Nz.shape[0]):
                if Nz[r, 2] == k and Nz[r, 1] > 0.0:
                    cnt += Nz[r, 1]
                    m = int(Nz[r, 0])
                    for j in range(n):
                        sig[a + j] += M[m, 2, j]
            top = 0.0
            for j in range(n):
                s = math.sqrt(sig[a + j] / cnt / 2.0)
                sig[a + j] = s
                if s > top:
                    top = s
            for j in range(n):
                if not sig[a + j] > 0.0:
                    sig[a + j] = top if top > 0.0 else 1.0
        a += n
    for k in range(K):
        Gi = np.linalg.inv(G[k])
        t = 0.0
        for i in range(4):
            t += G[k, i, i] * Gi[i, i]
            for j in range(4):
                Ginv[k, i, j] = Gi[i, j]
        tr[k] = t
