"""Choice of implementation, numpy (the reference) or compiled kernels (numba), shared by every stage.

``backend="auto"`` (the default) uses numba where it is installed (``pip install rimu[fast]``) and numpy otherwise;
``"numpy"`` and ``"numba"`` ask for one. Without an argument the environment variable ``RIMU_BACKEND`` decides
(``auto`` when unset). A foundation (stage 0): the runtime (:mod:`rimu.fusion.backend`) and the calibration
(:mod:`rimu.calibration.handheld`) resolve their ``backend=`` here, each with its own kernels.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from types import ModuleType

from .errors import BackendUnavailableError, OptionError

__all__ = ["BACKENDS", "import_once", "resolve", "resolve_loaded"]

#: accepted values of ``backend`` and ``RIMU_BACKEND``
BACKENDS = ("auto", "numpy", "numba")


def resolve(backend: str | None, available: bool | Callable[[], bool], what: str = "the compiled runtime") -> str:
    """``"numpy"`` or ``"numba"`` for a requested backend (None: ``RIMU_BACKEND``, else ``"auto"``), given whether
    the compiled kernels can be used (or a function that tells, called only when the answer matters: asking for
    numpy imports no numba).

    Raises
    ------
    OptionError
        Not one of :data:`BACKENDS`.
    BackendUnavailableError
        ``"numba"`` asked for and not ``available``.

    >>> resolve("auto", available=False)
    'numpy'
    >>> resolve("numba", available=True)
    'numba'
    >>> resolve("numpy", available=lambda: 1 / 0)  # not asked
    'numpy'
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
    if available() if callable(available) else available:
        return "numba"
    if name == "auto":
        return "numpy"
    raise BackendUnavailableError(
        f"{source}='numba' asks for {what}, and numba is not installed: pip install rimu[fast] "
        "(or use backend='numpy', the reference, or 'auto')")


def resolve_loaded(backend: str | None, available: bool | Callable[[], bool], what: str = "the compiled kernel") -> str:
    """:func:`resolve` for a step that numba makes only a little faster (a calibration's sums: a millisecond, where
    importing numba takes a second): ``"auto"`` takes numba only where it is loaded in the process already (by the
    runtime, another stage or the user); ``"numba"`` asked for by name imports it.

    >>> resolve_loaded("numpy", available=True)
    'numpy'
    """
    import sys

    requested = backend if backend is not None else (os.environ.get("RIMU_BACKEND", "").strip() or "auto")
    if str(requested).strip().lower() == "auto" and "numba" not in sys.modules:
        return "numpy"
    return resolve(backend, available, what)


def import_once(cache: list, module: str) -> ModuleType | None:
    """The kernels' module ``module`` (absolute name), imported at the first call and kept in ``cache`` (a list the
    caller owns, empty until then, so that a test can patch in ``[None]``); None where it cannot be imported
    (numba missing)."""
    if not cache:
        try:
            m: ModuleType | None = importlib.import_module(module)
        except ImportError:
            m = None
        cache.append(m)
    return cache[0]
