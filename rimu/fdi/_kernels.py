"""Compiled kernels of the FDI block paths (numba), the optional ``fast`` backend (``pip install rimu[fast]``,
:mod:`rimu.fusion.backend`).

:func:`cusum_block` runs :meth:`rimu.fdi.cusum.CusumBank.block` sample by sample in one call: the same
floating-point operations in the same order as the numpy path (running sums in blocks of 16 -- the earlier blocks'
sum plus a partial sum --, ``C+ = A - k delta^2 / 2``, ``C- = -A - k delta^2 / 2``, exact running minima, the
origin moved every ``rebase`` samples), so the two give the same bits; a restart after an alarm (``M = C``) costs
nothing more than any other sample, however many alarms come. :func:`kalman_block` runs the steady Kalman filter of
:class:`rimu.fdi.kalman.ParityKalman` and its test statistic in one pass, in the order of ``update()``. Compiled on
first use and cached on disk.
"""

from __future__ import annotations

from typing import Any

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - the numpy install: CusumBank calls here only with numba
    numba = None

__all__ = ["cusum_block", "kalman_block"]

#: IEEE arithmetic as numpy's (no fast-math, no contraction into fused multiply-adds: the same bits); without
#: numba the module still imports (doctest collection), its function is then plain (slow) Python
_jit = numba.njit(cache=True, nogil=True, error_model="numpy") if numba is not None else (lambda f: f)

#: index cast: an unsigned index needs no negative-index wraparound check (as in rimu.fusion._kernels)
_u = numba.uint64 if numba is not None else int


@_jit
def cusum_block(P: Any, W: Any, half: Any, inv: Any, idx: Any, isolable: bool, rebase: int, blk: int,
                restart: bool, out: Any, iso: Any) -> bool:  # pragma: no cover - compiled
    """The CUSUM bank over the rows of ``P`` (N, >= dof); ``W`` (dof, n_a) the LLR slopes, ``half`` (n_a,)
    ``delta^2 / 2``, ``inv`` (2 n_a,) the inverse thresholds [S+ of each active sensor, S- of each].

    Fills ``out`` (N,) with the largest statistic / threshold and ``iso`` (N,) with the sensor of that statistic
    (``idx`` (n_a,): the active sensors) where it exceeds 1 (an alarm) and ``isolable``, else -1; with
    ``restart`` every statistic restarts after an alarm.
    Returns False (outputs unspecified past that point) at the first non-finite running sum."""
    N = P.shape[0]
    dof, na = W.shape[0], W.shape[1]
    ns = 2 * na
    part = np.zeros(na)
    base = np.zeros(na)
    Acc = np.zeros(na)
    C = np.zeros(ns)
    M = np.zeros(ns)
    k = 0                                              # samples since the origin
    pos = 0                                            # k % blk
    b = 0                                              # k // blk
    for t in range(N):
        if k == rebase:                                # move the origin before the sample
            for i in range(ns):
                M[i] = M[i] - C[i]
            k = pos = b = 0
        if pos == 0:                                   # a new block: base = the earlier blocks' sum (cumsum)
            if b == 0:
                for j in range(na):
                    base[j] = 0.0
            elif b == 1:
                for j in range(na):
                    base[j] = part[j]
            else:
                for j in range(na):
                    base[j] = base[j] + part[j]
            for j in range(na):
                a = W[0, j] * P[t, 0]
                for i in range(1, dof):
                    a = a + W[_u(i), j] * P[t, _u(i)]
                part[j] = a
                Acc[j] = a + base[j]
        else:
            for j in range(na):
                a = W[0, j] * P[t, 0]
                for i in range(1, dof):
                    a = a + W[_u(i), j] * P[t, _u(i)]
                a = part[j] + a
                part[j] = a
                Acc[j] = a + base[j]
        k += 1
        pos += 1
        if pos == blk:
            pos = 0
            b += 1
        kf = float(k)
        best = -1.0
        kb = 0
        fin = 0.0                                      # NaN when a running sum is NaN or inf (inf * 0), else 0
        for j in range(na):                            # S+ of each active sensor, then S- (argmax order)
            fin += Acc[j] * 0.0
            c = Acc[j] - half[j] * kf
            C[j] = c
            m = min(M[j], c)
            M[j] = m
            r = (c - m) * inv[j]
            kb = j if r > best else kb
            best = max(best, r)
        for j in range(na):
            i = na + j
            c = -Acc[j] - half[j] * kf
            C[i] = c
            m = min(M[i], c)
            M[i] = m
            r = (c - m) * inv[i]
            kb = i if r > best else kb
            best = max(best, r)
        if fin != 0.0:
            return False
        out[t] = best
        if best > 1.0:
            iso[t] = idx[kb if kb < na else kb - na] if isolable else -1
            if restart:
                for i in range(ns):
                    M[i] = C[i]
        else:
            iso[t] = -1
    return True


@_jit
def kalman_block(P: Any, dof: int, K: float, innovation: bool, scale: float, V: Any, n2: Any, out: Any,
                 iso: Any) -> bool:  # pragma: no cover - compiled
    """The steady Kalman filter of :class:`rimu.fdi.kalman.ParityKalman` over the rows of ``P`` (N, >= dof), from
    zero: ``beta_k = (1 - K) beta_{k-1} + K p_k`` (lfilter's order), the innovations ``nu_k = p_k - beta_{k-1}``.

    Fills ``out`` (N,) with ``scale`` times the sum of squares of the innovations (``innovation``) or of the
    estimates, in component order (the order of ``update()``), and ``iso`` (N,) with the sensor j whose column
    ``V[:, j]`` (dof, n) best explains that vector, ``argmax_j (x . v_j)^2 / n2_j`` over the columns with
    ``n2_j > 1e-12`` (:func:`rimu.fdi.glt.block_isolate`; -1 where ``dof < 2``). Returns False at the first
    non-finite statistic."""
    N = P.shape[0]
    n = V.shape[1]
    a = 1.0 - K
    beta = np.zeros(dof)
    x = np.zeros(dof)
    for t in range(N):
        s = 0.0
        for i in range(dof):
            z = P[t, _u(i)]
            b = beta[_u(i)]
            nb = a * b + K * z
            beta[_u(i)] = nb
            v = z - b if innovation else nb
            x[_u(i)] = v
            s = v * v if i == 0 else s + v * v
        s = s * scale
        if not np.isfinite(s):
            return False
        out[t] = s
        if dof < 2:
            iso[t] = -1
            continue
        best = -np.inf
        jb = 0
        for j in range(n):
            if n2[_u(j)] > 1e-12:
                d = x[0] * V[0, _u(j)]
                for i in range(1, dof):
                    d = d + x[_u(i)] * V[_u(i), _u(j)]
                r = d * d / n2[_u(j)]
            else:
                r = -1.0
            if r > best:
                best = r
                jb = j
        iso[t] = jb
    return True
