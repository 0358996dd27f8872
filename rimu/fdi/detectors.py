"""The detector of a name, with its design settings: the factory the runtime's entry points share
(``rimu replay --detector``, the campaigns)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .baseline import MeanDisagreement
from .cusum import CusumBank
from .glt import GltSnapshot, GltWindow
from .kalman import ParityKalman
from .settings import DEFAULTS

__all__ = ["DETECTORS", "make_detector"]

#: the detectors of a name
DETECTORS = ("glt", "glt_window", "cusum", "kalman", "baseline")


def make_detector(name: str, sigma: float | np.ndarray, *, p_fa: float = DEFAULTS.p_fa, window: int = 5,
                  arl0: float = 1e5, cusum_bias: float = 1.0, tau: float = 20.0, dead_band: float = 2.0) -> Any:
    """The detector ``name`` (one of :data:`DETECTORS`) for sensors of per-sample noise ``sigma`` (SI).

    ``p_fa`` per sample (GLT snapshot and window, Kalman), ``window`` samples (GLT window), ``arl0`` samples
    between false alarms (CUSUM bank, baseline), ``cusum_bias`` in sigma, ``tau`` in samples, ``dead_band`` in
    sigma (baseline).

    >>> type(make_detector("cusum", 0.01)).__name__
    'CusumBank'
    """
    if name == "glt":
        return GltSnapshot(p_fa)
    if name == "glt_window":
        return GltWindow(window, p_fa)
    if name == "cusum":
        return CusumBank(cusum_bias * np.asarray(sigma), arl0)
    if name == "kalman":
        return ParityKalman(tau, p_fa)
    if name == "baseline":
        return MeanDisagreement(sigma, dead_band, arl0)
    raise ValueError(f"unknown detector {name!r}; known: {list(DETECTORS)}")
