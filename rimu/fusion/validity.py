"""The validity flag of a runtime output: what a flight computer may do with the estimate."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Validity"]


class Validity(IntEnum):
    """NOMINAL: every expected sensor used, no unresolved fault. DEGRADED: usable estimate with reduced
    redundancy or an unresolved (not isolable) fault, or sensors invalid/saturated. UNOBSERVABLE: no
    estimate (the active sensors do not span 3-D); x is not a number to use."""

    NOMINAL = 0
    DEGRADED = 1
    UNOBSERVABLE = 2
