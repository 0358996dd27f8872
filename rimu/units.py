"""Units and physical constants, declared once.

rimu works in SI inside the library: angular rate in rad/s, specific force in m/s^2, angles in rad,
time in s, temperature in degC. Raw sensor outputs are in the device's own unit ("counts" unless a
device says otherwise); a scale factor therefore has the unit ``SI / raw``.

Conversions are named constants, in the style of pyins: multiply a value in the unit on the left of
``_TO_`` by the constant to get the unit on the right.

>>> round(10 * DEG_TO_RAD, 6)
0.174533
>>> round(1.0 * DH_TO_RS * 3600 / DEG_TO_RAD, 9)  # 1 deg/h is 1/3600 deg/s
1.0
"""

from __future__ import annotations

import math

__all__ = [
    "G0",
    "EARTH_RATE",
    "DEG_TO_RAD",
    "RAD_TO_DEG",
    "ARCSEC_TO_RAD",
    "RAD_TO_ARCSEC",
    "DH_TO_RS",
    "RS_TO_DH",
    "DS_TO_RS",
    "RS_TO_DS",
    "UG_TO_MS2",
    "MS2_TO_UG",
    "MG_TO_MS2",
    "G_TO_MS2",
    "PPM",
    "ARW_DSQH_TO_RSQS",
    "VRW_UGSQHZ_TO_MS2SQHZ",
    "white_noise_sigma",
]

#: Standard gravity, m/s^2 (the conventional value, used to convert g and micro-g).
G0 = 9.80665
#: Earth rotation rate, rad/s (WGS-84).
EARTH_RATE = 7.2921150e-5

DEG_TO_RAD = math.pi / 180.0
RAD_TO_DEG = 180.0 / math.pi
ARCSEC_TO_RAD = DEG_TO_RAD / 3600.0
RAD_TO_ARCSEC = 1.0 / ARCSEC_TO_RAD
#: deg/h to rad/s
DH_TO_RS = DEG_TO_RAD / 3600.0
RS_TO_DH = 1.0 / DH_TO_RS
#: deg/s to rad/s
DS_TO_RS = DEG_TO_RAD
RS_TO_DS = RAD_TO_DEG
#: micro-g to m/s^2
UG_TO_MS2 = 1e-6 * G0
MS2_TO_UG = 1.0 / UG_TO_MS2
#: milli-g to m/s^2
MG_TO_MS2 = 1e-3 * G0
#: g to m/s^2
G_TO_MS2 = G0
#: one part per million
PPM = 1e-6
#: angle random walk, deg/sqrt(h) to rad/sqrt(s)
ARW_DSQH_TO_RSQS = DEG_TO_RAD / 60.0
#: velocity random walk given as a noise density, micro-g/sqrt(Hz) to (m/s^2)/sqrt(Hz)
VRW_UGSQHZ_TO_MS2SQHZ = UG_TO_MS2


def white_noise_sigma(density: float, sample_rate: float) -> float:
    """Standard deviation of one sample of white noise of a given density.

    Parameters
    ----------
    density : float
        Noise density in ``unit/sqrt(Hz)`` (the same as ``unit*sqrt(s)``: ARW in rad/sqrt(s) is a rate
        noise density in (rad/s)/sqrt(Hz)).
    sample_rate : float
        Sample rate in Hz.

    Returns
    -------
    float
        ``density * sqrt(sample_rate)`` (IEEE Std 952 convention: sigma = N / sqrt(dt)).

    >>> white_noise_sigma(0.1, 100.0)
    1.0
    """
    if not (sample_rate > 0 and math.isfinite(sample_rate)):
        raise ValueError(f"sample_rate must be a positive finite number of Hz, got {sample_rate!r}")
    return float(density) * math.sqrt(sample_rate)
