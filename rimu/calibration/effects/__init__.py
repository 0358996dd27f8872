"""The library of physical effects. Adding one: a new file here plus one line in the registry below.

See ``docs/effects.md`` for what each effect means, its units and the test that excites it.
"""

from ..model import EFFECTS, register_effect
from .bias import Bias
from .bias_drift import BiasDrift
from .bias_temperature import BiasTemperature
from .bias_temperature2 import BiasTemperature2
from .bias_temperature3 import BiasTemperature3
from .cross_coupling import CrossCoupling
from .earth_rate import EarthRate
from .g2_sensitivity import G2Sensitivity
from .g_sensitivity import GSensitivity
from .scale_misalignment import ScaleMisalignment
from .scale_temperature import ScaleTemperature
from .scale_temperature2 import ScaleTemperature2
from .sf_asymmetry import ScaleAsymmetry
from .sf_cubic import ScaleCubic
from .sf_quadratic import ScaleQuadratic
from .size_effect import SizeEffect

register_effect(Bias)
register_effect(ScaleMisalignment, "scale", "misalignment")
register_effect(ScaleQuadratic)
register_effect(ScaleCubic)
register_effect(ScaleAsymmetry)
register_effect(GSensitivity)
register_effect(G2Sensitivity)
register_effect(BiasTemperature)
register_effect(BiasTemperature2)
register_effect(BiasTemperature3)
register_effect(ScaleTemperature)
register_effect(ScaleTemperature2)
register_effect(BiasDrift)
register_effect(SizeEffect)
register_effect(EarthRate)
register_effect(CrossCoupling)

__all__ = [
    "EFFECTS",
    "Bias",
    "BiasDrift",
    "BiasTemperature",
    "BiasTemperature2",
    "BiasTemperature3",
    "CrossCoupling",
    "EarthRate",
    "G2Sensitivity",
    "GSensitivity",
    "ScaleAsymmetry",
    "ScaleCubic",
    "ScaleMisalignment",
    "ScaleQuadratic",
    "ScaleTemperature",
    "ScaleTemperature2",
    "SizeEffect",
]
