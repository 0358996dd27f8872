"""Which implementation runs the runtime pipeline: the numpy reference or the compiled kernels (numba).

``backend="auto"`` (the default) uses numba where it is installed (``pip install rimu[fast]``) and numpy
otherwise; ``"numpy"`` and ``"numba"`` ask for one. Without an argument the environment variable
``RIMU_BACKEND`` decides (``auto`` when unset). Both give the same numbers (tested to 1e-12 relative); numpy
stays the reference, and the compiled path hands every sample it cannot do on its common path (an invalid,
saturated or non-finite value, an unobservable set) to it.
"""

from __future__ import annotations

import os
from types import ModuleType

from ..errors import BackendUnavailableError, OptionError

__all__ = ["BACKENDS", "numba_available", "resolve_backend"]

#: accepted values of ``backend`` and ``RIMU_BACKEND``
BACKENDS = ("auto", "numpy", "numba")

_KERNELS: list[ModuleType | None] = []


def _kernels() -> ModuleType | None:
    """The compiled kernels (imports numba once), or None without numba."""
    if not _KERNELS:
        try:
            from . import _kernels as k
        except ImportError:
            k = None
        _KERNELS.append(k)
    return _KERNELS[0]


def numba_available() -> bool:
    """Whether the compiled backend can be used (numba importable)."""
    return _kernels() is not None


def resolve_backend(backend: str | None = None) -> str:
    """``"numpy"`` or ``"numba"`` for a requested backend (None: ``RIMU_BACKEND``, else ``"auto"``).

    Raises
    ------
    OptionError
        Not one of :data:`BACKENDS`.
    BackendUnavailableError
        ``"numba"`` asked for and numba is not installed.

    >>> resolve_backend("numpy")
    'numpy'
    >>> resolve_backend("fortran")
    Traceback (most recent call last):
    ...
    rimu.errors.OptionError: backend must be one of auto, numpy, numba; got 'fortran'
    """
    source = "backend"
    if backend is None:
        backend = os.environ.get("RIMU_BACKEND", "").strip() or "auto"
        source = "RIMU_BACKEND"
    name = str(backend).strip().lower()
    if name not in BACKENDS:
        raise OptionError(f"{source} must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if name == "numpy":
        return "numpy"
    if numba_available():
        return "numba"
    if name == "auto":
        return "numpy"
    raise BackendUnavailableError(
        f"{source}='numba' asks for the compiled runtime, and numba is not installed: pip install rimu[fast] "
        "(or use backend='numpy', the reference, or 'auto')")
