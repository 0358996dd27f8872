"""Compiled kernel (numba) of the per-segment statistics (:mod:`rimu.session.stats`): one pass over a segment's
samples for its column sums, sums of squares and sums of squared first differences. The numpy code of stats.py is
the reference; this gives its numbers to rounding (another summation order; tested in
tests/calibration/test_segment_statistics.py).

Imported only when numba is installed (``pip install rimu[fast]``), the backend is not ``"numpy"``
(:mod:`rimu._backend`) and a segment is long enough to repay it (:data:`rimu.session.stats.KERNEL_MIN_SAMPLES`).
Compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

try:
    import numba
except ImportError as exc:  # pragma: no cover - the caller checks availability first
    raise ImportError("the compiled statistics kernel needs numba: pip install rimu[fast]") from exc

__all__ = ["column_moments"]

#: IEEE arithmetic as numpy's (no exceptions, no fast-math)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def column_moments(Y, out):  # pragma: no cover - compiled
    """One pass over the samples Y (N, k) (rows as stored, any strides): per column j, into ``out[0, j]`` the sum,
    ``out[1, j]`` the sum of squares and ``out[2, j]`` the sum of the squared first differences
    ``(y[t] - y[t-1])^2`` (t >= 1). Four interleaved partial sums per quantity, so that the additions do not wait
    on each other (numpy's BLAS sums keep several too)."""
    n = Y.shape[0]
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
        out[2, j] = (d0 + d1) + (d2 + d3)
