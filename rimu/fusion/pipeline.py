"""The runtime pipeline: raw samples in, MB-frame estimate, covariance and parity vector out.

Per sample, for one instrument (gyros or accelerometers)::

    z = SF * y - B                       compensation (Cho & Park Eq. 20, inner part)
    x = G z,  P = (A^T W^2 A)^-1         projection to MB on the active sensors
    p = V_w W z                          normalised parity (de Oliveira Eq. 11), cov(p) = I

with A the calibrated axes (rows of M H). Everything that depends on which sensors are active is in a
:class:`~rimu.fusion.projection.ProjectionTable` built once; SF and B are folded into it, so the per-sample
work is one small matrix-vector product into a preallocated buffer and one finiteness check. A non-finite
raw value marks that sensor invalid for that sample (counted in ``invalid_count``) and the estimate uses the
rest; outputs never contain NaN (an unobservable sample gives x = 0, P = inf, ``observable = False``).

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

from ..calibration.result import Calibration, InstrumentCalibration
from ..epoch import Epoch, EpochBlock
from ..errors import ShapeError
from .projection import ProjectionTable, mask_bits

__all__ = ["InstrumentPipeline", "Pipeline", "StepResult", "BlockResult"]


@dataclass
class StepResult:
    """Output of one :meth:`InstrumentPipeline.step` (the same object is reused: copy what you keep).

    Attributes
    ----------
    x : ndarray (3,)
        Estimate in MB, SI units.
    P : ndarray (3, 3)
        Its covariance.
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
        Index in the projection table.
    """

    x: np.ndarray
    P: np.ndarray
    parity: np.ndarray
    dof: int
    active: np.ndarray
    invalid: np.ndarray
    observable: bool
    entry: int


@dataclass
class BlockResult:
    """Output of :meth:`InstrumentPipeline.process` for N samples."""

    x: np.ndarray
    parity: np.ndarray
    entry: np.ndarray
    dof: np.ndarray
    active: np.ndarray
    invalid: np.ndarray
    observable: np.ndarray
    table: ProjectionTable = field(repr=False)

    def covariance(self) -> np.ndarray:
        """Estimate covariance per sample, (N, 3, 3)."""
        return self.table.P[self.entry]

    def __len__(self) -> int:
        return int(self.x.shape[0])


class InstrumentPipeline:
    """Compensation, projection and parity for one instrument kind.

    Parameters
    ----------
    calibration : InstrumentCalibration
    sigma : float or ndarray (n,), optional
        Per-sample noise standard deviation of the compensated outputs, SI. Default: the calibration's
        ``noise_sigma``; without one, 1.0 (covariances are then in units of sigma^2).
    max_excluded : int, optional
        Precompute exclusion sets up to this size (default n - 3).

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.5, noise_sigma=0.001)
    >>> pipe = InstrumentPipeline(cal)
    >>> y = cal.raw_output(np.array([0.1, -0.2, 0.3]))
    >>> np.round(pipe.step(y).x, 12).tolist()
    [0.1, -0.2, 0.3]
    """

    def __init__(
        self,
        calibration: InstrumentCalibration,
        sigma: float | np.ndarray | None = None,
        max_excluded: int | None = None,
    ) -> None:
        self.calibration = calibration
        n = calibration.geometry.n
        #: True when the noise came from ``sigma`` or the calibration's ``noise_sigma``, False when 1.0 was assumed
        self.noise_given = sigma is not None or calibration.noise_sigma is not None
        if sigma is None:
            sigma = calibration.noise_sigma if calibration.noise_sigma is not None else 1.0
        self.table = ProjectionTable(calibration.axes_mb(), sigma, max_excluded)
        K = np.concatenate([self.table.G, self.table.Vz], axis=1)  # (K, n, n): outputs x then parity
        self._R = np.ascontiguousarray(K * calibration.scale[None, None, :])
        self._off = np.ascontiguousarray(K @ calibration.bias)
        self.n = n
        self.r = max(n - 3, 0)
        self.invalid_count = np.zeros(n, dtype=np.int64)
        self.samples = 0
        self._isolated = np.zeros(n, dtype=bool)
        self._out = np.zeros(3 + self.r)
        self._y0 = np.zeros(n)
        self._invalid = np.zeros(n, dtype=bool)
        self._dirty = False
        self.result = StepResult(self._out[:3], self.table.P[0], self._out[3:], 0, np.ones(n, bool),
                                 self._invalid, True, 0)
        self._select(self.table.full_code)

    # ------------------------------------------------------------------ isolation (Cho & Park Eq. 21)
    @property
    def isolated(self) -> np.ndarray:
        """Sensors currently excluded (copy)."""
        return self._isolated.copy()

    def _check_index(self, i: int) -> int:
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)) or not 0 <= i < self.n:
            raise IndexError(f"sensor index must be an integer in 0..{self.n - 1}, got {i!r}")
        return int(i)

    def isolate(self, i: int) -> None:
        """Exclude sensor ``i`` from now on (Cho & Park Eq. 21: its row of H and its output set to zero)."""
        i = self._check_index(i)
        self._isolated[i] = True
        self._select(mask_bits(~self._isolated))

    def readmit(self, i: int) -> None:
        """Bring sensor ``i`` back."""
        i = self._check_index(i)
        self._isolated[i] = False
        self._select(mask_bits(~self._isolated))

    def set_isolated(self, mask: np.ndarray) -> None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != (self.n,):
            raise ShapeError(f"isolation mask must have shape ({self.n},), got {m.shape}")
        self._isolated[:] = m
        self._select(mask_bits(~m))

    def _select(self, code: int) -> None:
        e = self.table.lookup(code)
        self._entry = e
        if e >= 0:
            self._Re = self._R[e]
            self._offe = self._off[e]
        self._point_result(e)

    def _point_result(self, e: int) -> None:
        res = self.result
        res.entry = e
        if e < 0 or not self.table.observable[e]:
            res.P = np.diag([np.inf] * 3)
            res.dof = 0
            res.observable = False
            res.active = np.zeros(self.n, bool) if e < 0 else self._active_of(e)
        else:
            res.P = self.table.P[e]
            res.dof = int(self.table.dof[e])
            res.observable = True
            res.active = self._active_of(e)

    def _active_of(self, e: int) -> np.ndarray:
        return ((int(self.table.codes[e]) >> np.arange(self.n)) & 1).astype(bool)

    # ------------------------------------------------------------------ per sample
    def step(self, y: np.ndarray, valid: np.ndarray | None = None) -> StepResult:
        """Process one raw sample ``y`` (n,). Returns :attr:`result` (reused; copy what you keep)."""
        self.samples += 1
        if self._entry >= 0 and (valid is None or valid.all()):
            try:
                yl = y.tolist()
            except AttributeError:  # not an ndarray: the careful path converts and checks it
                yl = None
            if yl is not None and len(yl) == self.n:
                s = sum(yl)  # Python floats: inf and nan propagate without floating-point warnings
                if s - s == 0.0:
                    out = self._out
                    np.dot(self._Re, y, out=out)
                    out -= self._offe
                    s = sum(out.tolist())
                    if s - s == 0.0:  # finite: the common path
                        if self._dirty:
                            self._invalid[:] = False
                            self._point_result(self._entry)
                            self._dirty = False
                        return self.result
        return self._step_slow(np.asarray(y, dtype=float), valid)

    def _step_slow(self, y: np.ndarray, valid: np.ndarray | None) -> StepResult:
        if y.shape != (self.n,):
            raise ShapeError(f"a raw sample must have shape ({self.n},), got {y.shape}")
        good = np.isfinite(y)
        if valid is not None:
            good &= np.asarray(valid, dtype=bool)
        bad = ~good
        self.invalid_count += bad
        self._invalid[:] = bad
        self._dirty = True
        e = self.table.lookup(mask_bits(good & ~self._isolated))
        self._point_result(e)
        if e < 0 or not self.table.observable[e]:
            self._out[:] = 0.0
            return self.result
        np.copyto(self._y0, y)
        self._y0[bad] = 0.0
        np.dot(self._R[e], self._y0, out=self._out)
        self._out -= self._off[e]
        return self.result

    # ------------------------------------------------------------------ blocks (replay)
    def process(self, Y: np.ndarray, valid: np.ndarray | None = None) -> BlockResult:
        """Process N samples at once, (N, n). Identical to calling :meth:`step` on each row."""
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2 or Y.shape[1] != self.n:
            raise ShapeError(f"a block of raw samples must have shape (N, {self.n}), got {Y.shape}")
        N = Y.shape[0]
        self.samples += N
        n, r, tab = self.n, self.r, self.table
        out = np.empty((N, 3 + r))
        if self._entry >= 0 and N and (valid is None or np.all(valid)):
            if self._fast_block(Y, out):
                e = self._entry
                return BlockResult(out[:, :3], out[:, 3:], np.broadcast_to(np.int64(e), (N,)),
                                   np.broadcast_to(tab.dof[e], (N,)), np.broadcast_to(self._active_of(e), (N, n)),
                                   np.broadcast_to(False, (N, n)), np.broadcast_to(bool(tab.observable[e]), (N,)), tab)
        good = np.isfinite(Y)
        if valid is not None:
            v = np.asarray(valid, dtype=bool)
            if v.shape != Y.shape:
                raise ShapeError(f"valid must have shape {Y.shape}, got {v.shape}")
            good &= v
        bad = ~good
        self.invalid_count += bad.sum(axis=0)
        codes = (good & ~self._isolated).astype(np.int64) @ (1 << np.arange(n, dtype=np.int64))
        entry = np.full(N, -1, dtype=np.int64)
        Y0 = np.where(good, Y, 0.0)
        for code in np.unique(codes):
            rows = codes == code
            e = tab.lookup(int(code))
            entry[rows] = e
            if e < 0 or not tab.observable[e]:
                out[rows] = 0.0
            else:
                out[rows] = Y0[rows] @ self._R[e].T - self._off[e]
        ok = entry >= 0
        obs = np.zeros(N, bool)
        obs[ok] = tab.observable[entry[ok]]
        dof = np.zeros(N, np.int64)
        dof[ok] = tab.dof[entry[ok]]
        active = np.zeros((N, n), bool)
        active[ok] = ((tab.codes[entry[ok]][:, None] >> np.arange(n)) & 1).astype(bool)
        # unobservable samples point at a covariance of inf through a sentinel entry
        ent = entry.copy()
        if not np.all(obs):
            ent[~obs] = self._inf_entry()
        return BlockResult(out[:, :3], out[:, 3:], ent, dof, active, bad, obs, tab)

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

    def _inf_entry(self) -> int:
        """Index of a table entry whose P is inf (an unobservable set), added on first use."""
        idx = np.flatnonzero(~self.table.observable)
        if idx.size:
            return int(idx[0])
        tab = self.table
        tab.G = np.concatenate([tab.G, np.zeros((1,) + tab.G.shape[1:])])
        tab.Vz = np.concatenate([tab.Vz, np.zeros((1,) + tab.Vz.shape[1:])])
        tab.P = np.concatenate([tab.P, np.diag([np.inf] * 3)[None]])
        tab.dof = np.append(tab.dof, 0)
        tab.observable = np.append(tab.observable, False)
        tab.codes = np.append(tab.codes, -1)
        return len(tab.codes) - 1


class Pipeline:
    """The runtime pipeline of a whole unit: one :class:`InstrumentPipeline` per instrument.

    Parameters
    ----------
    calibration : Calibration
    sigma : dict[str, float or ndarray], optional
        Noise per instrument (SI), overriding the calibration's.
    """

    def __init__(self, calibration: Calibration, sigma: dict[str, Any] | None = None,
                 max_excluded: int | None = None) -> None:
        sigma = sigma or {}
        self.calibration = calibration
        self.instruments = {k: InstrumentPipeline(calibration[k], sigma.get(k), max_excluded)
                            for k in calibration.instruments}

    def __getitem__(self, instrument: str) -> InstrumentPipeline:
        return self.instruments[instrument]

    def step(self, epoch: Epoch) -> dict[str, StepResult]:
        """One epoch through every instrument's pipeline."""
        return {k: p.step(epoch.raw[k], epoch.valid.get(k)) for k, p in self.instruments.items()}

    def process(self, block: EpochBlock) -> dict[str, BlockResult]:
        return {k: p.process(block.raw[k], block.valid.get(k)) for k, p in self.instruments.items()}
