"""imucal's Ferraris calibration folder (``example_ferraris_session.csv`` and its ``_list.json`` of sections) as a
recording: the one triad's samples of every section, back to back on the file's sample index at 102.4 Hz (the
rate imucal's example states). Its calibration session (the sections with their known inputs) is
:func:`rimu.session.load_ferraris`, which the commands use for this folder.

Units: the file's gyro columns are deg/s, its accelerometer columns m/s^2 (imucal's example; see the loader).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ...units import DEG_TO_RAD
from ..multiimu import ImuStream, MultiImuRecording

__all__ = ["EXTRA", "NAME", "read", "sniff"]

NAME = "ferraris"
EXTRA = None
CSV = "example_ferraris_session.csv"
SECTIONS = "example_ferraris_session_list.json"


def sniff(name: str, head: bytes) -> bool:
    """A folder with imucal's two Ferraris files."""
    p = Path(name)
    return p.is_dir() and (p / CSV).exists() and (p / SECTIONS).exists()


def read(path: str | os.PathLike[str], **options: Any) -> MultiImuRecording:
    """The triad ``imu0`` in SI (gyro deg/s -> rad/s)."""
    from ...session import load_ferraris

    s = load_ferraris(Path(path))
    t = np.concatenate([seg.t for seg in s.segments])
    order = np.argsort(t, kind="stable")
    g = np.vstack([seg.raw["gyro"] for seg in s.segments])[order] * DEG_TO_RAD
    a = np.vstack([seg.raw["accel"] for seg in s.segments])[order]
    return MultiImuRecording([ImuStream("imu0", t[order], g, a)],
                             {"format": NAME, "source": str(path), "sections": [seg.label for seg in s.segments],
                              "units_from": {"gyro": "imucal example (deg/s)", "accel": "imucal example (m/s^2)"}})
