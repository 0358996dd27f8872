"""Evidence that points at one sensor, or a common cause: what an isolation needs (issue 32, item 3).

An isolation removes one sensor (or one sub-unit's sensors) because the evidence points at it. Two situations
produce alarms or invalid samples that point at no one sensor, and must leave the unit DEGRADED with nothing
isolated:

* **Common invalidity**: sensors of more than one sub-unit are invalid at the same sample. A triad that clips at
  its range limit, drops out or reads a placeholder is invalid; when two or more triads are invalid at once the
  likely cause is common (the motion exceeds the range of all of them, a bus drops every chip), not a fault of
  one. :class:`EvidenceGate` counts, per sensor, only the invalid samples where the invalidity is confined to
  one sub-unit; the manager isolates on invalidity only when that count reaches its ``invalid_persist``.
* **Model exceeded**: a motion-aware detector (:class:`rimu.fdi.MotionAwareGlt`) states its thresholds for
  the motion its terms were fitted on (the largest angular rate and angular acceleration of the fit span,
  ``MotionAwareGlt.envelope``). Beyond that envelope the model's variance is an extrapolation: an alarm there
  is reported as ``model_exceeded`` (the unit DEGRADED), never used to isolate. The detector sets its
  ``model_exceeded`` flag at each :meth:`~rimu.fdi.MotionAwareGlt.update`; the manager reads it.

Both are decisions of the detector layer; :class:`rimu.fdi.RedundancyManager` maps them to its states (the hook
is two calls: :meth:`EvidenceGate.invalid_alone` in its invalid-data path and the detector's
``model_exceeded`` flag before an alarm is used as evidence).

Examples
--------
>>> from rimu.geometry import triads
>>> gate = EvidenceGate(triads(3))
>>> inv = np.zeros(9, bool); inv[3:6] = True                 # one triad invalid: points at it
>>> gate.invalid_alone(inv)[3:6].tolist(), gate.common
([True, True, True], False)
>>> inv[0] = True                                             # two triads at once: a common cause
>>> bool(gate.invalid_alone(inv).any()), gate.common
(False, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["EvidenceGate"]


class EvidenceGate:
    """Which invalid samples point at one sub-unit (see the module docstring).

    Parameters
    ----------
    geometry : rimu.geometry.Geometry
        The unit; its sub-units group the sensors (one sub-unit: any invalid sample points at its sensors).

    Attributes
    ----------
    owner : ndarray (n,) of int
        Sub-unit index of each sensor.
    common : bool
        The last sample's invalidity spanned more than one sub-unit.
    """

    def __init__(self, geometry: Any) -> None:
        subs = geometry.subunits
        self.owner = np.zeros(geometry.n, dtype=np.int64)
        for j, su in enumerate(subs):
            self.owner[list(su.members)] = j
        self.n_sub = len(subs)
        self.common = False

    def invalid_alone(self, invalid: np.ndarray) -> np.ndarray:
        """The invalid sensors of this sample that count as evidence against themselves: all of them when they
        belong to one sub-unit, none when they span several (a common cause)."""
        inv = np.asarray(invalid, bool)
        self.common = bool(self.n_sub > 1 and np.unique(self.owner[inv]).size > 1)
        return np.zeros_like(inv) if self.common else inv
