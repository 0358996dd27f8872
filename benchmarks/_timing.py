"""Timing shared by the benchmark scripts (not a benchmark itself: ``dev.py bench`` skips ``_`` files).

Every benchmark pins its BLAS and OpenMP threads to one itself (``os.environ`` before numpy is imported), so that
a run outside ``dev.py`` measures the same thing."""

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


def interleaved_times(fns: dict[str, Callable[[], float | None]], repeats: int,
                      clock: Callable[[], float] = time.perf_counter) -> dict[str, list[float]]:
    """Each of ``fns`` called once per round, ``repeats`` rounds, in turn (so that a change of the machine's load
    hits every candidate alike; the order turns by one each round); returns every call's time in s by name. A function that returns a number reports
    its own time (a C kernel timing itself inside C, with the same ``clock``); otherwise its time is measured here
    with ``clock`` (wall time by default; ``time.thread_time``, the CPU time of this thread, leaves out the time
    slices the shared cores give to other processes). Take medians of the times, and medians of per-round ratios
    for a ratio."""
    out: dict[str, list[float]] = {k: [] for k in fns}
    order = list(fns)
    for rnd in range(repeats):
        # the order turns by one each round, so that no candidate always runs on the caches, the TLB and the pages
        # its predecessor left (a candidate that allocates large arrays slows the next one's first touch)
        for k in order[rnd % len(order):] + order[:rnd % len(order)]:
            fn = fns[k]
            t0 = clock()
            r = fn()
            dt = clock() - t0
            out[k].append(float(r) if isinstance(r, (int, float)) else dt)
    return out


def round_ratio(times: dict[str, list[float]], num: str, den: str) -> float:
    """Median over rounds of ``times[num][i] / times[den][i]`` (of :func:`interleaved_times`)."""
    return statistics.median(a / b for a, b in zip(times[num], times[den]))


def ratio_stats(times: dict[str, list[float]], num: str, den: str) -> dict[str, float]:
    """Median, min and max over rounds of ``times[num][i] / times[den][i]`` (of :func:`interleaved_times`)."""
    r = [a / b for a, b in zip(times[num], times[den])]
    return {"median": statistics.median(r), "min": min(r), "max": max(r)}


#: the environment every benchmark sets before numpy loads
PINNED = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def load() -> str:
    """The machine's load average (1, 5, 15 min) as text, for the record of a run on shared cores."""
    try:
        import os
        a, b, c = os.getloadavg()
        return f"load average {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"
    except (OSError, AttributeError):
        return "load average unknown"
