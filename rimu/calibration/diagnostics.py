"""Deprecated alias of :mod:`rimu.diagnose` (kept for one release): import from ``rimu.diagnose`` instead.

Diagnosis consumes calibrations and sessions and sits above ``rimu.calibration`` on the data's path; this
alias is the one allowed exception to the layering rule (``tests/test_layering.py``) until it is removed.
"""

import warnings

from ..diagnose import *  # noqa: F403
from ..diagnose import __all__  # noqa: F401

warnings.warn("rimu.calibration.diagnostics is deprecated; import from rimu.diagnose", DeprecationWarning,
              stacklevel=2)
