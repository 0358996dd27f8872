"""Temperature coefficient of bias, cubic: a bias proportional to (T - T_ref)^3."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..model import RuntimeForm, RuntimeInputs, SensorContext
from ._common import TemperatureBias, runtime_temperature_offset

__all__ = ["BiasTemperature3"]


class BiasTemperature3(TemperatureBias):
    """``kb3 (T - T_ref)^3``: the third order of the bias-temperature polynomial (ArduPilot's in-flight temperature
    calibration, issue #16262, fits first to third order; ``rimu selfcal --temperature-orders 3`` writes here).

    The runtime evaluates it through :meth:`runtime_columns` (the compiled monomials stop at dT^2; the generic path
    of :class:`rimu.fusion.effects.EffectCompensation` gives the same numbers, per sample).

    >>> from rimu.geometry import cone6
    >>> ctx = SensorContext("gyro", 0, cone6())                      # T_ref 25 degC
    >>> BiasTemperature3().runtime_columns(RuntimeInputs(np.zeros(1), temperature=np.array([27.0])), [ctx])[:, 0, 0].tolist()
    [8.0]
    """

    name = "bias_temperature3"
    power = 3
    description = "bias temperature coefficient (cubic): bias changes in proportion to (T - T_ref)^3"
    physics = ("Third order of the bias-temperature characteristic (the S-shaped MEMS bias curves over a wide "
               "range). Error = kb3 (T - T_ref)^3; reported in (deg/h)/K^3 or ug/K^3.")
    excited_by = "segments at four or more temperatures (a thermal soak over a wide range)"

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(T - T_ref)^3`` for every sensor, (N, n, 1)."""
        dT = runtime_temperature_offset(inputs, ctxs)
        v = dT * dT * dT
        return np.broadcast_to(v, (v.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm | None:
        return None  # no dT^3 monomial in the compiled form: the generic path evaluates runtime_columns
