"""Calibration: sessions in, error models as sums of effects, estimators, results with uncertainties."""

from .result import FORMAT_VERSION, Calibration, InstrumentCalibration

__all__ = ["Calibration", "InstrumentCalibration", "FORMAT_VERSION"]
