"""Redundancy management: detection, isolation of one or several sensors, re-admission, honest outputs.

:class:`RedundancyManager` wraps one :class:`rimu.fusion.InstrumentPipeline` and, sample by sample:

1. applies its own active set to the pipeline (the manager owns the isolation set; change it through
   :meth:`RedundancyManager.isolate` / :meth:`RedundancyManager.readmit`, not on the pipeline) and runs it
   (compensation, projection, normalised parity);
2. feeds the parity vector to a detector (GLT snapshot by default; any detector of :mod:`rimu.fdi`);
3. on an alarm, accumulates the alarm episode's evidence and asks the generalised likelihood test over
   sensor sets (:class:`rimu.fdi.multiple.FaultSetGlt`) which set of 1..k sensors explains it; the same set
   named on ``confirm`` consecutive alarms is isolated (Cho & Park 2005, Eq. 21, for every sensor of the
   set). Until then the alarm sample's output already leaves the named set out. Where no set can be named
   (ambiguous, more faults than the parity space separates, or parity dimension below 2) the fault is
   reported as present but not isolable and every output is flagged DEGRADED until the alarms stop;
4. isolates a sensor whose output stays invalid (non-finite, dropout) for ``invalid_persist`` samples
   unless that would leave fewer sensors than span three dimensions; with ``common_cause=True`` only the
   samples where the invalidity is confined to one sub-unit count (:class:`rimu.fdi.common_cause.EvidenceGate`:
   triads clipping together are a common cause, ``common_invalid`` event, nothing isolated); an alarm while the detector says its
   motion model is exceeded (``detector.model_exceeded``) is logged as ``model_exceeded``, the output is
   DEGRADED and nothing is isolated;
5. re-admits an isolated sensor after its output agrees with the estimate of the others (each sample and
   the mean over the clean period pass a chi-square test), with a clean period that doubles with each
   isolation of that sensor and a FAILED state after ``fail_after`` isolations (no ping-pong; see
   :mod:`rimu.fdi.health`);
6. returns per sample one consistent :class:`FdiResult`: ``x``, ``P``, ``parity``, ``active`` describe the same
   sensor set, including on the isolation sample, with a :class:`rimu.fusion.validity.Validity` flag.

States of the set in use (:class:`HealthState`): ``nominal`` (all sensors, isolation possible),
``fault_isolated`` (one or more sensors out, isolation still possible), ``detection_only`` (the active set
detects but cannot isolate, e.g. four sensors), ``no_redundancy`` (three sensors), ``unobservable`` (the
sensors in use this sample do not span 3-D). Per-sensor states: :class:`rimu.fdi.health.SensorState`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

import numpy as np

from ..errors import MissingNoiseError, ShapeError
from ..fusion import InstrumentPipeline, StepResult
from ..fusion.projection import bits_mask, mask_bits
from ..fusion.validity import Validity
from .common_cause import EvidenceGate
from .glt import GltSnapshot, glt_threshold, isolate_argmax
from .health import SensorHealth, SensorState
from .kalman import ParityKalman
from .multiple import FaultSetGlt, SetDecision
from .parity import column_correlations
from .settings import DEFAULTS as _D

__all__ = ["Detector", "FdiEvent", "FdiResult", "Health", "HealthState", "RedundancyManager", "ReplayResult",
           "SensorState", "Validity", "unisolated_alarm_runs"]


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
    ``not_isolable_cleared``, ``invalid_isolated``, ``invalid_transient``, ``readmitted``, ``failed``,
    ``state``, ``common_invalid``, ``model_exceeded`` (see :mod:`rimu.fdi.common_cause`).

    ``sample`` counts the manager's samples from its last :meth:`RedundancyManager.reset` (0-based); ``t`` is
    the sample's time in s: the ``t`` given to ``step``/``run``, else ``sample / sample_rate``; without
    either it is the sample index (no unit).
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
    validity: Validity = Validity.NOMINAL
    suspects: list[str] = field(default_factory=list)


@dataclass
class FdiResult(StepResult):
    """One sample out of :meth:`RedundancyManager.step` (reused object: copy what you keep).

    ``x``, ``P``, ``parity``, ``dof``, ``active`` and ``entry`` describe the same sensor set: the isolation set
    minus the sensors invalid in this sample, minus (on an alarm sample) the set the isolation test names.
    ``observable`` is False exactly when there is no estimate (``x`` is then NaN, ``P`` infinite, ``validity``
    UNOBSERVABLE). ``statistic``/``threshold``/``alarm`` are the detector's on the
    pipeline's set of the sample.
    """

    validity: Validity = Validity.NOMINAL
    state: HealthState = HealthState.NOMINAL
    alarm: bool = False
    statistic: float = 0.0
    threshold: float = float("inf")
    fault_not_isolable: bool = False


@dataclass
class ReplayResult:
    """What :meth:`RedundancyManager.run` returns for N samples.

    ``validity`` (N,) holds :class:`Validity` codes, ``sensor_state`` (N, n) :class:`SensorState` codes,
    ``active`` (N, n) the sensors in each sample's estimate. ``t`` (N,) is in s when the manager has a
    ``sample_rate`` or ``run`` got ``t``; otherwise it holds the sample indices (see :class:`FdiEvent`).
    """

    t: np.ndarray
    x: np.ndarray
    statistic: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    state: np.ndarray
    n_active: np.ndarray
    events: list[FdiEvent]
    names: list[str]
    validity: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    sensor_state: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.int8))
    active: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    P_diag: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def state_names(self) -> list[str]:
        inv = {k: s.value for s, k in STATE_CODES.items()}
        return [inv[int(c)] for c in self.state]

    def first(self, kind: str, sensor: str | None = None) -> FdiEvent | None:
        """The first event of a kind (and sensor)."""
        for e in self.events:
            if e.kind == kind and (sensor is None or e.sensor == sensor):
                return e
        return None

    def transitions(self, sensor: str | int) -> int:
        """How many times a sensor went out of or back into the estimate (isolations plus re-admissions)."""
        i = self.names.index(sensor) if isinstance(sensor, str) else int(sensor)
        out = self.sensor_state[:, i] >= SensorState.ISOLATED
        return int(np.count_nonzero(out[1:] != out[:-1]) + (1 if len(out) and out[0] else 0))


def unisolated_alarm_runs(result: ReplayResult, confirm: int = 3) -> list[float]:
    """Times at which a run of ``confirm`` consecutive alarms completes without an isolation at that sample.

    One entry per run of alarms (a run of 7 alarms with ``confirm=3`` counts once, at its 3rd sample); a run
    that completes at a sample where the manager logged an ``isolated`` or ``invalid_isolated`` event is left
    out. These are the faults the manager saw with confirmation but did not isolate: the detections of a unit
    that cannot isolate (two parallel triads), or the confirmed false alarms of a fault-free recording.
    Times as in ``result.t`` (s, or sample indices; see :class:`ReplayResult`).

    >>> r = ReplayResult(np.arange(12.0), np.zeros((12, 3)), np.zeros(12), np.ones(12),
    ...                  np.array([1, 1, 1, 1, 0, 1, 1, 0, 1, 1, 1, 0], bool), np.zeros(12, np.int8),
    ...                  np.zeros(12, np.int8), [FdiEvent(10, 10.0, "isolated", "x1", "")], ["x1"])
    >>> unisolated_alarm_runs(r)
    [2.0]
    """
    if confirm < 1:
        raise ValueError(f"confirm must be at least 1 sample, got {confirm}")
    iso_t = {float(e.t) for e in result.events if e.kind in ("isolated", "invalid_isolated")}
    a = np.asarray(result.alarm, dtype=bool)
    # run length at each sample: samples since the last non-alarm sample, where alarmed
    idx = np.arange(len(a))
    last_quiet = np.maximum.accumulate(np.where(a, -1, idx))
    run = np.where(a, idx - last_quiet, 0)
    t = np.asarray(result.t, dtype=float)
    return [float(x) for x in t[run == confirm] if float(x) not in iso_t]


def _evidence_detector(det: Any) -> bool:
    """Detectors whose alarms come from the parity vector's size (the set GLT can then name the set)."""
    return isinstance(det, (GltSnapshot, ParityKalman))


class RedundancyManager:
    """Fault detection, isolation and reconfiguration around an :class:`InstrumentPipeline`.

    The manager owns the pipeline's isolation set: at every :meth:`step` it applies its own set
    (:attr:`isolated`); :meth:`reset` clears it. :meth:`run` and :meth:`step` continue from the current state.

    Parameters
    ----------
    pipeline : InstrumentPipeline
        Must know the noise of its sensors (the calibration's ``noise_sigma`` or ``sigma=``); otherwise
        :class:`rimu.errors.MissingNoiseError`.
    detector : Detector, optional
        Default :class:`GltSnapshot` at ``p_fa`` (with the calibration's noise model, when it has one).
    p_fa : float
        Design false-alarm probability (default detector, the set test's level, the re-admission test).
    confirm : int
        Consecutive alarms naming the same set before it is isolated (1 for the CUSUM bank, which
        accumulates evidence itself); also the alarm length after which an unnamed fault is reported as
        not isolable.
    invalid_persist : int
        Consecutive invalid samples of one sensor before it is isolated.
    readmit_after : int or None
        Clean samples before an isolated sensor is re-admitted the first time (doubled at each further
        isolation of that sensor, ``backoff``); None: never automatically. Default
        :data:`rimu.fdi.health.READMIT_AFTER` (100), the default of every entry point.
    sample_rate : float, optional
        Hz, for the times (s) of samples and events when :meth:`step` or :meth:`run` gets no ``t``
        (``index / sample_rate``); without it and without ``t`` the times are sample indices.
    max_events : int
        Events kept (counts in :attr:`counts` are always complete).
    isolator : FaultSetGlt, "detector" or None
        How an alarm is attributed: the set GLT (default for the GLT and Kalman detectors:
        ``FaultSetGlt(alpha=1e-4)``, :meth:`rimu.fdi.FdiSettings.isolator`, up to two simultaneous faults where the
        parity dimension allows; the
        small alpha keeps the true set from being rejected by chance while evidence accumulates), or
        ``"detector"`` (the detector's own single-sensor choice; default for the CUSUM bank and the
        baselines).
    fail_after, backoff : int, float
        See :class:`rimu.fdi.health.SensorHealth`.
    clear_after : int
        Alarm-free samples after which a "not isolable" report is withdrawn.
    episode_gap : int, optional
        An alarm episode, whose parity vectors are pooled as evidence for the set test, ends after this
        many consecutive alarm-free samples (default ``max(confirm, 5)``).
    scatter_window : int
        The most samples of an episode the set test pools in its scatter (two blocks of half as many; the
        older is dropped when the newer is full): every threshold it needs is in a finite table
        (:attr:`rimu.fdi.FdiSettings.scatter_window`).
    common_cause : bool
        Count toward ``invalid_persist`` only the samples whose invalidity is confined to one sub-unit
        (:class:`rimu.fdi.common_cause.EvidenceGate`): for units of triads that clip together in fast motion.
        Off: every invalid sample counts (a dropout of several triads isolates them until they are clean).

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
    ...     r = mgr.step(y)
    >>> mgr.health.state.value, mgr.health.isolated, r.validity.name, bool(r.active[4])
    ('fault_isolated', ['y2'], 'DEGRADED', False)
    """

    def __init__(self, pipeline: InstrumentPipeline, detector: Detector | None = None, *, p_fa: float = _D.p_fa,
                 confirm: int = _D.confirm, invalid_persist: int = _D.invalid_persist,
                 readmit_after: int | None = _D.readmit_after,
                 sample_rate: float | None = None, max_events: int = 10000,
                 isolator: FaultSetGlt | str | None = None, fail_after: int = _D.fail_after,
                 backoff: float = _D.backoff, clear_after: int = _D.clear_after,
                 episode_gap: int | None = _D.episode_gap, common_cause: bool = _D.common_cause,
                 scatter_window: int = _D.scatter_window) -> None:
        if confirm < 1 or invalid_persist < 1:
            raise ValueError("confirm and invalid_persist must be at least 1 sample")
        if not getattr(pipeline, "noise_given", True):
            raise MissingNoiseError(
                f"the {pipeline.calibration.instrument} calibration has no noise_sigma and the pipeline was built "
                "without sigma=: fault detection would assume 1.0 SI per sample. Pass the noise explicitly, "
                "InstrumentPipeline(cal, sigma=...) (SI per sample), or set the calibration's noise_sigma")
        self.pipeline = pipeline
        # the default detector uses the calibration's noise model (rimu.noise) when it has one
        self.detector = detector if detector is not None else GltSnapshot(p_fa, getattr(pipeline.calibration, "noise", None))
        self.p_fa = p_fa
        self.confirm = int(confirm)
        self.invalid_persist = int(invalid_persist)
        self.readmit_after = None if readmit_after is None else int(readmit_after)
        self.sample_rate = sample_rate
        self.max_events = int(max_events)
        self.clear_after = int(clear_after)
        self.episode_gap = int(episode_gap) if episode_gap is not None else max(self.confirm, 5)
        self.common_cause = bool(common_cause)
        if int(scatter_window) < 2 or int(scatter_window) % 2:
            raise ValueError(f"scatter_window must be an even number of samples (at least 2), got {scatter_window}")
        self.scatter_window = int(scatter_window)
        if isolator is None:
            isolator = _D.isolator() if _evidence_detector(self.detector) else "detector"
        if isinstance(isolator, str) and isolator != "detector":
            raise ValueError(f"isolator must be a FaultSetGlt or 'detector', got {isolator!r}")
        self.isolator = isolator
        cal = pipeline.calibration
        self.names = list(cal.geometry.names)
        self.n = pipeline.n
        self._full_code = (1 << self.n) - 1
        self._uses_input = bool(getattr(self.detector, "uses_input", False))
        self._thr1 = glt_threshold(p_fa, 1)
        self._axes = cal.axes_mb()
        self._scale = cal.scale
        self._bias = cal.bias
        self.sensors = SensorHealth(self.n, self.readmit_after, backoff, fail_after, self._thr1,
                                    glt_threshold(1e-6, 1))
        self._set_state: dict[int, HealthState] = {}
        self._remap: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.events: list[FdiEvent] = []
        self.counts: dict[str, int] = {}
        self.health = Health(HealthState.NOMINAL, False, 0.0, float("inf"), [])
        n, r = self.n, max(self.n - 3, 0)
        self._x = np.zeros(3)
        self._p = np.zeros(r)
        self.result = FdiResult(self._x, np.diag([np.inf] * 3), self._p, 0, np.zeros(n, bool), np.zeros(n, bool),
                                False, -1)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Start over: every sensor healthy and in the estimate, counters, episode and events cleared."""
        n = self.n
        self.sensors.reset()
        self._suspects_on = False
        self._apply()
        self.samples = 0
        self._cur = -2  # the set code of the previous sample
        self._observable = True
        self._r: StepResult | None = None
        self._new_episode()
        self._not_isolable = False
        self._quiet = 0
        self._invalid_run = np.zeros(n, dtype=np.int64)
        self._alone_run = np.zeros(n, dtype=np.int64)
        self._gate = EvidenceGate(self.pipeline.calibration.geometry)
        self._exceeded = False
        self._invalid_pending = False
        self.events.clear()
        self.counts.clear()
        self._plain_entry = -99
        h = self.health
        h.alarm, h.statistic, h.threshold, h.fault_not_isolable = False, 0.0, float("inf"), False
        h.isolated, h.suspects, h.validity = [], [], Validity.NOMINAL
        h.state = self._state_of(self.pipeline.table.full_code)

    def _new_episode(self) -> None:
        self._ep_code = -1
        self._ep_n = 0          # samples of the episode (alarms and the quiet gaps between them)
        self._ep_alarms = 0     # alarm samples of the episode
        self._ep_quiet = 0      # consecutive quiet samples at its end
        self._ep_sum: np.ndarray | None = None
        self._ep_M: np.ndarray | None = None      # the scatter's newer block (its samples: _ep_mn)
        self._ep_M_old: np.ndarray | None = None  # the older, full block (scatter_window / 2 samples), or None
        self._ep_mn = 0
        self._cand: tuple[int, ...] = ()
        self._streak = 0
        self._last_dec: SetDecision | None = None

    @property
    def state(self) -> HealthState:
        return self.health.state

    @property
    def active_code(self) -> int:
        """The set the manager keeps in, as a set code (bit i = sensor i): what each step hands the pipeline."""
        return self._iso_code

    @property
    def isolated(self) -> np.ndarray:
        """Sensors the manager keeps out of the estimate (copy)."""
        return self._iso.copy()

    @property
    def sensor_states(self) -> dict[str, str]:
        """Name -> per-sensor state (``healthy``, ``suspect``, ``isolated``, ``recovering``, ``failed``)."""
        return {nm: SensorState(int(s)).name.lower() for nm, s in zip(self.names, self.sensors.state)}

    def _index(self, sensor: str | int) -> int:
        if isinstance(sensor, str):
            if sensor not in self.names:
                raise ShapeError(f"no sensor named {sensor!r}; sensors: {self.names}")
            return self.names.index(sensor)
        if isinstance(sensor, (bool, np.bool_)) or not isinstance(sensor, (int, np.integer)) \
                or not 0 <= sensor < self.n:
            raise IndexError(f"sensor index must be an integer in 0..{self.n - 1}, got {sensor!r}")
        return int(sensor)

    def isolate(self, sensor: str | int) -> None:
        """Take a sensor out by command (logged; counts as an isolation of that sensor)."""
        i = self._index(sensor)
        t = self._t_last
        if self.sensors.isolate(i, "command"):
            self._log("failed", i, "isolated by command, isolation limit reached: FAILED", t)
        self._log("isolated", i, "isolated by command", t)
        self._apply()

    def readmit(self, sensor: str | int) -> None:
        """Bring a sensor back by command (also a FAILED one)."""
        i = self._index(sensor)
        self.sensors.readmit(i)
        self._log("readmitted", i, "re-admitted by command", self._t_last)
        self._apply()

    _t_last = float("nan")

    def _apply(self) -> None:
        """Take the sensor states' isolation set; the pipeline gets it with the next step (the pipeline holds no
        isolation set of its own: the set is an argument of each of its calls)."""
        self._iso = self.sensors.out.copy()
        self._iso_bytes = self._iso.tobytes()
        self._n_iso = int(self._iso.sum())
        self._iso_code = mask_bits(~self._iso)
        self.health.state = self._state_of(self._iso_code)
        self.health.isolated = [self.names[i] for i in np.flatnonzero(self._iso)]

    def _log(self, kind: str, sensor: int | None, message: str, t: float, statistic: float = float("nan")) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if len(self.events) < self.max_events:
            self.events.append(FdiEvent(self.samples - 1, t, kind, None if sensor is None else self.names[sensor],
                                        message, float(statistic)))

    def _state_of(self, code: int) -> HealthState:
        """State of a sensor set (cached per set)."""
        st = self._set_state.get(code)
        if st is None:
            tab = self.pipeline.table
            s = tab.get(code)
            n_act = int(code).bit_count()
            if not s.observable:
                st = HealthState.UNOBSERVABLE
            elif n_act == 3 or s.dof == 0:
                st = HealthState.NO_REDUNDANCY
            else:
                d = int(s.dof)
                act = bits_mask(code, self.n)
                ok = d >= 2
                if ok:
                    rho = column_correlations(s.Vz[:d])[np.ix_(act, act)]
                    ok = bool(np.all(np.abs(rho[~np.eye(len(rho), dtype=bool)]) < 1 - 1e-6))
                if not ok:
                    st = HealthState.DETECTION_ONLY
                elif n_act < self.n:
                    st = HealthState.FAULT_ISOLATED
                else:
                    st = HealthState.NOMINAL
            self._set_state[code] = st
        return st

    # ------------------------------------------------------------------ per sample
    def step(self, y: np.ndarray, valid: np.ndarray | None = None, t: float | None = None) -> FdiResult:
        """Process one raw sample; returns the manager's (reused) :class:`FdiResult`.

        :attr:`health` holds the state, alarm and statistic after this sample.
        """
        pipe = self.pipeline
        r = pipe.step(y, valid, self._iso_code)
        self._r = r
        self.samples += 1
        h = self.health
        if t is None:
            t = (self.samples - 1) / self.sample_rate if self.sample_rate else float(self.samples - 1)
        self._t_last = t
        c = r.code
        if c != self._cur:
            self._cur = c
            self.detector.configure(pipe.table.get(c).Vz, r.dof)
            if self._ep_n:
                self._end_episode(t)
        changed = False
        if c != self._iso_code or self._invalid_pending:  # the pipeline left a sensor out: invalid data
            changed = self._invalid(r.invalid, t)
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
        exclude: tuple[int, ...] = ()
        if alarm and getattr(self.detector, "model_exceeded", False):  # evidence beyond the model: no isolation
            if not self._exceeded:
                self._log("model_exceeded", None, "alarm while the motion exceeds what the detector's model was "
                          "fitted on: output DEGRADED, nothing isolated", t, stat)
            self._exceeded = True
            alarm = False           # reported (health.alarm, output DEGRADED), not evidence
        else:
            self._exceeded = self._exceeded and bool(getattr(self.detector, "model_exceeded", False))
        if alarm:
            self._quiet = 0
            exclude, changed2 = self._on_alarm(r, stat, t)
            changed = changed or changed2
        else:
            if self._ep_n:
                self._ep_quiet += 1
                gap = self.clear_after if self._not_isolable else self.episode_gap  # an unresolved fault: keep pooling
                if self._ep_quiet >= gap or r.dof < 1:
                    self._end_episode(t)
                else:
                    self._accumulate(r)
                    self._streak = 0
            if self._not_isolable:
                self._quiet += 1
                if self._quiet >= self.clear_after:
                    self._clear_not_isolable(t, f"no alarm for {self._quiet} samples")
            if self._suspects_on:
                self.sensors.set_suspects(r.invalid)
                self._suspects_on = bool(np.any(self.sensors.state == SensorState.SUSPECT))
        res = self._output(r, exclude if not changed else tuple(np.flatnonzero(self._iso & r.active)))
        if res.observable != self._observable:  # nothing to estimate from, or an estimate again: say so
            self._observable = res.observable
            st = self._state_of(self._iso_code)
            if res.observable:
                self._log("state", None, f"state unobservable -> {res.state.value} ({self._usable(r)} sensors "
                          "delivering usable data)", t)
            else:
                self._log("state", None, f"state {st.value if st is not HealthState.UNOBSERVABLE else 'nominal'} "
                          f"-> unobservable ({self._usable(r)} sensors delivering usable data): no estimate", t)
        if self._n_iso and self.readmit_after is not None and res.observable and not h.alarm \
                and not self._not_isolable and not self._ep_alarms:
            self._readmission(np.asarray(y, dtype=float), valid, res, t)
        return res

    def _output(self, r: StepResult, exclude: tuple[int, ...]) -> FdiResult:
        """Fill the result: the pipeline's sample, or the same sample without ``exclude`` (x, P, parity together)."""
        res = self.result
        h = self.health
        if not exclude and r.entry == self._plain_entry and not h.alarm and not self._not_isolable \
                and not self._ep_alarms:
            # the common case: the same set as the previous sample, nothing going on; only the numbers changed
            res.statistic, res.threshold, res.alarm = h.statistic, h.threshold, False
            return res
        self._plain_entry = -99
        if exclude and r.observable:
            act = r.active.copy()
            act[list(exclude)] = False
            code = mask_bits(act)  # state, active, x, P and parity: one set, the one the estimate uses
            tab = self.pipeline.table
            s1 = tab.get(code)
            e1 = s1.entry
            res.active = act
            res.invalid = r.invalid
            res.code = code
            if s1.observable:
                A, B = self._remap_of(tab.get(r.code), s1, r.active)
                d0 = r.dof
                zin = np.concatenate([r.x, r.parity[:d0]])
                self._x[:] = A @ zin
                self._p[:] = 0.0
                self._p[:B.shape[0]] = B @ zin
                res.x, res.parity, res.P = self._x, self._p, s1.P
                res.dof, res.entry, res.observable = int(s1.dof), e1, True
            else:
                self._x[:] = np.nan
                self._p[:] = 0.0
                res.x, res.parity, res.P = self._x, self._p, np.diag([np.inf] * 3)
                res.dof, res.entry, res.observable = 0, e1, False
        else:
            res.x, res.P, res.parity, res.dof = r.x, r.P, r.parity, r.dof
            res.active, res.invalid, res.observable, res.entry = r.active, r.invalid, r.observable, r.entry
            res.code = r.code
            code = r.code if r.observable else -1
        res.alarm, res.statistic, res.threshold = h.alarm, h.statistic, h.threshold
        res.fault_not_isolable = self._not_isolable
        if not res.observable:
            res.validity = Validity.UNOBSERVABLE
            res.state = HealthState.UNOBSERVABLE
        else:
            res.state = self._state_of(code)
            full = code == self._full_code and not exclude  # every expected sensor in this sample's estimate
            # an open alarm episode (an alarm in the last `episode_gap` samples, not resolved) is an unresolved fault
            ok = full and not h.alarm and not self._not_isolable and not self._ep_alarms
            res.validity = Validity.NOMINAL if ok else Validity.DEGRADED
        h.state = self._state_of(self._iso_code)  # the manager's state: its isolation set (res.state: the sample's)
        h.validity = res.validity
        if not exclude and not h.alarm and not self._not_isolable and not self._ep_alarms:
            self._plain_entry = r.entry
        h.fault_not_isolable = self._not_isolable
        return res

    def _remap_of(self, s0: Any, s1: Any, act0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear maps from (x, parity) of set e0 to x and parity of its subset e1.

        On the active sensors of e0 the compensated outputs are recovered exactly from the pipeline's outputs,
        ``z = A x + diag(sigma^2) Vz^T p`` (the projection and the parity split the whitened z), then projected
        with the subset's G and Vz.
        """
        tab = self.pipeline.table
        key = (s0.code, s1.code)  # by sensor set, not by entry (a table may renumber)
        m = self._remap.get(key)
        if m is None:
            d0 = int(s0.dof)
            n = self.n
            Z = np.zeros((n, 3 + d0))
            a = act0
            Z[a, :3] = tab.axes[a]
            Z[a, 3:] = (tab.sigma[a] ** 2)[:, None] * s0.Vz[:d0, a].T
            d1 = int(s1.dof)
            m = (s1.G @ Z, s1.Vz[:d1] @ Z)
            if len(self._remap) > 1024:
                self._remap.clear()
            self._remap[key] = m
        return m

    # ------------------------------------------------------------------ alarms and isolation
    def _accumulate(self, r: StepResult) -> None:
        """Add the sample's parity vector to the episode's evidence (its sum and scatter)."""
        d = r.dof
        p = r.parity[:d]
        if self._ep_sum is None or self._ep_sum.shape[0] != d:
            self._ep_sum = np.zeros(d)
            self._ep_M, self._ep_M_old, self._ep_mn = np.zeros((d, d)), None, 0
        if self._ep_mn >= self.scatter_window // 2:  # the newer block is full: it becomes the older, the oldest goes
            self._ep_M_old, self._ep_M, self._ep_mn = self._ep_M, np.zeros((d, d)), 0
        self._ep_sum += p
        self._ep_M += np.outer(p, p)
        self._ep_mn += 1
        self._ep_n += 1
        self._ep_code = r.code

    def _decide(self, r: StepResult) -> SetDecision:
        d = r.dof
        N = self._ep_n
        last = self._last_dec
        if last is not None and last.kind != "isolated" and self._ep_alarms > 4 * self.confirm \
                and self._ep_alarms % 10:
            return last  # an unresolved fault: re-decide every 10th alarm (the evidence changes slowly)
        if self.isolator == "detector":
            j, _ = self.detector.isolate(r.parity)
            st = self._state_of(r.code)
            if j < 0 or st not in (HealthState.NOMINAL, HealthState.FAULT_ISOLATED):
                return SetDecision("not_isolable")
            return SetDecision("isolated", (int(j),), (int(j),))
        iso = self.isolator
        Vz = self.pipeline.table.get(r.code).Vz
        mean = self._ep_sum / np.sqrt(N)
        dec = iso.decide(mean, Vz, d)
        if dec.kind != "isolated" and N > 1:
            # a fault whose size changes (sign) has little mean: the scatter of the episode may name it
            # over the last scatter_window / 2 + 1 .. scatter_window samples: a threshold of the finite table
            M, Ns = self._ep_M, self._ep_mn
            if self._ep_M_old is not None:
                M, Ns = M + self._ep_M_old, Ns + self.scatter_window // 2
            dec2 = iso.decide_scatter(M, Ns, Vz, d)
            if dec2.kind == "isolated" or float(mean @ mean) < iso.threshold(d, 0):
                dec = dec2
        return dec

    @property
    def _needed(self) -> int:
        """Consecutive alarms that confirm: ``confirm``, or ``(confirm - 1) span + 1`` for a detector whose
        statistics overlap over ``span`` samples (``evidence_span``: a window mean), i.e. ``confirm`` disjoint
        pieces of evidence."""
        span = int(getattr(self.detector, "evidence_span", 1))
        return self.confirm if span <= 1 else (self.confirm - 1) * span + 1

    def _on_alarm(self, r: StepResult, stat: float, t: float) -> tuple[tuple[int, ...], bool]:
        """Returns (sensors to leave out of this sample's output, whether the isolation set changed)."""
        self._ep_alarms += 1
        self._ep_quiet = 0
        if r.dof >= 1:
            self._accumulate(r)
        dec = self._decide(r) if r.dof >= 1 else SetDecision("not_isolable")
        self._last_dec = dec
        sus = np.zeros(self.n, bool)
        sus[list(dec.suspects)] = True
        self.sensors.set_suspects(sus | r.invalid)
        self._suspects_on = True
        if dec.kind != "isolated":
            self._streak = 0
            self._cand = ()
            if self._ep_alarms >= self._needed and not self._not_isolable:
                self._not_isolable = True
                self._quiet = 0
                what = {"ambiguous": "several sensor sets explain it equally well"
                        + (f" (suspects {[self.names[i] for i in dec.suspects]})" if dec.suspects else ""),
                        "unexplained": "no set of up to "
                        f"{getattr(self.isolator, 'max_size', 1)} sensors explains it",
                        "not_isolable": f"parity dimension {r.dof} cannot isolate"}.get(dec.kind, dec.kind)
                self._log("detected_not_isolable", None,
                          f"fault present with {int(r.active.sum())} active sensors, not isolable: {what}; "
                          "output DEGRADED", t, stat)
            self.health.suspects = [self.names[i] for i in dec.suspects]
            if dec.suspects:  # leave every suspect out of this sample's output when the rest still spans 3-D
                rest = r.active.copy()
                rest[list(dec.suspects)] = False
                if self._state_of(mask_bits(rest)) is not HealthState.UNOBSERVABLE:
                    return dec.suspects, False
            return (), False
        S = dec.sensors
        self.health.suspects = [self.names[i] for i in S]
        if S == self._cand:
            self._streak += 1
        else:
            self._cand, self._streak = S, 1
        remaining = r.active.copy()
        remaining[list(S)] = False
        if self._state_of(mask_bits(remaining)) is HealthState.UNOBSERVABLE:
            return (), False  # never isolate into blindness
        if self._streak < self._needed:
            return S, False
        names = [self.names[i] for i in S]
        for i in S:
            if self.sensors.isolate(i, "fault"):
                self._log("failed", i, f"isolated {int(self.sensors.isolations[i])} times: FAILED, "
                                       "re-admitted only on command", t, stat)
            self._log("isolated", i, f"isolated with {names} after {self._streak} consecutive alarms "
                                     f"(GLT over sensor sets, Eq. 21)", t, stat)
        old = self.health.state
        self._apply()
        self._new_episode()
        if self._not_isolable:
            self._clear_not_isolable(t, f"isolated {names}")
        self._log_state(old, t)
        return S, True

    def _end_episode(self, t: float) -> None:
        if self._ep_alarms:
            who = self._cand
            if not who and self._ep_sum is not None and self._ep_code >= 0:
                j, _ = isolate_argmax(self._ep_sum, self.pipeline.table.get(self._ep_code).Vz[:len(self._ep_sum)])
                who = (j,) if j >= 0 else ()
            for i in who:
                self._log("transient", i, f"alarm episode of {self._ep_alarms} alarm(s), not confirmed"
                          + ("" if self._cand else " (most likely sensor)"), t)
        self._new_episode()

    def _clear_not_isolable(self, t: float, why: str) -> None:
        self._not_isolable = False
        self._quiet = 0
        self._log("not_isolable_cleared", None, f"fault no longer reported: {why}", t)

    def _usable(self, r: StepResult | None) -> int:
        """Sensors in the isolation set that delivered usable data (finite, valid, inside the range) on ``r``."""
        keep = ~self._iso
        if r is not None:
            keep &= ~r.invalid
            if r.saturated.shape == keep.shape:
                keep &= ~r.saturated
        return int(np.count_nonzero(keep))

    def _log_state(self, old: HealthState, t: float) -> None:
        new = self._state_of(mask_bits(~self._iso))
        if new != old:
            self._log("state", None, f"state {old.value} -> {new.value} ({self._usable(self._r)} sensors "
                      "active, delivering usable data)", t)

    def _invalid(self, inv: np.ndarray, t: float) -> bool:
        run = self._invalid_run
        ended = (~inv) & (run > 0)
        for i in np.flatnonzero(ended):
            if not self._iso[i]:
                self._log("invalid_transient", int(i), f"{int(run[i])} invalid sample(s), routed around", t)
        run[ended] = 0
        run[inv] += 1
        alone = self._alone_run
        alone[~inv] = 0
        was_common = self._gate.common
        ev = self._gate.invalid_alone(inv) if self.common_cause else inv
        if self._gate.common and not was_common:
            self._log("common_invalid", None, f"{int(inv.sum())} sensors of several sub-units invalid at once "
                      "(range or common cause): routed around, nothing isolated", t)
        alone[ev] += 1
        alone[inv & ~ev] = 0
        self._invalid_pending = bool(run.any())
        self.sensors.set_suspects(inv | (self.sensors.state == SensorState.SUSPECT))
        self._suspects_on = True
        changed = False
        for i in np.flatnonzero((alone >= self.invalid_persist) & ~self._iso):
            keep = ~self._iso
            keep[i] = False
            if self._state_of(mask_bits(keep)) is HealthState.UNOBSERVABLE:
                continue  # isolating it would leave the unit blind; the pipeline routes around it per sample
            old = self._state_of(mask_bits(~self._iso))
            if self.sensors.isolate(int(i), "invalid"):
                self._log("failed", int(i), "isolated too often: FAILED, re-admitted only on command", t)
            self._apply()
            self._log("invalid_isolated", int(i), f"output invalid for {int(run[i])} samples", t)
            self._log_state(old, t)
            changed = True
        return changed

    def _readmission(self, y: np.ndarray, valid: np.ndarray | None, res: FdiResult, t: float) -> None:
        """The re-admission test of each isolated sensor on this sample: its compensated output against the
        estimate of the others, ``(z_j - a_j x) / sqrt(sigma_j^2 + a_j P a_j)``.

        ``z_j = SF_j y_j - b_j`` is the compensated output the pipeline would use: ``y`` is what the pipeline
        got, which, where the calibration holds further effects (temperature, drift, g-sensitivity, ...), is the
        compensation stage's output (an ideal SF/M/B sensor's raw value; :meth:`rimu.fusion.Pipeline.step_through`,
        :class:`rimu.fdi.UnitManager`), never the device's raw value. A sample that is no measurement (non-finite,
        flagged invalid, or clipped at the range limit: :meth:`rimu.fusion.InstrumentPipeline.usable`) restarts
        the sensor's clean period."""
        sig = self.pipeline.table.sigma
        sh = self.sensors
        back = []
        usable = self.pipeline.usable(y[None], None if valid is None else np.asarray(valid)[None])[0]
        for j in np.flatnonzero(self._iso):
            if sh.state[j] == SensorState.FAILED:
                continue
            if not usable[j]:
                sh.unclean(int(j))
                continue
            a = self._axes[j]
            rj = (self._scale[j] * y[j] - self._bias[j]) - a @ res.x
            zn = float(rj / np.sqrt(sig[j] ** 2 + a @ res.P @ a))
            n_before = sh.clean_count(int(j))
            if sh.clean_sample(int(j), zn):
                back.append(int(j))
                self._log("readmitted", int(j), f"clean for {n_before + 1} samples: re-admitted", t)
        if back:
            old = self._state_of(mask_bits(~self._iso))
            self._apply()
            self._log_state(old, t)

    # ------------------------------------------------------------------ blocks
    def run(self, Y: np.ndarray, valid: np.ndarray | None = None, t: np.ndarray | None = None) -> ReplayResult:
        """Process N samples one by one (closed loop) and collect the outputs; (N, n) raw samples.

        Continues from the manager's current state (isolated sensors, counters, sample count): a stream cut
        into blocks gives the same outputs as one call. Call :meth:`reset` first to start over. The returned
        ``events`` are the events of this call.
        """
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2 or Y.shape[1] != self.pipeline.n:
            raise ShapeError(f"a block of raw samples must have shape (N, {self.pipeline.n}), got {Y.shape}")
        N = len(Y)
        if t is None:
            base = self.samples
            t = (base + np.arange(N)) / (self.sample_rate or 1.0)
        t = np.asarray(t, float)
        out = _Collector(self, N)
        fast = self.pipeline.backend == "numba" and type(self.detector) is GltSnapshot
        buf = np.empty((min(N, _QUIET_MAX), 3 + max(self.n - 3, 0))) if fast else None
        size = _QUIET_MIN
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite raw values are routed around, not warned
            k = 0
            while k < N:
                if fast and self._is_quiet():
                    m = self._quiet_block(Y, valid, t, k, min(N, k + size), buf, out)
                    k += m
                    size = min(2 * size, _QUIET_MAX) if m == size else _QUIET_MIN
                    if k >= N:
                        break
                out.add(k, self.step(Y[k], None if valid is None else valid[k], float(t[k])))
                k += 1
        return out.result(t)

    # ------------------------------------------------------------------ block fast path
    def _is_quiet(self) -> bool:
        """Whether a clean sample below the threshold would change nothing but the numbers: the last output took
        :meth:`_output`'s common path on the isolation set, no episode, report, suspect, pending invalid run or
        isolated sensor (nothing to re-admit)."""
        return (self._plain_entry == self.pipeline.result.entry and self._cur == self._iso_code and not self._n_iso and not self._ep_n
                and not self._not_isolable and not self._suspects_on and not self._invalid_pending
                and not self._exceeded and not self._uses_input and self._observable)

    def _quiet_block(self, Y: np.ndarray, valid: np.ndarray | None, t: np.ndarray, k0: int, k1: int,
                     buf: np.ndarray, out: _Collector) -> int:
        """Samples k0.. up to k1 (exclusive) in bulk while nothing can happen: every sensor valid, every value on
        the pipeline's common path, every statistic at or below its threshold; the same state and outputs as
        :meth:`step` on each. Returns how many were taken (the first one that may change something, or the
        end, is left to :meth:`step`)."""
        Yb = Y[k0:k1]
        if valid is not None:
            v = np.asarray(valid[k0:k1], dtype=bool).all(axis=1)
            if not v.all():
                Yb = Yb[:int(np.argmin(v))]
        pipe = self.pipeline
        m = pipe.common_rows(Yb, buf, self._iso_code) if len(Yb) else 0
        if not m:
            return 0
        P = buf[:m]
        stat = self.detector.block_update(P[:, 3:])
        if stat is None:
            return 0
        thr = self.detector.threshold(pipe.result.dof)
        hit = stat > thr
        if hit.any():
            m = int(np.argmax(hit))
            if not m:
                return 0
            P, stat = P[:m], stat[:m]
        pipe.advance(P)
        self.samples += m
        self._t_last = float(t[k0 + m - 1])
        h, res = self.health, self.result
        h.statistic, h.threshold, h.alarm = float(stat[-1]), thr, False
        res.statistic, res.threshold, res.alarm = h.statistic, thr, False
        out.add_quiet(k0, P[:, :3], stat, thr, res)
        return m


#: the block fast path's run lengths (samples): from the first after an event, doubling while nothing happens
_QUIET_MIN, _QUIET_MAX = 16, 8192


class _Collector:
    """The per-sample outputs of one manager over N samples, gathered into a :class:`ReplayResult` (the active
    set and covariance diagonal are filled per set at the end, not copied per sample)."""

    def __init__(self, mgr: RedundancyManager, N: int) -> None:
        n = mgr.n
        self.mgr = mgr
        self.first = len(mgr.events)
        self.x, self.stat, self.thr = np.zeros((N, 3)), np.zeros(N), np.zeros(N)
        self.alarm, self.state = np.zeros(N, bool), np.zeros(N, np.int8)
        self.validity, self.sensor = np.zeros(N, np.int8), np.zeros((N, n), np.int8)
        self.entry = np.full(N, -1, dtype=np.int64)
        self.obs = np.zeros(N, bool)
        self.seen: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # entry -> (active, diag P), while the set is cached

    def add(self, k: int, r: FdiResult) -> None:
        self.x[k] = r.x
        self.stat[k], self.thr[k], self.alarm[k] = r.statistic, r.threshold, r.alarm
        self.state[k] = STATE_CODES[r.state]
        self.validity[k] = r.validity
        e = r.entry
        self.entry[k] = e
        self.obs[k] = r.observable
        self.sensor[k] = self.mgr.sensors.state
        if e not in self.seen:
            self.seen[e] = (np.asarray(r.active, bool).copy(), np.diagonal(r.P).copy())

    def add_quiet(self, k: int, x: np.ndarray, stat: np.ndarray, thr: float, r: FdiResult) -> None:
        """Samples k.. of a quiet run (:meth:`RedundancyManager._quiet_block`): their estimates and statistics;
        everything else as the last output ``r``."""
        m = len(x)
        sl = slice(k, k + m)
        self.x[sl] = x
        self.stat[sl], self.thr[sl], self.alarm[sl] = stat, thr, False
        self.state[sl] = STATE_CODES[r.state]
        self.validity[sl] = r.validity
        self.entry[sl] = r.entry
        self.obs[sl] = r.observable
        self.sensor[sl] = self.mgr.sensors.state
        if r.entry not in self.seen:
            self.seen[r.entry] = (np.asarray(r.active, bool).copy(), np.diagonal(r.P).copy())

    def result(self, t: np.ndarray) -> ReplayResult:
        N, mgr = len(self.entry), self.mgr
        active, P = np.zeros((N, mgr.n), bool), np.zeros((N, 3))
        for e, (act, pd) in self.seen.items():
            rows = (self.entry == e) & self.obs
            active[rows] = act
            P[rows] = pd
        P[~self.obs] = np.inf
        return ReplayResult(t, self.x, self.stat, self.thr, self.alarm, self.state,
                            active.sum(axis=1).astype(np.int8), mgr.events[self.first:], mgr.names, self.validity,
                            self.sensor, active, P)
