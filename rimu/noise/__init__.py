"""Noise identification (IEEE Std 952 / 1554): Allan deviation of every sensor, fitted terms, parity check.

* :mod:`rimu.noise.model`: :class:`NoiseModel` / :class:`InstrumentNoise` (terms in SI, JSON file), the
  variance of a window mean under white noise, quantisation, bias instability and rate random walk (what
  the detectors of :mod:`rimu.fdi` use);
* :mod:`rimu.noise.allan`: overlapping Allan deviation with confidence intervals (allantools, extra ``noise``);
* :mod:`rimu.noise.fit`: the terms by a weighted fit of the model to the Allan variance;
* :mod:`rimu.noise.parity`: the normalised parity vector's Allan deviation, white and independence verdicts;
* :mod:`rimu.noise.api`: :func:`identify`, :func:`identify_session`; :mod:`rimu.noise.plots`: figures.

Only :mod:`rimu.noise.model` is imported eagerly (it depends on nothing but numpy, so a calibration file can
hold a noise section); the rest load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from .model import TERMS, InstrumentNoise, NoiseModel, window_mean_difference_variance

__all__ = [
    "TERMS",
    "AllanDeviation",
    "InstrumentNoise",
    "NoiseModel",
    "ParityWhiteness",
    "allan_deviation",
    "fit_terms",
    "identify",
    "identify_session",
    "parity_allan",
    "window_mean_difference_variance",
]

_LAZY = {
    "allan_deviation": "allan",
    "AllanDeviation": "allan",
    "fit_terms": "fit",
    "parity_allan": "parity",
    "ParityWhiteness": "parity",
    "identify": "api",
    "identify_session": "api",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
