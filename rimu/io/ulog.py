"""PX4 ULog flight logs (pyulog, extra ``ulog``): every ``sensor_gyro`` / ``sensor_accel`` instance of a log
read as one redundant set.

A flight controller with k IMUs logs k instances of each topic (``multi_id`` 0..k-1). Instance i contributes
three sensors (x, y, z, as logged, in SI: rad/s and m/s^2) to the set, so the gyros form a ``3k``-sensor unit
of stacked triads (:meth:`ULogSource.geometry`). Epochs are on the time base of gyro instance 0
(``timestamp_sample`` where logged, otherwise ``timestamp``, in s); each other instance contributes its nearest
sample within ``tolerance`` (default: half the median period of the time base), each sample at most once;
otherwise that triad is invalid for the epoch. Accounting counts logged samples: a sample used in an epoch is
accepted, one never used is rejected with reason ``unmatched``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..epoch import Epoch
from ..errors import SessionFormatError, TransportError
from .base import Source

__all__ = ["ULogSource", "read_ulog_instances"]

TOPICS = {"gyro": "sensor_gyro", "accel": "sensor_accel"}


def read_ulog_instances(path: str | os.PathLike[str]) -> dict[str, list[dict[str, Any]]]:
    """Per instrument, the instances of its topic: ``{"t", "xyz" (N, 3), "temperature", "device_id",
    "multi_id"}``, sorted by ``multi_id``."""
    try:
        from pyulog import ULog
    except ImportError as exc:  # pragma: no cover
        raise TransportError("reading ULog files needs pyulog: pip install 'rimu[ulog]'") from exc
    try:
        ulog = ULog(os.fspath(path), list(TOPICS.values()))
    except Exception as exc:
        raise SessionFormatError(f"{path}: not a readable ULog file ({exc})") from exc
    out: dict[str, list[dict[str, Any]]] = {}
    for inst, topic in TOPICS.items():
        sets = sorted((d for d in ulog.data_list if d.name == topic), key=lambda d: d.multi_id)
        rows = []
        for d in sets:
            f = d.data
            ts = f.get("timestamp_sample", f["timestamp"]).astype(np.float64) * 1e-6
            xyz = np.column_stack([f["x"], f["y"], f["z"]]).astype(float)
            rows.append({"t": ts, "xyz": xyz, "multi_id": int(d.multi_id),
                         "temperature": f["temperature"].astype(float) if "temperature" in f else None,
                         "device_id": int(f["device_id"][0]) if "device_id" in f and len(f["device_id"]) else None})
        if rows:
            out[inst] = rows
    if "gyro" not in out:
        raise SessionFormatError(f"{path}: no sensor_gyro data in the log")
    return out


def _match(t_ref: np.ndarray, t: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Index into t of the nearest sample for every reference time (-1 if none within tol), each used once."""
    if len(t) == 0:
        return np.full(len(t_ref), -1), np.zeros(0, bool)
    j = np.clip(np.searchsorted(t, t_ref), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(t_ref), int)
    if len(t) > 1:
        left = j - 1
        j = np.where(np.abs(t[left] - t_ref) <= np.abs(t[j] - t_ref), left, j)
    d = np.abs(t[j] - t_ref)
    ok = d <= tol
    # each sample at most once: keep the nearest reference time
    order = np.lexsort((d, j))
    js, oks = j[order], ok[order]
    first = np.ones(len(js), bool)
    first[1:] = js[1:] != js[:-1]
    keep = np.zeros(len(t_ref), bool)
    keep[order] = first & oks
    idx = np.where(keep, j, -1)
    used = np.zeros(len(t), bool)
    used[idx[idx >= 0]] = True
    return idx, used


class ULogSource(Source):
    """Epochs of every IMU instance of a PX4 ULog file (see the module docstring)."""

    unit = "sample"

    def __init__(self, path: str | os.PathLike[str], tolerance: float | None = None) -> None:
        super().__init__()
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise TransportError(f"no ULog file at {self.path}")
        self.instances = read_ulog_instances(self.path)
        self.tolerance = tolerance

    def geometry(self, instrument: str = "gyro") -> Any:
        """Stacked triads, one sub-unit per instance (sensor names ``x0, y0, z0, x1, ...``)."""
        from ..geometry import Geometry
        from ..geometry.base import SubUnit

        k = len(self.instances[instrument])
        subs = [SubUnit(f"imu{i}", np.eye(3), (3 * i, 3 * i + 1, 3 * i + 2)) for i in range(k)]
        return Geometry(np.vstack([np.eye(3)] * k), [f"{a}{i}" for i in range(k) for a in "xyz"], subs,
                        name=f"px4_{k}x_triad")

    def _epochs(self) -> Iterator[Epoch]:
        ref = self.instances["gyro"][0]["t"]
        if len(ref) == 0:
            return
        tol = self.tolerance if self.tolerance is not None else 0.5 * float(np.median(np.diff(ref))) if len(ref) > 1 else 0.0
        acc = self.accounting
        cols: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
        temps = None
        for inst, rows in self.instances.items():
            cols[inst] = []
            for r in rows:
                idx, used = _match(ref, r["t"], tol)
                acc.received += len(r["t"])
                acc.accepted += int(used.sum())
                acc.reject("unmatched", int((~used).sum()))
                cols[inst].append((idx, r["xyz"]))
                if inst == "gyro" and r is rows[0] and r["temperature"] is not None:
                    temps = np.where(idx >= 0, r["temperature"][np.maximum(idx, 0)], np.nan)
        for e, t in enumerate(ref.tolist()):
            if self.stop_event.is_set():
                break
            raw, valid = {}, {}
            for inst, parts in cols.items():
                y = np.zeros(3 * len(parts))
                v = np.zeros(3 * len(parts), bool)
                for i, (idx, xyz) in enumerate(parts):
                    j = idx[e]
                    if j >= 0:
                        s = xyz[j]
                        ok = np.isfinite(s)
                        y[3 * i:3 * i + 3] = np.where(ok, s, 0.0)
                        v[3 * i:3 * i + 3] = ok
                raw[inst], valid[inst] = y, v
            temp = None if temps is None or not np.isfinite(temps[e]) else float(temps[e])
            acc.epochs += 1
            yield Epoch(float(t), raw, valid, temp, {"index": e})
