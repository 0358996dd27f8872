"""rimu's calibration of one triad to and from imucal's ``FerrarisCalibrationInfo`` (extra ``bench``), where the
models overlap.

imucal calibrates ``acc = R_a^-1 K_a^-1 (y_a - b_a)`` [m/s^2] and ``gyr = R_g^-1 K_g^-1 (y_g - K_ga acc - b_g)``
[its ``gyr_unit``, deg/s by default]; rimu ``A u = SF y - B`` with ``A`` the calibrated axes (unit rows, Cho &
Park Eq. 1-2) in SI. Row i of ``R K`` is the axis ``a_i`` over ``K_i``: so ``A`` = the rows of ``R`` normalised,
``SF_i = c / (K_i |r_i|)`` (``c`` the unit factor, ``DEG_TO_RAD`` for deg/s), ``B_i = SF_i b_i``. imucal's
``K_ga`` (acceleration sensitivity of the gyro) has no counterpart in rimu's scale-misalignment-bias model: a
non-zero one is refused unless ``drop_g_sensitivity`` (then the difference is named in ``metadata``).

>>> import numpy as np
>>> from rimu.geometry import triad3
>>> from rimu.calibration.result import Calibration, InstrumentCalibration
>>> cal = Calibration({k: InstrumentCalibration.nominal(k, triad3(), scale=s, bias=0.1)
...                    for k, s in (("gyro", 0.001), ("accel", 0.01))})
>>> d = to_imucal_dict(cal)
>>> np.allclose(np.diag(d["K_a"]), 100.0), np.allclose(d["b_a"], 10.0)
(True, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import NotCompensableError, ShapeError
from ..units import DEG_TO_RAD
from .result import Calibration, InstrumentCalibration

__all__ = ["from_imucal", "to_imucal", "to_imucal_dict"]

_GYR_UNITS = {"deg/s": DEG_TO_RAD, "rad/s": 1.0}


def _triad(c: InstrumentCalibration) -> None:
    if c.geometry.n != 3:
        raise ShapeError(f"imucal describes one triad; this {c.instrument} calibration has {c.geometry.n} sensors")
    if c.effects:
        raise NotCompensableError(f"the {c.instrument} calibration holds {sorted(c.effects)}, which imucal's "
                                  "Ferraris model has no place for")


def to_imucal_dict(cal: Calibration, gyr_unit: str = "deg/s") -> dict[str, Any]:
    """The parameters of imucal's ``FerrarisCalibrationInfo`` (K_a, R_a, b_a, K_g, R_g, K_ga, b_g and units)."""
    out: dict[str, Any] = {"acc_unit": "m/s^2", "gyr_unit": gyr_unit, "from_acc_unit": cal.raw_unit,
                           "from_gyr_unit": cal.raw_unit}
    for k, tag in (("accel", "a"), ("gyro", "g")):
        c = cal[k]
        _triad(c)
        unit = 1.0 if k == "accel" else _GYR_UNITS[gyr_unit]
        out[f"K_{tag}"] = np.diag(unit / c.scale)
        out[f"R_{tag}"] = c.axes_mb()
        out[f"b_{tag}"] = c.bias / c.scale
    out["K_ga"] = np.zeros((3, 3))
    return out


def to_imucal(cal: Calibration, gyr_unit: str = "deg/s") -> Any:
    """An imucal ``FerrarisCalibrationInfo`` of the triad (needs imucal: ``pip install 'rimu[bench]'``)."""
    try:
        from imucal import FerrarisCalibrationInfo
    except ImportError:
        raise ImportError("converting to imucal needs imucal: pip install 'rimu[bench]'", name="imucal") from None
    return FerrarisCalibrationInfo(**to_imucal_dict(cal, gyr_unit))


def from_imucal(info: Any, drop_g_sensitivity: bool = False) -> Calibration:
    """rimu's calibration (geometry ``triad3``) of an imucal calibration info (any object with its K/R/b fields)."""
    from ..geometry import triad3

    g = triad3()
    cals = {}
    for k, tag in (("accel", "a"), ("gyro", "g")):
        K = np.asarray(getattr(info, f"K_{tag}"), float)
        R = np.asarray(getattr(info, f"R_{tag}"), float)
        b = np.asarray(getattr(info, f"b_{tag}"), float).reshape(3)
        if K.shape != (3, 3) or R.shape != (3, 3) or not np.allclose(K, np.diag(np.diag(K))):
            raise ShapeError(f"imucal K_{tag} must be a diagonal 3x3 and R_{tag} a 3x3 matrix")
        unit = 1.0 if k == "accel" else _GYR_UNITS.get(getattr(info, "gyr_unit", "deg/s") or "deg/s", DEG_TO_RAD)
        norms = np.linalg.norm(R, axis=1)
        scale = unit / (np.diag(K) * norms)
        m = R / norms[:, None]
        cals[k] = InstrumentCalibration(k, g, scale, m, scale * b)
    meta: dict[str, Any] = {"source": "imucal", "comment": getattr(info, "comment", None)}
    kga = np.asarray(getattr(info, "K_ga", np.zeros((3, 3))), float)
    if np.any(kga != 0):
        if not drop_g_sensitivity:
            raise NotCompensableError("imucal's K_ga (gyro sensitivity to acceleration) is not zero and rimu's "
                                      "scale-misalignment-bias model has no place for it; pass drop_g_sensitivity=True "
                                      "to convert without it")
        meta["dropped_K_ga"] = kga.tolist()
    raw = getattr(info, "from_acc_unit", None) or "count"
    return Calibration(cals, raw_unit=str(raw), method="imucal", metadata=meta)
