"""Plain text / CSV logs of one IMU (imu_tk's and most loggers' ``t ax ay az gx gy gz`` tables; the reader of
``rimu detect``, :func:`rimu.io.rawtext.read_raw_text`): the columns are found by name or position, the sample
rate from the times or a ``Fs``/``rate`` line. Such a file does not say its units: they must be declared
(``gyro_unit``, ``accel_unit``: a unit name of :data:`rimu.io.multiimu.UNIT_FACTORS` or SI per raw count),
else the file is refused, never taken as SI.

>>> sniff("log.txt", b"t ax ay az gx gy gz\\n0 1 2 3 4 5 6\\n")
True
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ...errors import SessionFormatError
from ..multiimu import ImuStream, MultiImuRecording, _factor
from ._open import is_text

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "text"
EXTRA = None


def sniff(name: str, head: bytes) -> bool:
    """Text whose lines after any header hold numbers (the last resort of the sniffers)."""
    if not head or not is_text(head):
        return False
    lines = head.decode("utf-8", "replace").splitlines()
    if not head.endswith(b"\n"):
        lines = lines[:-1]  # the last line may be cut by the end of the head
    lines = [ln for ln in lines[1:] if ln.strip()]
    return any(sum(c.isdigit() for c in ln) >= 3 for ln in lines)


def read(path: str | os.PathLike[str], gyro_unit: Any = None, accel_unit: Any = None,
         sample_rate_hz: float | None = None, **options: Any) -> MultiImuRecording:
    """Every IMU of the table in SI, with the declared units: ``imu0`` (and ``imu1`` ... when the columns hold
    several triads side by side, in the order of their columns)."""
    from ..rawtext import read_raw_text

    log = read_raw_text(path, sample_rate_hz)
    missing = [f"{k}_unit" for k, u in (("gyro", gyro_unit), ("accel", accel_unit)) if u is None and k in log.raw]
    if missing:
        raise SessionFormatError(f"{path}: a text log does not state its units; declare {' and '.join(missing)} "
                                 "(rimu import --gyro-unit deg/s --accel-unit g, or counts as SI per count, e.g. "
                                 "--gyro-unit 1.332e-4)")
    g = log.raw.get("gyro")
    a = log.raw.get("accel")
    # several triads side by side (g0x g0y g0z g1x ...): one IMU per three columns, never one stream of 3k columns
    widths = {k: v.shape[1] for k, v in (("gyro", g), ("accel", a)) if v is not None}
    k_imu = {w // 3 for w in widths.values()}
    if any(w % 3 for w in widths.values()) or len(k_imu) != 1:
        cols = {k: log.columns.get(k) for k in widths}
        raise SessionFormatError(f"{path}: the gyro and accelerometer columns {cols} do not form whole triads of "
                                 "one IMU each; name the IMUs' columns with a mapping (rimu import LOG --format "
                                 "multiimu-csv --mapping MAP.json, docs/io.md)")
    k = k_imu.pop()
    t = np.asarray(log.t, float)
    units = []
    for j in range(k):
        gj = None if g is None else g[:, 3 * j:3 * j + 3] * _factor(gyro_unit, "gyro")
        aj = None if a is None else a[:, 3 * j:3 * j + 3] * _factor(accel_unit, "accel")
        units.append(ImuStream(f"imu{j}", t, gj, aj))
    return MultiImuRecording(units, {"format": NAME, "source": str(path), "header": dict(log.meta),
                                   "units_from": {"gyro": f"declared ({gyro_unit})",
                                                  "accel": f"declared ({accel_unit})"}})
