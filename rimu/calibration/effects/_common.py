"""Helpers shared by the effect files: the nominal input along a sensor's axis, and report units."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ...session import Segment
from ...units import DEG_TO_RAD, G0, MS2_TO_UG, PPM, RS_TO_DH
from ..model import Effect, ParamSpec, RuntimeForm, RuntimeInputs, SensorContext, monomial

__all__ = ["TemperatureBias", "axis_input", "geometry_cache", "input_unit", "output_unit", "per_input_power", "runtime_temperature_offset",
           "temperature_offset"]


def axis_input(segment: Segment, ctx: SensorContext) -> np.ndarray | None:
    """The known input along the sensor's nominal axis, ``s = h_i . u`` (N,), SI, or None."""
    u = ctx.input(segment)
    if u is None:
        return None
    return np.asarray(u, dtype=float) @ ctx.axis


def output_unit(ctx: SensorContext) -> tuple[str, str, float]:
    """(SI unit, report unit, factor) of an output error: rad/s -> deg/h, m/s^2 -> ug."""
    if ctx.instrument == "gyro":
        return "rad/s", "deg/h", RS_TO_DH
    return "m/s^2", "ug", MS2_TO_UG


def input_unit(ctx: SensorContext) -> tuple[str, str, float]:
    """(SI input unit, field input unit, SI per field unit): rad/s and deg/s, or m/s^2 and g."""
    if ctx.instrument == "gyro":
        return "rad/s", "deg/s", DEG_TO_RAD
    return "m/s^2", "g", G0


def per_input_power(ctx: SensorContext, power: int) -> tuple[str, str, float]:
    """Units of a coefficient k in ``error = k * s**(power + 1)`` reported as ppm per (field input)**power.

    The error relative to the input is ``k s**power``; in ppm per field unit**power that is
    ``k * (SI per field unit)**power / PPM``.
    """
    si, field, per = input_unit(ctx)
    suffix = "" if power == 1 else f"^{power}"
    return f"1/({si}){suffix}", f"ppm/({field}){suffix}", per**power / PPM


def temperature_offset(segment: Segment, ctx: SensorContext) -> np.ndarray | None:
    """``T - T_ref`` (N,), K, or None when the segment has no temperature."""
    if segment.temperature is None:
        return None
    return np.asarray(segment.temperature, dtype=float) - ctx.reference_temperature




_CACHE: dict[tuple[str, int, int], tuple[Any, Any]] = {}


def geometry_cache(key: str, ctxs: Sequence[SensorContext], make: Callable[[], Any]) -> Any:
    """A constant an effect derives from the geometry once (axes, cross axes, ...), kept per geometry object and
    calibrated axes (which the entry holds, so their ids stay unique) so that the per-sample runtime work is
    arithmetic only."""
    g = ctxs[0].geometry
    A = ctxs[0].axes
    k = (key, id(g), id(A))
    hit = _CACHE.get(k)
    if hit is None:
        hit = _CACHE[k] = ((g, A), make())
    return hit[1]


def runtime_temperature_offset(inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
    """``T - T_ref`` as (N, 1, 1), K (one reference temperature per instrument)."""
    return inputs.temperature_offset(ctxs[0])[:, None, None]


class TemperatureBias(Effect):
    """A bias proportional to ``(T - T_ref)^power`` (power 1 or 2): the shared body of the bias temperature
    effects; a subclass sets ``name``, ``power`` and its texts."""

    power = 1
    runtime_needs = ("temperature",)
    needs = "temperature"

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        si, rep, f = output_unit(ctx)
        per = "/K" if self.power == 1 else f"/K^{self.power}"
        return [ParamSpec(f"bias_tc{self.power}", f"{si}{per}", f"{rep}{per}", f)]

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        dT = temperature_offset(segment, ctx)
        return None if dT is None else (dT if self.power == 1 else dT**self.power)[:, None]

    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``(T - T_ref)^power`` for every sensor, (N, n, 1)."""
        dT = runtime_temperature_offset(inputs, ctxs)
        v = dT if self.power == 1 else dT * dT
        return np.broadcast_to(v, (v.shape[0], len(ctxs), 1))

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm:
        form = RuntimeForm.zeros("exogenous", len(ctxs), 1)
        form.F[:, 0, monomial("dT" if self.power == 1 else "dT2")] = 1.0
        return form
