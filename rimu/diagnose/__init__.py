"""Model against measurement: residual diagnostics, "which effect is missing", add it and watch the error fall.

``diagnose(session, model)`` fits the model sensor by sensor, describes the residual (rms, chi-square per
degree of freedom against the noise level, whiteness, per segment and per input condition), tests every
registered effect not in the model (nested F-tests, Holm-corrected, per-sensor attribution, information
criteria), reports what the session cannot test and which candidates it cannot tell apart; ``Diagnosis.add``
refits with an effect and compares before and after; ``iterate`` repeats until nothing is missing.
``write_report`` renders it all as Markdown with figures. See ``docs/diagnostics.md``.
"""

from .api import (
    DEFAULT_ALPHA,
    Comparison,
    Diagnosis,
    Finding,
    InstrumentDiagnosis,
    Iteration,
    candidate_effects,
    compare,
    diagnose,
    effect_sensors,
    format_p,
    iterate,
)
from .candidates import CandidateTest, SensorTest, holm, score_candidates
from .fitting import ModelFit, SensorFit, fit_model, noise_from_differences
from .handheld import diagnose_handheld  # registers the hand-held session kind with api.diagnose
from .report import render_markdown, write_report
from .residuals import SensorStats, autocorrelation, ljung_box, residual_statistics

__all__ = [
    "DEFAULT_ALPHA", "CandidateTest", "Comparison", "Diagnosis", "Finding", "InstrumentDiagnosis", "Iteration",
    "ModelFit", "SensorFit", "SensorStats", "SensorTest", "autocorrelation", "candidate_effects", "compare",
    "diagnose", "diagnose_handheld", "effect_sensors", "fit_model", "format_p", "holm", "iterate", "ljung_box",
    "noise_from_differences", "render_markdown", "residual_statistics", "score_candidates", "write_report",
]
