"""Temperature coefficient of bias, quadratic: a bias proportional to (T - T_ref)^2."""

from __future__ import annotations

from ._common import TemperatureBias

__all__ = ["BiasTemperature2"]


class BiasTemperature2(TemperatureBias):
    name = "bias_temperature2"
    power = 2
    description = "bias temperature coefficient (quadratic): bias changes in proportion to (T - T_ref)^2"
    physics = ("Curvature of the bias-temperature characteristic (MEMS bias curves are rarely straight over a "
               "wide range). Error = kb2 (T - T_ref)^2; reported in (deg/h)/K^2 or ug/K^2.")
    excited_by = "segments at three or more temperatures (a thermal soak over a wide range)"
