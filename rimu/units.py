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

Every figure rimu prints or writes goes through :func:`fmt` (a value in SI and its quantity: the text in the
field's unit, chosen once for a table by :func:`field_unit`) or :func:`fmt_raw` (a value in the device's raw
unit, never relabelled as SI). Raw units a file may declare are in :data:`RAW_UNITS`; :func:`raw_to_si` gives
their factor to SI, or None for counts (whose factor only a calibration knows).

Why not pint: rimu's quantities are few (rate, specific force, angle, ratio, time, their noise densities) and
live in numpy arrays on the runtime's hot path; pint's wrapped arrays would cost on every operation and its
registry about 0.3 s at import, while the one thing that went wrong (a figure printed in a unit it was not in)
is a formatting decision, made here once.

>>> fmt(0.0103, "rate")                     # a MEMS gyro residual reads in deg/s
'0.5901 deg/s'
>>> fmt(1e-5, "rate")                       # a tactical one in deg/h
'2.063 deg/h'
>>> fmt(3.7e-2, "specific_force"), fmt(75.22, "raw", raw_unit="count")
('3.773 mg', '75.22 count')
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
    "FIELD_UNITS",
    "RAW_UNITS",
    "SI_UNITS",
    "field_unit",
    "fmt",
    "fmt_raw",
    "raw_to_si",
    "raw_unit_for",
    "scale_unit",
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


#: SI unit of each quantity rimu prints
SI_UNITS: dict[str, str] = {"rate": "rad/s", "specific_force": "m/s^2", "angle": "rad", "ratio": "1",
                            "time": "s", "frequency": "Hz", "length": "m"}
#: the field's units of each quantity, (name, factor from SI), from the finest to the coarsest: a table of values
#: reads in the finest unit in which its largest value stays below 1000 (:func:`field_unit`)
FIELD_UNITS: dict[str, tuple[tuple[str, float], ...]] = {
    "rate": (("deg/h", RS_TO_DH), ("deg/s", RS_TO_DS)),
    "specific_force": (("ug", MS2_TO_UG), ("mg", 1.0 / MG_TO_MS2), ("m/s^2", 1.0)),
    "angle": (("arcsec", RAD_TO_ARCSEC), ("deg", RAD_TO_DEG)),
    "ratio": (("ppm", 1.0 / PPM), ("%", 100.0), ("", 1.0)),
    "time": (("us", 1e6), ("ms", 1e3), ("s", 1.0)),
    "frequency": (("Hz", 1.0),),
    "length": (("mm", 1e3), ("m", 1.0)),
}
#: physical raw units a recording may declare, per instrument: name -> factor to SI ("count" has none)
RAW_UNITS: dict[str, dict[str, float]] = {
    "accel": {"m/s^2": 1.0, "m/s2": 1.0, "g": G0, "mg": MG_TO_MS2, "ug": UG_TO_MS2},
    "gyro": {"rad/s": 1.0, "deg/s": DS_TO_RS, "deg/h": DH_TO_RS, "mrad/s": 1e-3},
}
_QUANTITY_OF = {"gyro": "rate", "accel": "specific_force"}


def raw_to_si(instrument: str, raw_unit: str | None) -> float | None:
    """Factor from a declared raw unit to SI, or None when the unit is not physical (counts, unknown).

    >>> raw_to_si("gyro", "deg/s") == DS_TO_RS, raw_to_si("accel", "count"), raw_to_si("accel", "SI")
    (True, None, 1.0)
    """
    if raw_unit is None:
        return None
    u = str(raw_unit).strip().replace(" ", "")
    if u.lower() == "si":
        return 1.0
    return RAW_UNITS.get(instrument, {}).get(u)


def raw_unit_for(raw_unit: "str | dict[str, str] | None", instrument: str) -> str:
    """The raw unit of one instrument from a declaration for all: one string, a mapping, or the text form
    ``"gyro: deg/s; accel: m/s^2"`` that session and calibration files keep.

    >>> raw_unit_for("gyro: deg/s; accel: m/s^2", "gyro"), raw_unit_for("count", "accel"), raw_unit_for(None, "gyro")
    ('deg/s', 'count', 'count')
    """
    if raw_unit is None:
        return "count"
    if isinstance(raw_unit, dict):
        return str(raw_unit.get(instrument, "count"))
    text = str(raw_unit)
    if ":" in text:
        for part in text.split(";"):
            k, _, v = part.partition(":")
            if k.strip() == instrument:
                return v.strip()
        return "count"
    return text


def scale_unit(instrument: str, raw_unit: str | None = "count") -> str:
    """Unit of a scale factor SI/raw, naming the raw unit the data were declared in.

    >>> scale_unit("gyro", "deg/s"), scale_unit("accel", "count"), scale_unit("accel", None)
    ('(rad/s)/(deg/s)', '(m/s^2)/count', '(m/s^2)/count')
    """
    si = SI_UNITS[_QUANTITY_OF.get(instrument, instrument)]
    u = "count" if raw_unit is None else str(raw_unit).strip()
    if u.lower() in ("si", "", "file units") or u == si:
        return "1" if u == si or u.lower() == "si" else f"({si})/count"
    return f"({si})/{u}" if "/" not in u else f"({si})/({u})"


def field_unit(quantity: str, magnitude_si: float | None = None) -> tuple[str, float]:
    """(unit, factor from SI) in which a value of this size reads best: the finest field unit in which it stays
    below 1000. ``quantity`` is a key of :data:`FIELD_UNITS` or an instrument (``"gyro"``, ``"accel"``).

    >>> field_unit("rate", 1e-5)[0], field_unit("gyro", 0.01)[0], field_unit("accel", 50.0)[0]
    ('deg/h', 'deg/s', 'm/s^2')
    """
    units = FIELD_UNITS[_QUANTITY_OF.get(quantity, quantity)]
    m = abs(float(magnitude_si)) if magnitude_si is not None and math.isfinite(magnitude_si) else 0.0
    for name, f in units:
        if m * f < 1000.0:
            return name, f
    return units[-1]


def fmt(value_si: float | None, quantity: str, unit: str | None = None, digits: int = 4,
        raw_unit: str | None = None, decimals: int | None = None, width: int = 0) -> str:
    """A value in SI as text in a field unit: ``unit`` (a name of :data:`FIELD_UNITS`) or the one that reads
    best (:func:`field_unit`). ``quantity="raw"`` formats a raw value with :func:`fmt_raw`. None or NaN: "n/a".
    ``decimals`` gives fixed decimals in place of ``digits`` significant ones, ``width`` right-aligns the number
    (a column of a live status line).

    >>> fmt(1e-5, "rate", "deg/s"), fmt(None, "rate"), fmt(2e-6, "ratio")
    ('0.0005730 deg/s', 'n/a', '2 ppm')
    >>> fmt(12.3456, "time", "s", decimals=2, width=8), fmt(2.5e-3, "angle", "arcsec", decimals=1)
    ('   12.35 s', '515.7 arcsec')
    """
    if quantity == "raw":
        return fmt_raw(value_si, raw_unit or "count", digits)
    if value_si is None or not math.isfinite(float(value_si)):
        return "n/a"
    if unit is None:
        unit, f = field_unit(quantity, value_si)
    else:
        units = dict(FIELD_UNITS[_QUANTITY_OF.get(quantity, quantity)])
        if unit not in units:
            raise ValueError(f"{unit!r} is not a unit of {quantity}; units: {sorted(units)}")
        f = units[unit]
    v = float(value_si) * f
    if decimals is not None:
        text = f"{v:.{decimals}f}"
    else:
        text = f"{v:#.{digits}g}" if abs(v) < 1e-3 and v != 0 else f"{v:.{digits}g}"
    return f"{text:>{width}} {unit}".rstrip()


def fmt_raw(value: float | None, raw_unit: str = "count", digits: int = 4) -> str:
    """A value in the device's raw unit, labelled with that unit (never as SI).

    >>> fmt_raw(75.2213, "count")
    '75.22 count'
    """
    if value is None or not math.isfinite(float(value)):
        return "n/a"
    return f"{float(value):.{digits}g} {raw_unit}"
