"""Fault detection and isolation on the parity vector."""

from .glt import GltDecision, glt_snapshot, glt_threshold

__all__ = ["glt_threshold", "glt_snapshot", "GltDecision"]
