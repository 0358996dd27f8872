"""Noise identification of a static recording: every sensor's Allan deviation and terms, and the parity check."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import IdentifiabilityError, SessionFormatError
from .allan import allan_deviation
from .fit import fit_instrument
from .model import TERMS, NoiseModel
from .parity import parity_allan

__all__ = ["identify", "identify_session", "static_segment"]

#: segment kinds a noise recording may have (the input must be constant)
STATIC_KINDS = ("static", "static_unknown")


def identify(outputs: dict[str, np.ndarray], sample_rate: float, axes_mb: dict[str, np.ndarray] | None = None,
             names: dict[str, list[str]] | None = None, terms: tuple[str, ...] = TERMS, p_fa: float = 1e-3,
             per_decade: int = 8, meta: dict[str, Any] | None = None) -> NoiseModel:
    """Noise model of a static recording given as compensated outputs per instrument.

    Parameters
    ----------
    outputs : dict[str, ndarray (N, n)]
        ``SF y - b`` per instrument (``"gyro"``: rad/s, ``"accel"``: m/s^2) of a static recording.
    sample_rate : float
        Hz.
    axes_mb : dict[str, ndarray (n, 3)], optional
        Calibrated sensing axes per instrument: with 4+ sensors, the parity-space check is added.
    names : dict[str, list of str], optional
    terms : tuple of str
        Terms to fit (default all four of :data:`rimu.noise.model.TERMS`).
    p_fa : float
        False-verdict probability of each parity check.

    Examples
    --------
    >>> from rimu.geometry import cone6
    >>> rng = np.random.default_rng(0)
    >>> z = 0.01 * rng.standard_normal((20000, 6))            # white: N = 0.01 / sqrt(100) per sqrt(s)
    >>> model = identify({"gyro": z}, 100.0, {"gyro": cone6().H}, terms=("white",))
    >>> np.round(model["gyro"].terms["white"] / 1e-3, 1).tolist()
    [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
    >>> model.parity["gyro"]["white"]
    True
    """
    insts = {}
    parity = {}
    for k, z in outputs.items():
        z = np.asarray(z, dtype=float)
        nm = (names or {}).get(k) or [f"{k}{i}" for i in range(z.shape[1])]
        ad = allan_deviation(z, sample_rate, nm, per_decade=per_decade)
        insts[k] = fit_instrument(ad, k, terms)
        A = (axes_mb or {}).get(k)
        if A is not None and np.asarray(A).shape[0] >= 4:
            white = np.asarray(insts[k].terms["white"], dtype=float)
            bad = [n for n, w in zip(nm, white) if not (np.isfinite(w) and w > 0)]
            if bad:
                raise IdentifiabilityError(
                    f"no white noise could be identified for {len(bad)} of {len(nm)} {k} sensors ({', '.join(bad[:4])}"
                    f"{', ...' if len(bad) > 4 else ''}): their Allan deviation has no -1/2 slope, as on a moving "
                    "recording; noise identification needs the unit still: give a static recording")
            pw = parity_allan(z, A, sample_rate, insts[k], instrument=k, p_fa=p_fa, per_decade=per_decade)
            parity[k] = pw.to_dict()
    return NoiseModel(insts, parity, meta=dict(meta or {}))


def static_segment(session: Any, label: str | None = None) -> Any:
    """The segment to analyse: ``label``, or the longest static one."""
    if label is not None:
        try:
            return session.segment(label)
        except KeyError as exc:
            raise SessionFormatError(str(exc).strip('"')) from None
    cands = [s for s in session.segments if s.kind in STATIC_KINDS]
    if not cands:
        raise SessionFormatError(f"the session has no static segment (kinds {STATIC_KINDS}); the noise analysis "
                                 "needs a recording at rest. Name a segment with --segment if one is at rest")
    return max(cands, key=lambda s: s.n_samples)


def _declared_factor(session: Any, instrument: str) -> float | None:
    """Factor to SI of the unit the session declares for an instrument's outputs (None for counts)."""
    from ..units import raw_to_si, raw_unit_for

    per = session.meta.get("raw_units") if isinstance(getattr(session, "meta", None), dict) else None
    unit = per[instrument] if isinstance(per, dict) and instrument in per else raw_unit_for(session.raw_unit, instrument)
    return raw_to_si(instrument, unit)


def identify_session(session: Any, calibration: Any = None, segment: str | None = None,
                     instruments: list[str] | None = None, terms: tuple[str, ...] = TERMS, p_fa: float = 1e-3,
                     per_decade: int = 8) -> NoiseModel:
    """:func:`identify` on one static segment of a :class:`rimu.session.Session`.

    Raw outputs are compensated with the calibration (``SF y - b``); without one they must be declared in a
    physical unit (``session.raw_unit`` ``"SI"``, ``"deg/s"``, ``"g"``, ...: converted to SI), otherwise (counts)
    an :class:`~rimu.errors.IdentifiabilityError` asks for the calibration.
    The parity check uses the calibrated axes (nominal axes without a calibration).
    """
    seg = static_segment(session, segment)
    insts = instruments or [k for k in session.instruments]
    outputs, axes, names = {}, {}, {}
    for k in insts:
        if k not in session.geometries:
            raise SessionFormatError(f"the session has no {k!r}; it has {list(session.instruments)}")
        g = session.geometries[k]
        y = seg.raw[k]
        if calibration is not None and k in calibration:
            unit = _declared_factor(session, k)
            if unit is not None and str(getattr(calibration, "raw_unit", "count")).lower() in ("count", "counts"):
                raise IdentifiabilityError(
                    f"the {k} outputs of this recording are already in a physical unit (declared by the file or "
                    "applied by its reader's nominal scale factors), and the calibration is one of raw counts: it "
                    "would scale them twice. Drop --calibration to use the recording's own unit, or give the "
                    "recording in counts", [f"{k}.scale"])
            c = calibration[k]
            calibration.check_geometry(k, g)
            outputs[k] = c.compensate(y)
            axes[k] = c.axes_mb()
        elif _declared_factor(session, k) is not None:  # outputs declared in a physical unit: to SI
            outputs[k] = np.asarray(y, dtype=float) * _declared_factor(session, k)
            axes[k] = g.H
        else:
            raise IdentifiabilityError(
                f"the {k} outputs are in {session.raw_unit!r}: the noise terms in SI need the scale factors; give "
                "a calibration file (rimu noise ... --calibration cal.json)", [f"{k}.scale"])
        names[k] = list(g.names)
    meta = {"segment": seg.label, "duration_s": float(seg.n_samples / session.sample_rate),
            "calibrated": calibration is not None}
    return identify(outputs, session.sample_rate, axes, names, terms, p_fa, per_decade, meta)
