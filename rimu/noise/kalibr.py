"""kalibr's ``imu.yaml`` noise parameters from rimu's noise model, and back.

kalibr (and allan_variance_ros, OpenVINS, VINS-Mono, ORB-SLAM3) describe an IMU by four numbers and a rate::

    accelerometer_noise_density: 2.0e-3   # m/s^2/sqrt(Hz)   white noise (VRW), IEEE 952 N of the accelerometer
    accelerometer_random_walk:   3.0e-3   # m/s^3/sqrt(Hz)   bias random walk, IEEE 952 K (rate random walk)
    gyroscope_noise_density:     1.7e-4   # rad/s/sqrt(Hz)   white noise (ARW), N of the gyro
    gyroscope_random_walk:       2.0e-5   # rad/s^2/sqrt(Hz) bias random walk, K of the gyro
    update_rate:                 200.0    # Hz

These are rimu's ``white`` and ``rate_random_walk`` terms in SI (:data:`rimu.noise.model.SI_TERM_UNITS`: rad/sqrt(s)
= rad/s/sqrt(Hz), and so on), one value per instrument for the whole triad: :func:`to_kalibr` gives the root mean
square over the triad's three sensors, with its 1-sigma from the sensors' own sigmas. A unit of k triads gives
k blocks ``imu0``, ``imu1``, ... (kalibr's IMU-chain layout); a single triad a plain ``imu.yaml``.
:func:`noise_from_kalibr` makes an :class:`~rimu.noise.model.InstrumentNoise` of every sensor from such a file
(quantisation and bias instability zero), to seed the detectors where no static recording exists.

>>> from rimu.noise.model import InstrumentNoise
>>> g = InstrumentNoise.from_terms("gyro", ["x", "y", "z"], 200.0, white=1.7e-4, rate_random_walk=2e-5)
>>> a = InstrumentNoise.from_terms("accel", ["x", "y", "z"], 200.0, white=2e-3, rate_random_walk=3e-3)
>>> doc = to_kalibr({"gyro": g, "accel": a})
>>> doc["gyroscope_noise_density"], doc["accelerometer_random_walk"], doc["update_rate"]
(0.00017, 0.003, 200.0)
>>> noise_from_kalibr(doc, "gyro", ["x", "y", "z"]).terms["white"].tolist()
[0.00017, 0.00017, 0.00017]
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CalibrationFileError
from .model import InstrumentNoise

__all__ = ["KALIBR_KEYS", "UNITS", "kalibr_yaml", "noise_from_kalibr", "read_kalibr", "to_kalibr", "to_kalibr_chain"]

#: (instrument, rimu term) -> kalibr key
KALIBR_KEYS = {("accel", "white"): "accelerometer_noise_density", ("accel", "rate_random_walk"): "accelerometer_random_walk",
               ("gyro", "white"): "gyroscope_noise_density", ("gyro", "rate_random_walk"): "gyroscope_random_walk"}


def _rms(v: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """RMS of the values and its 1-sigma (first order: d rms / d v_i = v_i / (n rms))."""
    r = float(np.sqrt(np.mean(v ** 2)))
    if r == 0:
        return 0.0, float(np.sqrt(np.sum(s ** 2))) / len(v)
    return r, float(np.sqrt(np.sum((v * s) ** 2))) / (len(v) * r)


def to_kalibr(instruments: dict[str, InstrumentNoise], members: list[int] | None = None,
              with_sigma: bool = False) -> dict[str, Any]:
    """kalibr's parameters of one triad (sensors ``members`` of each instrument, default all), SI.

    With ``with_sigma`` the 1-sigma of each value is added under ``<key>_sigma``.
    """
    doc: dict[str, Any] = {}
    rate = None
    for (k, term), key in KALIBR_KEYS.items():
        if k not in instruments:
            continue
        m = instruments[k]
        idx = list(range(m.n)) if members is None else members
        v, s = _rms(m.terms[term][idx], m.sigma[term][idx])
        doc[key] = v
        if with_sigma:
            doc[key + "_sigma"] = s
        rate = m.sample_rate
    if rate is not None:
        doc["update_rate"] = float(rate)
    return doc


def to_kalibr_chain(instruments: dict[str, InstrumentNoise], triads: list[list[int]], rostopics: list[str] | None = None
                    ) -> dict[str, Any]:
    """kalibr's IMU-chain document: ``imu<k>`` blocks, one per triad (sensor indices ``triads[k]``)."""
    out = {}
    for j, members in enumerate(triads):
        d = to_kalibr(instruments, members)
        d["rostopic"] = rostopics[j] if rostopics else f"/imu{j}"
        out[f"imu{j}"] = d
    return out


#: the unit of each kalibr field
UNITS = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
         "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)", "update_rate": "Hz"}


def kalibr_yaml(doc: dict[str, Any]) -> str:
    """The YAML text of a kalibr document (units as comments, no PyYAML needed)."""
    unit = UNITS

    def block(d: dict[str, Any], indent: str) -> list[str]:
        lines = []
        for k, v in d.items():
            if isinstance(v, dict):
                lines += [f"{indent}{k}:"] + block(v, indent + "  ")
            elif isinstance(v, str):
                lines.append(f"{indent}{k}: {v}")
            else:
                u = unit.get(k) or unit.get(k.removesuffix("_sigma"))
                lines.append(f"{indent}{k}: {float(v):.6e}" + (f"  # {u}" if u else ""))
        return lines

    return "\n".join(block(doc, "")) + "\n"


def read_kalibr(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A kalibr ``imu.yaml`` (or IMU-chain file) as a dict (needs PyYAML)."""
    try:
        import yaml
    except ImportError:
        raise ImportError("reading kalibr YAML needs PyYAML: pip install pyyaml", name="yaml") from None
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise CalibrationFileError(f"{p}: not a readable kalibr YAML file ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise CalibrationFileError(f"{p}: a kalibr imu.yaml is a mapping of accelerometer_noise_density, ...")
    return doc


def noise_from_kalibr(doc: dict[str, Any], instrument: str, names: list[str]) -> InstrumentNoise:
    """An :class:`InstrumentNoise` of every sensor ``names`` from a kalibr document (one IMU's block): its noise
    density as the white term, its random walk as the rate random walk, at its ``update_rate``."""
    keys = {t: KALIBR_KEYS[(instrument, t)] for t in ("white", "rate_random_walk")}
    vals = {}
    for t, key in keys.items():
        v = doc.get(key)
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise CalibrationFileError(f"kalibr parameter {key} must be a number >= 0, got {v!r}")
        vals[t] = float(v)
    rate = doc.get("update_rate", 0)
    if not isinstance(rate, (int, float)) or not rate > 0:
        raise CalibrationFileError(f"kalibr update_rate must be a positive number of Hz, got {rate!r}")
    m = InstrumentNoise.from_terms(instrument, list(names), float(rate), white=vals["white"],
                                   rate_random_walk=vals["rate_random_walk"])
    m.meta["source"] = "kalibr"
    return m
