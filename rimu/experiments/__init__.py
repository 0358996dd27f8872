"""The experiment harness above the runtime: fault injection, campaigns, scenarios, validation, quality reports.

It drives the runtime (:mod:`rimu.fusion`, :mod:`rimu.fdi`) and may use the simulator (:mod:`rimu.sim`); the
runtime never imports it (``tests/test_layering.py``).

* :mod:`rimu.experiments.faults`: fault types, one file each, and their injection into raw data;
* :mod:`rimu.experiments.campaign`: fault-injection campaigns against theory (process pool or dask);
* :mod:`rimu.experiments.scenarios`: the fault-management campaign (every fault type, closed loop, three
  geometries);
* :mod:`rimu.experiments.validate`: a calibration judged on a held-out session through the runtime;
* :mod:`rimu.experiments.quality` and :mod:`rimu.experiments.static_quality`: parity-based calibration quality
  (de Oliveira et al. 2012, Eq. 21-25; accelerometers at rest).
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "FAULTS", "Injection", "inject", "parse_injection",
    "CampaignSpec", "CampaignResult", "run_campaign", "clopper_pearson",
    "ScenarioSpec", "run_scenarios",
    "validate",
    "parity_quality", "QualityReport", "static_parity_quality",
]

_LAZY = {
    "FAULTS": "faults", "Injection": "faults", "inject": "faults", "parse_injection": "faults",
    "CampaignSpec": "campaign", "CampaignResult": "campaign", "run_campaign": "campaign",
    "clopper_pearson": "campaign",
    "ScenarioSpec": "scenarios", "run_scenarios": "scenarios",
    "validate": "validate",
    "parity_quality": "quality", "QualityReport": "quality", "static_parity_quality": "static_quality",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
