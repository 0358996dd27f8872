"""Plausibility checks at the boundary: data that parse but cannot be what their file declares.

The readers of rimu's session format (:func:`rimu.session.load_session`) run :func:`check_session` on every
session they load. Each check compares the data with physics the file itself states:

``units``
    Accelerometer outputs declared in a physical unit (``raw_unit`` ``"g"``, ``"m/s^2"``, ``"mg"``) must give a
    specific-force magnitude of one gravity (the sidecar's ``gravity_m_s2``) in the segments at rest; gyro
    outputs declared as ``"rad/s"``, ``"deg/s"`` or ``"deg/h"`` must give the commanded table rate of the
    ``rate`` segments (and the commanded total angle of ``angle`` segments). The vector is the least-squares
    solution ``x = H^+ y`` of the sensors' mean outputs, so any redundant geometry works. A magnitude off by the
    ratio of two units (9.81 for m/s^2 under ``g``, 57.3 for deg/s under ``rad/s``) names the likely unit. Raw
    outputs in counts (the default) have no physical unit to check: the check says so and passes.
``sample_rate``
    ``sample_rate_hz`` against the median step of the time column within segments; a factor of 1000 names
    milliseconds.
``constant``
    A sensor column that never changes: an error when the known input along its axis changes between segments
    (a dead sensor, an unconnected channel, a placeholder column), else a warning (noise-free synthetic data can
    be constant).

Findings have a level: ``"error"`` (the data cannot be right as declared unless the declaration is wrong; the
readers refuse them with :class:`rimu.errors.PlausibilityError` unless told ``checks="warn"``, CLI
``--accept-implausible``) or ``"warning"`` (probably wrong, logged). Monotonic time and finite values are checked
by the readers themselves and are never overridable.

>>> from rimu.sim import Simulator, cho_park_table1
>>> run = Simulator(seed=1).run(cho_park_table1(duration=2.0))
>>> s = run.session
>>> [f.check for f in check_session(s)]     # raw outputs in counts: nothing to compare
[]
>>> for seg in s.segments:                   # accelerometer outputs in m/s^2 (the true calibration applied) ...
...     seg.raw["accel"] = run.truth["accel"].compensate(seg.raw["accel"])
>>> s.raw_unit = {"accel": "g"}              # ... declared in g
>>> print(check_session(s)[0].message)  # doctest: +ELLIPSIS
accel: columns accel_* are declared in 'g' but the specific force at rest has magnitude 9.8 g ... look like m/s^2...
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import PlausibilityError
from ..units import DEG_TO_RAD, RAW_UNITS, raw_unit_for
from .model import Session

__all__ = ["UNITS", "Finding", "check_session", "enforce", "raw_unit_of", "CHECK_MODES"]

log = logging.getLogger("rimu.session.checks")

#: physical raw units rimu can check, per instrument: name -> factor to SI
UNITS: dict[str, dict[str, float]] = RAW_UNITS
#: the canonical name of each unit (for messages)
_CANON = {"m/s2": "m/s^2"}
#: the magnitude ratio (measured / expected) accepted without a word, and the one refused as an error
_OK = (0.8, 1.25)
_ERROR = (0.5, 2.0)
#: sample rate: relative disagreement that warns, and that refuses
_RATE_WARN, _RATE_ERROR = 0.01, 0.05
#: the modes of :func:`enforce`
CHECK_MODES = ("strict", "warn", "off")


@dataclass(frozen=True)
class Finding:
    """One failed plausibility check: which check, ``"error"`` or ``"warning"``, the message (what, where, the
    likely cause, what to do) and the column or key concerned."""

    check: str
    level: str
    message: str
    where: str = ""


def raw_unit_of(session: Session, instrument: str) -> str:
    """The declared unit of an instrument's raw outputs: ``raw_unit`` may be one string for every instrument or a
    mapping per instrument (``{"gyro": "deg/s", "accel": "g"}``); ``meta["raw_units"]`` likewise."""
    per = session.meta.get("raw_units") if isinstance(session.meta, dict) else None
    if isinstance(per, dict) and instrument in per:
        return str(per[instrument])
    return raw_unit_for(session.raw_unit, instrument)


def _unit_factor(instrument: str, unit: str) -> float | None:
    return UNITS.get(instrument, {}).get(unit.strip().replace(" ", ""))


def _likely_unit(instrument: str, declared_factor: float, ratio: float) -> str | None:
    """The physical unit under which the measured magnitude would be right (ratio within the accepted band)."""
    best, err = None, math.inf
    for name, fac in UNITS[instrument].items():
        r = ratio * fac / declared_factor
        e = abs(math.log(r)) if r > 0 else math.inf
        if e < err and _OK[0] <= r <= _OK[1]:
            best, err = _CANON.get(name, name), e
    return best


def _magnitudes(session: Session, instrument: str) -> tuple[list[float], list[float], list[str]]:
    """(measured magnitude in raw units, expected magnitude in SI, segment labels) of the segments whose input
    magnitude is known: gravity at rest for accelerometers; table rate or total angle for gyros."""
    g = session.geometries[instrument]
    Hp = np.linalg.pinv(g.H)
    # at rest, each sub-unit that resolves a 3-vector on its own (a triad) gives gravity's magnitude whatever its
    # attitude: the median over them is right for triads whose declared axes are off (a unit set up with parallel
    # triads that are mounted tens of degrees apart read 6.7 m/s^2 through the unit's H^+, and was warned about)
    subs = [list(su.members) for su in g.subunits] if len(g.subunits) > 1 else []
    own = [(m, np.linalg.pinv(g.H[m])) for m in subs if np.linalg.matrix_rank(g.H[m]) == 3]
    meas, exp, labels = [], [], []
    for s in session.segments:
        y = s.raw[instrument]
        if instrument == "accel":
            if s.kind not in ("static", "static_unknown"):
                continue
            ym = y.mean(axis=0)
            meas.append(float(np.median([np.linalg.norm(P @ ym[m]) for m, P in own])) if own
                        else float(np.linalg.norm(Hp @ ym)))
            exp.append(float(session.gravity))
        elif s.kind == "rate":
            w = float(np.linalg.norm(s.table_rate()))
            if w < 1.0 * DEG_TO_RAD:  # slower rates drown in bias and Earth rate
                continue
            meas.append(float(np.linalg.norm(Hp @ y.mean(axis=0))))
            exp.append(w)
        elif s.kind == "angle" and s.angle_mb is not None and s.n_samples > 2:
            a = float(np.linalg.norm(np.asarray(s.angle_mb).reshape(-1, 3)[-1]))
            if a < 10 * DEG_TO_RAD:
                continue
            dt = np.diff(s.t)
            inc = Hp @ (0.5 * (y[1:] + y[:-1]) * dt[:, None]).sum(axis=0)
            meas.append(float(np.linalg.norm(inc)))
            exp.append(a)
        else:
            continue
        labels.append(s.label)
    return meas, exp, labels


def _check_units(session: Session, source: str) -> list[Finding]:
    out = []
    for k in session.instruments:
        unit = raw_unit_of(session, k)
        fac = _unit_factor(k, unit)
        if fac is None:  # counts, or a unit rimu does not know: nothing to compare with
            continue
        meas, exp, labels = _magnitudes(session, k)
        if not meas:
            continue
        ratios = np.array(meas) * fac / np.array(exp)
        r = float(np.median(ratios))
        if _OK[0] <= r <= _OK[1]:
            continue
        level = "error" if not _ERROR[0] <= r <= _ERROR[1] else "warning"
        likely = _likely_unit(k, fac, r)
        what = "gravity at rest" if k == "accel" else "the commanded table rate/angle"
        shown = float(np.median(meas))
        cols = f"columns {k}_*"
        if k == "accel":
            head = (f"{k}: {cols} are declared in {unit!r} but the specific force at rest has magnitude "
                    f"{shown:.3g} {unit} (expected 1 gravity = {np.median(exp) / fac:.3g} {unit}; median over "
                    f"{len(meas)} static segments)")
        else:
            head = (f"{k}: {cols} are declared in {unit!r} but measure {r:.3g} times {what} "
                    f"(median over {len(meas)} segments, e.g. {labels[0]!r})")
        cause = (f"; the values look like {likely}: set raw_unit to {likely!r} in the sidecar" if likely else
                 "; check the unit declared in raw_unit, or whether the columns are raw counts (raw_unit 'count')")
        out.append(Finding("units", level, head + cause, f"{k}_*"))
    return out


def _check_sample_rate(session: Session, source: str) -> list[Finding]:
    steps = [np.diff(s.t) for s in session.segments if s.n_samples >= 3]
    if not steps:
        return []
    dt = float(np.median(np.concatenate(steps)))
    if not dt > 0:
        return []
    fs_t = 1.0 / dt
    fs = float(session.sample_rate)
    rel = fs_t / fs - 1.0
    if abs(rel) <= _RATE_WARN:
        return []
    hint = ""
    ratio = fs_t / fs
    for f, name in ((1e-3, "milliseconds"), (1e-6, "microseconds"), (1e-9, "nanoseconds")):
        if ratio > 0 and abs(math.log(ratio / f)) < 0.05:
            hint = f"; the time column looks like {name}: write t in seconds"
    if not hint:
        hint = (f"; fix sample_rate_hz in the sidecar (the timestamps say {fs_t:.6g} Hz), or the time column if it "
                "is the one that is wrong")
    level = "error" if abs(rel) > _RATE_ERROR else "warning"
    return [Finding("sample_rate", level, f"sample_rate_hz is {fs:g} Hz but the time column steps by {dt:.6g} s "
                    f"(median within segments), that is {fs_t:.6g} Hz ({100 * rel:+.1f}%){hint}", "sample_rate_hz")]


def _excitation(session: Session, instrument: str, i: int) -> float:
    """Range over the segments of the known input along sensor i's nominal axis (m/s^2 or rad/s); 0 when no
    segment knows its input."""
    h = session.geometries[instrument].H[i]
    vals = []
    for s in session.segments:
        if instrument == "accel":
            f = s.specific_force(session.gravity) if s.kind in ("static", "rate") else None
            if f is not None:
                vals.append(float(np.mean(f @ h)))
        elif s.kind == "rate" or (s.kind == "static" and s.rate_mb is None):
            vals.append(float(s.table_rate() @ h))
    return float(np.ptp(vals)) if vals else 0.0


def _check_constant(session: Session, source: str) -> list[Finding]:
    out = []
    for k in session.instruments:
        y = np.vstack([s.raw[k] for s in session.segments])
        if y.shape[0] < 2:
            continue
        dead = np.flatnonzero(np.ptp(y, axis=0) == 0)
        for i in dead:
            name = session.geometries[k].names[i]
            # constant although the known input along its axis changes: the sensor does not respond. A constant
            # without such a change may be noise-free synthetic data: a warning
            limit = 0.1 * session.gravity if k == "accel" else 1.0 * DEG_TO_RAD
            level = "error" if _excitation(session, k, i) > limit else "warning"
            why = ("although the known input along its axis changes between segments: a dead sensor, an unconnected"
                   " channel or a placeholder column; remove the sensor from the geometry or fix the recording"
                   if level == "error" else "(noise-free data, or a dead sensor the inputs of this session do not "
                   "reveal)")
            out.append(Finding("constant", level, f"column {k}_{name} is constant ({y[0, i]:g} in all {y.shape[0]} "
                               f"samples) {why}", f"{k}_{name}"))
    return out


def check_session(session: Session, source: str = "") -> list[Finding]:
    """Every plausibility finding of a session (empty: nothing implausible). ``source`` prefixes the messages
    (the file name)."""
    found = _check_constant(session, source) + _check_units(session, source) + _check_sample_rate(session, source)
    if source:
        found = [Finding(f.check, f.level, f"{source}: {f.message}", f.where) for f in found]
    return found


def enforce(findings: list[Finding], mode: str = "strict") -> list[Finding]:
    """Act on findings: ``"strict"`` raises :class:`PlausibilityError` on the first error (warnings are logged),
    ``"warn"`` logs all of them, ``"off"`` ignores them. Returns the findings."""
    if mode not in CHECK_MODES:
        from ..errors import OptionError

        raise OptionError(f"checks must be one of {CHECK_MODES}, got {mode!r}")
    if mode == "off":
        return findings
    errors = [f for f in findings if f.level == "error"]
    if mode == "strict" and errors:
        extra = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise PlausibilityError(f"{errors[0].message}{extra}. If the data are right as declared, read them with "
                                "checks='warn' (command line: --accept-implausible)", findings)
    for f in findings:
        log.warning(f.message)
    return findings
