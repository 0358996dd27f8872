"""Pieces of a streamed log put back together (for readers whose ``read`` is their ``iter_chunks`` joined)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from ..multiimu import ImuStream, MultiImuRecording

__all__ = ["join_chunks"]


def join_chunks(chunks: Iterable[MultiImuRecording]) -> MultiImuRecording:
    """One recording of the pieces: each IMU's samples in order, the ``meta`` of the last piece (the file's counts).

    >>> a = MultiImuRecording([ImuStream("imu0", np.array([0.0]), np.zeros((1, 3)))])
    >>> b = MultiImuRecording([ImuStream("imu0", np.array([1.0]), np.ones((1, 3)))], {"records": 2})
    >>> r = join_chunks([a, b]); r["imu0"].t.tolist(), r.meta
    ([0.0, 1.0], {'records': 2})
    """
    parts: dict[str, list[ImuStream]] = {}
    meta: dict[str, Any] = {}
    for c in chunks:
        for u in c.units:
            parts.setdefault(u.name, []).append(u)
        meta = c.meta
    units = []
    for name, us in parts.items():
        def cat(attr: str, us: list[ImuStream] = us) -> np.ndarray | None:
            xs = [getattr(u, attr) for u in us]
            return None if any(x is None for x in xs) else np.concatenate(xs)
        t = cat("t")
        units.append(ImuStream(name, t if t is not None else np.zeros(0), cat("gyro"), cat("accel"),
                               cat("temperature")))
    return MultiImuRecording(units, dict(meta))
