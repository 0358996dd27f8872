"""Deprecated alias of :mod:`rimu.session` (kept for one release): import from ``rimu.session`` instead."""

import warnings

from .session import (
    FERRARIS_SECTIONS,
    SESSION_FORMAT,
    SESSION_FORMAT_VERSION,
    load_ferraris,
    load_session,
    save_session,
    session_sidecar,
)

warnings.warn("rimu.session_io is deprecated; import from rimu.session", DeprecationWarning, stacklevel=2)

__all__ = ["FERRARIS_SECTIONS", "SESSION_FORMAT", "SESSION_FORMAT_VERSION", "load_ferraris", "load_session",
           "save_session", "session_sidecar"]
