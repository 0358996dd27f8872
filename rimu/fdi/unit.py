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
from .glt import GltSnapshot
from .health import SensorState
from .manager import FdiEvent, FdiResult, RedundancyManager, ReplayResult, _Collector
from .multiple import FaultSetGlt
from .selfcal import SelfCalLoop, SelfCalTracker, TrackedGltWindow
from .settings import DEFAULTS, NAMES, FdiSettings

__all__ = ["Runtime", "UnitManager"]

#: epochs of the first run after an isolation set changed (runs then double up to ``chunk``)
_RESTART = 64


class Runtime:
    """The runtime of a unit: the one object that owns its state (see the module docstring).

    It holds the unit's :class:`rimu.fusion.Pipeline` (compensation of every effect, projection, parity: pure
    with respect to isolation, the sets are arguments of its calls) and one :class:`RedundancyManager` per
    instrument (detection, isolation, health, re-admission, validity), and steps them epoch by epoch with the
    instruments' effects coupled. ``rimu monitor``, ``rimu replay``, ``rimu demo``, the campaigns, the scenarios,
    :func:`rimu.experiments.validate.validate` and the exported C (``rimu_fdi_step``, checked decision for
    decision) all decide through it.

    Parameters
    ----------
    pipeline : Pipeline or Calibration
        The unit's pipeline, or its calibration (a default :class:`rimu.fusion.Pipeline` is built).
    settings : FdiSettings, optional
        The fault management's settings (default :data:`rimu.fdi.settings.DEFAULTS`).
    detector_factory : callable, optional
        ``factory(instrument_pipeline) -> detector``: another detector than the GLT snapshot, per instrument.
    managers : dict[str, RedundancyManager], optional
        Managers built on ``pipeline``'s own instrument pipelines (``pipeline[k]``), instead of ``settings``.
    selfcal : dict[str, SelfCalTracker or SelfCalLoop], optional
        In-flight self-calibration (:mod:`rimu.fdi.selfcal`, docs/selfcal.md) of these instruments: the runtime
        holds one :class:`rimu.fdi.selfcal.SelfCalLoop` per instrument (the tracker's state, :attr:`selfcal`), every
        epoch's compensated outputs are corrected by the tracked terms before the manager's step (estimate,
        detection and re-admission see them taken out), the detector's thresholds carry the tracker's covariance
        (a :class:`rimu.fdi.selfcal.TrackedGltWindow`; the default managers get one, of the tracker's window), and
        the tracker absorbs a window only ``hold_s`` after it without any alarm, never for isolated sensors. A
        tracker needs the managers' ``sample_rate`` (Hz).
    **options
        Further keyword arguments of :class:`RedundancyManager` (``sample_rate``, ``max_events``, ``isolator``;
        or any setting, which then overrides ``settings``).

    Examples
    --------
    >>> from rimu.calibration import Calibration, InstrumentCalibration
    >>> from rimu.geometry import cone6
    >>> cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)})
    >>> rt = Runtime(Pipeline(cal))
    >>> y = cal["gyro"].raw_output(np.array([0.1, 0.2, 0.3]))
    >>> for k in range(6):
    ...     y_k = y.copy()
    ...     y_k[4] += 0.5 if k >= 2 else 0.0      # 50 sigma on y2 from the third epoch
    ...     r = rt.step(Epoch(0.01 * k, {"gyro": y_k}))
    >>> rt.managers["gyro"].health.isolated, r["gyro"].validity.name
    (['y2'], 'DEGRADED')
    """

    def __init__(self, pipeline: Pipeline | Any, settings: FdiSettings | None = None, *,
                 detector_factory: Any = None, managers: dict[str, RedundancyManager] | None = None,
                 selfcal: dict[str, Any] | None = None, **options: Any) -> None:
        if not isinstance(pipeline, Pipeline):
            pipeline = Pipeline(pipeline)
        if isinstance(settings, dict):  # Runtime(pipeline, managers)
            managers, settings = settings, None
        if managers is None:
            st = settings if settings is not None else DEFAULTS
            own = {k: options.pop(k) for k in list(options) if k in NAMES}
            if own:
                st = FdiSettings(**{**st.as_dict(), **own})
            kw = st.manager_kwargs()
            if detector_factory is not None and "isolator" not in options:
                kw.pop("isolator")  # the manager picks the isolator that fits the detector
            if selfcal and detector_factory is None:  # thresholds that carry the tracker's covariance
                rate = options.get("sample_rate")
                win = {k: max(1, int(round(_tracker(v).settings.window_s * rate))) if rate else 1
                       for k, v in selfcal.items()}

                def detector_factory(ip: Any, st: FdiSettings = st) -> Any:
                    k = ip.calibration.instrument
                    return TrackedGltWindow(win[k], st.p_fa) if k in win else GltSnapshot(
                        st.p_fa, getattr(ip.calibration, "noise", None))
            kw.update(options)
            managers = {}
            for k, ip in pipeline.instruments.items():
                kk = dict(kw)
                if isinstance(kk.get("isolator"), FaultSetGlt):
                    kk["isolator"] = st.isolator()  # one isolator object per manager
                managers[k] = RedundancyManager(ip, detector_factory(ip) if detector_factory else None, **kk)
            self.settings = st
        else:
            if options or settings is not None or detector_factory is not None:
                raise TypeError("settings, detector_factory and options are for the default managers; the given "
                                "managers have their own")
            self.settings = None
        if set(managers) != set(pipeline.instruments):
            raise ShapeError(f"one manager per instrument of the pipeline ({sorted(pipeline.instruments)}), got "
                             f"{sorted(managers)}")
        for k, m in managers.items():
            if m.pipeline is not pipeline.instruments[k]:
                raise ValueError(f"the {k} manager must be built on the pipeline's own {k} pipeline "
                                 f"(RedundancyManager(pipeline[{k!r}], ...)): the compensation estimates on it")
        self.pipeline = pipeline
        self.managers = managers
        #: instruments whose detector takes the unit's motion from the gyros (accelerometers' motion-aware test,
        #: ``MotionAwareGlt(input_is_rate=False)``): fed the gyro manager's last estimate and its difference
        self._motion_fed = [k for k, m in managers.items() if k != "gyro" and "gyro" in managers
                            and hasattr(m.detector, "set_motion") and not getattr(m.detector, "input_is_rate", True)]
        self._gyro_last: tuple[float, np.ndarray] | None = None
        self._motion = (np.zeros(3), np.zeros(3))
        #: the in-flight self-calibration of each tracked instrument (its state: ``selfcal[k].state``)
        self.selfcal: dict[str, SelfCalLoop] = {}
        for k, v in (selfcal or {}).items():
            if k not in managers:
                raise ShapeError(f"selfcal names {k!r}, not an instrument of the pipeline ({sorted(managers)})")
            if isinstance(v, SelfCalLoop):
                self.selfcal[k] = v
            else:
                rate = managers[k].sample_rate
                if not rate:
                    raise ValueError("a self-calibrating runtime needs the sample rate (sample_rate=, Hz): the "
                                     "tracker's windows are counted in samples")
                self.selfcal[k] = SelfCalLoop(v, rate, managers[k].detector)

    def _mstep(self, k: str, y: np.ndarray, valid: Any, t: float, temperature: float | None) -> FdiResult:
        """Instrument ``k``'s manager on one epoch's compensated outputs, corrected by its tracked terms first."""
        loop = self.selfcal.get(k)
        m = self.managers[k]
        if k in self._motion_fed:
            m.detector.set_motion(*self._motion)
        if loop is None:
            r = m.step(y, valid, t)
        else:
            r = m.step(loop.correct(y, valid, t, temperature), valid, t)
            loop.observe(r, m.sensors.state >= SensorState.ISOLATED)
        if k == "gyro" and self._motion_fed:
            self._feed_motion(r, t)
        return r

    def _feed_motion(self, r: FdiResult, t: float) -> None:
        """The gyro manager's estimate (from its detector's rest level, the array's common bias) and its
        difference: the motion the accelerometers' test assumes at the next accelerometer step (in the pipeline's
        order: the same epoch when the gyros go first, else the next one)."""
        x = np.asarray(r.x, dtype=float)
        if not np.all(np.isfinite(x)):  # no rate (unobservable): the motion is unknown, taken as beyond any
            self._motion = (np.full(3, 1e6), np.full(3, 1e6))  # envelope (finite: the covariance stays a number)
            self._gyro_last = None
            return
        x = x - np.asarray(getattr(self.managers["gyro"].detector, "rest_level", np.zeros(3)), dtype=float)
        last = self._gyro_last
        alpha = (x - last[1]) / (t - last[0]) if last is not None and t > last[0] else np.zeros(3)
        self._gyro_last = (t, x)
        self._motion = (x, alpha)

    def selfcal_terms(self) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
        """The tracked terms of every tracked instrument now, with their 1-sigma (SI; see
        :meth:`rimu.fdi.selfcal.SelfCalTracker.terms`)."""
        return {k: loop.terms() for k, loop in self.selfcal.items()}

    def active_sets(self) -> dict[str, int]:
        """Each instrument's set in use (set codes; bit i = sensor i): what the next epoch is computed on."""
        return {k: m.active_code for k, m in self.managers.items()}

    @property
    def events(self) -> list[tuple[str, FdiEvent]]:
        """Every instrument's events, ``(instrument, event)`` in time order."""
        ev = [(k, e) for k, m in self.managers.items() for e in m.events]
        return sorted(ev, key=lambda ke: (ke[1].sample, ke[1].t))

    def reset(self) -> None:
        """Every manager starts over (see :meth:`RedundancyManager.reset`); the drift's time origin and the
        tracked terms of the self-calibration (calibration knowledge, :attr:`selfcal`) are kept."""
        for m in self.managers.values():
            m.reset()

    def step(self, epoch: Epoch) -> dict[str, FdiResult]:
        """One epoch: compensation with each manager's isolation set, then each manager's step on its
        instrument's compensated outputs, in the pipeline's order. Returns the managers' (reused) results."""
        t = float(epoch.t)
        pipe = self.pipeline
        if pipe.compiled:  # the compiled compensation stage: the epoch as a block of one, as run() does
            return self._step_compiled(epoch, t)
        T = epoch.temperature
        return pipe.step_through(epoch, lambda k, y, valid: self._mstep(k, y, valid, t, T), self.active_sets())

    def _step_compiled(self, epoch: Epoch, t: float) -> dict[str, FdiResult]:
        """:meth:`step` with the compensation computed by the compiled block path (one epoch; the managers'
        sets), each manager stepping on its instrument's compensated outputs in order; closed loop through
        :meth:`rimu.fusion.Pipeline.step_through` on an epoch where the first instrument's manager estimate is not
        the compensation's (an alarm leaving suspects out: the next instrument's effects take the manager's)."""
        pipe = self.pipeline
        valid = epoch.valid
        T = epoch.temperature
        sub = EpochBlock(np.array([t]), {k: np.asarray(y, dtype=float)[None] for k, y in epoch.raw.items()},
                         {k: np.asarray(v, dtype=bool)[None] for k, v in valid.items()},
                         None if epoch.temperature is None else np.array([float(epoch.temperature)]))
        active = self.active_sets()
        ycomp, xcomp = pipe.compensate_block(sub, active)
        order = pipe.order
        done: dict[str, FdiResult] = {}
        for n_k, k in enumerate(order):
            r = self._mstep(k, ycomp[k][0], valid.get(k), t, T)
            done[k] = r
            if n_k + 1 < len(order) and k in xcomp and not np.array_equal(r.x, xcomp[k][0], equal_nan=True):
                def rest(kk: str, y: np.ndarray, vv: Any, done: dict = done) -> Any:
                    return done[kk] if kk in done else self._mstep(kk, y, vv, t, T)

                return dict(pipe.step_through(epoch, rest, active))
        return {k: done[k] for k in pipe.instruments}

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
        if not self.pipeline.compensation and not self.selfcal and not self._motion_fed:
            # nothing couples the instruments: each manager alone
            return {k: m.run(block.raw[k], block.valid.get(k), t) for k, m in self.managers.items()}
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1 epochs, got {chunk}")
        pipe = self.pipeline
        order = pipe.order
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
                j1 = min(N, i + size)
                sub = EpochBlock(t[i:j1], {k: y[i:j1] for k, y in raw.items()},
                                 {k: v[i:j1] for k, v in valid.items()}, None if T is None else T[i:j1])
                ycomp, xcomp = pipe.compensate_block(sub, self.active_sets())
                j = 0
                while j < j1 - i:
                    g = i + j
                    before = [m.active_code for m in mgrs.values()]
                    done: dict[str, FdiResult] = {}
                    for n_k, k in enumerate(order):
                        v = valid.get(k)
                        r = self._mstep(k, ycomp[k][j], None if v is None else v[g], float(t[g]),
                                        None if T is None else float(T[g]))
                        done[k] = r
                        if n_k + 1 < len(order) and k in xcomp and not np.array_equal(r.x, xcomp[k][j],
                                                                                      equal_nan=True):
                            # the next instrument's effects take this estimate: that epoch, closed loop
                            def rest(kk: str, y: np.ndarray, vv: Any, done: dict = done, tg: float = float(t[g]),
                                     Tg: float | None = None if T is None else float(T[g])):
                                return done[kk] if kk in done else self._mstep(kk, y, vv, tg, Tg)

                            done = dict(pipe.step_through(epoch(g), rest, self.active_sets()))
                            break
                    for k in order:
                        out[k].add(g, done[k])
                    j += 1
                    if [m.active_code for m in mgrs.values()] != before:
                        break  # the next epoch's compensation uses the new sets
                size = min(chunk, 2 * size) if i + j == j1 else min(chunk, _RESTART)
                i += j
        return {k: c.result(t) for k, c in out.items()}


def _tracker(v: Any) -> SelfCalTracker:
    return v.tracker if isinstance(v, SelfCalLoop) else v


#: the former name of :class:`Runtime`
UnitManager = Runtime
