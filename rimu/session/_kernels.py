"""Compiled kernel (numba) of the per-segment statistics (:mod:`rimu.session.stats`): one pass over a segment's
samples for its column sums, sums of squares and sums of squared first differences. The numpy code of stats.py is
the reference; this gives its numbers to rounding (another summation order, fused multiply-adds; tested against
exactly rounded sums in tests/calibration/test_base_fast_path.py).

Used where numba is loaded in the process already and the backend is not ``"numpy"``, or where ``"numba"`` is asked
for by name (:func:`rimu._backend.resolve_loaded`: a calibration's sums never repay importing numba by themselves).
Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

try:
    import numba
except ImportError as exc:  # pragma: no cover - the caller checks availability first
    raise ImportError("the compiled statistics kernel needs numba: pip install rimu[fast]") from exc

__all__ = ["column_moments"]

#: IEEE arithmetic as numpy's (no exceptions, no reassociation), except that a product added to a sum may be one
#: fused multiply-add (one rounding instead of two: the squares' sums twice as fast)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})


@_jit
def column_moments(Y, out):  # pragma: no cover - compiled
    """One pass over the samples Y (N, k) (rows as stored, any strides): per column j, into ``out[0, j]`` the sum,
    ``out[1, j]`` the sum of squares and ``out[2, j]`` the sum of the squared first differences
    ``(y[t] - y[t-1])^2`` (t >= 1) less ``(y[-1] - y[0])^2 / (N - 1)`` (their squared deviations from their mean,
    :attr:`rimu.session.SegmentSums.diff`; for N >= 3). Four interleaved partial sums per quantity, so that the additions do not wait
    on each other (numpy's BLAS sums keep several too)."""
    n = Y.shape[0]
    if Y.shape[1] == 3 and n >= 3:  # a triad (the common case): one pass over the rows, nine running sums
        _triad_moments(Y, out)
        return
    for j in range(Y.shape[1]):
        s0 = s1 = s2 = s3 = 0.0
        q0 = q1 = q2 = q3 = 0.0
        d0 = d1 = d2 = d3 = 0.0
        if n > 0:
            prev = Y[0, j]
            t = 0
            while t + 4 <= n:
                a = Y[t, j]
                b = Y[t + 1, j]
                c = Y[t + 2, j]
                d = Y[t + 3, j]
                s0 += a
                s1 += b
                s2 += c
                s3 += d
                q0 += a * a
                q1 += b * b
                q2 += c * c
                q3 += d * d
                e0 = a - prev
                e1 = b - a
                e2 = c - b
                e3 = d - c
                d0 += e0 * e0
                d1 += e1 * e1
                d2 += e2 * e2
                d3 += e3 * e3
                prev = d
                t += 4
            while t < n:
                a = Y[t, j]
                s0 += a
                q0 += a * a
                e0 = a - prev
                d0 += e0 * e0
                prev = a
                t += 1
        out[0, j] = (s0 + s1) + (s2 + s3)
        out[1, j] = (q0 + q1) + (q2 + q3)
        dd = (d0 + d1) + (d2 + d3)
        if n >= 3:  # about their mean (y[-1] - y[0]) / (n - 1), as SegmentSums.diff
            e = Y[n - 1, j] - Y[0, j]
            dd -= e**2 / (n - 1)
        out[2, j] = dd


@_jit
def _triad_moments(Y, out):  # pragma: no cover - compiled
    """:func:`column_moments` of an (N, 3) array, N >= 3, row by row: the three columns' sums are independent
    chains, kept twice (even and odd rows), so one pass over the rows keeps the adder busy without reading the
    array three times."""
    n = Y.shape[0]
    a0 = Y[0, 0]
    a1 = Y[0, 1]
    a2 = Y[0, 2]
    s0 = a0
    s1 = a1
    s2 = a2
    q0 = a0 * a0
    q1 = a1 * a1
    q2 = a2 * a2
    d0 = d1 = d2 = 0.0
    t0 = t1 = t2 = 0.0  # the odd rows' sums, squares and differences
    r0 = r1 = r2 = 0.0
    f0 = f1 = f2 = 0.0
    t = 1
    while t + 1 < n:
        b0 = Y[t, 0]
        b1 = Y[t, 1]
        b2 = Y[t, 2]
        c0 = Y[t + 1, 0]
        c1 = Y[t + 1, 1]
        c2 = Y[t + 1, 2]
        s0 += b0
        s1 += b1
        s2 += b2
        t0 += c0
        t1 += c1
        t2 += c2
        q0 += b0 * b0
        q1 += b1 * b1
        q2 += b2 * b2
        r0 += c0 * c0
        r1 += c1 * c1
        r2 += c2 * c2
        e0 = b0 - a0
        e1 = b1 - a1
        e2 = b2 - a2
        d0 += e0 * e0
        d1 += e1 * e1
        d2 += e2 * e2
        e0 = c0 - b0
        e1 = c1 - b1
        e2 = c2 - b2
        f0 += e0 * e0
        f1 += e1 * e1
        f2 += e2 * e2
        a0 = c0
        a1 = c1
        a2 = c2
        t += 2
    if t < n:
        b0 = Y[t, 0]
        b1 = Y[t, 1]
        b2 = Y[t, 2]
        s0 += b0
        s1 += b1
        s2 += b2
        q0 += b0 * b0
        q1 += b1 * b1
        q2 += b2 * b2
        e0 = b0 - a0
        e1 = b1 - a1
        e2 = b2 - a2
        d0 += e0 * e0
        d1 += e1 * e1
        d2 += e2 * e2
    out[0, 0] = s0 + t0
    out[0, 1] = s1 + t1
    out[0, 2] = s2 + t2
    out[1, 0] = q0 + r0
    out[1, 1] = q1 + r1
    out[1, 2] = q2 + r2
    e0 = Y[n - 1, 0] - Y[0, 0]
    e1 = Y[n - 1, 1] - Y[0, 1]
    e2 = Y[n - 1, 2] - Y[0, 2]
    out[2, 0] = (d0 + f0) - e0**2 / (n - 1)
    out[2, 1] = (d1 + f1) - e1**2 / (n - 1)
    out[2, 2] = (d2 + f2) - e2**2 / (n - 1)

