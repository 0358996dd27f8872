"""Named geometries. Adding one is a new file in this folder plus one line in ``PRESETS``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ...errors import GeometryError
from ..base import Geometry
from .cone import cone
from .cone6 import cone6
from .dodecahedron6 import dodecahedron6
from .mimu4444 import mimu4444
from .tetrad4 import tetrad4
from .triad3 import triad3
from .triads import triads

__all__ = ["PRESETS", "preset", "cone", "cone6", "tetrad4", "triad3", "triads", "dodecahedron6"]

#: name -> factory returning a Geometry
PRESETS: dict[str, Callable[..., Geometry]] = {
    "cone6": cone6,
    "tetrad4": tetrad4,
    "triad3": triad3,
    "dodecahedron6": dodecahedron6,
    "cone": cone,
    "triads": triads,
    "mimu4444": mimu4444,
}


def preset(name: str, **kwargs: Any) -> Geometry:
    """Build a named geometry (``cone`` takes ``n`` and ``half_angle``; ``triads`` takes
    ``rotations``, ``positions_mb_m``, ``names``).

    >>> preset("cone6").n
    6
    """
    try:
        factory = PRESETS[name]
    except KeyError:
        raise GeometryError(f"unknown geometry {name!r}; known: {sorted(PRESETS)}") from None
    return factory(**kwargs)
