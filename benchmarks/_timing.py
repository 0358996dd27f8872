"""Timing shared by the benchmark scripts (not a benchmark itself: ``dev.py bench`` skips ``_`` files)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_time(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``repeats`` calls of ``fn``, s."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def interleaved_times(fns: dict[str, Callable[[], float | None]], repeats: int) -> dict[str, list[float]]:
    """Each of ``fns`` called once per round, ``repeats`` rounds, in turn (so that a change of the machine's load
    hits every candidate alike); returns every call's time in s by name. A function that returns a number reports
    its own time (a C kernel timing itself inside C); otherwise its wall time is measured here. Take medians of
    the times, and medians of per-round ratios for a ratio."""
    out: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            r = fn()
            dt = time.perf_counter() - t0
            out[k].append(float(r) if isinstance(r, (int, float)) else dt)
    return out


def round_ratio(times: dict[str, list[float]], num: str, den: str) -> float:
    """Median over rounds of ``times[num][i] / times[den][i]`` (of :func:`interleaved_times`)."""
    return statistics.median(a / b for a, b in zip(times[num], times[den]))
