"""Sessions: recorded segments of raw samples with their known inputs, rimu's file format, third-party loaders.

``rimu.session.model`` holds the data model (:class:`Segment`, :class:`Session`), ``rimu.session.native``
rimu's own CSV/NPZ format, ``rimu.session.stream`` reads such a file in chunks of
constant memory, and ``rimu.session.loaders`` one module per third-party recording format.
"""

from .loaders import FERRARIS_SECTIONS, load_ferraris
from .model import SEGMENT_KINDS, Segment, Session, earth_rate_ln, rotation_matrix, skew
from .native import (
    SESSION_FORMAT,
    SESSION_FORMAT_VERSION,
    load_session,
    save_session,
    session_from_sidecar,
    session_sidecar,
    sidecar_geometries,
)
from .stream import iter_blocks

__all__ = [
    "FERRARIS_SECTIONS",
    "SEGMENT_KINDS",
    "SESSION_FORMAT",
    "SESSION_FORMAT_VERSION",
    "Segment",
    "Session",
    "earth_rate_ln",
    "iter_blocks",
    "load_ferraris",
    "load_session",
    "rotation_matrix",
    "save_session",
    "session_from_sidecar",
    "session_sidecar",
    "sidecar_geometries",
    "skew",
]
