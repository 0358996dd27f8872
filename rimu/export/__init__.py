"""Flight code from a calibration: the runtime pipeline and its fault management as dependency-free C99
(:func:`export_c`), and the estimates file its filter writes (:mod:`rimu.export.estimates`)."""

from ..fdi.settings import FdiSettings
from .c99 import REALS, build_filter, export_c
from .estimates import ESTIMATE_COLUMNS, Estimates, estimate_columns, read_estimates, write_estimates

__all__ = ["ESTIMATE_COLUMNS", "REALS", "Estimates", "FdiSettings", "build_filter", "estimate_columns", "export_c",
           "read_estimates", "write_estimates"]
