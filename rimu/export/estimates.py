"""The estimates file: what the exported C filter (``rimu_filter``) and ``rimu replay --estimates`` write.

One CSV row per sample: ``t``, then per instrument in the calibration's order (gyro, accel)
``{k}_x, {k}_y, {k}_z`` (SI: rad/s, m/s^2; master-body frame), ``{k}_validity`` (the integer value of
:class:`rimu.fusion.validity.Validity`: 0 nominal, 1 degraded, 2 unobservable) and ``{k}_isolated`` (0-based
indices of the sensors the redundancy manager keeps out of the estimate after that sample -- isolated,
recovering or failed -- joined by ``;``, empty when none). Numbers are written with 17 significant digits, so
a file read back gives the same doubles. Further named columns may follow (``Estimates.extra``: ``rimu replay
--selfcal`` writes the tracked terms of every sensor and their 1-sigma, ``gyro_bias_x1``, ``gyro_bias_x1_sigma``...,
SI); :func:`read_estimates` reads them back into ``extra``.

>>> import io
>>> import numpy as np
>>> est = Estimates(np.array([0.0, 0.01]), {"gyro": np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]])},
...                 {"gyro": np.array([0, 1])}, {"gyro": np.array([[False] * 6, [False, True] + [False] * 4])})
>>> buf = io.StringIO()
>>> write_estimates(buf, est)
>>> buf.getvalue().splitlines()[2]
'0.01,0.1,0.2,0.3,1,1'
>>> _ = buf.seek(0)
>>> back = read_estimates(buf, {"gyro": 6})
>>> back.isolated["gyro"][1].nonzero()[0].tolist(), back.validity["gyro"].tolist()
([1], [0, 1])
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..errors import SessionFormatError, ShapeError

__all__ = ["ESTIMATE_COLUMNS", "Estimates", "estimate_columns", "read_estimates", "write_estimates"]


def _sizes(cal: Any) -> dict[str, int]:
    """Instrument -> number of sensors, from a Calibration or a mapping instrument -> n."""
    if hasattr(cal, "instruments") and not isinstance(cal, Mapping):
        return {k: int(cal[k].geometry.n) for k in cal.instruments}
    return {str(k): int(v) for k, v in dict(cal).items()}


def estimate_columns(cal: Any) -> list[str]:
    """The header of an estimates file for a calibration (or a mapping instrument -> sensor count, or a list of
    instrument names).

    >>> estimate_columns({"gyro": 6})
    ['t', 'gyro_x', 'gyro_y', 'gyro_z', 'gyro_validity', 'gyro_isolated']
    >>> estimate_columns(["gyro", "accel"])[-1]
    'accel_isolated'
    """
    names = list(cal) if isinstance(cal, (list, tuple)) else list(_sizes(cal))
    cols = ["t"]
    for k in names:
        cols += [f"{k}_x", f"{k}_y", f"{k}_z", f"{k}_validity", f"{k}_isolated"]
    return cols


#: the lead's name for :func:`estimate_columns`
ESTIMATE_COLUMNS = estimate_columns


@dataclass
class Estimates:
    """The content of an estimates file: ``t`` (N,), and per instrument ``x`` (N, 3) SI, ``validity`` (N,) int,
    ``isolated`` (N, n) bool; ``extra`` further named columns (N,) after those, in order."""

    t: np.ndarray
    x: dict[str, np.ndarray]
    validity: dict[str, np.ndarray]
    isolated: dict[str, np.ndarray]
    extra: dict[str, np.ndarray] | None = None

    @classmethod
    def from_replay(cls, t: np.ndarray, results: Mapping[str, Any]) -> Estimates:
        """From :meth:`rimu.fdi.RedundancyManager.run` results per instrument (``ReplayResult``)."""
        from ..fdi.health import SensorState

        return cls(np.asarray(t, float), {k: np.asarray(r.x, float) for k, r in results.items()},
                   {k: np.asarray(r.validity, int) for k, r in results.items()},
                   {k: np.asarray(r.sensor_state) >= SensorState.ISOLATED for k, r in results.items()})


def write_estimates(dest: str | os.PathLike[str] | TextIO, est: Estimates, header: bool = True) -> None:
    """Write an estimates file (a path or an open text stream); ``header=False`` appends rows only, so that a
    long replay writes its chunks one after another (floats as Python's shortest repr: they read back
    exactly)."""
    N = len(est.t)
    for k in est.x:
        if est.x[k].shape != (N, 3) or est.validity[k].shape != (N,) or est.isolated[k].ndim != 2 \
                or len(est.isolated[k]) != N:
            raise ShapeError(f"{k}: x must be (N, 3), validity (N,), isolated (N, n) with N = {N} samples")
    cols = [list(map(repr, np.asarray(est.t, float).tolist()))]
    for k in est.x:
        x = np.asarray(est.x[k], float)
        sets, inv = np.unique(np.asarray(est.isolated[k], bool), axis=0, return_inverse=True)
        names = [";".join(str(i) for i in np.flatnonzero(row)) for row in sets]
        cols += [list(map(repr, x[:, a].tolist())) for a in range(3)]
        cols += [list(map(str, np.asarray(est.validity[k], int).tolist())),
                 [names[i] for i in np.asarray(inv).reshape(-1).tolist()]]
    for name, v in (est.extra or {}).items():
        if np.shape(v) != (N,):
            raise ShapeError(f"extra column {name}: (N,) values with N = {N} samples, got {np.shape(v)}")
        cols.append(list(map(repr, np.asarray(v, float).tolist())))
    text = "".join(",".join(row) + "\n" for row in zip(*cols))
    if header:
        text = ",".join(estimate_columns({k: est.isolated[k].shape[1] for k in est.x}) + list(est.extra or {})) \
            + "\n" + text
    own = not hasattr(dest, "write")
    fh: Any = open(dest, "w", newline="") if own else dest
    try:
        fh.write(text)
    finally:
        if own:
            fh.close()


def read_estimates(src: str | os.PathLike[str] | TextIO, cal: Any) -> Estimates:
    """Read an estimates file written for ``cal`` (a Calibration, or a mapping instrument -> sensor count).

    Raises :class:`rimu.errors.SessionFormatError` when the header is not the calibration's or a cell is not a
    number / a sensor index.
    """
    sizes = _sizes(cal)
    want = estimate_columns(sizes)
    text = Path(src).read_text() if not hasattr(src, "read") else src.read()
    rows = list(csv.reader(io.StringIO(text)))
    name = str(src) if not hasattr(src, "read") else "the estimates stream"
    if not rows or rows[0][:len(want)] != want:
        raise SessionFormatError(f"{name}: the header is {rows[0] if rows else 'missing'}, expected {want} "
                                 "(an estimates file of this calibration's instruments)")
    names_extra = rows[0][len(want):]
    # another instrument's estimate columns (a file of another calibration); the tracked terms of a triad array's
    # sensors (gyro_bias_imu0_x) end in _x too and are further columns
    other = {f"{k}_{c}" for k in ("gyro", "accel") for c in ("x", "y", "z", "validity", "isolated")}
    if any(nm in other for nm in names_extra):
        raise SessionFormatError(f"{name}: the header is {rows[0]}, expected {want} (an estimates file of this "
                                 "calibration's instruments)")
    body = [r for r in rows[1:] if r]
    N = len(body)
    extra = {nm: np.zeros(N) for nm in names_extra}
    t = np.zeros(N)
    x = {k: np.zeros((N, 3)) for k in sizes}
    val = {k: np.zeros(N, int) for k in sizes}
    iso = {k: np.zeros((N, n), bool) for k, n in sizes.items()}
    for r, row in enumerate(body):
        if len(row) != len(want) + len(names_extra):
            raise SessionFormatError(f"{name}: row {r + 2} has {len(row)} fields, expected "
                                     f"{len(want) + len(names_extra)}")
        try:
            t[r] = float(row[0])
            c = 1
            for k, n in sizes.items():
                x[k][r] = [float(v) for v in row[c:c + 3]]
                val[k][r] = int(row[c + 3])
                if val[k][r] not in (0, 1, 2):
                    raise ValueError(f"{k}_validity must be 0, 1 or 2, got {val[k][r]}")
                idx = [int(i) for i in row[c + 4].split(";") if i != ""]
                if any(not 0 <= i < n for i in idx):
                    raise ValueError(f"sensor index out of 0..{n - 1}: {idx}")
                iso[k][r, idx] = True
                c += 5
            for j, nm in enumerate(names_extra):
                extra[nm][r] = float(row[c + j])
        except ValueError as exc:
            raise SessionFormatError(f"{name}: row {r + 2}: {exc}") from None
    return Estimates(t, x, val, iso, extra or None)
