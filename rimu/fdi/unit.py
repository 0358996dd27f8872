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

import copy
from typing import Any

import numpy as np

from ..epoch import Epoch, EpochBlock
from ..errors import ShapeError
from ..fusion import Pipeline
from .health import SensorState
from .manager import FdiEvent, FdiResult, RedundancyManager, ReplayResult, _Collector, _evidence_detector
from .multiple import FaultSetGlt
from .selfcal import SelfCalLoop, SelfCalTracker, TrackedGltWindow
from .selfcal_record import SelfCalRecord
from .settings import DEFAULTS, NAMES, FdiSettings

__all__ = ["Runtime", "UnitManager", "noise_at_rate", "stored_motion_detectors"]

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
    detectors : dict[str, detector], optional
        The detector of these instruments (e.g. the motion-aware tests of a unit file,
        :func:`stored_motion_detectors`; ``rimu replay --detector``'s); the others take ``detector_factory``'s,
        else the default (below).
    detector_factory : callable, optional
        ``factory(instrument_pipeline) -> detector``: another detector than the GLT snapshot, per instrument.

        The default managers are built by one rule, the one of ``rimu replay``, ``rimu monitor`` and the
        exported C: the detector is ``detectors[k]``, else the factory's, else for a tracked instrument the window
        GLT with the tracker's covariance, else the GLT snapshot under the calibration's noise (model); the
        isolator is the ``isolator`` option when given, else the settings' set GLT
        (:meth:`FdiSettings.isolator`, one per manager) for a detector whose alarms come from the parity vector's
        size (the GLT family, the parity Kalman filter), else the detector's own choice (``"detector"``: the
        motion-aware GLT, whose thresholds follow the motion; CUSUM; the baselines).
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
    selfcal_history : bool
        Keep the tracked terms after every window (:attr:`selfcal_records`, :meth:`selfcal_columns`), for the
        estimates files, summaries and reports of ``rimu replay`` and ``rimu monitor``; off, the memory of a
        self-calibrating runtime does not grow with the run.
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
                 detectors: dict[str, Any] | None = None, detector_factory: Any = None,
                 managers: dict[str, RedundancyManager] | None = None, selfcal: dict[str, Any] | None = None,
                 selfcal_history: bool = False, **options: Any) -> None:
        if not isinstance(pipeline, Pipeline):
            pipeline = Pipeline(pipeline)
        if isinstance(settings, dict):  # Runtime(pipeline, managers)
            managers, settings = settings, None
        if managers is None:
            st = settings if settings is not None else DEFAULTS
            own = {k: options.pop(k) for k in list(options) if k in NAMES}
            if own:
                st = FdiSettings(**{**st.as_dict(), **own})
            unknown = sorted(set(detectors or {}) - set(pipeline.instruments))
            if unknown:
                raise ShapeError(f"detectors names {', '.join(unknown)}, not an instrument of the pipeline "
                                 f"({sorted(pipeline.instruments)})")
            managers = {k: _manager(ip, st, _detector(ip, st, detectors, detector_factory, selfcal, options), options)
                        for k, ip in pipeline.instruments.items()}
            self.settings = st
        else:
            if options or settings is not None or detector_factory is not None or detectors:
                raise TypeError("settings, detectors, detector_factory and options are for the default managers; "
                                "the given managers have their own")
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
                if selfcal_history and not v.keep_history:
                    raise ValueError(f"selfcal_history: the given {k} SelfCalLoop keeps no history (SelfCalLoop(..., "
                                     "history=True), or give its tracker)")
                self.selfcal[k] = v
            else:
                rate = managers[k].sample_rate
                if not rate:
                    raise ValueError("a self-calibrating runtime needs the sample rate (sample_rate=, Hz): the "
                                     "tracker's windows are counted in samples")
                self.selfcal[k] = SelfCalLoop(v, rate, managers[k].detector, history=selfcal_history)
        #: each tracked instrument's terms over the run (``selfcal_history=True``; else empty): what the estimates
        #: files, the summaries and the reports show (:class:`rimu.fdi.selfcal_record.SelfCalRecord`)
        self.selfcal_records: dict[str, SelfCalRecord] = (
            {k: SelfCalRecord(loop) for k, loop in self.selfcal.items()} if selfcal_history else {})

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

    def selfcal_columns(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """The tracked terms of every tracked instrument at the sample times ``t`` (s) of the epochs stepped since
        the last call: per sample the terms of the last window that ended before it, as the estimates file's
        columns ``{k}_{term}_{sensor}`` and ``..._sigma`` (SI; :meth:`SelfCalRecord.add`). Needs
        ``selfcal_history=True``."""
        out: dict[str, np.ndarray] = {}
        for rec in self.selfcal_records.values():
            out.update(rec.add(t))
        return out

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


def _detector(ip: Any, st: FdiSettings, detectors: dict[str, Any] | None, factory: Any,
              selfcal: dict[str, Any] | None, options: dict[str, Any]) -> Any:
    """The detector of one instrument's default manager, by the one rule of every entry point: the one given for
    the instrument (``detectors``), else the factory's, else for a tracked instrument the window GLT whose
    thresholds carry the tracker's covariance (of the tracker's window, counted at ``sample_rate``), else None
    (the manager's GLT snapshot under the calibration's noise)."""
    k = ip.calibration.instrument
    if detectors and k in detectors:
        return detectors[k]
    if factory is not None:
        return factory(ip)
    if selfcal and k in selfcal:
        rate = options.get("sample_rate")
        win = max(1, int(round(_tracker(selfcal[k]).settings.window_s * rate))) if rate else 1
        return TrackedGltWindow(win, st.p_fa)
    return None


def _manager(ip: Any, st: FdiSettings, det: Any, options: dict[str, Any]) -> RedundancyManager:
    """One instrument's default manager, with the isolator rule of every entry point: the ``isolator`` option
    when given; else a detector whose alarms come from the parity vector's size (the GLT family, the parity
    Kalman filter, and the manager's default) gets the settings' set GLT (:meth:`FdiSettings.isolator`, one object
    per manager), any other (the motion-aware GLT, CUSUM, the baselines) isolates on its own choice
    (``"detector"``)."""
    kw = {**st.manager_kwargs(), **options}
    if "isolator" not in options:
        kw["isolator"] = st.isolator() if det is None or _evidence_detector(det) else "detector"
    elif isinstance(kw["isolator"], FaultSetGlt):
        kw["isolator"] = copy.deepcopy(kw["isolator"])  # one isolator object per manager (it holds a cache)
    return RedundancyManager(ip, det, **kw)


def stored_motion_detectors(calibration: Any, p_fa: float, sample_rate: float | None = None) -> dict[str, Any]:
    """The motion-aware tests a unit file holds (``rimu setup --motion-fit``: ``metadata["motion_terms"]``), per
    instrument of ``calibration`` (:func:`rimu.fdi.motion.motion_detector_from_dict`), for ``Runtime(...,
    detectors=)``: what ``rimu replay`` and ``rimu monitor`` both decide with.

    The terms hold for the rate they were fitted at (the angular acceleration is a difference of successive
    epochs): a stream at another ``sample_rate`` (Hz, more than 2 % off) raises
    :class:`rimu.errors.CalibrationFileError`, as do malformed terms.

    >>> from rimu.calibration import Calibration, InstrumentCalibration
    >>> from rimu.geometry import cone6
    >>> stored_motion_detectors(Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6())}), 1e-3)
    {}
    """
    from ..errors import CalibrationFileError
    from .motion import motion_detector_from_dict

    out = {}
    for k, d in (calibration.metadata.get("motion_terms") or {}).items():
        if k not in calibration.instruments:
            continue
        try:
            det = motion_detector_from_dict(calibration[k], d, p_fa)
        except ShapeError as exc:
            raise CalibrationFileError(f"the calibration's {k} motion terms: {exc}") from None
        if sample_rate is not None and abs(det.sample_rate / sample_rate - 1.0) > 0.02:
            raise CalibrationFileError(f"the calibration's {k} motion terms were fitted at {det.sample_rate:.4g} Hz "
                                       f"and the data run at {sample_rate:.4g} Hz: set the unit up at the data's "
                                       "rate (rimu setup --average)")
        out[k] = det
    return out


def noise_at_rate(calibration: Any, sample_rate: float) -> tuple[Any, dict[str, float]]:
    """The calibration with every instrument's noise at a stream's rate, and the periods converted.

    ``rimu setup`` states the noise of the epochs it measured it on (its 0.1 s averages: ``noise_period_s``); a
    stream at ``sample_rate`` (Hz) more than 2 % off that period takes
    :meth:`rimu.calibration.InstrumentCalibration.noise_sigma_at` (white noise: ``sigma sqrt(T_noise / T)``)
    with its period set to ``1 / sample_rate``. The other instruments are kept as they are (the same objects).
    Returns the calibration (a new one when anything changed) and ``{instrument: period it was stated for (s)}``.
    ``rimu replay`` (the data's rate) and ``rimu monitor`` (the stream's declared or measured rate) both convert
    through it.

    >>> from rimu.calibration import Calibration, InstrumentCalibration
    >>> from rimu.geometry import triads
    >>> g = InstrumentCalibration.nominal("gyro", triads(2), noise_sigma=0.001)
    >>> g.noise_period_s = 0.1
    >>> cal, was = noise_at_rate(Calibration({"gyro": g}), 100.0)
    >>> was, round(float(cal["gyro"].noise_sigma[0]), 6), cal["gyro"].noise_period_s
    ({'gyro': 0.1}, 0.003162, 0.01)
    """
    from dataclasses import replace

    if not (sample_rate > 0 and np.isfinite(sample_rate)):
        raise ValueError(f"sample_rate must be positive (Hz), got {sample_rate}")
    was: dict[str, float] = {}
    cals = {}
    for k in calibration.instruments:
        c = calibration[k]
        per = c.noise_period_s
        if per is not None and c.noise_sigma is not None and abs(per * sample_rate - 1.0) > 0.02:
            c = replace(c, noise_sigma=c.noise_sigma_at(1.0 / sample_rate), noise_period_s=1.0 / sample_rate)
            was[k] = per
        cals[k] = c
    if not was:
        return calibration, was
    return type(calibration)(cals, calibration.raw_unit, calibration.method, calibration.created,
                             dict(calibration.metadata)), was


#: the former name of :class:`Runtime`
UnitManager = Runtime
