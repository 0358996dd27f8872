"""rimu: calibration, runtime fusion and fault detection for redundant inertial measurement units.

Units are SI inside the library (rad/s, m/s^2, rad, s); see :mod:`rimu.units`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names below are imported on first use (PEP 562): ``import rimu.session`` or
    # ``import rimu.io`` does not pull in the calibration estimators
    from .calibration import Calibration, InstrumentCalibration
    from .epoch import INSTRUMENTS, Epoch, EpochBlock
    from .geometry import Geometry, SubUnit, preset
    from .session import Segment, Session

#: public name -> the subpackage that defines it
_LAZY = {"Calibration": "calibration", "InstrumentCalibration": "calibration", "INSTRUMENTS": "epoch",
         "Epoch": "epoch", "EpochBlock": "epoch", "Geometry": "geometry", "SubUnit": "geometry",
         "preset": "geometry", "Segment": "session", "Session": "session"}
#: subpackages reachable as attributes after a bare ``import rimu`` (as when this module imported them)
_SUBPACKAGES = ("array", "calibration", "cli", "diagnose", "epoch", "errors", "experiments", "export", "fdi", "fusion", "geometry",
                "io", "noise", "session", "sim", "units")

__version__ = "0.1.0"

__all__ = [
    "Geometry",
    "SubUnit",
    "preset",
    "Calibration",
    "InstrumentCalibration",
    "Epoch",
    "EpochBlock",
    "INSTRUMENTS",
    "Segment",
    "Session",
    "__version__",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'rimu' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
