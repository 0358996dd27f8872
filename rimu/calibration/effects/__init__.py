"""The library of physical effects. Adding one: a new file here plus one line in the registry below."""

from ..model import EFFECTS, register_effect
from .bias import Bias
from .scale_misalignment import ScaleMisalignment

register_effect(Bias)
register_effect(ScaleMisalignment, "scale", "misalignment")

__all__ = ["EFFECTS", "Bias", "ScaleMisalignment"]
