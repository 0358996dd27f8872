"""Runtime pipeline: compensation, projection to the MB frame, parity vector, isolation (Cho & Park Eq. 20-21)."""

from .backend import BACKENDS, numba_available, resolve_backend
from .compensation import cho_park_eq20, eq20_matrix
from .effects import EffectCompensation, compensable_effects
from .pipeline import BlockResult, InstrumentPipeline, Pipeline, StepResult
from .projection import ActiveSet, ProjectionTable, bits_mask, mask_bits
from .validation import InstrumentErrors, replay_errors, segment_errors, session_block
from .validity import Validity

__all__ = [
    "Pipeline",
    "InstrumentPipeline",
    "StepResult",
    "BlockResult",
    "ProjectionTable",
    "ActiveSet",
    "Validity",
    "BACKENDS",
    "numba_available",
    "resolve_backend",
    "mask_bits",
    "bits_mask",
    "cho_park_eq20",
    "eq20_matrix",
    "EffectCompensation",
    "compensable_effects",
    "InstrumentErrors",
    "replay_errors",
    "segment_errors",
    "session_block",
]
