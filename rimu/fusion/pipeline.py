"""The runtime pipeline: raw samples in, MB-frame estimate, covariance and parity vector out.

Per sample, for one instrument (gyros or accelerometers)::

    z = SF * y - B                       compensation (Cho & Park Eq. 20, inner part)
    x = G z,  P = (A^T W^2 A)^-1         projection to MB on the active sensors
    p = V_w W z                          normalised parity (de Oliveira Eq. 11), cov(p) = I

with A the calibrated axes (rows of M H). Everything that depends on which sensors are active comes from a
:class:`~rimu.fusion.projection.ProjectionTable`, which computes an active set's matrices when the set first
occurs and keeps the sets that occurred in a small cache; SF and B are folded into them, so the per-sample work
is one matrix-vector product into a preallocated buffer and one finiteness check -- no decomposition.

Invalid and saturated samples. A non-finite raw value (or one marked invalid) makes that sensor invalid for
that sample (counted in ``invalid_count``); a raw value at the sensor's range limit, ``|y_i| >= range_raw_i``,
makes it saturated for that sample (counted in ``saturated_count``): a clipped output is not a measurement but
says nothing about the sensor's health. Both are routed around for that sample -- the estimate uses the rest.
A sensor that stays invalid is isolated by the redundancy manager after ``invalid_persist`` samples; a saturated
one never is (saturation is reported in ``saturated``, not ``invalid``).

Validity (:class:`~rimu.fusion.validity.Validity`) of each output: ``NOMINAL`` when every sensor is used,
``DEGRADED`` when some are isolated, invalid or saturated, ``UNOBSERVABLE`` when the sensors in use do not span
three dimensions. When nothing can be estimated there is no number: an unobservable sample reports ``x = NaN``
with ``P = inf`` (diagonal), ``observable = False`` and validity ``UNOBSERVABLE`` (the parity is zero, dof 0).

The pipeline holds no isolation decision: the set of sensors to use is an argument of every call
(``step(y, valid, active)``, ``process(Y, valid, active)``); the runtime (:class:`rimu.fdi.Runtime`) owns it.

Equivalence with Cho & Park Eq. 20. Where every sub-unit is a full triad, Eq. 20 reads
``x = (H^T H)^-1 H^T M^-1 (SF Y - B)``. Both that matrix and G here are left inverses of A = M H, so both
return the true input exactly without noise; G is the minimum-variance one (weighted least squares), and the
two differ by terms of second order in the misalignment. G also works where M is not square per block (the
tetrad's fourth gyro), and isolation (Eq. 21) stays exact: Eq. 20 with a zeroed output inside a triad still
mixes the missing value through M^-1, which leaks misalignment times input into the estimate.
:func:`rimu.fusion.compensation.cho_park_eq20` implements Eq. 20 literally for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calibration.model import RuntimeInputs
from ..calibration.result import Calibration, InstrumentCalibration
from ..epoch import Epoch, EpochBlock
from ..errors import MissingInputError, ShapeError
from .backend import _kernels, resolve_backend
from .effects import EffectCompensation, _monomials_one
from .projection import ActiveSet, ProjectionTable, mask_bits
from .validity import Validity

__all__ = ["InstrumentPipeline", "Pipeline", "StepResult", "BlockResult"]

_INF_P = np.diag([np.inf] * 3)
_INF_P.setflags(write=False)
_NDARRAY = np.ndarray
_F8 = np.dtype(np.float64)
_B1 = np.dtype(bool)


@dataclass
class StepResult:
    """Output of one :meth:`InstrumentPipeline.step` (the same object is reused: copy what you keep).

    Attributes
    ----------
    x : ndarray (3,)
        Estimate in MB, SI units. NaN when ``validity`` is ``UNOBSERVABLE`` (no estimate).
    P : ndarray (3, 3)
        Its covariance (``inf`` on the diagonal when unobservable).
    parity : ndarray (n - 3,)
        Normalised parity vector (unit covariance without faults); zero-padded past ``dof``.
    dof : int
        n_active - 3.
    active : ndarray (n,) of bool
        Sensors used for this sample.
    invalid : ndarray (n,) of bool
        Sensors whose raw value was non-finite (or marked invalid) in this sample.
    observable : bool
        False when the valid, non-isolated sensors do not span three dimensions.
    entry : int
        Entry number of the active set in the projection table.
    saturated : ndarray (n,) of bool
        Sensors whose raw value was at their range limit in this sample (routed around, not faulty).
    validity : Validity
        NOMINAL (every sensor used), DEGRADED (some isolated, invalid or saturated), UNOBSERVABLE.
    code : int
        The set code of ``active`` (bit i = sensor i): the key of the set in the projection table, which
        recomputes a set it no longer holds (``table.get(code)``; an entry number may be evicted).
    """

    x: np.ndarray
    P: np.ndarray
    parity: np.ndarray
    dof: int
    active: np.ndarray
    invalid: np.ndarray
    observable: bool
    entry: int
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    validity: Validity = Validity.NOMINAL
    code: int = -1


@dataclass
class BlockResult:
    """Output of :meth:`InstrumentPipeline.process` for N samples.

    ``x`` is NaN where ``validity == Validity.UNOBSERVABLE`` (see the module docstring).
    """

    x: np.ndarray
    parity: np.ndarray
    entry: np.ndarray
    dof: np.ndarray
    active: np.ndarray
    invalid: np.ndarray
    observable: np.ndarray
    table: ProjectionTable = field(repr=False)
    saturated: np.ndarray | None = None
    validity: np.ndarray | None = None
    _P: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    def covariance(self) -> np.ndarray:
        """Estimate covariance per sample, (N, 3, 3)."""
        N = len(self.entry)
        out = np.empty((N, 3, 3))
        ent = np.asarray(self.entry)
        for e in np.unique(ent):
            P = self._P.get(int(e))
            if P is None:
                P = self.table.set(int(e)).P
            out[ent == e] = P
        return out

    def __len__(self) -> int:
        return int(self.x.shape[0])


def _out_buffer(out: np.ndarray | None, N: int, m: int) -> np.ndarray:
    """``out`` checked as a C-ordered float64 (N, m) buffer, or a new one."""
    if out is None:
        return np.empty((N, m))
    if type(out) is not _NDARRAY or out.shape != (N, m) or out.dtype != _F8 or not out.flags.c_contiguous:
        raise ShapeError(f"out must be a C-ordered float64 array of shape ({N}, {m}), got "
                         f"{getattr(out, 'shape', type(out).__name__)}")
    return out


def _validity(s: ActiveSet, n: int) -> Validity:
    if not s.observable:
        return Validity.UNOBSERVABLE
    return Validity.NOMINAL if s.code == (1 << n) - 1 else Validity.DEGRADED


class InstrumentPipeline:
    """Compensation, projection and parity for one instrument kind.

    Parameters
    ----------
    calibration : InstrumentCalibration
    sigma : float or ndarray (n,), optional
        Per-sample noise standard deviation of the compensated outputs, SI. Default: the calibration's
        ``noise_sigma``, else the per-sample sigma of its ``noise`` model (:mod:`rimu.noise`); without
        either, 1.0 (covariances are then in units of sigma^2).
    max_excluded : int, optional
        Deprecated, without effect (see :class:`~rimu.fusion.projection.ProjectionTable`).
    range_raw : float or ndarray (n,), optional
        Range limit of each sensor in RAW output units (the units of ``y``, before scale and bias): a sample
        with ``|y_i| >= range_raw_i`` is saturated. Default: the calibration's ``range_raw``; None: no limit.
    cache_size : int, optional
        Active sets kept by the projection table besides the full set (default ``max(64, 2 n)``).
    backend : {"auto", "numpy", "numba"}, optional
        Implementation of the common path (:mod:`rimu.fusion.backend`); default ``RIMU_BACKEND``, else
        ``"auto"`` (numba where installed). Same numbers either way.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.5, noise_sigma=0.001)
    >>> pipe = InstrumentPipeline(cal, range_raw=3000.0)
    >>> y = cal.raw_output(np.array([0.1, -0.2, 0.3]))
    >>> np.round(pipe.step(y).x, 12).tolist(), pipe.result.validity.name
    ([0.1, -0.2, 0.3], 'NOMINAL')
    >>> y[1] = 3000.0                        # clipped at the range limit: routed around
    >>> r = pipe.step(y)
    >>> np.round(r.x, 12).tolist(), r.validity.name, pipe.saturated_count.tolist()
    ([0.1, -0.2, 0.3], 'DEGRADED', [0, 1, 0, 0, 0, 0])
    """

    def __init__(
        self,
        calibration: InstrumentCalibration,
        sigma: float | np.ndarray | None = None,
        max_excluded: int | None = None,
        range_raw: float | np.ndarray | None = None,
        cache_size: int | None = None,
        backend: str | None = None,
    ) -> None:
        self.calibration = calibration
        #: ``"numpy"`` or ``"numba"``: the implementation of the common path
        self.backend = resolve_backend(backend)
        kern = _kernels() if self.backend == "numba" else None
        self._kstep = None if kern is None else kern.project_one
        self._bpath: Any = None  # the compiled block path (rimu.fusion._kernels.BlockPath), made on first use
        n = calibration.geometry.n
        #: True when the noise came from ``sigma`` or the calibration's ``noise_sigma``, False when 1.0 was assumed
        self.noise_given = sigma is not None or calibration.noise_sigma is not None
        if sigma is None:
            sigma = calibration.noise_sigma if calibration.noise_sigma is not None else 1.0
            if calibration.noise_sigma is None and getattr(calibration, "noise", None) is not None:
                sigma = calibration.noise.sample_sigma()  # the identified noise model (rimu.noise)
        self.table = ProjectionTable(calibration.axes_mb(), sigma, max_excluded, cache_size=cache_size,
                                     scale=calibration.scale, bias=calibration.bias)
        if range_raw is None:
            range_raw = getattr(calibration, "range_raw", None)
        if range_raw is None:
            self.range_raw = None
            self._range_min = float("inf")
            self._range = np.full(n, np.inf)
        else:
            rr = np.broadcast_to(np.asarray(range_raw, dtype=float), (n,)).copy()
            if np.any(~(rr > 0)):
                raise ShapeError(f"range_raw must be positive (raw output units), got {rr.tolist()}")
            self.range_raw = rr
            self._range_min = float(rr.min())
            self._range = rr
        self.n = n
        self.r = max(n - 3, 0)
        self.invalid_count = np.zeros(n, dtype=np.int64)
        self.saturated_count = np.zeros(n, dtype=np.int64)
        self.samples = 0
        self._code = -1
        self._full = self.table.full_code
        self._out = np.zeros(3 + self.r)
        self._y0 = np.zeros(n)
        self._invalid = np.zeros(n, dtype=bool)
        self._saturated = np.zeros(n, dtype=bool)
        self._dirty = False
        self._bkey: tuple[Any, int] | None = None
        self.result = StepResult(self._out[:3], _INF_P, self._out[3:], 0, np.ones(n, bool),
                                 self._invalid, True, 0, self._saturated, Validity.NOMINAL)
        self._select(self.table.full_code)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """A copy (``copy.deepcopy``, pickle) keeps :attr:`result` a view of the step's buffers (a copied view is an
        array of its own: the copy's result would never change again)."""
        self.__dict__.update(state)
        res = self.result
        res.x, res.parity = self._out[:3], self._out[3:]
        res.invalid, res.saturated = self._invalid, self._saturated

    # ------------------------------------------------------------------ the active set (Cho & Park Eq. 21)
    def _check_index(self, i: int) -> int:
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)) or not 0 <= i < self.n:
            raise IndexError(f"sensor index must be an integer in 0..{self.n - 1}, got {i!r}")
        return int(i)

    def _use(self, active: np.ndarray | int | None) -> None:
        """Make the set ``active`` current: a boolean mask (n,) of the sensors the caller keeps in, a set code
        (bit i = sensor i, :func:`rimu.fusion.projection.mask_bits`), or None for every sensor. The pipeline holds
        no isolation decision: the set is an argument of each call (the runtime, :class:`rimu.fdi.Runtime`, owns
        it); the matrices of the last set used are kept so that an unchanged set costs one comparison."""
        if active is None:
            code = self.table.full_code
        elif isinstance(active, (int, np.integer)) and not isinstance(active, (bool, np.bool_)):
            code = int(active)
            if not 0 <= code <= self.table.full_code:
                raise ShapeError(f"an active-set code must be in 0..{self.table.full_code}, got {code}")
        else:
            m = np.asarray(active, dtype=bool)
            if m.shape != (self.n,):
                raise ShapeError(f"active-set mask must have shape ({self.n},), got {m.shape}")
            code = mask_bits(m)
        if code != self._code:
            self._select(code)

    def _select(self, code: int) -> None:
        """Make the set ``code`` current (computed now if it is new: not per sample)."""
        s = self.table.get(code)
        self._code = code
        self._set = s
        self._entry = s.entry
        self._Re = s.R
        self._offe = s.off
        if not s.observable:  # no estimate on this set: NaN, which also sends every sample to the careful path
            self._offe = s.off.copy()
            self._offe[:3] = np.nan
        self._point_result(s)

    def _point_result(self, s: ActiveSet) -> None:
        res = self.result
        res.entry = s.entry
        res.code = s.code
        res.P = s.P if s.observable else _INF_P
        res.dof = s.dof
        res.observable = s.observable
        res.active = s.active
        res.validity = _validity(s, self.n)

    # ------------------------------------------------------------------ per sample
    def _clean(self) -> None:
        """Back to the current set after a sample that routed around some sensors."""
        self._invalid[:] = False
        self._saturated[:] = False
        self._point_result(self._set)
        self._dirty = False

    def step(self, y: np.ndarray, valid: np.ndarray | None = None, active: np.ndarray | int | None = None
             ) -> StepResult:
        """Process one raw sample ``y`` (n,) on the sensors ``active`` (a mask (n,), a set code, or None: all;
        invalid and clipped values are left out of the sample on top). Returns :attr:`result` (reused; copy
        what you keep)."""
        if active is None:
            if self._code != self._full:
                self._use(None)
        elif type(active) is not int or active != self._code:  # (an unchanged set code costs one comparison)
            self._use(active)
        self.samples += 1
        if valid is not None:  # every sensor flagged valid? (a bool array's bytes are 0 or 1: no zero byte)
            clean = (0 not in valid.tobytes()) if type(valid) is _NDARRAY and valid.dtype is _B1 else bool(np.all(valid))
            if not clean:
                return self._step_slow(np.asarray(y, dtype=float), valid)
        k = self._kstep
        if k is not None:  # compiled: range, R y - off and finiteness in one call
            if type(y) is _NDARRAY and y.dtype is _F8 and y.ndim == 1:
                if k(y, self._Re, self._offe, self._range, self._out):
                    if self._dirty:
                        self._clean()
                    return self.result
            return self._step_slow(np.asarray(y, dtype=float), valid)
        try:
            yl = y.tolist()
        except AttributeError:  # not an ndarray: the careful path converts and checks it
            yl = None
        if yl is not None and len(yl) == self.n:
            s = sum(yl)  # Python floats: inf and nan propagate without floating-point warnings
            lim = self._range_min
            if s - s == 0.0 and max(yl) < lim and min(yl) > -lim:
                out = self._out
                np.dot(self._Re, y, out=out)
                out -= self._offe
                s = sum(out.tolist())
                if s - s == 0.0:  # finite: the common path
                    if self._dirty:
                        self._clean()
                    return self.result
        return self._step_slow(np.asarray(y, dtype=float), valid)

    def common_rows(self, Y: np.ndarray, out: np.ndarray, active: int) -> int:
        """How many leading rows of ``Y`` (N, n) :meth:`step` would take on its common path on the set code
        ``active`` (every value finite and inside the range, the output finite), with their outputs (x, parity)
        written into ``out[:m]`` exactly as :meth:`step` computes them (its compiled kernel, row by row).

        0 where :meth:`step` has no compiled kernel or its last sample was not on the common path. Changes no
        state: :meth:`advance` does, for the rows the caller takes (the block fast path of
        :meth:`rimu.fdi.RedundancyManager.run`)."""
        k = self._kstep
        if k is None or self._dirty or type(active) is not int or active != self._code \
                or Y.dtype != np.float64 or Y.ndim != 2 or Y.shape[1] != self.n:
            return 0
        ok = (np.abs(Y) < self._range).all(axis=1)
        m = len(ok) if ok.all() else int(np.argmin(ok))
        if m and not _kernels().project_block(Y[:m], self._Re, self._offe, self._range, out[:m]):
            return 0  # a non-finite output somewhere: the caller steps sample by sample
        return m

    def advance(self, rows: np.ndarray) -> None:
        """Account for ``len(rows)`` samples taken on the common path (:meth:`common_rows`): the state as after
        stepping them, the result holding the last row's (x, parity)."""
        if len(rows):
            self.samples += len(rows)
            self._out[:] = rows[-1]

    def _step_slow(self, y: np.ndarray, valid: np.ndarray | None) -> StepResult:
        if y.shape != (self.n,):
            raise ShapeError(f"a raw sample must have shape ({self.n},), got {y.shape}")
        good = np.isfinite(y)
        if valid is not None:
            good &= np.asarray(valid, dtype=bool)
        bad = ~good
        sat = np.zeros(self.n, bool)
        if self.range_raw is not None:
            with np.errstate(invalid="ignore"):
                sat = good & (np.abs(y) >= self.range_raw)
        use = good & ~sat
        self.invalid_count += bad
        self.saturated_count += sat
        self._invalid[:] = bad
        self._saturated[:] = sat
        self._dirty = True
        s = self.table.get(mask_bits(use & self._set.active))
        self._point_result(s)
        if (bad.any() or sat.any()) and self.result.validity == Validity.NOMINAL:
            self.result.validity = Validity.DEGRADED
        if not s.observable:
            self._out[:3] = np.nan  # no estimate: the sensors in use do not span 3-D
            self._out[3:] = 0.0
            return self.result
        np.copyto(self._y0, y)
        self._y0[~use] = 0.0
        np.dot(s.R, self._y0, out=self._out)
        self._out -= s.off
        return self.result

    # ------------------------------------------------------------------ blocks (replay)
    def process(self, Y: np.ndarray, valid: np.ndarray | None = None, out: np.ndarray | None = None, *,
                active: np.ndarray | int | None = None) -> BlockResult:
        """Process N samples at once, (N, n), on the sensors ``active`` (as :meth:`step`). Identical to calling
        :meth:`step` on each row.

        ``out`` (N, 3 + r), float64, C-ordered: the buffer the estimates and parity are written into (a stream
        that passes the same buffer every block allocates nothing; the result's ``x`` and ``parity`` are views of
        it, and the result object itself is reused while the set, the length and the buffer stay the same)."""
        self._use(active)
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2 or Y.shape[1] != self.n:
            raise ShapeError(f"a block of raw samples must have shape (N, {self.n}), got {Y.shape}")
        N = Y.shape[0]
        self.samples += N
        n, r, tab = self.n, self.r, self.table
        kk = self._bkey
        keep = out is not None  # a buffer of the caller's: the result is kept for the next block with it
        if out is None or kk is None or out is not kk[2] or kk[1] != N:  # (a buffer checked last block is fine)
            out = _out_buffer(out, N, 3 + r)
        bp = self._bpath if self._bpath is not None else self._block_path()
        if bp:
            if N and (valid is None or np.all(valid)):
                if bp.run((Y,), (out,)) == 0:
                    return self._clean_block(out, keep)
        else:
            in_range = self.range_raw is None or not N or bool(np.all(np.abs(Y) < self.range_raw))
            if N and in_range and (valid is None or np.all(valid)) and self._fast_block(Y, out):
                return self._clean_block(out, keep)
        good = np.isfinite(Y)
        if valid is not None:
            v = np.asarray(valid, dtype=bool)
            if v.shape != Y.shape:
                raise ShapeError(f"valid must have shape {Y.shape}, got {v.shape}")
            good &= v
        bad = ~good
        sat = np.zeros_like(good)
        if self.range_raw is not None:
            with np.errstate(invalid="ignore"):
                sat = good & (np.abs(Y) >= self.range_raw)
        use = good & ~sat
        self.invalid_count += bad.sum(axis=0)
        self.saturated_count += sat.sum(axis=0)
        rows_use = use & self._set.active
        keys = np.packbits(rows_use, axis=1, bitorder="little")
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        entry = np.empty(N, dtype=np.int64)
        dof = np.empty(N, np.int64)
        obs = np.empty(N, bool)
        validity = np.empty(N, np.int8)
        active = np.empty((N, n), bool)
        Y0 = np.where(use, Y, 0.0)
        Ps: dict[int, np.ndarray] = {}
        for u in range(len(uniq)):
            rows = inv == u
            s = tab.get(int.from_bytes(uniq[u].tobytes(), "little"))  # packbits little = bit i is sensor i
            entry[rows] = s.entry
            dof[rows] = s.dof
            obs[rows] = s.observable
            active[rows] = s.active
            validity[rows] = _validity(s, n)
            Ps[s.entry] = s.P if s.observable else _INF_P
            if not s.observable:
                out[rows, :3] = np.nan
                out[rows, 3:] = 0.0
            else:
                out[rows] = Y0[rows] @ s.R.T - s.off
        validity[(bad | sat).any(axis=1) & (validity == Validity.NOMINAL)] = Validity.DEGRADED
        return BlockResult(out[:, :3], out[:, 3:], entry, dof, active, bad, obs, tab, sat, validity, Ps)

    def _block_path(self) -> Any:
        """The compiled block path of this instrument (numba backend and at most ``UNROLL_MAX`` coefficients),
        else False (numpy's chunked product)."""
        self._bpath = False
        if self._kstep is not None:
            kern = _kernels()
            if self.n * (3 + self.r) <= kern.UNROLL_MAX:
                self._bpath = kern.BlockPath([self])
        return self._bpath

    def _clean_block(self, out: np.ndarray, keep: bool = True) -> BlockResult:
        """The result of a block whose every sample took the common path on the current set (the per-sample
        arrays are read-only broadcasts of the set's, kept while the set and the block length stay the same;
        the result itself while the output buffer stays the same too, where ``keep``: a buffer made for this call
        is the caller's alone, so that it is freed when the caller lets go of it, not at the next call)."""
        N, n, cur = out.shape[0], self.n, self._set
        key = self._bkey
        if key is None or key[0] is not cur or key[1] != N:
            self._bviews = (np.broadcast_to(np.int64(cur.entry), (N,)), np.broadcast_to(np.int64(cur.dof), (N,)),
                            np.broadcast_to(cur.active, (N, n)), np.broadcast_to(False, (N, n)),
                            np.broadcast_to(cur.observable, (N,)), np.broadcast_to(np.int8(_validity(cur, n)), (N,)))
            self._bkey = key = (cur, N, None, None)
        elif key[2] is out:
            return key[3]
        e, d, a, no, o, v = self._bviews
        res = BlockResult(out[:, :3], out[:, 3:], e, d, a, no, o, self.table, no, v,
                          {cur.entry: cur.P if cur.observable else _INF_P})
        self._bkey = (cur, N, out, res) if keep else (cur, N, None, None)
        return res

    # ------------------------------------------------------------------ estimates without side effects
    def clipped(self, Y: np.ndarray) -> np.ndarray:
        """Mask of the raw samples Y (..., n) at the range limit, ``|y| >= range_raw`` (False for NaN)."""
        with np.errstate(invalid="ignore"):
            return np.abs(np.asarray(Y, dtype=float)) >= self._range

    def usable(self, Y: np.ndarray, valid: np.ndarray | None = None, clipped: np.ndarray | None = None
               ) -> np.ndarray:
        """Mask (N, n) of the raw samples Y (N, n) that are measurements: finite, flagged valid, and inside the
        range (not :meth:`clipped`, which may be passed when already computed)."""
        Y = np.asarray(Y, dtype=float)
        ok = np.isfinite(Y) & ~(self.clipped(Y) if clipped is None else clipped)
        if valid is not None:
            ok &= np.asarray(valid, dtype=bool)
        return ok

    def estimate(self, Z: np.ndarray, usable: np.ndarray | None = None) -> np.ndarray:
        """MB estimates (N, 3) of compensated outputs Z (N, n), SI, on the active sensors (non-finite entries
        and entries where ``usable`` (N, n) is False excluded per sample, isolated sensors left out), without
        touching counters or state; zero where the remaining sensors are unobservable. The compensation stage
        uses it for the inputs of the effects, with ``usable`` from :meth:`usable` of the raw samples (a value
        flagged invalid or clipped at the range limit must not move the estimate that compensates the others)."""
        Z = np.asarray(Z, dtype=float)
        good = np.isfinite(Z)
        if usable is not None:
            good &= np.asarray(usable, dtype=bool)
        tab = self.table
        if good.all() and self._set.observable:
            return Z @ self._set.G.T
        keys = np.packbits(good & self._set.active, axis=1, bitorder="little")
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        Z0 = np.where(good, Z, 0.0)
        X = np.zeros((Z.shape[0], 3))
        for u in range(len(uniq)):
            s = tab.get(int.from_bytes(uniq[u].tobytes(), "little"))
            if s.observable:
                rows = inv == u
                X[rows] = Z0[rows] @ s.G.T
        return X

    _CHUNK = 8192

    def _fast_block(self, Y: np.ndarray, out: np.ndarray) -> bool:
        """``out = Y @ R.T - off`` in cache-sized chunks; False as soon as a chunk is not finite.

        The offset is subtracted from the flat chunk with a pre-tiled copy (a broadcast over rows of six
        would iterate row by row), and the finiteness check is a flat sum while the chunk is in cache.
        """
        R = self._Re.T
        m = out.shape[1]
        tiled = self._tiled_offset()
        flat = out.reshape(-1)
        C = self._CHUNK
        with np.errstate(invalid="ignore", over="ignore"):
            for a in range(0, Y.shape[0], C):
                np.matmul(Y[a:a + C], R, out=out[a:a + C])
                fo = flat[m * a:m * (a + C)]
                np.subtract(fo, tiled[:fo.size], out=fo)
                s = np.add.reduce(fo)
                if not s - s == 0.0:
                    return False
        return True

    def _tiled_offset(self) -> np.ndarray:
        key = (self._entry, self._CHUNK)
        if getattr(self, "_tiled_key", None) != key:
            self._tiled = np.tile(self._offe, self._CHUNK)
            self._tiled_key = key
        return self._tiled


class Pipeline:
    """The runtime pipeline of a whole unit: compensation of every calibrated effect, then one
    :class:`InstrumentPipeline` per instrument.

    Where the calibration holds further effects (``InstrumentCalibration.effects``: g-sensitivity,
    temperature, nonlinearity, drift, size effect, ...), a compensation stage (:mod:`rimu.fusion.effects`)
    inverts the full calibrated output model before the projection: the accelerometers are compensated and
    projected first and their specific force feeds the gyros' g-sensitivity; the gyros' angular rate feeds
    the accelerometers' size effect (the gyros then go first; where both are present, a two-round fixed point
    between the two instruments gives the gyro rate the size effect uses, see :attr:`cycle_rounds`); temperature effects use the temperature channel; drift uses the time since the stream
    started (``t0``, the first sample's time unless given).

    Parameters
    ----------
    calibration : Calibration
    sigma : dict[str, float or ndarray], optional
        Noise per instrument (SI), overriding the calibration's.
    max_excluded : int, optional
        Deprecated, without effect.
    range_raw : dict[str, float or ndarray], optional
        Range limit per instrument in raw output units, overriding the calibration's ``range_raw``.
    cache_size : int, optional
        Active sets cached per instrument besides the full set (default ``max(64, 2 n)``).
    temperature : bool, optional
        Whether the stream carries the unit temperature. False refuses, when the pipeline is built, a
        calibration with temperature effects; None (default) leaves the check to each sample.
    t0 : float, optional
        Time of switch-on (the origin of the drift), s; default the first sample's time.
    backend : {"auto", "numpy", "numba"}, optional
        Implementation (:mod:`rimu.fusion.backend`): numba compiles the whole epoch -- every effect's
        compensation, the fixed point between the instruments and the projections -- into one call per epoch
        (per block in :meth:`process`); default ``RIMU_BACKEND``, else ``"auto"`` (numba where installed). Same
        numbers either way; samples off the common path (invalid, saturated, non-finite) take the numpy path.

    Raises
    ------
    MissingInputError
        An effect needs an input the stream does not carry (temperature declared absent, or the other
        instrument not calibrated); the message names the effect and the input.
    NotCompensableError
        The calibration holds an effect without runtime compensation.
    """

    def __init__(self, calibration: Calibration, sigma: dict[str, Any] | None = None,
                 max_excluded: int | None = None, range_raw: dict[str, Any] | None = None,
                 cache_size: int | None = None, *, temperature: bool | None = None,
                 t0: float | None = None, backend: str | None = None) -> None:
        sigma = sigma or {}
        range_raw = range_raw or {}
        self.calibration = calibration
        #: ``"numpy"`` or ``"numba"``
        self.backend = resolve_backend(backend)
        self.instruments = {k: InstrumentPipeline(calibration[k], sigma.get(k), max_excluded, range_raw.get(k),
                                                  cache_size, backend=self.backend)
                            for k in calibration.instruments}
        meta = calibration.metadata or {}
        self._t_ref = float(meta.get("reference_temperature", 25.0))
        comps = {k: EffectCompensation(calibration[k], self._t_ref) for k in calibration.instruments}
        #: compensation stage per instrument with further effects
        self.compensation: dict[str, EffectCompensation] = {k: c for k, c in comps.items() if c}
        self._generic = any(c.has_generic for c in self.compensation.values())
        self._estimators = {k: (lambda q, p=self.instruments[k]: p.estimate(q[None])[0]) for k in self.compensation}
        self.t0 = t0
        provided = {"time", "specific_force" if "accel" in self.instruments else "", "angular_rate"
                    if "gyro" in self.instruments else ""}
        if temperature:
            provided.add("temperature")
        for k, c in self.compensation.items():
            for need in c.needs:
                if need in provided or (need == "temperature" and temperature is None):
                    continue
                eff = c.effects_needing(need)[0]
                why = {"temperature": "the stream carries no temperature channel",
                       "specific_force": "the calibration has no accelerometers to give it",
                       "angular_rate": "the calibration has no gyros to give it"}[need]
                fix = {"temperature": "record the temperature with the data (or recalibrate without "
                                      f"{eff!r}, which drops the effect)",
                       "specific_force": f"calibrate the accelerometers too (a calibration of gyro and accel, so "
                                         f"that {eff!r} is compensated), or pass them the specific force",
                       "angular_rate": f"calibrate the gyros too (a calibration of accel and gyro, so that "
                                       f"{eff!r} is compensated), or pass them the angular rate"}[need]
                raise MissingInputError(f"{k} effect {eff!r} needs the {need.replace('_', ' ')}, and {why}; {fix}",
                                        eff, need)
        acc, gyr = self.compensation.get("accel"), self.compensation.get("gyro")
        acc_needs_w = bool(acc) and "angular_rate" in acc.needs
        gyr_needs_f = bool(gyr) and "specific_force" in gyr.needs
        self._cyclic = acc_needs_w and gyr_needs_f
        first = ("gyro", "accel") if acc_needs_w and not gyr_needs_f else ("accel", "gyro")
        self._order = [k for k in first if k in self.instruments]
        #: the compiled compensation stage (numba backend, every effect with a compiled form)
        self._program = None
        if (self.backend == "numba" and self.compensation and not self._generic
                and set(self._order) == set(self.instruments)):
            kern = _kernels()
            self._program = kern.Program([(k, self.compensation.get(k), self.instruments[k]) for k in self._order],
                                         self._cyclic, self.cycle_rounds)
            self._epoch_step, self._epoch_block = kern.epoch_step, kern.epoch_block
            self._results = {k: p.result for k, p in self.instruments.items()}  # StepResults are reused
        self._bpath: Any = None  # the compiled block path of a unit without compensation stage, made on first use
        self._keys = tuple(self.instruments)

    def __getitem__(self, instrument: str) -> InstrumentPipeline:
        return self.instruments[instrument]

    # ------------------------------------------------------------------ compensation stage
    #: rounds of the gyro <-> accelerometer fixed point where g-sensitivity and size effect are both present
    cycle_rounds = 2

    def _preliminary_rate(self, solve: Any, zeros: Any) -> Any:
        """Gyro estimate for the accelerometers' size effect when the gyros need the specific force too: a fixed
        point started from the accelerometers with zero rate (no size effect). Each round shrinks the error by
        the loop gain (size-effect slope 2|w||r| times the g-sensitivity, ~1e-5); two rounds leave ~1e-12.
        ``solve(k, f, w)`` is the MB estimate of instrument k given the other inputs."""
        f = solve("accel", None, zeros)
        w = solve("gyro", f, None)
        for _ in range(self.cycle_rounds - 1):
            f = solve("accel", None, w)
            w = solve("gyro", f, None)
        return w

    @property
    def compiled(self) -> bool:
        """Whether the compensation stage runs compiled (numba backend, every effect with a compiled form)."""
        return self._program is not None

    @property
    def order(self) -> list[str]:
        """The instruments in the order the compensation stage steps them (the first one's estimate feeds the
        second one's effects)."""
        return list(self._order)

    def _use(self, active: dict[str, Any] | None) -> None:
        """Each instrument pipeline on its set of ``active`` (instrument -> mask or set code; absent: every
        sensor)."""
        for k, ip in self.instruments.items():
            a = None if active is None else active.get(k)
            if a is not None or ip._code != ip._full:
                ip._use(a)

    def compensate(self, block: EpochBlock, active: dict[str, Any] | None = None) -> EpochBlock:
        """The block with every further effect removed from the raw outputs (an ideal SF/M/B unit's raw data),
        for FDI managers and anything else built on :class:`InstrumentPipeline`. Equal to what
        :meth:`process` feeds its instrument pipelines. No counter changes."""
        raw, _ = self.compensate_block(block, active)
        return EpochBlock(block.t, raw, dict(block.valid), block.temperature, dict(block.meta))

    def compensate_block(self, block: EpochBlock, active: dict[str, Any] | None = None
                         ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """The compensated raw outputs of ``block`` on the sets ``active`` and each compensated instrument's
        estimate (what fed the next instrument's effects), without touching any counter: a look ahead for
        :class:`rimu.fdi.Runtime`, which steps the epochs through its managers afterwards."""
        self._use(active)
        saved = {k: (p.samples, p.invalid_count.copy(), p.saturated_count.copy()) for k, p in self.instruments.items()}
        try:
            raw, res = self._compensate_block(block, True)
        finally:  # a look ahead: the counters count the samples stepped, not the ones looked at
            for k, (n, inv, sat) in saved.items():
                p = self.instruments[k]
                p.samples, p.invalid_count, p.saturated_count = n, inv, sat
        return raw, {k: np.asarray(r.x) for k, r in res.items()}

    def _compensate_block(self, block: EpochBlock, want_raw: bool = True, out: dict[str, np.ndarray] | None = None
                          ) -> tuple[dict[str, np.ndarray], dict[str, BlockResult]]:
        outb = out or {}  # output buffers (process's out=)
        if self._program is not None:
            done = self._compensate_block_compiled(block, want_raw, outb)
            if done is not None:
                return done
        out = dict(block.raw)
        results: dict[str, BlockResult] = {}
        if not self.compensation:
            return out, results
        temp = self._origin(block.temperature, float(block.t[0]) if len(block) else None)
        t = block.t - self.t0

        ests, clipped = {}, {}
        for k in self.compensation:
            ip = self.instruments[k]
            clipped[k] = ip.clipped(block.raw[k])
            use = ip.usable(block.raw[k], block.valid.get(k), clipped[k])
            ests[k] = ip.estimate if use.all() else (lambda q, ip=ip, use=use: ip.estimate(q, use))

        def solve(k: str, f: np.ndarray | None, w: np.ndarray | None) -> np.ndarray:
            inputs = RuntimeInputs(t=t, temperature=temp, specific_force=f, angular_rate=w)
            return self.compensation[k].solve(block.raw[k], inputs, estimate=ests[k])

        f = w = None
        if self._cyclic:
            w = self._preliminary_rate(lambda k, f_, w_: ests[k](solve(k, f_, w_)), np.zeros((len(block), 3)))
        for k in self._order:
            comp = self.compensation.get(k)
            if comp is not None:
                out[k] = comp.raw(block.raw[k], RuntimeInputs(t=t, temperature=temp, specific_force=f, angular_rate=w),
                                  ests[k])
                if clipped[k].any():  # a clipped output stays clipped: the projection routes around it
                    out[k] = np.where(clipped[k], block.raw[k], out[k])
            res = self.instruments[k].process(out[k], block.valid.get(k), outb.get(k), active=self.instruments[k]._code)
            results[k] = res
            # the next instrument's effects take the estimate; where there is none, zero (no input)
            x_feed = np.asarray(res.x) if np.all(res.observable) else np.where(
                np.asarray(res.observable)[:, None], res.x, 0.0)
            if k == "accel":
                f = x_feed
            else:
                w = x_feed
        return out, results

    def _program_ready(self) -> Any:
        """The compiled program with the current active sets and rounds."""
        prog = self._program
        prog.L[2] = prog.rounds = self.cycle_rounds
        if prog.changed():
            prog.refresh()
        return prog

    def _compensate_block_compiled(self, block: EpochBlock, want_raw: bool, outb: dict[str, np.ndarray]
                                   ) -> tuple[dict[str, np.ndarray], dict[str, BlockResult]] | None:
        """:meth:`_compensate_block` in one compiled call; None (nothing changed) when a sample is off the common
        path, for the numpy path to do the whole block."""
        N = len(block)
        if not N or any(not np.all(v) for v in block.valid.values()):
            return None
        for k in self._order:  # a clipped raw value is judged before compensation: the numpy path routes it
            ip = self.instruments[k]
            if ip.range_raw is not None and ip.clipped(block.raw[k]).any():
                return None
        temp = self._origin(block.temperature, float(block.t[0]) if len(block) else None)
        t = block.t - self.t0
        dT = np.zeros(N) if temp is None else np.asarray(temp, dtype=float) - self._t_ref
        prog = self._program_ready()
        order = self._order
        Ys = [np.ascontiguousarray(block.raw[k], dtype=float) for k in order]
        if any(Y.ndim != 2 or Y.shape[1] != self.instruments[k].n for k, Y in zip(order, Ys)):
            return None
        outs = [_out_buffer(outb.get(k), N, 3 + self.instruments[k].r) for k in order]
        raws = [np.empty((N, self.instruments[k].n) if want_raw else (1, 1)) for k in order]
        row = self._epoch_block(prog.F, prog.L, prog.W, Ys[0], Ys[-1], t, dT, outs[0], outs[-1], raws[0], raws[-1],
                                want_raw)
        if row >= 0:
            return None
        raw = dict(block.raw)
        results: dict[str, BlockResult] = {}
        for j, k in enumerate(order):
            p = self.instruments[k]
            p.samples += N
            results[k] = p._clean_block(outs[j])
            if want_raw and k in self.compensation:
                raw[k] = raws[j]
        return raw, results

    def _step_compiled(self, epoch: Epoch) -> dict[str, StepResult] | None:
        """:meth:`step` in one compiled call; None (nothing changed) when the epoch is off the common path."""
        valid = epoch.valid
        if valid:
            for v in valid.values():
                if not v.all():
                    return None
        T = epoch.temperature
        if T is None or self.t0 is None:
            self._origin(T, float(epoch.t))
        prog = self._program
        pipes = prog.pipes
        p0, p1 = pipes[0], pipes[-1]
        if p0._set is not prog._sets[0] or p1._set is not prog._sets[-1] or prog.rounds != self.cycle_rounds:
            self._program_ready()
        raw = epoch.raw
        order = self._order
        y0 = raw[order[0]]
        y1 = raw[order[-1]]
        if type(y0) is not _NDARRAY or type(y1) is not _NDARRAY:
            return None
        # a clipped raw value is judged before compensation: the numpy path routes it
        if (p0.range_raw is not None and p0.clipped(y0).any()) or (p1.range_raw is not None and p1.clipped(y1).any()):
            return None
        try:
            ok = self._epoch_step(prog.F, prog.L, prog.W, y0, y1, float(epoch.t) - self.t0,
                                  0.0 if T is None else float(T) - self._t_ref, p0._out, p1._out)
        except Exception:  # an array the kernel cannot type (2-D, object): the numpy path says what is wrong
            return None
        if not ok:
            return None
        for p in pipes:
            p.samples += 1
            if p._dirty:
                p._clean()
        return self._results.copy()

    def _origin(self, temperature: Any, t_first: float | None) -> Any:
        """Check that a temperature comes when the effects need one, and set the time origin (the start of
        drift) at the first sample seen; returns the temperature."""
        if temperature is None:
            self._need_temperature(False)
        if self.t0 is None and t_first is not None:
            self.t0 = t_first
        return temperature

    def _need_temperature(self, present: bool) -> None:
        if present:
            return
        for k, c in self.compensation.items():
            if "temperature" in c.needs:
                eff = c.effects_needing("temperature")[0]
                raise MissingInputError(f"{k} effect {eff!r} needs the temperature, and the data carry none; "
                                        "record the temperature with the data (recalibrating without it would drop the effect)",
                                        eff, "temperature")

    # ------------------------------------------------------------------ run
    def step(self, epoch: Epoch, active: dict[str, Any] | None = None) -> dict[str, StepResult]:
        """One epoch through the compensation stage and every instrument's pipeline, on the sensor sets
        ``active`` (instrument -> mask or set code; absent: every sensor)."""
        self._use(active)
        if not self.compensation:
            return {k: p.step(epoch.raw[k], epoch.valid.get(k), p._code) for k, p in self.instruments.items()}
        if self._program is not None:
            res_c = self._step_compiled(epoch)
            if res_c is not None:
                return res_c
        ins = self.instruments
        return self._step_numpy(epoch, lambda k, y, valid: ins[k].step(y, valid, ins[k]._code))

    def step_through(self, epoch: Epoch, step: Any, active: dict[str, Any] | None = None) -> dict[str, Any]:
        """One epoch through the compensation stage, each instrument's step done by ``step``.

        ``step(instrument, y, valid)`` gets the instrument's raw outputs with every further effect removed
        (an ideal SF/M/B unit's raw data; a clipped output stays as it came), in the pipeline's order, and
        returns a result whose ``x`` (3,) is the instrument's estimate of the epoch: that estimate is the input
        of the next instrument's effects (the specific force of the gyros' g-sensitivity, the rate of the
        accelerometers' size effect). The estimates inside the compensation use the non-isolated, usable
        sensors of each instrument pipeline. :meth:`step` is ``step_through`` with the instrument pipelines'
        own steps; :class:`rimu.fdi.UnitManager` passes its redundancy managers' steps, so that the
        compensation, the isolation set and the estimate feeding the other instrument are those of the
        managers (as the exported C's ``rimu_fdi_step``). ``active`` as in :meth:`step`: the sets the
        compensation's estimates use. Returns ``{instrument: step's result}``.
        """
        self._use(active)
        if not self.compensation:
            return {k: step(k, epoch.raw[k], epoch.valid.get(k)) for k in self.instruments}
        return self._step_numpy(epoch, step)

    def _step_numpy(self, epoch: Epoch, step: Any) -> dict[str, Any]:
        T = self._origin(epoch.temperature, float(epoch.t))
        t = float(epoch.t) - self.t0
        dT = 0.0 if T is None else float(T) - self._t_ref
        generic = self._generic
        comps = self.compensation

        ests, clips = {}, {}
        for k in comps:
            ip = self.instruments[k]
            y0 = np.asarray(epoch.raw[k], dtype=float)
            clips[k] = ip.clipped(y0)
            use = ip.usable(y0[None], None if epoch.valid.get(k) is None else np.asarray(epoch.valid[k])[None],
                            clips[k][None])
            ests[k] = self._estimators[k] if use.all() else (lambda q, ip=ip, use=use: ip.estimate(q[None], use)[0])

        def solve_q(k: str, f: list[float] | None, w: list[float] | None, raw: bool = False) -> np.ndarray:
            y = np.asarray(epoch.raw[k], dtype=float)
            inputs = None
            if generic:
                inputs = RuntimeInputs(np.array([t]), None, None if T is None else np.array([float(T)]),
                                       None if f is None else np.array([f]), None if w is None else np.array([w]))
                comps[k]._check(inputs)
            mono = _monomials_one(t, dT, f, w)
            est = ests[k]
            if raw:
                return comps[k].raw_one(y, mono, inputs, est)
            return comps[k].solve_one(y, mono, inputs, est)

        f = w = None
        if self._cyclic:
            w = self._preliminary_rate(lambda k, f_, w_: np.asarray(ests[k](solve_q(k, f_, w_))).tolist(),
                                       [0.0, 0.0, 0.0])
        res: dict[str, Any] = {}
        for k in self._order:
            comp = comps.get(k)
            y = epoch.raw[k] if comp is None else solve_q(k, f, w, raw=True)
            if comp is not None and clips[k].any():  # a clipped output stays clipped: the projection routes it
                y = np.where(clips[k], np.asarray(epoch.raw[k], dtype=float), y)
            r = step(k, y, epoch.valid.get(k))
            res[k] = r
            x_feed = r.x.tolist() if r.observable else [0.0, 0.0, 0.0]  # no estimate: no input to the effects
            if k == "accel":
                f = x_feed
            else:
                w = x_feed
        return {k: res[k] for k in self.instruments}

    def process(self, block: EpochBlock, out: dict[str, np.ndarray] | None = None, *,
                active: dict[str, Any] | None = None) -> dict[str, BlockResult]:
        """N epochs at once on the sets ``active`` (as :meth:`step`); the same numbers as :meth:`step` on each
        epoch.

        ``out``: per instrument, the buffer of :meth:`InstrumentPipeline.process` (a stream that passes the same
        buffers every block allocates nothing)."""
        if not self.compensation:
            if self._bpath is not False:  # compiled: every instrument in one call
                res = self._process_compiled(block, out, active)
                if res is not None:
                    return res
            self._use(active)
            out = out or {}
            return {k: p.process(block.raw[k], block.valid.get(k), out.get(k), active=p._code)
                    for k, p in self.instruments.items()}
        self._use(active)
        _, results = self._compensate_block(block, want_raw=False, out=out)
        return {k: results[k] for k in self.instruments}

    def _block_path(self) -> Any:
        """The compiled block path of the unit (:class:`rimu.fusion._kernels.BlockPath`), else False."""
        self._bpath = False
        pipes = list(self.instruments.values())
        if self.backend == "numba" and 1 <= len(pipes) <= 2:
            kern = _kernels()
            if all(p.n * (3 + p.r) <= kern.UNROLL_MAX for p in pipes):
                self._bpath = kern.BlockPath(pipes)
                self._bslots = tuple(zip(self._keys, pipes, [3 + p.r for p in pipes]))
        return self._bpath

    def _process_compiled(self, block: EpochBlock, out: dict[str, np.ndarray] | None, active: dict[str, Any] | None
                          ) -> dict[str, BlockResult] | None:
        """:meth:`process` of a unit without a compensation stage in one compiled call
        (:class:`rimu.fusion._kernels.BlockPath`); None when a sample is off the common path.

        The per-call work in Python is kept to what the kernel cannot do: the shapes, the dtype, the layout and the
        finiteness are the kernel's checks (its signature and its return code), the output buffers are checked when
        they change, and the result objects are reused while the sets, the length and the buffers stay."""
        bp = self._bpath
        if bp is None:
            bp = self._block_path()
            if not bp:
                return None
        if active is not None:
            self._use(active)
        valid = block.valid
        if valid and not all(np.all(v) for v in valid.values()):
            return None
        raw = block.raw
        slots = self._bslots
        if out is not None and len(slots) == 2:  # a stream's steady state: a unit's two instruments, their buffers
            (k0, p0, _), (k1, p1, _) = slots
            o0, o1 = out.get(k0), out.get(k1)
            kk0, kk1 = p0._bkey, p1._bkey
            if kk0 is not None and kk1 is not None and o0 is kk0[2] and o1 is kk1[2] and o0 is not None \
                    and o1 is not None:
                if active is None and (p0._code != p0._full or p1._code != p1._full):
                    self._use(None)
                st = bp.sets
                if p0._set is not st[0] or p1._set is not st[1]:
                    bp.pack()
                try:
                    code = bp.kernel(raw[k0], raw[k1], bp.P, o0, o1)
                except TypeError:  # a block the kernel does not take as it is: converted
                    code = bp.run([raw[k0], raw[k1]], [o0, o1])
                if code:
                    return None
                N = o0.shape[0]
                p0.samples += N
                p1.samples += N
                return {k0: kk0[3] if kk0[0] is p0._set and kk0[1] == N else p0._clean_block(o0),
                        k1: kk1[3] if kk1[0] is p1._set and kk1[1] == N else p1._clean_block(o1)}
        Ys, outs, kept = [], [], []
        for k, p, m in slots:
            if p._code != p._full and active is None:
                p._use(None)
            Y = raw[k]
            Ys.append(Y)
            o = None if out is None else out.get(k)
            kept.append(o is not None)
            kk = p._bkey
            if o is None or kk is None or o is not kk[2]:  # a buffer checked at an earlier block is fine
                N = Y.shape[0] if hasattr(Y, "shape") and len(Y.shape) == 2 else -1
                if N < 1:
                    return None
                o = _out_buffer(o, N, m)
            outs.append(o)
        if bp.run(Ys, outs):  # off the common path (or shapes that disagree: the numpy path says what is wrong)
            return None
        N = outs[0].shape[0]
        res = {}
        for (k, p, _), o, keep in zip(slots, outs, kept):
            p.samples += N
            kk = p._bkey
            res[k] = kk[3] if kk is not None and kk[2] is o and kk[0] is p._set and kk[1] == N else \
                p._clean_block(o, keep)
        return res
