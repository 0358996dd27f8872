"""Test procedures: sequences of static attitudes and constant-rate rotations on a turntable.

A procedure is a list of :class:`SegmentSpec`. Attitudes are ``mat_ln_mb`` (MB -> local level East-North-Up).
The reference attitude of a turntable here is the one of Cho & Park 2005, Section IV: tilt axis along North,
table axis vertical; MB x along the tilt axis (North), MB z along the table axis. Their Table 1 lists the
specific force at rest as ``(0, 0, -g)`` in that position, so MB z points down: the reference is
x = North, y = East, z = Down.

Where a paper leaves the table's heading open, the attitude is the smallest rotation of the reference that
puts the required MB direction up (static) or the rotation axis where the paper needs it; each builder says
which.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..session import SEGMENT_KINDS, rotation_matrix
from ..units import DEG_TO_RAD, G0

__all__ = [
    "SegmentSpec",
    "REFERENCE_ATTITUDE",
    "attitude_with_up",
    "attitude_with_axis",
    "static",
    "rotation",
    "cho_park_table1",
    "cho_park_table2",
    "cho_park_procedure",
    "oliveira_table1",
    "zhang_scheme",
    "PROCEDURES",
]

#: MB (x North, y East, z Down) -> ENU
REFERENCE_ATTITUDE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_UP = np.array([0.0, 0.0, 1.0])
_NORTH = np.array([0.0, 1.0, 0.0])


@dataclass
class SegmentSpec:
    """One step of a procedure.

    Attributes
    ----------
    label : str
    duration : float
        s.
    mat_ln_mb : ndarray (3, 3)
        Commanded attitude at the start of the step (MB -> ENU).
    rate_mb : ndarray (3,)
        Commanded table rate in MB, rad/s (zero when static).
    report : str
        What the session will say it knows: a segment kind of :data:`rimu.session.SEGMENT_KINDS`.
    report_attitude : bool
        Whether the attitude is given to the session (False for Zhang's attitude-free scheme).
    meta : dict
    """

    label: str
    duration: float
    mat_ln_mb: np.ndarray
    rate_mb: np.ndarray = field(default_factory=lambda: np.zeros(3))
    report: str = "static"
    report_attitude: bool = True
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.report not in SEGMENT_KINDS:
            raise ValueError(f"report must be one of {SEGMENT_KINDS}, got {self.report!r}")
        if not self.duration > 0:
            raise ValueError(f"segment {self.label!r}: duration must be positive, got {self.duration}")
        self.mat_ln_mb = np.asarray(self.mat_ln_mb, dtype=float).reshape(3, 3)
        self.rate_mb = np.asarray(self.rate_mb, dtype=float).reshape(3)

    @property
    def is_static(self) -> bool:
        return not np.any(self.rate_mb)

    def specific_force_mb(self, gravity: float = G0) -> np.ndarray:
        """Specific force in MB at the start of the step (m/s^2)."""
        return self.mat_ln_mb.T @ np.array([0.0, 0.0, gravity])


def _min_rotation(a: np.ndarray, b: np.ndarray, fallback_axis: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector a to unit vector b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    c = float(a @ b)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return rotation_matrix(np.pi * fallback_axis / np.linalg.norm(fallback_axis))
    axis = np.cross(a, b)
    axis /= np.linalg.norm(axis)
    return rotation_matrix(axis * math.acos(max(-1.0, min(1.0, c))))


def attitude_with_up(up_mb: Sequence[float], reference: np.ndarray = REFERENCE_ATTITUDE) -> np.ndarray:
    """Attitude (MB -> ENU) with MB direction ``up_mb`` pointing up, closest to ``reference``.

    >>> C = attitude_with_up([0, 0, -1])
    >>> np.allclose(C, REFERENCE_ATTITUDE)
    True
    """
    v = reference @ np.asarray(up_mb, dtype=float)
    return _min_rotation(v, _UP, _NORTH) @ reference


def attitude_with_axis(axis_mb: Sequence[float], direction_ln: Sequence[float],
                       reference: np.ndarray = REFERENCE_ATTITUDE, up_mb: Sequence[float] | None = None) -> np.ndarray:
    """Attitude with the MB direction ``axis_mb`` along ``direction_ln`` (ENU).

    With ``up_mb`` given (orthogonal to ``axis_mb``), that MB direction is also put as close to up as the first
    condition allows; otherwise the smallest rotation of ``reference`` is used.
    """
    axis_mb = np.asarray(axis_mb, dtype=float) / np.linalg.norm(axis_mb)
    d = np.asarray(direction_ln, dtype=float) / np.linalg.norm(direction_ln)
    C = _min_rotation(reference @ axis_mb, d, _UP if abs(d @ _UP) < 0.9 else _NORTH) @ reference
    if up_mb is not None:
        u = C @ np.asarray(up_mb, dtype=float)
        u_perp = u - d * (u @ d)
        up_perp = _UP - d * (_UP @ d)
        if np.linalg.norm(u_perp) > 1e-9 and np.linalg.norm(up_perp) > 1e-9:
            u_perp /= np.linalg.norm(u_perp)
            up_perp /= np.linalg.norm(up_perp)
            ang = math.atan2(float(np.cross(u_perp, up_perp) @ d), float(u_perp @ up_perp))
            C = rotation_matrix(d * ang) @ C
    return C


def static(label: str, up_mb: Sequence[float], duration: float = 60.0, report: str = "static",
           reference: np.ndarray = REFERENCE_ATTITUDE) -> SegmentSpec:
    """A static position with MB direction ``up_mb`` (specific force direction) pointing up."""
    return SegmentSpec(label, duration, attitude_with_up(up_mb, reference), np.zeros(3), report,
                       report != "static_unknown")


def rotation(label: str, rate_mb: Sequence[float], duration: float = 60.0, axis_direction_ln: Sequence[float] = (0, 0, 1),
             report: str = "rate", mat_ln_mb: np.ndarray | None = None, up_mb: Sequence[float] | None = None) -> SegmentSpec:
    """A constant-rate rotation about the MB direction of ``rate_mb``.

    The line of the rotation axis is placed along ``axis_direction_ln`` (default vertical), with its
    canonical direction (first non-zero component positive) pointing there, so a +w / -w pair shares one
    attitude. Pass ``mat_ln_mb`` to set the attitude yourself.
    """
    w = np.asarray(rate_mb, dtype=float)
    if mat_ln_mb is None:
        line = w / np.linalg.norm(w)
        k = int(np.flatnonzero(np.abs(line) > 1e-12)[0])
        if line[k] < 0:
            line = -line
        mat_ln_mb = attitude_with_axis(line, axis_direction_ln, up_mb=up_mb)
    spec = SegmentSpec(label, duration, mat_ln_mb, w, report, report != "static_unknown")
    if report == "angle":
        spec.meta["angle_mb"] = (w * duration).tolist()
    return spec


# ---------------------------------------------------------------------- the papers' procedures
#: Cho & Park 2005, Table 1: specific force in MB at the ten static positions, in g.
CHO_PARK_TABLE1 = (
    (0, 0, -1), (0, -1, 0), (0, 0, 1), (0, 1, 0), (1, 0, 0), (-1, 0, 0),
    (-math.cos(math.pi / 4), math.sin(math.pi / 4), 0), (math.cos(math.pi / 4), math.sin(math.pi / 4), 0),
    (-math.cos(math.pi / 4), 0, math.sin(math.pi / 4)), (math.cos(math.pi / 4), 0, math.sin(math.pi / 4)),
)
_S30, _C30, _S45 = 0.5, math.sqrt(3) / 2, math.sqrt(0.5)
#: Cho & Park 2005, Table 2: table rate in MB for the 14 steps, in units of w_rt.
CHO_PARK_TABLE2 = (
    (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
    (-_S30, -_C30, 0), (_S30, _C30, 0), (-_S30, _C30, 0), (_S30, -_C30, 0),
    (_S45, -_S45, 0), (-_S45, _S45, 0), (_S45, _S45, 0), (-_S45, -_S45, 0),
)


def cho_park_table1(duration: float = 60.0, positions: Sequence[int] | None = None) -> list[SegmentSpec]:
    """Cho & Park 2005, Table 1: the multi-position test (10 static positions, or the chosen 1-based ones).

    Each position puts the listed specific force direction up, by the smallest rotation from the reference
    attitude (tilt axis North).
    """
    idx = range(1, 11) if positions is None else positions
    return [static(f"P{k}", CHO_PARK_TABLE1[k - 1], duration) for k in idx]


def cho_park_table2(rate: float = 30.0 * DEG_TO_RAD, duration: float = 60.0,
                    steps: Sequence[int] | None = None) -> list[SegmentSpec]:
    """Cho & Park 2005, Table 2: the rate test (14 steps of +/- w_rt about fixed MB directions, rad/s).

    The rotation axis of each step is vertical (the table axis), so gravity is constant in MB during the
    step and the Earth rate adds the same vertical component to a +w / -w pair (cancelled by Eq. 11).
    """
    idx = range(1, 15) if steps is None else steps
    return [rotation(f"R{k}", np.array(CHO_PARK_TABLE2[k - 1]) * rate, duration) for k in idx]


def cho_park_procedure(rate: float = 30.0 * DEG_TO_RAD, duration: float = 60.0) -> list[SegmentSpec]:
    """Table 1 followed by Table 2."""
    return cho_park_table1(duration) + cho_park_table2(rate, duration)


def oliveira_table1(rate: float = 10.0 * DEG_TO_RAD, turns: int = 4) -> list[SegmentSpec]:
    """de Oliveira et al. 2012, Table 1: 16 rate sequences for the tetrad (MB X vertical, up).

    Sequences 1-4 turn the inner axis about X (vertical), with the outer axis at 0 deg (X up) for 1-2 and at
    180 deg (X down) for 3-4, so the vertical Earth rate changes sign between the pairs. Sequences 5-16 turn
    the outer axis, horizontal and pointing North; the inner-axis angle sets which body direction lies along
    it (Y, Z and the +/-30 deg combinations of the table), and the pairs 7-8 and 11-12 point that body
    direction South instead of North. Each step lasts a whole number of turns, so the Earth-rate modulation
    integrates to zero (their Eq. 20).
    """
    w = rate
    C, S = math.cos(math.radians(30)), math.sin(math.radians(30))
    duration = turns * 2 * math.pi / rate
    x_up = np.array([1.0, 0, 0])
    rows = [
        ((1, 0, 0), "up"), ((-1, 0, 0), "up"), ((1, 0, 0), "down"), ((-1, 0, 0), "down"),
        ((0, 1, 0), "N"), ((0, -1, 0), "N"), ((0, 1, 0), "S"), ((0, -1, 0), "S"),
        ((0, 0, 1), "N"), ((0, 0, -1), "N"), ((0, 0, 1), "S"), ((0, 0, -1), "S"),
        ((0, C, S), "N"), ((0, -C, -S), "N"), ((0, C, -S), "N"), ((0, -C, S), "N"),
    ]
    out = []
    for k, (r, where) in enumerate(rows, start=1):
        rate_mb = np.array(r, dtype=float) * w
        line = np.array(r, dtype=float)
        nz = int(np.flatnonzero(np.abs(line) > 1e-12)[0])
        if line[nz] < 0:
            line = -line
        if where in ("up", "down"):
            att = attitude_with_up(x_up if where == "up" else -x_up)
        else:
            d = (0, 1, 0) if where == "N" else (0, -1, 0)
            att = attitude_with_axis(line, d, up_mb=x_up)
        spec = SegmentSpec(f"S{k}", duration, att, rate_mb, "rate", True, {"sequence": k})
        out.append(spec)
    return out


def zhang_scheme(static_duration: float = 100.0, rate: float = 10.0 * DEG_TO_RAD,
                 rotation_duration: float = 180.0) -> list[SegmentSpec]:
    """Zhang et al. 2010, Section 3.2: nine static attitudes and six CW/CCW rotation pairs.

    Static: each triad axis up and down (6), and gravity in each axis plane at 45 deg (3); reported with
    unknown attitude. Rotations: about x, y, z and the three 45-deg in-plane axes, +w then -w, each rotation
    axis horizontal (North) so that the accelerometers see the axis (their Eq. 42-47 need it not vertical);
    reported by their total angle (the table's angle display, Eq. 16-18).
    """
    r = math.sqrt(0.5)
    ups = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (r, r, 0), (r, 0, r), (0, r, r)]
    out = [static(f"A{k}", u, static_duration, report="static_unknown") for k, u in enumerate(ups, start=1)]
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (r, r, 0), (r, 0, r), (0, r, r)]
    for k, a in enumerate(axes, start=1):
        a = np.array(a)
        for sgn, tag in ((1, "cw"), (-1, "ccw")):
            spec = rotation(f"W{k}{tag}", sgn * rate * a, rotation_duration, axis_direction_ln=(0, 1, 0), report="angle")
            spec.meta["pair"] = k
            out.append(spec)
    return out


PROCEDURES = {
    "cho_park": cho_park_procedure,
    "cho_park_table1": cho_park_table1,
    "cho_park_table2": cho_park_table2,
    "oliveira_table1": oliveira_table1,
    "zhang": zhang_scheme,
}
