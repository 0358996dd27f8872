"""Redundancy management of a whole unit, closed loop with the compensation of every further effect.

A :class:`rimu.fdi.RedundancyManager` decides on the raw outputs of one instrument as its
:class:`rimu.fusion.InstrumentPipeline` sees them: ``z = SF y - b``. Where the calibration holds further effects
(temperature, drift, g-sensitivity, nonlinearity, cross coupling, size effect: :mod:`rimu.fusion.effects`), the
outputs the managers decide on must be those effects' compensation, epoch by epoch, with the managers in the loop:

* the compensation's own estimates (the cross coupling's input, the preliminary rounds of the gyro <->
  accelerometer fixed point) use the sensors each manager keeps in (not the ones it isolated);
* the estimate that feeds the next instrument's effects (the specific force of the gyros' g-sensitivity, the
  angular rate of the accelerometers' size effect) is the manager's output for the epoch;
* an isolated sensor's re-admission test compares its compensated output, not its raw one, with the estimate of
  the others (a sensor with a large temperature effect would otherwise look faulty for as long as the
  temperature is away from the reference, or healthy while its fault and its effect cancel).

:class:`UnitManager` does exactly that, with :meth:`rimu.fusion.Pipeline.step_through`; it is what the
exported C's ``rimu_fdi_step`` does (:mod:`rimu.export.c_fdi`, :mod:`rimu.export.c_effects`), decision for
decision. Without further effects it is one manager per instrument stepped on the raw outputs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from ..errors import ShapeError
from ..fusion import Pipeline
from .manager import FdiResult, RedundancyManager, ReplayResult, _Collector

__all__ = ["UnitManager"]

#: epochs of the first run after an isolation set changed (runs then double up to ``chunk``)
_RESTART = 64


class UnitManager:
    """One :class:`RedundancyManager` per instrument of a :class:`rimu.fusion.Pipeline`, run epoch by epoch through
    the pipeline's compensation of further effects (see the module docstring).

    Parameters
    ----------
    pipeline : Pipeline
        The unit's runtime (its calibration, compensation stage and instrument pipelines).
    managers : dict[str, RedundancyManager], optional
        Managers built on ``pipeline``'s own instrument pipelines (``pipeline[k]``); default
        :meth:`RedundancyManager.for_unit` with ``**settings``.
    **settings
        Keyword arguments of :class:`RedundancyManager` for the default managers.

    Examples
    --------
    >>> from rimu.calibration import Calibration, InstrumentCalibration
    >>> from rimu.geometry import cone6
    >>> cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)})
    >>> um = UnitManager(Pipeline(cal), confirm=3)
    >>> y = cal["gyro"].raw_output(np.array([0.1, 0.2, 0.3]))
    >>> for k in range(6):
    ...     y_k = y.copy()
    ...     y_k[4] += 0.5 if k >= 2 else 0.0      # 50 sigma on y2 from the third epoch
    ...     r = um.step(Epoch(0.01 * k, {"gyro": y_k}))
    >>> um.managers["gyro"].health.isolated, r["gyro"].validity.name
    (['y2'], 'DEGRADED')
    """

    def __init__(self, pipeline: Pipeline, managers: dict[str, RedundancyManager] | None = None,
                 **settings: Any) -> None:
        if managers is None:
            managers = RedundancyManager.for_unit(pipeline, **settings)
        elif settings:
            raise TypeError(f"settings {sorted(settings)} are for the default managers; the given managers have "
                            "their own")
        if set(managers) != set(pipeline.instruments):
            raise ShapeError(f"one manager per instrument of the pipeline ({sorted(pipeline.instruments)}), got "
                             f"{sorted(managers)}")
        for k, m in managers.items():
            if m.pipeline is not pipeline.instruments[k]:
                raise ValueError(f"the {k} manager must be built on the pipeline's own {k} pipeline "
                                 f"(RedundancyManager(pipeline[{k!r}], ...)): the compensation estimates on it")
        self.pipeline = pipeline
        self.managers = managers

    def reset(self) -> None:
        """Every manager starts over (see :meth:`RedundancyManager.reset`); the drift's time origin is kept."""
        for m in self.managers.values():
            m.reset()

    def step(self, epoch: Epoch) -> dict[str, FdiResult]:
        """One epoch: compensation with each manager's isolation set, then each manager's step on its
        instrument's compensated outputs, in the pipeline's order. Returns the managers' (reused) results."""
        for m in self.managers.values():
            m.sync_pipeline()
        t = float(epoch.t)
        mgrs = self.managers
        return self.pipeline.step_through(epoch, lambda k, y, valid: mgrs[k].step(y, valid, t))

    def run(self, block: EpochBlock, chunk: int = 4096) -> dict[str, ReplayResult]:
        """N epochs one by one (closed loop); continues from the current state, as
        :meth:`RedundancyManager.run`. Returns one :class:`ReplayResult` per instrument.

        The compensation is computed for a run of epochs at once (the block path, compiled where it can be)
        with the managers' isolation sets of the run's start, and each manager steps on it epoch by epoch. That
        is the closed loop exactly as long as nothing the loop feeds back changes: the run stops after an epoch
        where a manager's isolation set changed (the next epoch's compensation must use the new set), and the
        instruments after the first are redone closed loop on an epoch where the first one's manager estimate
        differs from the compensation's (an alarm episode leaving suspects out), since their effects take the
        manager's estimate. ``chunk`` bounds a run's length (memory); after a set change a run starts at 64
        epochs and doubles, so that sets changing often do not each waste a chunk's compensation."""
        N = len(block)
        t = np.asarray(block.t, dtype=float)
        if not self.pipeline.compensation:  # nothing couples the instruments: each manager runs on its own
            return {k: m.run(block.raw[k], block.valid.get(k), t) for k, m in self.managers.items()}
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1 epochs, got {chunk}")
        pipe = self.pipeline
        order = pipe._order
        mgrs = self.managers
        out = {k: _Collector(m, N) for k, m in mgrs.items()}
        raw = {k: np.asarray(block.raw[k], dtype=float) for k in mgrs}
        valid = {k: np.asarray(block.valid[k], dtype=bool) for k in mgrs if k in block.valid}
        T = block.temperature

        def epoch(i: int) -> Epoch:
            return Epoch(float(t[i]), {k: y[i] for k, y in raw.items()}, {k: v[i] for k, v in valid.items()},
                         None if T is None else float(T[i]))

        i = 0
        size = chunk  # a run's length: back to _RESTART after a set change (the compensation ahead of it was
        #               wasted; sets that change often would waste a whole chunk each time), doubled after a run
        #               that ends whole, up to chunk
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite raw values are routed around, not warned
            while i < N:
                for m in mgrs.values():
                    m.sync_pipeline()
                j1 = min(N, i + size)
                sub = EpochBlock(t[i:j1], {k: y[i:j1] for k, y in raw.items()},
                                 {k: v[i:j1] for k, v in valid.items()}, None if T is None else T[i:j1])
                ycomp, xcomp = self._open_loop(sub)
                j = 0
                while j < j1 - i:
                    g = i + j
                    before = [m._iso_bytes for m in mgrs.values()]
                    done: dict[str, FdiResult] = {}
                    for n_k, k in enumerate(order):
                        v = valid.get(k)
                        r = mgrs[k].step(ycomp[k][j], None if v is None else v[g], float(t[g]))
                        done[k] = r
                        if n_k + 1 < len(order) and k in xcomp and not np.array_equal(r.x, xcomp[k][j]):
                            # the next instrument's effects take this estimate: that epoch, closed loop
                            def rest(kk: str, y: np.ndarray, vv: Any, done: dict = done, tg: float = float(t[g])):
                                return done[kk] if kk in done else mgrs[kk].step(y, vv, tg)

                            done = dict(pipe.step_through(epoch(g), rest))
                            break
                    for k in order:
                        out[k].add(g, done[k])
                    j += 1
                    if [m._iso_bytes for m in mgrs.values()] != before:
                        break  # the next epoch's compensation uses the new sets
                size = min(chunk, 2 * size) if i + j == j1 else min(chunk, _RESTART)
                i += j
        return {k: c.result(t) for k, c in out.items()}

    def _open_loop(self, sub: EpochBlock) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """The compensated raw outputs of ``sub`` with the current isolation sets and each instrument's estimate
        (what fed the next instrument's effects); the instrument pipelines' counters are left as they were (the
        managers' steps count the samples). Clipped and invalid outputs are left out of the compensation's
        estimates and a clipped one is handed on as it came, in the block path as epoch by epoch."""
        pipe = self.pipeline
        saved = {k: (p.samples, p.invalid_count.copy(), p.saturated_count.copy()) for k, p in pipe.instruments.items()}
        try:
            ycomp, res = pipe._compensate_block(sub)
        finally:
            for k, (s, inv, sat) in saved.items():
                p = pipe.instruments[k]
                p.samples, p.invalid_count, p.saturated_count = s, inv, sat
        return ycomp, {k: np.asarray(r.x) for k, r in res.items()}
