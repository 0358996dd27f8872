"""Fault detection and isolation on the parity vector.

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
from .calaware import CalibrationAwareGlt, CalibrationCovariance, stated_covariance
from .cusum import CusumBank, cusum_threshold, markov_arl, siegmund_arl
from .glt import GltDecision, GltSnapshot, GltWindow, glt_snapshot, glt_threshold
from .health import SensorHealth, SensorState
from .kalman import ParityKalman
from .manager import FdiEvent, FdiResult, Health, HealthState, RedundancyManager, ReplayResult, unisolated_alarm_runs
from .motion import MotionAwareGlt, MotionNoiseModel, fit_motion_detector, fit_motion_terms
from .multiple import FaultSetGlt, SetDecision, set_fault_rates, single_fault_rates
from .noise import NoiseEstimator
from .parity import IsolabilityReport, detection_probability, isolability, wrong_isolation_bounds
from .px4_selector import Px4GyroSelector, Px4SelectorResult
from .unit import UnitManager

__all__ = [
    "glt_threshold",
    "glt_snapshot",
    "GltDecision",
    "GltSnapshot",
    "GltWindow",
    "CusumBank",
    "cusum_threshold",
    "siegmund_arl",
    "markov_arl",
    "ParityKalman",
    "MeanDisagreement",
    "Px4GyroSelector",
    "Px4SelectorResult",
    "CalibrationAwareGlt",
    "MotionAwareGlt",
    "MotionNoiseModel",
    "fit_motion_detector",
    "fit_motion_terms",
    "CalibrationCovariance",
    "stated_covariance",
    "NoiseEstimator",
    "RedundancyManager",
    "UnitManager",
    "HealthState",
    "Health",
    "FdiEvent",
    "ReplayResult",
    "unisolated_alarm_runs",
    "FdiResult",
    "SensorState",
    "SensorHealth",
    "FaultSetGlt",
    "SetDecision",
    "single_fault_rates",
    "set_fault_rates",
    "IsolabilityReport",
    "isolability",
    "detection_probability",
    "wrong_isolation_bounds",
]
