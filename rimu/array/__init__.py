"""The array as one instrument: k triads on one board.

* :mod:`rimu.array.layout`: :class:`ArrayLayout` (rotations, positions), ``from_geometry``.
* :mod:`rimu.array.runtime`: lever-arm removal and the maximum-likelihood angular rate, angular acceleration and
  specific force of Skog et al. 2016, with the Cramer-Rao bound.
"""

from .layout import ArrayLayout
from .runtime import (
    DERIVATIVE_NOISE_GAIN,
    ArrayMotion,
    LeverArmTransfer,
    accel_jacobian,
    accel_model,
    angular_acceleration,
    crb,
    fisher_information,
    lever_arm_acceleration,
    ml_motion,
    remove_lever_arms,
    skew,
    transfer_to_reference,
)

__all__ = [
    "ArrayLayout",
    "ArrayMotion",
    "DERIVATIVE_NOISE_GAIN",
    "LeverArmTransfer",
    "accel_jacobian",
    "angular_acceleration",
    "accel_model",
    "crb",
    "fisher_information",
    "lever_arm_acceleration",
    "ml_motion",
    "remove_lever_arms",
    "skew",
    "transfer_to_reference",
]
from .relative import (
    BASE_TERMS,
    CANDIDATE_TERMS,
    CandidateScore,
    RelativeFit,
    derivative,
    fit_relative_gyro,
    rank_candidates,
    time_shift,
    to_array_gauge,
)
from .terms import GYRO_TERMS, Signals, Term

__all__ += ["BASE_TERMS", "CANDIDATE_TERMS", "CandidateScore", "RelativeFit", "derivative", "fit_relative_gyro",
            "rank_candidates", "time_shift", "to_array_gauge", "GYRO_TERMS", "Signals", "Term"]
from .positions import (  # noqa: E402
    PositionFit,
    aa_from_accelerometers_refusal,
    accel_angular_acceleration,
    angular_acceleration_check,
    fit_positions,
)

__all__ += ["PositionFit", "aa_from_accelerometers_refusal", "accel_angular_acceleration",
            "angular_acceleration_check", "fit_positions"]
from .report import ArrayReport, array_report, lowpass  # noqa: E402

__all__ += ["ArrayReport", "array_report", "lowpass"]
from .remainder import RemainderAnalysis, ljung_box, remainder_analysis  # noqa: E402

__all__ += ["RemainderAnalysis", "ljung_box", "remainder_analysis"]
