"""Per-sensor health: a state machine with hysteresis, re-admission and a bound on ping-pong.

States (:class:`SensorState`) and their transitions::

    HEALTHY --(named by an alarm, or invalid data)--> SUSPECT --(alarm/invalid ends)--> HEALTHY
    SUSPECT --(confirmed: isolated set, or invalid for `invalid_persist` samples)--> ISOLATED
    ISOLATED --(valid and consistent with the estimate of the others)--> RECOVERING
    RECOVERING --(one inconsistent or invalid sample)--> ISOLATED
    RECOVERING --(clean for `required` samples and the mean passes)--> HEALTHY   (re-admitted)
    ISOLATED --(isolated for the `fail_after`-th time)--> FAILED          (re-admitted only on command)

Hysteresis: entering takes ``confirm`` consecutive alarms (or ``invalid_persist`` invalid samples), leaving
takes ``required`` consecutive clean samples, each within a loose chi-square test (1e-6) AND their mean
and their energy within the chi-square tests of the mean and of the sum of squares at the design false-alarm
probability (a bias of ``sqrt(chi2_1 / required)`` sigma keeps a sensor out).
Against ping-pong (PX4's class of bug: a sensor switched in and out over and over) the clean period doubles
with every isolation of the same sensor (``required = readmit_after * backoff^(isolations - 1)``), and after
``fail_after`` isolations the sensor is FAILED: a fault that keeps coming back costs at most
``2 fail_after - 1`` transitions in and out, whatever its timing.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from scipy.special import chdtrc, chdtri

__all__ = ["READMIT_AFTER", "SensorHealth", "SensorState"]

#: Clean samples before an isolated sensor is re-admitted the first time (doubled at each further isolation of
#: it): the one default of :class:`SensorHealth`, :class:`rimu.fdi.RedundancyManager`,
#: :class:`rimu.export.FdiSettings`, ``rimu replay --readmit-after`` and ``rimu export-c --readmit-after``.
#: 100 samples is 1 s at 100 Hz: long enough for the mean and energy tests over the clean period to see a bias
#: of ``sqrt(chi2_1 / 100)`` ~ 0.33 sigma, short enough to bring back a sensor whose fault was a transient.
READMIT_AFTER = 100


class SensorState(IntEnum):
    """Health of one sensor (integer codes for arrays and plots)."""

    HEALTHY = 0
    SUSPECT = 1
    ISOLATED = 2
    RECOVERING = 3
    FAILED = 4


_OUT = (SensorState.ISOLATED, SensorState.RECOVERING, SensorState.FAILED)


class SensorHealth:
    """The state machine of every sensor of one instrument (see the module docstring).

    Parameters
    ----------
    n : int
        Sensors.
    readmit_after : int or None
        Clean samples before the first re-admission; None: isolated sensors stay out.
    backoff : float
        Factor on the clean period at each further isolation of the same sensor.
    fail_after : int
        Isolations of one sensor after which it is FAILED (not re-admitted automatically).
    mean_threshold : float
        Chi-square (1 dof) threshold of the test on the mean residual over the clean period.
    sample_threshold : float
        Chi-square (1 dof) threshold each clean sample must pass (default: probability 1e-6 without a fault,
        so that a clean period of 400 samples is not restarted by noise; gross outliers still restart it).

    Examples
    --------
    >>> h = SensorHealth(3, readmit_after=2, fail_after=2, mean_threshold=10.8)
    >>> h.isolate(1)
    False
    >>> [h.clean_sample(1, 0.1) for _ in range(2)], h.state[1].item()
    ([False, True], 0)
    >>> h.isolate(1), SensorState(int(h.state[1])).name
    (True, 'FAILED')
    """

    def __init__(self, n: int, readmit_after: int | None = READMIT_AFTER, backoff: float = 2.0, fail_after: int = 4,
                 mean_threshold: float = 10.83, sample_threshold: float = 23.93) -> None:
        if readmit_after is not None and readmit_after < 1:
            raise ValueError(f"readmit_after must be at least 1 sample (or None), got {readmit_after}")
        if backoff < 1.0:
            raise ValueError(f"backoff must be at least 1, got {backoff}")
        if fail_after < 1:
            raise ValueError(f"fail_after must be at least 1, got {fail_after}")
        self.n = int(n)
        self.readmit_after = None if readmit_after is None else int(readmit_after)
        self.backoff = float(backoff)
        self.fail_after = int(fail_after)
        self.mean_threshold = float(mean_threshold)
        self.sample_threshold = float(sample_threshold)
        self.reset()

    def reset(self) -> None:
        """Every sensor healthy, counters cleared."""
        n = self.n
        self.state = np.zeros(n, dtype=np.int8)
        self.isolations = np.zeros(n, dtype=np.int64)
        self.transitions = np.zeros(n, dtype=np.int64)  # in/out switches of the estimate (isolate, re-admit)
        self.reason = [""] * n
        self._clean = np.zeros(n, dtype=np.int64)
        self._sum = np.zeros(n)
        self._sumsq = np.zeros(n)

    # ---------------------------------------------------------------- queries
    @property
    def out(self) -> np.ndarray:
        """Sensors kept out of the estimate (isolated, recovering or failed)."""
        return self.state >= SensorState.ISOLATED

    def required(self, i: int) -> int | None:
        """Clean samples sensor i needs before re-admission (None: never automatically)."""
        if self.readmit_after is None or self.state[i] == SensorState.FAILED:
            return None
        k = max(int(self.isolations[i]) - 1, 0)
        return round(self.readmit_after * self.backoff ** k)

    # ---------------------------------------------------------------- transitions
    def set_suspects(self, mask: np.ndarray) -> None:
        """HEALTHY sensors in ``mask`` become SUSPECT, SUSPECT ones outside it HEALTHY again."""
        st = self.state
        m = np.asarray(mask, dtype=bool)
        st[m & (st == SensorState.HEALTHY)] = SensorState.SUSPECT
        st[~m & (st == SensorState.SUSPECT)] = SensorState.HEALTHY

    def isolate(self, i: int, reason: str = "fault") -> bool:
        """Take sensor i out; True when this isolation makes it FAILED."""
        if self.state[i] >= SensorState.ISOLATED:
            return False
        self.isolations[i] += 1
        self.transitions[i] += 1
        self.reason[i] = reason
        self._clean[i] = 0
        self._sum[i] = 0.0
        self._sumsq[i] = 0.0
        failed = self.isolations[i] >= self.fail_after
        self.state[i] = SensorState.FAILED if failed else SensorState.ISOLATED
        return bool(failed)

    def readmit(self, i: int) -> None:
        """Bring sensor i back (re-admission test passed, or a command)."""
        if self.state[i] >= SensorState.ISOLATED:
            self.transitions[i] += 1
        self.state[i] = SensorState.HEALTHY
        self.reason[i] = ""
        self._clean[i] = 0
        self._sum[i] = 0.0
        self._sumsq[i] = 0.0

    def unclean(self, i: int) -> None:
        """An invalid or inconsistent sample: a recovering sensor goes back to ISOLATED, its count restarts."""
        if self.state[i] == SensorState.RECOVERING:
            self.state[i] = SensorState.ISOLATED
        self._clean[i] = 0
        self._sum[i] = 0.0
        self._sumsq[i] = 0.0

    def clean_sample(self, i: int, z: float) -> bool:
        """One valid sample of an out sensor, normalised residual ``z`` against the estimate of the others.

        Returns True when the sensor is re-admitted by this sample.
        """
        if self.state[i] not in (SensorState.ISOLATED, SensorState.RECOVERING):
            return False
        need = self.required(i)
        if need is None:
            return False
        if not z * z < self.sample_threshold:
            self.unclean(i)
            return False
        self.state[i] = SensorState.RECOVERING
        self._clean[i] += 1
        self._sum[i] += z
        self._sumsq[i] += z * z
        if self._clean[i] >= need:
            N = int(self._clean[i])
            if self._sum[i] ** 2 / N < self.mean_threshold and self._sumsq[i] < self._energy_threshold(N):
                self.readmit(i)
                return True
            self.unclean(i)
        return False

    def _energy_threshold(self, N: int) -> float:
        """chi2(N) quantile at the mean test's probability: the residuals' energy over the clean period (catches
        a fault whose sign changes, e.g. a scale-factor error under a swinging input, which the mean misses)."""
        cache = self.__dict__.setdefault("_energy", {})
        if N not in cache:
            cache[N] = float(chdtri(N, chdtrc(1, self.mean_threshold)))  # chi2.isf(chi2.sf(., 1), N)
        return cache[N]

    def clean_count(self, i: int) -> int:
        return int(self._clean[i])
