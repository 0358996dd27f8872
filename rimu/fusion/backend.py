"""Which implementation runs the runtime pipeline: the numpy reference or the compiled kernels (numba).

``backend="auto"`` (the default) uses numba where it is installed (``pip install rimu[fast]``) and numpy
otherwise; ``"numpy"`` and ``"numba"`` ask for one. Without an argument the environment variable
``RIMU_BACKEND`` decides (``auto`` when unset; the generic choice lives in the foundation :mod:`rimu._backend`). Both give the same numbers (tested to 1e-12 relative); numpy
stays the reference, and the compiled path hands every sample it cannot do on its common path (an invalid,
saturated or non-finite value, an unobservable set) to it.
"""

from __future__ import annotations

from types import ModuleType

from .._backend import BACKENDS, import_once, resolve

__all__ = ["BACKENDS", "numba_available", "resolve_backend"]

_KERNELS: list[ModuleType | None] = []


def _kernels() -> ModuleType | None:
    """The compiled kernels (imports numba once), or None without numba."""
    return import_once(_KERNELS, "rimu.fusion._kernels")


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
    return resolve(backend, numba_available)
