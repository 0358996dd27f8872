"""Per-segment sufficient statistics of a session's raw samples, each computed once and shared by every step of
a calibration (noise level, means, least-squares normal equations, pair differences).

A calibration estimator reads each segment's samples for a handful of numbers: the column sums (means of a
static position, integrals of a turn), the sums of squares (the residual sum of squares of a least-squares fit),
the sum of squared first differences (the noise level) and, for a segment turning at a constant rate with a
known attitude, the moments of ``cos`` and ``sin`` of the turned angle. :class:`SessionStatistics` computes each
on first use and keeps it, so the memory of a fit grows with the number of segments, not of samples.

Rotation moments. A vector ``v`` fixed in the local level frame, seen in MB on a segment turning at the constant
rate ``w`` (unit axis ``k``, angle ``theta = |w| (t - t0)``) about a fixed MB axis with attitude ``C0`` at its first
sample, is ``x cos(theta) - (k x x) sin(theta) + k (k . x)(1 - cos(theta))`` with ``x = C0^T v``
(:meth:`~rimu.session.Segment.ln_vector_in_mb`), that is ``a + b cos(theta) + c sin(theta)`` with constant
``a = k (k . x)``, ``b = x - a``, ``c = -(k x x)``. Every known input of such a segment (specific force, Earth
rate plus the table rate) lies in the span of the basis ``B = [1, cos(theta), sin(theta)]``, so its mean, its
Gram matrix and its products with the samples follow from ``B^T B`` (3 x 3) and ``B^T Y`` (3 x n): one
evaluation of the angles per segment, whatever the vector or the instrument (the session-wide attitude cache).

Sums are taken as matrix-vector products with a vector of ones (BLAS): a strided reduction over the samples of
an (N, 3) array (``y.sum(axis=0)``, ``y.mean(axis=0)``) is 20-30 times slower. They equal the plain per-sample
sums to rounding (checked in ``tests/calibration/test_segment_statistics.py``).

Scope. The statistics are kept for the life of a :class:`SessionStatistics` object: an estimator makes one per
``fit``, so a segment's samples changed in place between two fits are read afresh (``Segment.raw`` arrays are
mutable, and nothing here could tell that they changed).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._backend import import_once
from .._backend import resolve_loaded as _resolve_loaded
from .model import Segment, Session

__all__ = ["KERNEL_MIN_SAMPLES", "RotationMoments", "SegmentSums", "SessionStatistics", "column_sums"]

#: without the compiled pass (numba not loaded), segments shorter than this are summed by numpy all together (a few
#: calls for all of them), longer ones one by one
KERNEL_MIN_SAMPLES = 2048
#: at most this many rows of short segments are stacked at once (the stack holds three times as many)
STACK_ROWS = 1 << 16
_KERNELS: list = []


def _kernels():
    """The compiled kernel's module (imports numba once), or None without numba."""
    return import_once(_KERNELS, "rimu.session._kernels")

_ONES = np.ones(0)


def _ones(n: int) -> np.ndarray:
    """A read-only vector of n ones (one buffer, grown when a longer one is asked for)."""
    global _ONES
    if _ONES.shape[0] < n:
        buf = np.ones(max(n, 2 * _ONES.shape[0]))
        buf.setflags(write=False)
        _ONES = buf
    return _ONES[:n]


def column_sums(y: np.ndarray) -> np.ndarray:
    """Column sums of samples (N, k) as one matrix-vector product: ``y.sum(axis=0)`` to rounding, 20-30 times
    faster for a few columns.

    >>> column_sums(np.array([[1.0, 2.0], [3.0, 4.0]])).tolist()
    [4.0, 6.0]
    """
    y = np.asarray(y, dtype=float)
    return _ones(y.shape[0]) @ y


@dataclass(eq=False)
class SegmentSums:
    """Sufficient statistics of one instrument's raw samples on one segment (float64, raw units).

    Attributes
    ----------
    n : int
        Samples.
    total : ndarray (k,)
        Column sums.
    """

    n: int
    total: np.ndarray
    _y: np.ndarray = field(repr=False)
    _sumsq: np.ndarray | None = field(default=None, repr=False)
    _gram: np.ndarray | None = field(default=None, repr=False)
    _diff: tuple[np.ndarray, int] | None = field(default=None, repr=False)

    @property
    def mean(self) -> np.ndarray:
        """Column means (k,)."""
        return self.total / self.n

    @property
    def sumsq(self) -> np.ndarray:
        """Column sums of squares (k,): ``y.y`` of every sensor."""
        if self._sumsq is None:
            sq = np.square(self._y)
            self._sumsq = _ones(self.n) @ sq
        return self._sumsq

    @property
    def gram(self) -> np.ndarray:
        """``Y^T Y`` (k, k): the sums of squares on the diagonal (:attr:`sumsq`), the sums of products of two
        columns off it (one dot product each for a few columns; one matrix product for many)."""
        if self._gram is None:
            y = self._y
            k = y.shape[1]
            if k > 4:
                G = y.T @ y
            else:
                G = np.diag(self.sumsq)
                for i in range(k):
                    for j in range(i + 1, k):
                        G[i, j] = G[j, i] = y[:, i] @ y[:, j]
            self._gram = G
        return self._gram

    @property
    def diff(self) -> tuple[np.ndarray, int]:
        """``(ss, m - 1)``: the sum of squared deviations of the first differences ``d = y[k+1] - y[k]`` from
        their mean ``(y[-1] - y[0]) / m`` (``m = n - 1``) and its degrees of freedom; zeros and 0 for fewer than
        three samples. ``ss / (m - 1) / 2`` is the white-noise variance of the samples."""
        if self._diff is None:
            y = self._y
            if self.n < 3:
                self._diff = (np.zeros(y.shape[1]), 0)
            else:
                d = y[1:] - y[:-1]
                d *= d
                self._diff = _diff_from(_ones(self.n - 1) @ d, y, self.n)
        return self._diff


def _diff_from(dd: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """:attr:`SegmentSums.diff` from the sums ``dd`` of the squared first differences of ``y`` (n samples): their
    sum of squared deviations from their mean ``(y[-1] - y[0]) / m`` (``m = n - 1``), and its degrees of freedom."""
    if n < 3:
        return np.zeros(y.shape[1]), 0
    m = n - 1
    return dd - (y[-1] - y[0]) ** 2 / m, m - 1


@dataclass(eq=False)
class RotationMoments:
    """Moments of the basis ``B = [1, cos(theta), sin(theta)]`` of a segment turning at a constant rate with a
    known attitude (see the module docstring).

    Attributes
    ----------
    k : ndarray (3,)
        Unit rotation axis in MB.
    gram : ndarray (3, 3)
        ``B^T B`` over the samples.
    products : dict[str, ndarray (3, n)]
        ``B^T Y`` of the instruments asked for (:meth:`SessionStatistics.basis_products`).
    """

    k: np.ndarray
    gram: np.ndarray
    products: dict[str, np.ndarray]

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        """``P`` (3, 3) with rows ``a, b, c``: the LN-fixed vector with ``x = C0^T v`` is ``B @ P`` in MB."""
        x = np.asarray(x, dtype=float)
        a = self.k * float(self.k @ x)
        return np.vstack([a, x - a, -np.cross(self.k, x)])

    def mean_vector(self, x: np.ndarray) -> np.ndarray:
        """Mean over the samples of the LN-fixed vector with ``x = C0^T v``, seen in MB (3,)."""
        return (self.gram[0] / self.gram[0, 0]) @ self.coefficients(x)


class SessionStatistics:
    """Per-segment statistics of ``session``, each computed on first use and then kept (see the module
    docstring). One object per calibration ``fit``.

    >>> from rimu.sim import Simulator, cho_park_procedure
    >>> s = Simulator(seed=1).run(cho_park_procedure(duration=1.0)).session
    >>> st = SessionStatistics(s)
    >>> seg = s.segments[0]
    >>> bool(np.allclose(st.sums(seg, "gyro").mean, seg.raw["gyro"].mean(axis=0)))
    True
    """

    def __init__(self, session: Session, backend: str | None = None) -> None:
        self.session = session
        #: "auto", "numpy" or "numba" (:mod:`rimu._backend`): the compiled pass where numba is loaded already (auto),
        #: or asked for by name (:func:`rimu._backend.resolve_loaded`)
        self.backend = backend
        self._kernel: object = False  # not resolved yet
        self._sums: dict[tuple[int, str], tuple[Segment, SegmentSums]] = {}
        #: rows of a :meth:`moments` array, made into a SegmentSums only when :meth:`sums` asks for one
        self._rows: dict[tuple[int, str], tuple[Segment, np.ndarray, int]] = {}
        self._rot: dict[int, tuple[Segment, RotationMoments | None]] = {}

    def sums(self, seg: Segment, instrument: str, full: bool = False) -> SegmentSums:
        """The :class:`SegmentSums` of ``instrument`` on ``seg``; ``full``: with its sums of squares and its
        first-difference sum computed now, together (one compiled pass over a long segment where numba is
        installed, :mod:`rimu.session._kernels`; numpy's passes otherwise), not on first use."""
        key = (id(seg), instrument)
        hit = self._sums.get(key) or self._from_rows(key, seg)
        if hit is not None and hit[0] is seg:
            out = hit[1]
            if full:
                self._fill(out)
            return out
        y = seg.raw[instrument]
        n = y.shape[0]
        if full and self._compiled() is not None:
            m = np.empty((3, y.shape[1]))
            self._kernel.column_moments(y, m)  # type: ignore[attr-defined]
            out = SegmentSums(n, m[0], y, m[1], None, (m[2], n - 2) if n >= 3 else (np.zeros(y.shape[1]), 0))
        else:
            out = SegmentSums(n, _ones(n) @ y, y)
            if full:
                self._fill(out)
        self._sums[key] = (seg, out)
        return out

    def sums_of(self, segs: "list[Segment]", instrument: str, full: bool = False) -> list[SegmentSums]:
        """:meth:`sums` of each of ``segs``, in order. The short ones not known yet (under
        :data:`KERNEL_MIN_SAMPLES` samples) are summed together: their samples, squares and squared first
        differences stacked in one array, every sum of every segment in one ``np.add.reduceat``, so that a session
        of many short segments costs a few numpy calls, not a few per segment (the per-segment sums to rounding)."""
        cache = self._sums
        out: list = []
        todo = []
        for seg in segs:
            hit = cache.get((id(seg), instrument)) or self._from_rows((id(seg), instrument), seg)
            if hit is not None and hit[0] is seg:
                if full:
                    self._fill(hit[1])
                out.append(hit[1])
            elif seg.raw[instrument].shape[0] < KERNEL_MIN_SAMPLES:
                out.append(None)
                todo.append(seg)
            else:
                out.append(self.sums(seg, instrument, full))
        kern = self._compiled() if full and todo else None
        if kern is not None:  # numba loaded already: a compiled pass per segment (about 1 us for a short one)
            for j, seg in enumerate(segs):
                if out[j] is None:
                    y = seg.raw[instrument]
                    n = y.shape[0]
                    M = np.empty((3, y.shape[1]))
                    kern.column_moments(y, M)
                    new = SegmentSums(n, M[0], y, M[1], None, (M[2], n - 2) if n >= 3 else (np.zeros(y.shape[1]), 0))
                    cache[(id(seg), instrument)] = (seg, new)
                    out[j] = new
        elif todo:
            # a few numpy calls per chunk of at most STACK_ROWS stacked rows (memory: 3 x STACK_ROWS rows at a time)
            chunk: list[Segment] = []
            rows = 0
            for seg in todo + [None]:  # type: ignore[list-item]
                n = 0 if seg is None else seg.raw[instrument].shape[0]
                if chunk and (seg is None or rows + n > STACK_ROWS):
                    self._stacked(chunk, instrument, full)
                    chunk, rows = [], 0
                if seg is not None:
                    chunk.append(seg)
                    rows += n
            for j, seg in enumerate(segs):
                if out[j] is None:
                    out[j] = cache[(id(seg), instrument)][1]
        return out

    def moments(self, segs: "list[Segment]", instrument: str) -> tuple[list[int], np.ndarray]:
        """Every one of ``segs``' sums in one array: ``(n, M)``, ``n`` their numbers of samples and ``M`` (S, 3, k)
        their column sums (``M[:, 0]``), sums of squares (``M[:, 1]``) and first-difference sums (``M[:, 2]``:
        :attr:`SegmentSums.diff`, zero under three samples). Where the compiled pass is used, one call per segment
        writes its row, and no object is made per segment (:meth:`sums` makes one from a row when asked); else the
        sums of :meth:`sums_of`. Kept, as every statistic here.

        >>> from rimu.sim import Simulator, cho_park_procedure
        >>> s = Simulator(seed=1).run(cho_park_procedure(duration=1.0)).session
        >>> n, M = SessionStatistics(s).moments(s.segments[:2], "accel")
        >>> M.shape, bool(np.allclose(M[1, 0], s.segments[1].raw["accel"].sum(axis=0)))
        ((2, 3, 6), True)
        """
        ys = [seg.raw[instrument] for seg in segs]
        ns = [y.shape[0] for y in ys]
        M = np.empty((len(ys), 3, ys[0].shape[1] if ys else 0))
        kern = self._compiled()
        if kern is None:
            known = self._sums.keys() | self._rows.keys()
            if (ys and max(ns) < KERNEL_MIN_SAMPLES and sum(ns) <= STACK_ROWS
                    and not any((id(x), instrument) in known for x in segs)):
                # short segments, none known: numpy's stacked sums straight into M
                R = _stacked_sums(ys, ns, True)
                S = len(ys)
                M[:, 0], M[:, 1], M[:, 2] = R[:S], R[S:2 * S], R[2 * S:]
                M[[j for j, n in enumerate(ns) if n < 3], 2] = 0.0
                for j, seg in enumerate(segs):
                    self._rows[(id(seg), instrument)] = (seg, M, j)
                return ns, M
            for j, st in enumerate(self.sums_of(segs, instrument, full=True)):
                M[j, 0], M[j, 1], M[j, 2] = st.total, st.sumsq, st.diff[0]
            return ns, M
        cache, rows, f = self._sums, self._rows, kern.column_moments
        fresh = not cache and not rows  # (a fit's first call: nothing to look up)
        for j, seg in enumerate(segs):
            key = (id(seg), instrument)
            if not fresh:
                hit = cache.get(key) or rows.get(key)
                if hit is not None and hit[0] is seg:  # known already
                    st = self.sums(seg, instrument, full=True)
                    M[j, 0], M[j, 1], M[j, 2] = st.total, st.sumsq, st.diff[0]
                    continue
            f(ys[j], M[j])
            if ns[j] < 3:
                M[j, 2] = 0.0
            rows[key] = (seg, M, j)
        return ns, M

    def _from_rows(self, key: tuple[int, str], seg: Segment) -> tuple[Segment, SegmentSums] | None:
        """The :class:`SegmentSums` of a :meth:`moments` row (made now and kept), or None."""
        row = self._rows.get(key)
        if row is None or row[0] is not seg:
            return None
        _, M, j = row
        y = seg.raw[key[1]]
        n = y.shape[0]
        hit = self._sums[key] = (seg, SegmentSums(n, M[j, 0], y, M[j, 1], None,
                                                  (M[j, 2], n - 2) if n >= 3 else (np.zeros(y.shape[1]), 0)))
        return hit

    def _stacked(self, todo: "list[Segment]", instrument: str, full: bool) -> None:
        """The :class:`SegmentSums` of the short segments ``todo`` (stacked: a few numpy calls for all of them), kept.
        Rows: the samples, their squares and their squared first differences (zero at each segment's first row);
        every sum of every segment in one ``np.add.reduceat``."""
        ys = [seg.raw[instrument] for seg in todo]
        ns = [y.shape[0] for y in ys]
        R = _stacked_sums(ys, ns, full)
        m = len(ys)
        for k, (seg, n) in enumerate(zip(todo, ns)):
            if not full:
                new = SegmentSums(n, R[k], ys[k])
            elif n < 3:
                new = SegmentSums(n, R[k], ys[k], R[m + k], None, (np.zeros(R.shape[1]), 0))
            else:
                new = SegmentSums(n, R[k], ys[k], R[m + k], None, (R[2 * m + k], n - 2))
            self._sums[(id(seg), instrument)] = (seg, new)

    def _compiled(self):
        """The compiled kernel's module, or None: where numba is loaded in the process already and the backend
        allows it, or the backend asks for numba by name (:func:`rimu._backend.resolve_loaded`: the sums of a
        calibration never repay importing numba by themselves). Resolved once per object."""
        if self._kernel is False and self.backend == "numba" and _KERNELS and _KERNELS[0] is not None:
            self._kernel = _KERNELS[0]  # (asked for by name and imported already: nothing to resolve)
        if self._kernel is False:
            name = _resolve_loaded(self.backend, lambda: _kernels() is not None, "the compiled statistics kernel")
            self._kernel = _kernels() if name == "numba" else None
        return self._kernel

    @staticmethod
    def _fill(out: SegmentSums) -> None:
        """The sums of squares and the first-difference sum of ``out`` by numpy (one temporary at a time), where
        they are not known yet."""
        out.sumsq  # noqa: B018 - computed and kept on first use
        out.diff  # noqa: B018

    def mean(self, seg: Segment, instrument: str) -> np.ndarray:
        """Column means of ``instrument`` on ``seg`` (k,)."""
        return self.sums(seg, instrument).mean

    def rotation(self, seg: Segment) -> RotationMoments | None:
        """The :class:`RotationMoments` of a segment turning at a nonzero constant rate with a known attitude;
        None otherwise (at rest, or the attitude unknown). Uniformly sampled segments get ``B^T B`` in closed form
        (:func:`_uniform_moments`), others from the angles of their samples; the products with the samples are
        :meth:`basis_products`."""
        hit = self._rot.get(id(seg))
        if hit is not None and hit[0] is seg:
            return hit[1]
        out = None
        if seg.mat_ln_mb is not None:
            w = seg.table_rate()
            wn = float(np.linalg.norm(w))
            if wn != 0.0:
                gram = _uniform_moments(seg.t, wn)
                if gram is None:
                    c, s = _angles(seg, wn)
                    one = _ones(seg.n_samples)
                    sc, ss = float(one @ c), float(one @ s)
                    gram = np.array([[seg.n_samples, sc, ss], [sc, float(c @ c), float(c @ s)],
                                     [ss, float(c @ s), float(s @ s)]])
                out = RotationMoments(w / wn, gram, {})
        self._rot[id(seg)] = (seg, out)
        return out

    def basis_products(self, seg: Segment, instruments: tuple[str, ...]) -> dict[str, np.ndarray] | None:
        """``B^T Y`` (3, n) of each of ``instruments`` on a rotating segment with known attitude (None otherwise):
        the column sums and the sums of ``cos(theta) y`` and ``sin(theta) y``. The angles of the samples are
        evaluated once for all the instruments asked for together and not kept."""
        rm = self.rotation(seg)
        if rm is None:
            return None
        todo = [k for k in instruments if k not in rm.products]
        if todo:
            c, s = _angles(seg, float(np.linalg.norm(seg.table_rate())))
            for k in todo:
                y = seg.raw[k]
                rm.products[k] = np.vstack([self.sums(seg, k).total, c @ y, s @ y])
        return {k: rm.products[k] for k in instruments}


def _stacked_sums(ys: "list[np.ndarray]", counts: "list[int]", full: bool) -> np.ndarray:
    """The sums of the samples ``ys`` (each (n, k)) stacked: rows ``R[:m]`` their column sums and, if ``full``,
    ``R[m:2m]`` their sums of squares and ``R[2m:]`` their first-difference sums (:attr:`SegmentSums.diff`; the
    squared first differences, zero at each segment's first row, less ``(y[-1] - y[0])^2 / (n - 1)``): every sum of
    every segment in one ``np.add.reduceat``."""
    ns = np.array(counts, dtype=np.intp)
    N, m = int(ns.sum()), len(ys)
    starts = np.zeros(m, dtype=np.intp)
    np.cumsum(ns[:-1], out=starts[1:])
    # rows: the samples, their squares, their squared first differences (zero at each segment's first row)
    Z = np.empty(((3 if full else 1) * N, ys[0].shape[1]))
    Y = Z[:N]
    np.concatenate(ys, out=Y)
    idx = starts
    if full:
        np.square(Y, out=Z[N:2 * N])
        D = Z[2 * N:]
        np.subtract(Y[1:], Y[:-1], out=D[1:])
        D[starts] = 0.0
        np.square(D, out=D)
        idx = np.concatenate([starts, starts + N, starts + 2 * N])
    R = np.add.reduceat(Z, idx, axis=0)
    if full:
        ends = starts + ns - 1
        R[2 * m:] -= (Y[ends] - Y[starts]) ** 2 / np.maximum(ns - 1, 1)[:, None]  # (:func:`_diff_from`)
    return R


def _angles(seg: Segment, wn: float) -> tuple[np.ndarray, np.ndarray]:
    th = wn * (seg.t - seg.t[0])
    return np.cos(th), np.sin(th)


def _dirichlet(n: int, phi: float) -> complex | None:
    """``sum_{k<n} exp(i k phi)`` in closed form; None when ``sin(phi / 2)`` is too small for it."""
    s = np.sin(phi / 2.0)
    if abs(s) < 1e-6:
        return None
    return complex(np.exp(0.5j * (n - 1) * phi) * (np.sin(n * phi / 2.0) / s))


def _uniform_moments(t: np.ndarray, wn: float) -> np.ndarray | None:
    """``B^T B`` of the angles ``theta_k = wn (t_k - t_0)`` in closed form when the samples are uniform (every
    ``t_k`` within ``1e-12 / wn`` s of ``t_0 + k dt``, so each angle within 1e-12 rad of ``k phi``): with
    ``D(phi) = sum exp(i k phi)`` (a geometric series), ``sum cos = Re D(phi)``, ``sum sin = Im D(phi)``,
    ``sum cos^2 = (n + Re D(2 phi)) / 2``, ``sum sin^2 = (n - Re D(2 phi)) / 2``, ``sum cos sin = Im D(2 phi) / 2``.
    None when the samples are not uniform or the step is near a multiple of pi."""
    n = t.shape[0]
    if n < 3:
        return None
    dt = (t[-1] - t[0]) / (n - 1)
    if not dt > 0:
        return None
    dev = t - t[0]
    dev -= dt * np.arange(n)
    if float(np.max(np.abs(dev))) * wn > 1e-12:
        return None
    phi = wn * dt
    d1, d2 = _dirichlet(n, phi), _dirichlet(n, 2.0 * phi)
    if d1 is None or d2 is None:
        return None
    sc, ss = d1.real, d1.imag
    cc, sn, cs = (n + d2.real) / 2.0, (n - d2.real) / 2.0, d2.imag / 2.0
    return np.array([[float(n), sc, ss], [sc, cc, cs], [ss, cs, sn]])
