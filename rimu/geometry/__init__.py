"""Sensor geometries: H, sensor names, sub-units, parity matrices, presets."""

from .base import Geometry, SubUnit, null_space_rows
from .presets import PRESETS, cone, cone6, dodecahedron6, preset, tetrad4, triad3, triads

__all__ = [
    "Geometry",
    "SubUnit",
    "null_space_rows",
    "PRESETS",
    "preset",
    "cone",
    "cone6",
    "tetrad4",
    "triad3",
    "triads",
    "dodecahedron6",
]
