"""Truth simulation: error models and turntable procedures -> sessions and epoch streams.

Only tests, examples, the CLI and campaigns import this package.
"""

from .procedures import (
    PROCEDURES,
    REFERENCE_ATTITUDE,
    SegmentSpec,
    attitude_with_axis,
    attitude_with_up,
    cho_park_procedure,
    cho_park_table1,
    cho_park_table2,
    oliveira_table1,
    rotation,
    static,
    zhang_scheme,
)
from .simulator import SimRun, Simulator, TruthEffect
from .truth import cho_park_table3, default_truth, random_truth

__all__ = [
    "Simulator",
    "SimRun",
    "TruthEffect",
    "SegmentSpec",
    "static",
    "rotation",
    "attitude_with_up",
    "attitude_with_axis",
    "REFERENCE_ATTITUDE",
    "cho_park_table1",
    "cho_park_table2",
    "cho_park_procedure",
    "oliveira_table1",
    "zhang_scheme",
    "PROCEDURES",
    "cho_park_table3",
    "random_truth",
    "default_truth",
]
