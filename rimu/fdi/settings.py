"""The one settings object of the runtime's fault management, with the one set of defaults.

:class:`FdiSettings` is read by everything that decides: :class:`rimu.fdi.Runtime` (and the managers it holds),
``rimu monitor``, ``rimu replay``, ``rimu demo``, ``rimu export-c`` (the settings baked into the flight code),
:func:`rimu.experiments.validate.validate`, the campaigns and the scenarios. Each of them takes its default from
:data:`DEFAULTS`; ``tests/fdi/test_settings_defaults.py`` compares every consumer's default with it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from ..errors import ExportError
from .health import READMIT_AFTER

__all__ = ["DEFAULTS", "FdiSettings"]

#: the largest count the generated code holds (a 32-bit C int)
C_INT_MAX = 2**31 - 1
#: the most isolations of one sensor the generated code tables (fail_after)
MAX_ISOLATIONS = 1000
#: the longest scatter window of the set test (its thresholds are a table of scatter_window (n - 4) numbers)
MAX_SCATTER_WINDOW = 1000


@dataclass(frozen=True)
class FdiSettings:
    """The fault management's configuration: the runtime's, and the one baked into the generated C.

    Parameters
    ----------
    p_fa : float
        Per-sample false-alarm probability of the detector (GLT snapshot, Daly, Gai & Harrison 1979), of the
        re-admission test.
    confirm : int
        Consecutive alarms naming the same sensor set before it is isolated (Cho & Park 2005, Eq. 21).
    invalid_persist : int
        Consecutive invalid samples of one sensor before it is isolated.
    readmit_after : int or None
        Clean samples before the first re-admission (None: never automatically).
    fail_after, backoff : int, float
        FAILED after this many isolations; the clean period grows by ``backoff`` per isolation.
    clear_after : int
        Alarm-free samples after which a "not isolable" report is withdrawn.
    episode_gap : int or None
        Alarm-free samples that end an alarm episode (None: ``max(confirm, 5)``).
    scatter_window : int
        The most samples of an alarm episode the set test pools in its scatter (an even number): the scatter is
        kept in two blocks of ``scatter_window / 2`` samples and, when the newer block is full, the older one is
        dropped, so the test sees the episode's last ``scatter_window / 2 + 1`` to ``scatter_window`` samples.
        Every consistency threshold the set test can need is then one of a finite table,
        ``chi2_{1 - alpha}(nu)`` for ``nu`` up to ``scatter_window (n - 4)`` (:meth:`set_thresholds`), computed
        once (at export time for the generated code): no chi-square quantile at run time.
    common_cause : bool
        Count toward ``invalid_persist`` only invalid samples confined to one sub-unit
        (:class:`rimu.fdi.common_cause.EvidenceGate`; units of triads that clip together). Not in the generated
        C: the export refuses it.
    alpha, max_size, max_sets, collinear_tol
        The set test's (:class:`rimu.fdi.multiple.FaultSetGlt`): level ``alpha`` = 1e-4 (small, so that the true
        set is not rejected by chance while the evidence accumulates), sets of up to ``max_size`` sensors.

    Examples
    --------
    >>> FdiSettings().confirm, FdiSettings().alpha
    (3, 0.0001)
    >>> FdiSettings(confirm=5).manager_kwargs()["confirm"]
    5
    """

    p_fa: float = 1e-3
    confirm: int = 3
    invalid_persist: int = 10
    readmit_after: int | None = READMIT_AFTER
    fail_after: int = 4
    backoff: float = 2.0
    clear_after: int = 50
    episode_gap: int | None = None
    scatter_window: int = 64
    alpha: float = 1e-4
    max_size: int = 2
    max_sets: int = 20000
    collinear_tol: float = 1e-3
    common_cause: bool = False

    def __post_init__(self) -> None:
        checks = [
            (0 < self.p_fa < 1, f"p_fa must be in (0, 1), got {self.p_fa}"),
            (0 < self.alpha < 1, f"alpha must be in (0, 1), got {self.alpha}"),
            (self.confirm >= 1, f"confirm must be at least 1 sample, got {self.confirm}"),
            (self.invalid_persist >= 1, f"invalid_persist must be at least 1 sample, got {self.invalid_persist}"),
            (self.readmit_after is None or self.readmit_after >= 1,
             f"readmit_after must be at least 1 sample (or None), got {self.readmit_after}"),
            (self.fail_after >= 1, f"fail_after must be at least 1, got {self.fail_after}"),
            (self.backoff >= 1.0, f"backoff must be at least 1, got {self.backoff}"),
            (self.clear_after >= 1, f"clear_after must be at least 1 sample, got {self.clear_after}"),
            (self.episode_gap is None or self.episode_gap >= 1,
             f"episode_gap must be at least 1 sample, got {self.episode_gap}"),
            (2 <= self.scatter_window <= MAX_SCATTER_WINDOW and self.scatter_window % 2 == 0,
             f"scatter_window must be an even number of samples from 2 to {MAX_SCATTER_WINDOW}, got "
             f"{self.scatter_window}"),
            (self.max_size in (1, 2), f"the set test names sets of 1 or 2 sensors (max_size), got {self.max_size}"),
            (self.max_sets >= 1, f"max_sets must be at least 1, got {self.max_sets}"),
            (0 <= self.collinear_tol < 1, f"collinear_tol must be in [0, 1), got {self.collinear_tol}"),
        ]
        for ok, msg in checks:
            if not ok:  # (ExportError: these settings are also baked into the flight code, rimu.export)
                raise ExportError(msg)
        # the generated code holds counts in C ints (32 bits) and one re-admission period per isolation in a table
        for name in ("confirm", "invalid_persist", "readmit_after", "fail_after", "clear_after", "episode_gap"):
            v = getattr(self, name)
            if v is not None and v > C_INT_MAX:
                raise ExportError(f"{name} must be at most {C_INT_MAX} (a C int of the generated code), got {v}")
        if self.fail_after > MAX_ISOLATIONS:
            raise ExportError(f"fail_after must be at most {MAX_ISOLATIONS} (one re-admission period per isolation is "
                              f"tabled in the generated code), got {self.fail_after}")
        if self.readmit_after is not None:
            top = math.log(self.readmit_after) + max(self.fail_after - 2, 0) * math.log(self.backoff)
            if top > math.log(C_INT_MAX):
                raise ExportError(f"readmit_after x backoff^(fail_after - 2) = {self.readmit_after} x "
                                  f"{self.backoff:g}^{max(self.fail_after - 2, 0)} exceeds {C_INT_MAX} samples (a C "
                                  "int): lower readmit_after, backoff or fail_after")

    @property
    def gap(self) -> int:
        return int(self.episode_gap) if self.episode_gap is not None else max(self.confirm, 5)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def replace(self, **changes: Any) -> FdiSettings:
        """A copy with some settings changed (None values are ignored: the option was not given)."""
        d = self.as_dict()
        d.update({k: v for k, v in changes.items() if v is not None})
        return FdiSettings(**d)

    def isolator(self) -> Any:
        from .multiple import FaultSetGlt

        return FaultSetGlt(alpha=self.alpha, max_size=self.max_size, max_sets=self.max_sets,
                           collinear_tol=self.collinear_tol)

    def manager_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`rimu.fdi.RedundancyManager` that make the same decisions
        (``RedundancyManager(InstrumentPipeline(inst), **settings.manager_kwargs())``; the whole unit's:
        ``rimu.fdi.Runtime(cal, settings)``, what the generated ``rimu_fdi_step`` does per epoch)."""
        return {"p_fa": self.p_fa, "confirm": self.confirm, "invalid_persist": self.invalid_persist,
                "readmit_after": self.readmit_after, "fail_after": self.fail_after, "backoff": self.backoff,
                "clear_after": self.clear_after, "episode_gap": self.episode_gap, "isolator": self.isolator(),
                "common_cause": self.common_cause, "scatter_window": self.scatter_window}

    # ---------------------------------------------------------------- tables of the generated code
    def required(self) -> list[int]:
        """Clean samples before re-admission after the 1st, 2nd, ... isolation (rimu.fdi.health.SensorHealth)."""
        if self.readmit_after is None:
            return [0]
        return [round(self.readmit_after * self.backoff ** k) for k in range(max(self.fail_after - 1, 1))]

    def set_top(self, nmax: int) -> int:
        """The largest ``nu`` of :meth:`set_thresholds` for units of up to ``nmax`` sensors: the scatter over
        ``scatter_window`` samples of a set of ``nmax - 3`` parity dimensions less one suspect sensor, and at least
        the parity dimension itself (the test of the episode's mean, ``chi2(dof)``)."""
        return max(self.scatter_window * max(nmax - 4, 0), nmax - 3, 1)

    def set_thresholds(self, nmax: int) -> np.ndarray:
        """``chi2_{1 - alpha}(nu)`` for ``nu = 0 .. set_top(nmax)`` (entry 0 unused): every consistency threshold of
        the set test, ``c = chi2_{1 - alpha}(samples (dof - size))`` with ``samples <= scatter_window``, for units of
        up to ``nmax`` sensors (Daly, Gai & Harrison 1979, extended to sets). The same scipy quantile as
        :meth:`rimu.fdi.multiple.FaultSetGlt.threshold`, which the Python runtime decides with, entry for entry.

        >>> t = FdiSettings(scatter_window=4).set_thresholds(6)
        >>> len(t), round(float(t[3]), 3)          # nu = 0 .. 4 x (6 - 4); chi2_(1 - 1e-4)(3)
        (9, 21.108)
        """
        from scipy.stats import chi2

        nu = np.arange(self.set_top(nmax) + 1)
        return np.where(nu > 0, chi2.isf(self.alpha, np.maximum(nu, 1)), 0.0)

    def mean_threshold(self) -> float:
        from scipy.stats import chi2

        return float(chi2.isf(self.p_fa, 1))

    def energy(self) -> list[float]:
        """chi2(N) quantile at the mean test's probability for each clean period N (SensorHealth._energy_threshold)."""
        from scipy.stats import chi2

        p = chi2.sf(self.mean_threshold(), 1)
        return [float(chi2.isf(p, max(N, 1))) for N in self.required()]


#: the defaults, read by every consumer
DEFAULTS = FdiSettings()
#: names of the settings
NAMES = tuple(f.name for f in fields(FdiSettings))
