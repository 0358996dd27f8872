"""Calibration data: a :class:`Session` is a list of :class:`Segment` s, each with its samples and what the
test rig knows about it.

What a segment can know (``kind``):

``"static"``
    The unit is at rest in a known attitude: the specific force in MB is known (``specific_force_mb``), and
    where the attitude is known (``mat_ln_mb``) so is the Earth rate seen by the gyros.
``"static_unknown"``
    At rest, attitude unknown (Zhang et al. 2010's norm-based method): only |f| = g and |w| = Earth rate.
``"rate"``
    Rotating at a known constant table rate ``rate_mb`` (MB frame, rad/s, relative to the local level
    frame, that is without Earth rate). With ``mat_ln_mb`` (attitude at the segment's first sample) the
    specific force and Earth rate along the rotation are known sample by sample.
``"angle"``
    Rotated through a known total angle (``angle_mb``, a rotation vector in MB, rad) with unknown rate
    profile: Zhang's integrated CW/CCW rotations, hand turns of a Ferraris-style session.
``"motion"``
    Moving, nothing known (a hand-held rotation between two poses; ``rimu detect`` and the hand-held
    calibration integrate the gyros over it).

Frames: ``ln`` is the local level frame, East-North-Up. Gravity points down, so a unit at rest with MB
aligned to ENU measures specific force ``[0, 0, +g]``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..epoch import INSTRUMENTS
from ..errors import SessionFormatError, ShapeError
from ..geometry import Geometry
from ..units import EARTH_RATE, G0

__all__ = ["SEGMENT_KINDS", "Segment", "Session", "rotation_matrix", "skew", "earth_rate_ln"]

SEGMENT_KINDS = ("static", "static_unknown", "rate", "angle", "motion")


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices, vectorised over leading axes: ``skew(a) @ b == cross(a, b)``; (..., 3) -> (..., 3, 3).

    >>> bool(np.allclose(skew(np.array([1.0, 2, 3])) @ [4.0, 5, 6], np.cross([1, 2, 3], [4, 5, 6])))
    True
    """
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape + (3,))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues), vectorised over leading axes.

    >>> np.allclose(rotation_matrix(np.array([0, 0, np.pi / 2])) @ [1, 0, 0], [0, 1, 0])
    True
    """
    r = np.asarray(rotvec, dtype=float)
    flat = r.reshape(-1, 3)
    th = np.linalg.norm(flat, axis=1)
    out = np.empty((flat.shape[0], 3, 3))
    small = th < 1e-12
    k = np.zeros_like(flat)
    k[~small] = flat[~small] / th[~small, None]
    K = np.zeros((flat.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], (1.0 - np.cos(th))[:, None, None]
    out[:] = np.eye(3) + s * K + c * (K @ K)
    return out.reshape(r.shape[:-1] + (3, 3))


def earth_rate_ln(latitude: float) -> np.ndarray:
    """Earth rate in the local level frame (ENU), rad/s: ``[0, W cos(lat), W sin(lat)]``."""
    return np.array([0.0, EARTH_RATE * np.cos(latitude), EARTH_RATE * np.sin(latitude)])


@dataclass
class Segment:
    """One interval of a calibration session.

    Attributes
    ----------
    label : str
    kind : str
        One of :data:`SEGMENT_KINDS`.
    t : ndarray (N,)
        Sample times, s.
    raw : dict[str, ndarray (N, n)]
        Raw outputs per instrument.
    temperature : ndarray (N,) or None
        degC.
    specific_force_mb : ndarray (3,) or (N, 3) or None
        Known specific force in MB, m/s^2.
    rate_mb : ndarray (3,) or None
        Known table rate in MB, rad/s, relative to the local level frame.
    angle_mb : ndarray (3,) or None
        Known total rotation over the segment (rotation vector in MB), rad.
    mat_ln_mb : ndarray (3, 3) or None
        Attitude at the first sample: maps MB vectors to the local level frame (ENU).
    meta : dict
        Free-form (procedure step, commanded values in the rig's units, ...).
    """

    label: str
    kind: str
    t: np.ndarray
    raw: dict[str, np.ndarray]
    temperature: np.ndarray | None = None
    specific_force_mb: np.ndarray | None = None
    rate_mb: np.ndarray | None = None
    angle_mb: np.ndarray | None = None
    mat_ln_mb: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in SEGMENT_KINDS:
            raise SessionFormatError(f"segment {self.label!r}: kind {self.kind!r} is not one of {SEGMENT_KINDS}")
        self.t = np.asarray(self.t, dtype=float)
        N = self.t.shape[0]
        if self.t.ndim != 1 or N < 1:
            raise ShapeError(f"segment {self.label!r}: t must be a non-empty 1-D array, got shape {self.t.shape}")
        for k in list(self.raw):
            y = np.asarray(self.raw[k], dtype=float)
            if y.ndim != 2 or y.shape[0] != N:
                raise ShapeError(f"segment {self.label!r}: raw[{k!r}] must have shape ({N}, n), got {y.shape}")
            self.raw[k] = y
        for name in ("specific_force_mb", "rate_mb", "angle_mb"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v, dtype=float)
                if v.shape not in ((3,), (N, 3)):
                    raise ShapeError(f"segment {self.label!r}: {name} must have shape (3,) or ({N}, 3), got {v.shape}")
                setattr(self, name, v)
        if self.mat_ln_mb is not None:
            self.mat_ln_mb = np.asarray(self.mat_ln_mb, dtype=float).reshape(3, 3)
        if self.temperature is not None:
            self.temperature = np.asarray(self.temperature, dtype=float).reshape(N)
        if self.kind == "static" and self.specific_force_mb is None and self.mat_ln_mb is None:
            raise SessionFormatError(
                f"segment {self.label!r} is 'static' but gives neither specific_force_mb nor mat_ln_mb; "
                "use kind 'static_unknown' when the attitude is not known"
            )
        if self.kind == "rate" and self.rate_mb is None:
            raise SessionFormatError(f"segment {self.label!r} is 'rate' but has no rate_mb")
        if self.kind == "angle" and self.angle_mb is None:
            raise SessionFormatError(f"segment {self.label!r} is 'angle' but has no angle_mb")

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if self.n_samples > 1 else 0.0

    def table_rate(self) -> np.ndarray:
        """Commanded table rate in MB, (3,), rad/s (zero for static segments)."""
        if self.rate_mb is not None:
            return np.asarray(self.rate_mb, dtype=float) if self.rate_mb.ndim == 1 else self.rate_mb.mean(axis=0)
        return np.zeros(3)

    def _turns_unknown(self) -> bool:
        """An 'angle' segment without a table rate: it turns through ``angle_mb``, but when is not known."""
        return self.kind == "angle" and self.rate_mb is None and self.angle_mb is not None and bool(
            np.any(np.asarray(self.angle_mb, dtype=float).reshape(-1, 3)[-1]))

    def fixed_under_turn(self, x: np.ndarray) -> bool:
        """Whether the MB vector ``x`` (seen at the first sample) stays the same through this segment's turn:
        true unless the segment is an 'angle' one without a table rate whose axis (``angle_mb``) is not parallel
        to ``x`` (within 1e-6 of ``|x|``). A turn about the vertical leaves gravity where it is; a reported turn
        about a horizontal axis, at a rate nobody stated, does not, and gravity during it is not known.

        >>> import numpy as np
        >>> t = np.arange(3) * 0.01
        >>> s = Segment("z_rot", "angle", t, {"accel": np.zeros((3, 3))}, angle_mb=np.array([0, 0, 6.2832]),
        ...             mat_ln_mb=np.eye(3))
        >>> s.fixed_under_turn(np.array([0, 0, 9.81])), s.fixed_under_turn(np.array([9.81, 0, 0]))
        (True, False)
        """
        if not self._turns_unknown():
            return True
        a = np.asarray(self.angle_mb, dtype=float).reshape(-1, 3)[-1]
        k = a / np.linalg.norm(a)
        x = np.asarray(x, dtype=float)
        return bool(np.linalg.norm(x - k * float(k @ x)) <= 1e-6 * np.linalg.norm(x))

    def attitude(self) -> np.ndarray | None:
        """mat_ln_mb for every sample, (N, 3, 3), or None where the attitude is unknown.

        The body turns at the constant ``rate_mb`` about an axis fixed in MB:
        ``C(t) = C(t0) exp(skew(rate_mb (t - t0)))``.
        """
        if self.mat_ln_mb is None or self._turns_unknown():
            return None
        w = self.table_rate()
        if not np.any(w):  # at rest: one attitude for every sample
            return np.broadcast_to(self.mat_ln_mb, (self.n_samples, 3, 3))
        dt = self.t - self.t[0]
        return self.mat_ln_mb @ rotation_matrix(np.outer(dt, w))

    def ln_vector_in_mb(self, v_ln: np.ndarray) -> np.ndarray | None:
        """A vector fixed in the local level frame, seen in MB at every sample: ``C(t)^T v``, (N, 3).

        With ``C(t) = C0 R(t)`` and R the rotation by ``theta = |w| t`` about the fixed MB axis k of the table
        rate, ``R^T x = x cos(theta) - (k x x) sin(theta) + k (k . x)(1 - cos(theta))`` with ``x = C0^T v``:
        three constant vectors and one angle per sample, no rotation matrix per sample (the costliest step
        of a calibration before; equal to ``einsum(attitude(), v)`` to rounding). A static segment returns a
        read-only broadcast of one vector. None where the attitude is unknown.
        """
        if self.mat_ln_mb is None:
            return None
        x = self.mat_ln_mb.T @ np.asarray(v_ln, dtype=float)
        w = self.table_rate()
        wn = float(np.linalg.norm(w))
        if wn == 0.0:
            if self._turns_unknown() and not self.fixed_under_turn(x):
                return None
            return np.broadcast_to(x, (self.n_samples, 3))
        k = w / wn
        th = wn * (self.t - self.t[0])
        kx = np.cross(k, x)
        c, s = np.cos(th)[:, None], np.sin(th)[:, None]
        return x * c - kx * s + np.outer(1.0 - np.cos(th), k * (k @ x))

    def specific_force(self, gravity: float = G0) -> np.ndarray | None:
        """Known specific force in MB, (N, 3), m/s^2, or None."""
        if self.specific_force_mb is not None:
            return np.broadcast_to(self.specific_force_mb, (self.n_samples, 3))
        return self.ln_vector_in_mb(np.array([0.0, 0.0, gravity]))

    def earth_rate(self, latitude: float | None) -> np.ndarray | None:
        """Earth rate seen in MB, (N, 3), rad/s, or None when attitude or latitude is unknown."""
        if latitude is None:
            return None
        return self.ln_vector_in_mb(earth_rate_ln(latitude))

    def angular_rate(self, latitude: float | None = None, include_earth: bool = True) -> np.ndarray:
        """Known angular rate in MB, (N, 3): table rate plus, if asked and known, Earth rate."""
        w = np.broadcast_to(self.table_rate(), (self.n_samples, 3)).copy()
        if include_earth:
            we = self.earth_rate(latitude)
            if we is not None:
                w += we
        return w


@dataclass
class Session:
    """A calibration session: segments plus what holds for all of them.

    Attributes
    ----------
    segments : list of Segment
    geometries : dict[str, Geometry]
        Geometry per instrument present (``"gyro"``, ``"accel"``).
    sample_rate : float
        Hz.
    latitude : float or None
        rad, for Earth rate.
    gravity : float
        Local gravity magnitude, m/s^2.
    raw_unit : str
        Unit of raw outputs (``"count"``).
    meta : dict
    """

    segments: list[Segment]
    geometries: dict[str, Geometry]
    sample_rate: float
    latitude: float | None = None
    gravity: float = G0
    raw_unit: str = "count"
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = set(self.geometries) - set(INSTRUMENTS)
        if unknown:
            raise SessionFormatError(f"unknown instruments {sorted(unknown)}; use {INSTRUMENTS}")
        for seg in self.segments:
            for k, g in self.geometries.items():
                if k not in seg.raw:
                    raise SessionFormatError(f"segment {seg.label!r} has no {k} samples")
                if seg.raw[k].shape[1] != g.n:
                    raise ShapeError(
                        f"segment {seg.label!r}: {k} has {seg.raw[k].shape[1]} columns, geometry {g.name!r} has {g.n} sensors"
                    )

    def __iter__(self) -> Iterator[Segment]:
        return iter(self.segments)

    def __len__(self) -> int:
        return len(self.segments)

    @property
    def instruments(self) -> tuple[str, ...]:
        return tuple(k for k in INSTRUMENTS if k in self.geometries)

    def segment(self, label: str) -> Segment:
        for s in self.segments:
            if s.label == label:
                return s
        raise KeyError(f"no segment labelled {label!r}; labels: {[s.label for s in self.segments]}")

    def subset(self, labels: list[str]) -> "Session":
        """A session with only the named segments (same order as given)."""
        return Session([self.segment(x) for x in labels], dict(self.geometries), self.sample_rate,
                       self.latitude, self.gravity, self.raw_unit, dict(self.meta))
