"""A calibration in the model of Tedaldi et al. (2014) (as imu_tk and the MPU-6050 authors' ImuCalibration write it)
as a rimu :class:`~rimu.calibration.result.Calibration` of one triad of counts, to compare with (``rimu calibrate
--reference``).

Tedaldi's accelerometer model ``a = T K (y + b)`` [m/s^2], ``T = [[1, -a0, a1], [0, 1, -a2], [0, 0, 1]]``,
``K = diag(k)``, and gyro model ``w = T K (y - b)`` [rad/s], ``T = [[1, -g0, g1], [g2, 1, -g3], [-g4, g5, 1]]``, with
``b`` in counts (the parameter files: misalignments, then scales, then biases). rimu's ``A u = SF y - B`` (Cho &
Park 2005, Eq. 1-2 and 20: ``A`` the unit-norm calibrated axes): ``y = (T K)^-1 u -+ b``, so with ``r_i`` the i-th
row of ``(T K)^-1``: ``A_i = r_i / |r_i|``, ``SF_i = 1 / |r_i|`` and ``B_i = -+ SF_i b_i`` (minus for the
accelerometers' ``y + b``, plus for the gyros' ``y - b``).

>>> import numpy as np
>>> from rimu.geometry import triad3
>>> c = from_tedaldi_params("accel", [0, 0, 0, 2e-3, 2e-3, 2e-3, 10.0, 0.0, 0.0], triad3())
>>> float(c.scale[0]), float(c.bias[0])          # SF = k, B = -k b
(0.002, -0.02)
>>> bool(np.allclose(c.compensate(np.array([[490.0, 0.0, 4903.3]])), [[1.0, 0.0, 9.8066]]))
True
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import CalibrationFileError
from ..geometry import Geometry
from .result import Calibration, InstrumentCalibration

__all__ = ["from_tedaldi_params", "load_tedaldi"]

_N = {"accel": 9, "gyro": 12}


def _T(instrument: str, p: np.ndarray) -> np.ndarray:
    if instrument == "accel":
        return np.array([[1.0, -p[0], p[1]], [0.0, 1.0, -p[2]], [0.0, 0.0, 1.0]])
    return np.array([[1.0, -p[0], p[1]], [p[2], 1.0, -p[3]], [-p[4], p[5], 1.0]])


def from_tedaldi_params(instrument: str, params: Sequence[float], geometry: Geometry) -> InstrumentCalibration:
    """One instrument's Tedaldi parameters (module docstring; 9 for the accelerometers, 12 for the gyros) as an
    :class:`InstrumentCalibration` of ``geometry`` (one triad) in counts."""
    p = np.asarray(params, dtype=float).ravel()
    if instrument not in _N or p.size != _N[instrument] or not np.all(np.isfinite(p)):
        raise CalibrationFileError(f"Tedaldi {instrument} parameters: expected {_N.get(instrument, '9 or 12')} finite "
                                   f"numbers (misalignments, 3 scales, 3 biases), got {p.size}")
    if geometry.n != 3:
        raise CalibrationFileError(f"a Tedaldi calibration is of one triad; the {instrument} geometry has "
                                   f"{geometry.n} sensors")
    n_mis = _N[instrument] - 6
    k, b = p[n_mis:n_mis + 3], p[n_mis + 3:]
    R = np.linalg.inv(_T(instrument, p[:n_mis]) @ np.diag(k))   # y = R u -+ b
    norms = np.linalg.norm(R, axis=1)
    sf = 1.0 / norms
    bias = (-1.0 if instrument == "accel" else 1.0) * sf * b
    return InstrumentCalibration(instrument, geometry, sf, R / norms[:, None], bias)


def load_tedaldi(acc_params: str | Path | None, gyro_params: str | Path | None,
                 geometries: dict[str, Geometry]) -> Calibration:
    """A :class:`Calibration` from the parameter files (one number a line: ``params_acc.csv``,
    ``params_gyro.csv``) for the given geometries (those of the session it is compared on)."""
    insts = {}
    for k, path in (("accel", acc_params), ("gyro", gyro_params)):
        if path is None:
            continue
        if k not in geometries:
            raise CalibrationFileError(f"{path}: the session has no {k}")
        try:
            p = np.loadtxt(path, delimiter=",", ndmin=1)
        except (OSError, ValueError) as exc:
            raise CalibrationFileError(f"{path}: not a list of numbers ({exc})") from None
        insts[k] = from_tedaldi_params(k, p, geometries[k])
    return Calibration(insts, raw_unit="count", method="Tedaldi et al. 2014 (converted)")
