"""Temperature coefficient of bias, linear: a bias proportional to T - T_ref."""

from __future__ import annotations

from ._common import TemperatureBias

__all__ = ["BiasTemperature"]


class BiasTemperature(TemperatureBias):
    name = "bias_temperature"
    power = 1
    description = "bias temperature coefficient (linear): bias changes in proportion to T - T_ref"
    physics = ("Thermal expansion and temperature-dependent electronics offsets. Error = kb1 (T - T_ref); "
               "reported in (deg/h)/K or ug/K.")
    excited_by = "segments at different temperatures: a thermal soak or a temperature ramp in a chamber"
