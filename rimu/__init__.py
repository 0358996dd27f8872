"""rimu: calibration, runtime fusion and fault detection for redundant inertial measurement units.

Units are SI inside the library (rad/s, m/s^2, rad, s); see :mod:`rimu.units`.
"""

from .calibration import Calibration, InstrumentCalibration
from .epoch import INSTRUMENTS, Epoch, EpochBlock
from .geometry import Geometry, SubUnit, preset
from .session import Segment, Session

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
