"""Flight code from a calibration: the runtime pipeline as dependency-free C99 (:func:`export_c`)."""

from .c99 import REALS, export_c

__all__ = ["REALS", "export_c"]
