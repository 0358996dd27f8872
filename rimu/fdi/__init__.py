"""Fault detection and isolation on the parity vector.

* :class:`Runtime`: the one object that owns a unit's runtime state (compensation of every effect, projection,
  parity, detection, isolation, health, re-admission, validity); ``rimu monitor``, ``rimu replay``, the demo,
  the campaigns and the exported C decide through it. :class:`FdiSettings`: its settings, with the one set of
  defaults every consumer reads.
* :class:`RedundancyManager` wraps an :class:`rimu.fusion.InstrumentPipeline`: detection, isolation of one or
  several sensors (:class:`FaultSetGlt`, the GLT over sensor sets; Cho & Park 2005, Eq. 21), reconfiguration,
  per-sensor health with re-admission (:mod:`rimu.fdi.health`), a validity flag per output, explicit
  :class:`HealthState` and events.
* :class:`UnitManager`: one manager per instrument of a :class:`rimu.fusion.Pipeline`, closed loop with the
  compensation of every further effect (temperature, g-sensitivity, ...), as the exported C's ``rimu_fdi_step``.
* Detectors, thresholds from a stated false-alarm probability or ARL0: :class:`GltSnapshot`,
  :class:`GltWindow` (Daly, Gai & Harrison 1979), :class:`CusumBank`, :class:`ParityKalman` (steady-state filter; filterpy as its reference),
  :class:`CalibrationAwareGlt`, and the autopilot-style baseline :class:`MeanDisagreement`.
* :func:`isolability`: what a geometry can detect and isolate, with wrong-isolation bounds.

The experiment harness (fault injection, campaigns, scenarios, validation, calibration quality reports) lives
above the runtime in :mod:`rimu.experiments`; the runtime never imports it.
"""

from .baseline import MeanDisagreement
from .calaware import (
    CalibrationAwareGlt,
)
from .calaware import (
    CalibrationCovariance as CalibrationCovariance,
)
from .calaware import (
    stated_covariance as stated_covariance,
)
from .cusum import (
    CusumBank,
)
from .cusum import (
    cusum_threshold as cusum_threshold,
)
from .cusum import (
    markov_arl as markov_arl,
)
from .cusum import (
    siegmund_arl as siegmund_arl,
)
from .detectors import make_detector
from .glt import GltDecision as GltDecision
from .glt import GltSnapshot, GltWindow, glt_threshold
from .glt import glt_snapshot as glt_snapshot
from .health import SensorHealth as SensorHealth
from .health import SensorState
from .kalman import ParityKalman
from .manager import FdiEvent, FdiResult, Health, HealthState, RedundancyManager, ReplayResult, unisolated_alarm_runs
from .motion import (
    MotionAwareGlt,
    fit_motion_detector,
    motion_detector_from_dict,
    motion_detector_to_dict,
)
from .motion import (
    MotionNoiseModel as MotionNoiseModel,
)
from .motion import (
    fit_motion_terms as fit_motion_terms,
)
from .multiple import (
    FaultSetGlt,
)
from .multiple import (
    SetDecision as SetDecision,
)
from .multiple import (
    set_fault_rates as set_fault_rates,
)
from .multiple import (
    single_fault_rates as single_fault_rates,
)
from .noise import NoiseEstimator as NoiseEstimator
from .parity import (
    IsolabilityReport as IsolabilityReport,
)
from .parity import (
    detection_probability as detection_probability,
)
from .parity import (
    isolability,
)
from .parity import (
    wrong_isolation_bounds as wrong_isolation_bounds,
)
from .px4_selector import Px4GyroSelector
from .px4_selector import Px4SelectorResult as Px4SelectorResult
from .settings import FdiSettings
from .unit import Runtime
from .unit import UnitManager as UnitManager

#: the runtime's public API (the other names above stay importable here and from their modules)
__all__ = [
    # the one runtime, its settings and its outputs
    "Runtime",
    "FdiSettings",
    "RedundancyManager",
    "FdiResult",
    "ReplayResult",
    "FdiEvent",
    "Health",
    "HealthState",
    "SensorState",
    "unisolated_alarm_runs",
    # detectors and the set test
    "make_detector",
    "GltSnapshot",
    "GltWindow",
    "CusumBank",
    "ParityKalman",
    "MeanDisagreement",
    "Px4GyroSelector",
    "CalibrationAwareGlt",
    "MotionAwareGlt",
    "fit_motion_detector",
    "motion_detector_from_dict",
    "motion_detector_to_dict",
    "FaultSetGlt",
    "glt_threshold",
    # what a geometry can detect and isolate
    "isolability",
]
