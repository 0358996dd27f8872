"""The terms an in-flight self-calibration tracked over a run, as the estimates files, summaries and reports show them.

A :class:`rimu.fdi.selfcal.SelfCalLoop` built with ``history=True`` keeps the tracked terms after every window;
:class:`SelfCalRecord` turns them into what the outputs of a run need: per sample, the terms of the last window
that ended before it (the estimates file's columns, :meth:`SelfCalRecord.columns`), a decimated series for the
plots, and the last terms. :class:`rimu.fdi.Runtime` holds one per tracked instrument with
``selfcal_history=True`` (:attr:`rimu.fdi.Runtime.selfcal_records`, :meth:`rimu.fdi.Runtime.selfcal_columns`):
``rimu replay --selfcal`` and ``rimu monitor --selfcal`` both read them there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SelfCalRecord"]


class SelfCalRecord:
    """One instrument's tracked terms over a run (see the module docstring).

    Parameters
    ----------
    loop : SelfCalLoop
        The instrument's loop, built with ``history=True`` (its entries are taken, :meth:`SelfCalLoop.take_history`,
        so the loop's memory does not grow with the run).
    max_points : int
        The most points :attr:`series` keeps (every d-th window, d doubling as the run grows).

    Examples
    --------
    >>> from rimu.calibration import InstrumentCalibration
    >>> from rimu.fdi.selfcal import SelfCalLoop, SelfCalSettings, SelfCalTracker
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> loop = SelfCalLoop(SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-6, window_s=1.0)), 10.0, history=True)
    >>> rec = SelfCalRecord(loop)
    >>> rec.columns()[:2]
    ['gyro_bias_x1', 'gyro_bias_x1_sigma']
    >>> cols = rec.add(np.array([0.0, 0.1]))          # no window ended yet: the initial terms
    >>> cols["gyro_bias_x1"].tolist()
    [0.0, 0.0]
    """

    def __init__(self, loop: Any, max_points: int = 20000) -> None:
        if not loop.keep_history:
            raise ValueError("the loop keeps no history: build it with SelfCalLoop(..., history=True)")
        self.loop = loop
        trk = loop.tracker
        terms = loop.terms()
        #: the terms now: (time of the window's end (s), values (m, n), 1-sigma (m, n)), SI
        self.last: tuple[float, np.ndarray, np.ndarray] = (
            float("-inf"), np.stack([terms[b][0] for b in trk.blocks]), np.stack([terms[b][1] for b in trk.blocks]))
        #: the terms after every d-th window, as ``last``
        self.series: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.max_points = int(max_points)
        self._stride = 1
        self._seen = 0

    def columns(self) -> list[str]:
        """The estimates file's columns of the tracked terms: ``{k}_{term}_{sensor}`` and ``..._sigma`` (SI)."""
        trk = self.loop.tracker
        k = trk.calibration.instrument
        return [c for b in trk.blocks for nm in trk.calibration.geometry.names
                for c in (f"{k}_{b}_{nm}", f"{k}_{b}_{nm}_sigma")]

    def add(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """The columns of :meth:`columns` at the sample times ``t`` (s) of the epochs stepped since the last call:
        a sample takes the terms of the last window that ended before it (a window's terms apply after it)."""
        trk = self.loop.tracker
        hist = [(h[0], h[1], h[2]) for h in self.loop.take_history()]
        T = np.array([self.last[0]] + [h[0] for h in hist])
        V = np.stack([self.last[1]] + [h[1] for h in hist])
        S = np.stack([self.last[2]] + [h[2] for h in hist])
        idx = np.clip(np.searchsorted(T, np.asarray(t, float), side="left") - 1, 0, len(T) - 1)
        k = trk.calibration.instrument
        out = {}
        for b, name in enumerate(trk.blocks):
            for i, nm in enumerate(trk.calibration.geometry.names):
                out[f"{k}_{name}_{nm}"] = V[idx, b, i]
                out[f"{k}_{name}_{nm}_sigma"] = S[idx, b, i]
        for h in hist:
            if self._seen % self._stride == 0:
                self.series.append(h)
            self._seen += 1
            if len(self.series) > self.max_points:  # every other one, twice the stride
                self.series = self.series[::2]
                self._stride *= 2
        if hist:
            self.last = hist[-1]
        return out
