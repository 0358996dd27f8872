"""Calibration: sessions in, error models as sums of effects, estimators, results with uncertainties.

Estimators (constructor stores settings, ``fit(session)`` returns a :class:`CalibrationResult`):
:class:`ChoPark` (Cho & Park 2005), :class:`Oliveira` (de Oliveira et al. 2012),
:class:`Zhang` (Zhang et al. 2010), :class:`LeastSquares` (generic,
any effect model).
"""

from . import effects  # noqa: F401  (first: fills the effect registry)
from .cho_park import ChoPark
from .estimate import CalibrationResult, LeastSquares
from .oliveira import Oliveira
from .result import FORMAT_VERSION, Calibration, InstrumentCalibration
from .zhang import Zhang

__all__ = ["Calibration", "InstrumentCalibration", "FORMAT_VERSION", "CalibrationResult", "ChoPark",
           "LeastSquares", "Oliveira", "Zhang"]
