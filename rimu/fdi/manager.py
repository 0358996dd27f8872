"""Redundancy management: detection, confirmation, isolation, reconfiguration and re-admission.

:class:`RedundancyManager` wraps one :class:`rimu.fusion.InstrumentPipeline` and, sample by sample:

1. runs the pipeline (compensation, projection, normalised parity);
2. feeds the parity vector to a detector (GLT snapshot by default; any detector of :mod:`rimu.fdi`);
3. on an alarm, asks the detector for the most likely faulty sensor and counts consecutive alarms on it;
   after ``confirm`` of them the sensor is isolated (Cho & Park 2005, Eq. 21, through
   :meth:`InstrumentPipeline.isolate`) and detection continues on the remaining sensors with their own
   parity space; a shorter alarm episode is logged as a transient event;
4. never isolates where the active set cannot (parity dimension 1, or collinear parity columns): the fault
   is then reported as detected but not isolable;
5. isolates a sensor whose output stays invalid (non-finite, dropout) for ``invalid_persist`` samples;
   shorter gaps are routed around by the pipeline and logged as transient;
6. optionally re-admits an isolated sensor after ``readmit_after`` consecutive samples in which its
   output agrees with the estimate of the others (each sample, and the mean over the clean period, pass a
   chi-square test at the design false-alarm probability);
7. reports an explicit :class:`HealthState` and logs every event.

States: ``nominal`` (isolation possible, nothing isolated), ``fault_isolated`` (one or more sensors out, one
more can still be isolated), ``detection_only`` (the active set detects but cannot isolate, e.g. four
sensors), ``no_redundancy`` (three sensors), ``unobservable`` (fewer than three, or rank deficient).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any, Protocol

import numpy as np

from ..errors import ShapeError
from ..fusion import InstrumentPipeline, StepResult
from ..fusion.projection import ActiveSet, ProjectionTable
from .glt import GltSnapshot, glt_threshold
from .parity import column_correlations

__all__ = ["HealthState", "FdiEvent", "Health", "RedundancyManager", "ReplayResult", "Detector"]


class Detector(Protocol):
    """What the manager needs from a detector (see :class:`rimu.fdi.GltSnapshot`)."""

    name: str

    def configure(self, Vz: np.ndarray, dof: int) -> None: ...

    def update(self, parity: np.ndarray) -> tuple[float, float]: ...

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]: ...


class HealthState(str, Enum):
    NOMINAL = "nominal"
    FAULT_ISOLATED = "fault_isolated"
    DETECTION_ONLY = "detection_only"
    NO_REDUNDANCY = "no_redundancy"
    UNOBSERVABLE = "unobservable"


#: integer code of each state (for arrays and plots)
STATE_CODES = {s: k for k, s in enumerate(HealthState)}


@dataclass
class FdiEvent:
    """One logged event.

    kind: ``isolated``, ``transient`` (alarm episode shorter than the confirmation), ``detected_not_isolable``,
    ``invalid_isolated``, ``invalid_transient``, ``readmitted``, ``state``.
    """

    sample: int
    t: float
    kind: str
    sensor: str | None
    message: str
    statistic: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        if not np.isfinite(d["statistic"]):
            d["statistic"] = None
        return d


@dataclass
class Health:
    """The manager's view after the latest sample (reused object; copy what you keep)."""

    state: HealthState
    alarm: bool
    statistic: float
    threshold: float
    isolated: list[str]
    fault_not_isolable: bool = False


@dataclass
class ReplayResult:
    """What :meth:`RedundancyManager.run` returns for N samples."""

    t: np.ndarray
    x: np.ndarray
    statistic: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    state: np.ndarray
    n_active: np.ndarray
    events: list[FdiEvent]
    names: list[str]

    def state_names(self) -> list[str]:
        inv = {k: s.value for s, k in STATE_CODES.items()}
        return [inv[int(c)] for c in self.state]

    def first(self, kind: str, sensor: str | None = None) -> FdiEvent | None:
        """The first event of a kind (and sensor)."""
        for e in self.events:
            if e.kind == kind and (sensor is None or e.sensor == sensor):
                return e
        return None


class RedundancyManager:
    """Fault detection, isolation and reconfiguration around an :class:`InstrumentPipeline`.

    Parameters
    ----------
    pipeline : InstrumentPipeline
    detector : Detector, optional
        Default :class:`GltSnapshot` at ``p_fa`` (with the calibration's noise model, when it has one).
    p_fa : float
        Design false-alarm probability (default detector, and the re-admission test).
    confirm : int
        Consecutive alarms pointing at the same sensor before it is isolated (1 for the CUSUM bank, which
        accumulates evidence itself).
    invalid_persist : int
        Consecutive invalid samples of one sensor before it is isolated.
    readmit_after : int or None
        Clean samples before an isolated sensor is re-admitted; None: never.
    sample_rate : float, optional
        Hz, for event times when :meth:`step` gets no ``t``.
    max_events : int
        Events kept (counts in :attr:`counts` are always complete).

    Examples
    --------
    >>> from rimu.calibration import InstrumentCalibration
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0, noise_sigma=0.01)
    >>> mgr = RedundancyManager(InstrumentPipeline(cal), confirm=3)
    >>> rng = np.random.default_rng(1)
    >>> for k in range(10):
    ...     y = cal.raw_output(np.array([0.1, 0.2, 0.3])) + 0.01 * rng.standard_normal(6)
    ...     y[4] += 0.2 if k >= 5 else 0.0          # 20 sigma bias on y2 from sample 5
    ...     _ = mgr.step(y)
    >>> mgr.health.state.value, mgr.health.isolated
    ('fault_isolated', ['y2'])
    """

    def __init__(self, pipeline: InstrumentPipeline, detector: Detector | None = None, *, p_fa: float = 1e-3,
                 confirm: int = 3, invalid_persist: int = 10, readmit_after: int | None = None,
                 sample_rate: float | None = None, max_events: int = 10000) -> None:
        if confirm < 1 or invalid_persist < 1:
            raise ValueError("confirm and invalid_persist must be at least 1 sample")
        self.pipeline = pipeline
        # the default detector uses the calibration's noise model (rimu.noise) when it has one
        self.detector = detector if detector is not None else GltSnapshot(p_fa, getattr(pipeline.calibration, "noise", None))
        self.p_fa = p_fa
        self.confirm = int(confirm)
        self.invalid_persist = int(invalid_persist)
        self.readmit_after = None if readmit_after is None else int(readmit_after)
        self.sample_rate = sample_rate
        self.max_events = int(max_events)
        cal = pipeline.calibration
        self.names = list(cal.geometry.names)
        self.isolable = _Isolable(pipeline.table)  # per active set, computed when the set first occurs
        self._uses_input = bool(getattr(self.detector, "uses_input", False))
        self._thr1 = glt_threshold(p_fa, 1)
        self._axes = cal.axes_mb()
        self._scale = cal.scale
        self._bias = cal.bias
        self.events: list[FdiEvent] = []
        self.counts: dict[str, int] = {}
        self.health = Health(HealthState.NOMINAL, False, 0.0, float("inf"), [])
        self.reset()

    @classmethod
    def for_unit(cls, pipeline: Any, **kwargs: Any) -> dict[str, "RedundancyManager"]:
        """One manager per instrument of a :class:`rimu.fusion.Pipeline` (same settings for each; a detector
        object cannot be shared, so pass ``detector_factory=lambda instrument_pipeline: ...`` instead).

        >>> from rimu.calibration import Calibration, InstrumentCalibration
        >>> from rimu.fusion import Pipeline
        >>> from rimu.geometry import cone6
        >>> cal = Calibration({k: InstrumentCalibration.nominal(k, cone6(), 1.0, noise_sigma=0.01)
        ...                    for k in ("gyro", "accel")})
        >>> sorted(RedundancyManager.for_unit(Pipeline(cal), confirm=3))
        ['accel', 'gyro']
        """
        factory = kwargs.pop("detector_factory", None)
        return {k: cls(ip, factory(ip) if factory else None, **kwargs) for k, ip in pipeline.instruments.items()}

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything: all sensors re-admitted, counters and events cleared."""
        self.pipeline.set_isolated(np.zeros(self.pipeline.n, bool))
        n = self.pipeline.n
        self.samples = 0
        self._entry = -2
        self._suspect = -1
        self._streak = 0
        self._unisolable_streak = 0
        self._not_isolable_reported = False
        self._invalid_run = np.zeros(n, dtype=np.int64)
        self._invalid_pending = False
        self._clean = np.zeros(n, dtype=np.int64)
        self._clean_sum = np.zeros(n)
        self.events.clear()
        self.counts.clear()
        self._update_state(log=False)

    @property
    def state(self) -> HealthState:
        return self.health.state

    @property
    def isolated(self) -> np.ndarray:
        return self.pipeline.isolated

    def _log(self, kind: str, sensor: int | None, message: str, t: float, statistic: float = float("nan")) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if len(self.events) < self.max_events:
            self.events.append(FdiEvent(self.samples - 1, t, kind, None if sensor is None else self.names[sensor],
                                        message, float(statistic)))

    def _update_state(self, log: bool = True, t: float = float("nan")) -> None:
        tab = self.pipeline.table
        iso = self.pipeline.isolated
        e = tab.lookup(tab.full_code & ~sum(1 << int(i) for i in np.flatnonzero(iso)))
        self._iso_entry = e
        self._n_isolated = int(iso.sum())
        n_act = int((~iso).sum())
        if e < 0 or not tab.observable[e]:
            st = HealthState.UNOBSERVABLE
        elif n_act == 3 or tab.dof[e] == 0:
            st = HealthState.NO_REDUNDANCY
        elif not self.isolable[e]:
            st = HealthState.DETECTION_ONLY
        elif iso.any():
            st = HealthState.FAULT_ISOLATED
        else:
            st = HealthState.NOMINAL
        old = self.health.state
        self.health.state = st
        self.health.isolated = [self.names[i] for i in np.flatnonzero(iso)]
        if log and st != old:
            self._log("state", None, f"state {old.value} -> {st.value} ({n_act} sensors active)", t)

    # ------------------------------------------------------------------ per sample
    def step(self, y: np.ndarray, valid: np.ndarray | None = None, t: float | None = None) -> StepResult:
        """Process one raw sample; returns the pipeline's (reused) :class:`StepResult`.

        :attr:`health` holds the state, alarm and statistic after this sample.
        """
        pipe = self.pipeline
        r = pipe.step(y, valid)
        self.samples += 1
        h = self.health
        if t is None:
            t = (self.samples - 1) / self.sample_rate if self.sample_rate else float(self.samples - 1)
        e = r.entry
        if e != self._entry:
            self._entry = e
            self.detector.configure(pipe.table.Vz[e] if e >= 0 else np.zeros((0, pipe.n)), r.dof)
            self._streak = 0
        if e != self._iso_entry or self._invalid_pending:
            self._invalid(r.invalid, t)
        if r.dof >= 1:
            if self._uses_input:
                self.detector.set_input(r.x)
            stat, thr = self.detector.update(r.parity)
        else:
            stat, thr = 0.0, float("inf")
        h.statistic = stat
        h.threshold = thr
        alarm = stat > thr
        h.alarm = alarm
        if alarm:
            self._on_alarm(r, stat, t)
        elif self._streak or self._unisolable_streak:
            if self._streak:
                self._log("transient", self._suspect, f"alarm episode of {self._streak} sample(s), not confirmed", t)
            self._streak = 0
            self._unisolable_streak = 0
            self._suspect = -1
        if self._n_isolated and self.readmit_after is not None:
            self._readmission(np.asarray(y, dtype=float), valid, r, t)
        return r

    def _on_alarm(self, r: StepResult, stat: float, t: float) -> None:
        j, _ = self.detector.isolate(r.parity)
        if j < 0 or not self.isolable[r.entry]:
            self._unisolable_streak += 1
            if self._unisolable_streak >= self.confirm and not self._not_isolable_reported:
                self._not_isolable_reported = True
                self.health.fault_not_isolable = True
                self._log("detected_not_isolable", None,
                          f"fault detected with {int(r.active.sum())} active sensors: isolation impossible "
                          f"(parity dimension {r.dof}); output continues on all of them", t, stat)
            return
        if j == self._suspect:
            self._streak += 1
        else:
            if self._streak:
                self._log("transient", self._suspect, f"alarm episode of {self._streak} sample(s), not confirmed", t)
            self._suspect, self._streak = j, 1
        if self._streak >= self.confirm:
            self.pipeline.isolate(j)
            self._log("isolated", j, f"isolated after {self._streak} consecutive alarms (Eq. 21)", t, stat)
            self._streak, self._suspect = 0, -1
            self._clean[j] = 0
            self._clean_sum[j] = 0.0
            self._not_isolable_reported = False
            self.health.fault_not_isolable = False
            self._update_state(t=t)

    def _invalid(self, inv: np.ndarray, t: float) -> None:
        run = self._invalid_run
        ended = (~inv) & (run > 0)
        for i in np.flatnonzero(ended):
            self._log("invalid_transient", int(i), f"{int(run[i])} invalid sample(s), routed around", t)
        run[ended] = 0
        run[inv] += 1
        self._invalid_pending = bool(run.any())
        iso = self.pipeline._isolated
        for i in np.flatnonzero((run >= self.invalid_persist) & ~iso):
            tab = self.pipeline.table
            e = tab.lookup(tab.full_code & ~sum(1 << k for k in np.flatnonzero(iso)) & ~(1 << int(i)))
            if e < 0 or not tab.observable[e]:
                continue  # isolating it would leave the unit blind; the pipeline routes around it per sample
            self.pipeline.isolate(int(i))
            run[i] = 0
            self._invalid_pending = bool(run.any())
            self._clean[i] = 0
            self._clean_sum[i] = 0.0
            self._log("invalid_isolated", int(i), f"output invalid for {self.invalid_persist} samples", t)
            self._update_state(t=t)

    def _readmission(self, y: np.ndarray, valid: np.ndarray | None, r: StepResult, t: float) -> None:
        if not r.observable:
            return
        sig = self.pipeline.table.sigma
        for j in np.flatnonzero(self.pipeline._isolated):
            ok = np.isfinite(y[j]) and (valid is None or bool(valid[j]))
            if ok:
                a = self._axes[j]
                res = (self._scale[j] * y[j] - self._bias[j]) - a @ r.x
                var = sig[j] ** 2 + a @ r.P @ a
                zn = res / np.sqrt(var)
                ok = zn * zn < self._thr1
            if not ok:
                self._clean[j] = 0
                self._clean_sum[j] = 0.0
                continue
            self._clean[j] += 1
            self._clean_sum[j] += zn
            if self._clean[j] >= self.readmit_after:
                N = self._clean[j]
                if self._clean_sum[j] ** 2 / N < self._thr1:
                    self.pipeline.readmit(int(j))
                    self._log("readmitted", int(j), f"clean for {N} samples: re-admitted", t)
                    self._update_state(t=t)
                self._clean[j] = 0
                self._clean_sum[j] = 0.0

    # ------------------------------------------------------------------ blocks
    def run(self, Y: np.ndarray, valid: np.ndarray | None = None, t: np.ndarray | None = None) -> ReplayResult:
        """Process N samples one by one (closed loop) and collect the outputs; (N, n) raw samples."""
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2 or Y.shape[1] != self.pipeline.n:
            raise ShapeError(f"a block of raw samples must have shape (N, {self.pipeline.n}), got {Y.shape}")
        N = len(Y)
        if t is None:
            base = self.samples
            t = (base + np.arange(N)) / (self.sample_rate or 1.0)
        x = np.zeros((N, 3))
        stat = np.zeros(N)
        thr = np.zeros(N)
        alarm = np.zeros(N, bool)
        state = np.zeros(N, np.int8)
        n_act = np.zeros(N, np.int8)
        first = len(self.events)
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite raw values are routed around, not warned
            self._run_loop(Y, valid, t, x, stat, thr, alarm, state, n_act)
        return ReplayResult(np.asarray(t, float), x, stat, thr, alarm, state, n_act, self.events[first:], self.names)

    def _run_loop(self, Y, valid, t, x, stat, thr, alarm, state, n_act) -> None:  # type: ignore[no-untyped-def]
        h = self.health
        for k in range(len(Y)):
            r = self.step(Y[k], None if valid is None else valid[k], float(t[k]))
            x[k] = r.x
            stat[k], thr[k], alarm[k] = h.statistic, h.threshold, h.alarm
            state[k] = STATE_CODES[h.state]
            n_act[k] = r.dof + 3 if r.observable else int(r.active.sum())


class _Isolable:
    """``isolable[entry]``: the active set can isolate one fault (dof >= 2 and no two parity columns collinear),
    computed once per set when it first occurs (a unit of many sensors has too many sets to tabulate)."""

    def __init__(self, table: ProjectionTable) -> None:
        self._table = table

    @staticmethod
    def _compute(s: ActiveSet) -> bool:
        d = s.dof
        if d < 2 or not s.observable:
            return False
        act = s.active
        rho = column_correlations(s.Vz[:d])[np.ix_(act, act)]
        off = np.abs(rho[~np.eye(len(rho), dtype=bool)])
        return bool(np.all(off < 1 - 1e-6))

    def __getitem__(self, entry: int) -> bool:
        if entry < 0:
            return False
        return bool(self._table.derived("isolable", int(entry), self._compute))
