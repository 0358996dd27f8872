"""The runtime error where users see it: a session with known inputs replayed through the pipeline.

For every segment whose input is known (static positions with attitude, rate-table steps), the error of the
segment-mean master-body estimate against the segment-mean known input is what a calibration leaves at
runtime: systematic errors (an effect the calibration lacks) survive the averaging, white noise falls as
1/sqrt(N). ``segment_error_rms`` is the rms of those errors over segments and axes; ``sample_error_rms`` the
rms over every sample and axis (noise included). Replaying a *held-out* session (not the one calibrated on)
is how a calibration is validated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.result import Calibration
from ..epoch import EpochBlock
from ..session import Session
from ..units import MS2_TO_UG, RS_TO_DH
from .pipeline import Pipeline

__all__ = ["InstrumentErrors", "known_inputs", "plot_segment_errors", "replay_errors", "segment_errors",
           "session_block"]


def session_block(session: Session) -> tuple[EpochBlock, np.ndarray]:
    """The samples of every segment back to back, and the segment index of each sample."""
    segs = session.segments
    temps = [s.temperature for s in segs]
    block = EpochBlock(np.concatenate([s.t for s in segs]),
                       {k: np.vstack([s.raw[k] for s in segs]) for k in session.instruments},
                       temperature=None if any(x is None for x in temps) else np.concatenate(temps))
    index = np.concatenate([np.full(s.n_samples, i) for i, s in enumerate(segs)])
    return block, index


def known_inputs(session: Session, instrument: str) -> list[np.ndarray | None]:
    """Per segment, the known input of ``instrument`` in MB (N, 3), SI, or None where it is not known.

    Gyros: table rate plus Earth rate (where attitude and latitude are known) for ``rate`` and ``static``
    segments. Accelerometers: the specific force (where the attitude or the force is known).
    """
    out: list[np.ndarray | None] = []
    for seg in session.segments:
        if instrument == "gyro":
            out.append(seg.angular_rate(session.latitude) if seg.kind in ("rate", "static") else None)
        else:
            f = seg.specific_force(session.gravity)
            out.append(None if f is None else np.asarray(f, dtype=float))
    return out


@dataclass
class InstrumentErrors:
    """Runtime errors of one instrument over a replayed session (SI: rad/s, m/s^2)."""

    instrument: str
    segment_error_rms: float
    sample_error_rms: float
    segments: list[str]
    segment_errors: np.ndarray = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        unit = "rad/s" if self.instrument == "gyro" else "m/s^2"
        return {"segment_error_rms": self.segment_error_rms, "sample_error_rms": self.sample_error_rms,
                "unit": unit, "segments_compared": len(self.segments)}


def segment_errors(session: Session, instrument: str, x: np.ndarray, index: np.ndarray) -> InstrumentErrors:
    """Errors of the estimates ``x`` (N, 3) of ``instrument`` against the session's known inputs.

    Raises
    ------
    ValueError
        No segment of the session has a known input for this instrument.
    """
    known = known_inputs(session, instrument)
    errs, labels, sq, count = [], [], 0.0, 0
    for i, (seg, u) in enumerate(zip(session.segments, known)):
        if u is None:
            continue
        xs = x[index == i]
        errs.append(xs.mean(axis=0) - u.mean(axis=0))
        labels.append(seg.label)
        d = xs - u
        sq += float(np.sum(d * d))
        count += d.size
    if not errs:
        raise ValueError(f"no segment of the session has a known {instrument} input (static with attitude, or rate)")
    E = np.array(errs)
    return InstrumentErrors(instrument, float(np.sqrt(np.mean(E * E))), float(np.sqrt(sq / count)), labels, E)


def replay_errors(session: Session, calibration: Calibration, **pipeline_kwargs: Any) -> dict[str, InstrumentErrors]:
    """Replay ``session`` through a :class:`Pipeline` of ``calibration`` and measure its runtime errors.

    Examples
    --------
    >>> from rimu.sim import Simulator, cho_park_procedure
    >>> run = Simulator(seed=1, sample_rate=20.0).run(cho_park_procedure(duration=2.0))
    >>> err = replay_errors(run.session, run.truth)
    >>> err["gyro"].segment_error_rms < 1e-3
    True
    """
    block, index = session_block(session)
    pipe = Pipeline(calibration, temperature=block.temperature is not None, **pipeline_kwargs)
    out = pipe.process(block)
    return {k: segment_errors(session, k, np.asarray(out[k].x), index) for k in out if k in session.instruments}


def plot_segment_errors(errors: dict[str, InstrumentErrors], path: str | Path, title: str = "") -> Path | None:
    """Bar plot of the segment-mean error (norm over the three axes, in the field's unit) per segment for each
    labelled result, e.g. ``{"base model": before, "+ g_sensitivity": after}``; None without matplotlib (the
    ``plots`` extra)."""
    from ..plotting import pyplot

    plt = pyplot(optional=True)
    if plt is None:
        return None
    first = next(iter(errors.values()))
    unit, f = ("deg/h", RS_TO_DH) if first.instrument == "gyro" else ("ug", MS2_TO_UG)
    n = len(first.segments)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.22 * n + 2), 3.8))
    width = 0.8 / len(errors)
    for k, (label, e) in enumerate(errors.items()):
        v = np.linalg.norm(e.segment_errors, axis=1) * f
        ax.bar(np.arange(n) + (k - (len(errors) - 1) / 2) * width, v, width,
               label=f"{label}: rms {e.segment_error_rms * f:.3g} {unit}")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(n))
    ax.set_xticklabels(first.segments, rotation=90, fontsize=6)
    ax.set_ylabel(f"|segment-mean error| [{unit}]")
    ax.set_title(title or f"{first.instrument} runtime error per segment")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
