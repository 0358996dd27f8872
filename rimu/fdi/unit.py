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

    def run(self, block: EpochBlock) -> dict[str, ReplayResult]:
        """N epochs one by one (closed loop); continues from the current state, as
        :meth:`RedundancyManager.run`. Returns one :class:`ReplayResult` per instrument."""
        N = len(block)
        t = np.asarray(block.t, dtype=float)
        if not self.pipeline.compensation:  # nothing couples the instruments: each manager runs on its own
            return {k: m.run(block.raw[k], block.valid.get(k), t) for k, m in self.managers.items()}
        out = {k: _Collector(m, N) for k, m in self.managers.items()}
        raw = {k: np.asarray(block.raw[k], dtype=float) for k in self.managers}
        valid = {k: np.asarray(block.valid[k], dtype=bool) for k in self.managers if k in block.valid}
        T = block.temperature
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite raw values are routed around, not warned
            for i in range(N):
                ep = Epoch(float(t[i]), {k: y[i] for k, y in raw.items()}, {k: v[i] for k, v in valid.items()},
                           None if T is None else float(T[i]))
                for k, r in self.step(ep).items():
                    out[k].add(i, r)
        return {k: c.result(t) for k, c in out.items()}
