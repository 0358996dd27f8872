"""A fault-management campaign: every fault type through the closed-loop manager on several geometries.

Where :mod:`rimu.experiments.campaign` measures the detectors against their theory one fault at a time, this campaign
asks what a flight computer sees: for each geometry (cone6, tetrad4, dodecahedron6 by default) and each
scenario (``single``, ``double``, ``intermittent``, ``dropout``, ``stuck``, ``ramp``) it replays seeded runs
sample by sample through :class:`rimu.fdi.RedundancyManager` and counts

* detection (an alarm, or for a dropout the invalid data, after the onset), correct / wrong / missed
  isolation and "flagged not isolable", the delay to the first isolation (to the first "not isolable" report
  where nothing was isolated), false alarm episodes
  and false isolations per hour before the onset, the share of post-onset samples flagged DEGRADED or worse,
  re-admission at the end (intermittent faults and dropouts), the number of isolations (ping-pong);
* **biased while nominal**: samples whose output says NOMINAL while the fault moves the estimate by more than
  3 sigma of its covariance *and* the fault's parity signal is one the detection test misses with probability
  below 1e-6 (noncentrality above ``lambda_md``). Smaller faults (a parity signal below that, e.g. the first
  samples of a ramp or of a stuck value) are counted apart, with the largest bias they caused: the test sees
  them only with some probability per sample, which is what a protection level accounts for.

Run it with ``python examples/fault_management_campaign.py`` (the table in ``docs/fdi.md``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq
from scipy.stats import chi2, ncx2

from ..fdi.manager import RedundancyManager
from ..fdi.settings import DEFAULTS as _D
from ..fusion import InstrumentPipeline
from ..fusion.validity import Validity
from .campaign import check_spec, run_tasks, split_isolations

__all__ = ["SCENARIOS", "ScenarioSpec", "run_scenarios", "scenario_table"]

SCENARIOS = ("single", "double", "intermittent", "dropout", "stuck", "ramp")


@dataclass
class ScenarioSpec:
    """Settings of the fault-management campaign (sizes in sigma of the sensor noise)."""

    geometries: list[str] = field(default_factory=lambda: ["cone6", "tetrad4", "dodecahedron6"])
    """Preset geometries, one gyro unit each."""
    scenarios: list[str] = field(default_factory=lambda: list(SCENARIOS))
    """Names from :data:`SCENARIOS`."""
    runs: int = 10
    """Seeded runs per (geometry, scenario)."""
    duration: float = 30.0
    """Length of a run, s."""
    onset: float = 10.0
    """Time of the fault's onset, s (inside the run)."""
    sample_rate: float = 100.0
    """Hz."""
    rate_dps: float = 30.0
    """Amplitude of the swinging manoeuvre rates, deg/s."""
    single_sigma: float = 10.0
    """Step of the ``single`` fault, sigma."""
    double_sigma: tuple[float, float] = (8.0, 20.0)
    """Range of the two steps of ``double``, sigma."""
    intermittent_sigma: float = 15.0
    """Step of each ``intermittent`` burst, sigma."""
    ramp_sigma_per_s: float = 0.5
    """Slope of ``ramp``, sigma/s."""
    p_fa: float = _D.p_fa
    """False-alarm probability per sample of the manager's detection test."""
    confirm: int = _D.confirm
    """Alarms in a row before the manager isolates."""
    readmit_after: int | None = _D.readmit_after
    """Clean samples before an isolated sensor is re-admitted."""
    base_seed: int = 14
    """Seed of the whole campaign (each run's seed derives from it)."""

    def __post_init__(self) -> None:
        check_spec("scenarios", self.scenarios, SCENARIOS, "onset", self.onset, self.duration)


def _lambda_md(dof: int, p_fa: float, p_md: float = 1e-6) -> float:
    """Noncentrality the chi-square test detects with probability 1 - p_md (per sample)."""
    thr = chi2.isf(p_fa, dof)
    return float(brentq(lambda lam: ncx2.sf(thr, dof, lam) - (1 - p_md), 1e-6, 1e4))


def _inject(kind: str, Y: np.ndarray, valid: np.ndarray, k0: int, rng: np.random.Generator, spec: ScenarioSpec,
            sig: np.ndarray, scale: np.ndarray) -> tuple[tuple[int, ...], list[tuple[int, int]]]:
    """Apply one scenario to raw data in place; (faulty sensors, fault windows in samples)."""
    N, n = Y.shape
    fs = spec.sample_rate
    raw = sig / scale  # one sigma in raw units
    if kind == "single":
        j = int(rng.integers(n))
        Y[k0:, j] += rng.choice([-1, 1]) * spec.single_sigma * raw[j]
        return (j,), [(k0, N)]
    if kind == "double":
        i, j = (int(x) for x in rng.choice(n, 2, replace=False))
        b = rng.uniform(*spec.double_sigma, 2) * rng.choice([-1, 1], 2)
        Y[k0:, i] += b[0] * raw[i]
        Y[k0:, j] += b[1] * raw[j]
        return (i, j), [(k0, N)]
    if kind == "intermittent":
        j = int(rng.integers(n))
        win = [(k0 + int(4 * fs) * b, k0 + int(4 * fs) * b + int(fs)) for b in range(3)]
        for a, z in win:
            Y[a:z, j] += spec.intermittent_sigma * raw[j]
        return (j,), win
    if kind == "dropout":
        ch = tuple(int(x) for x in rng.choice(n, min(4, n), replace=False))
        for j in ch:
            valid[k0:k0 + 20, j] = False
            Y[k0:k0 + 20, j] = 0.0
        return ch, [(k0, k0 + 20)]
    if kind == "stuck":
        j = int(rng.integers(n))
        Y[k0:, j] = Y[k0, j]
        return (j,), [(k0, N)]
    j = int(rng.integers(n))  # ramp
    Y[k0:, j] += spec.ramp_sigma_per_s * raw[j] * np.arange(N - k0) / fs
    return (j,), [(k0, N)]


def _one_run(spec: ScenarioSpec, geometry: str, kind: str, run: int, cal: Any, mgr: RedundancyManager
             ) -> dict[str, Any]:
    seed = int(np.random.SeedSequence([spec.base_seed, SCENARIOS.index(kind), run,
                                       sum(map(ord, geometry))]).generate_state(1)[0])
    rng = np.random.default_rng(seed)
    fs = spec.sample_rate
    N = round(spec.duration * fs)
    k0 = round(spec.onset * fs)
    n = cal.geometry.n
    sig = np.broadcast_to(cal.noise_sigma, (n,))
    # a manoeuvre: rates swinging about all three axes (stuck and scale faults need a changing input)
    t = np.arange(N)[:, None] / fs
    w = math.radians(spec.rate_dps)
    u = w * np.sin(2 * np.pi * t / np.array([7.0, 11.0, 13.0]) + rng.uniform(0, 2 * np.pi, 3))
    clean = cal.raw_output(u) + rng.standard_normal((N, n)) * (sig / cal.scale)
    Y = clean.copy()
    valid = np.ones((N, n), bool)
    faulty, _windows = _inject(kind, Y, valid, k0, rng, spec, sig, cal.scale)
    mgr.reset()
    res = mgr.run(Y, valid)
    tab = mgr.pipeline.table
    names = mgr.names
    # fault-induced error of NOMINAL samples (the full set): bias in sigma of P, parity noncentrality
    F = np.where(valid, cal.scale * (Y - clean), 0.0)
    nominal = res.validity == Validity.NOMINAL
    post = np.arange(N) >= k0
    idx = np.flatnonzero(nominal & post)
    bias = lam = np.zeros(0)
    if idx.size:
        b = F[idx] @ tab.G[0].T
        Pi = np.linalg.inv(tab.P[0])
        bias = np.sqrt(np.einsum("ij,jk,ik->i", b, Pi, b))
        pz = F[idx] @ tab.Vz[0][: int(tab.dof[0])].T
        lam = np.einsum("ij,ij->i", pz, pz)
    lam_md = _lambda_md(int(tab.dof[0]), spec.p_fa) if tab.dof[0] >= 1 else math.inf
    biased = int(np.sum((bias > 3.0) & (lam > lam_md)))
    undetectable = bias[(bias > 3.0) & (lam <= lam_md)]
    ev = res.events
    before, after = split_isolations(ev, k0, lambda e: e.sample)
    fset = {names[j] for j in faulty}
    alarms_before = int(np.count_nonzero(res.alarm[:k0] & ~np.concatenate([[False], res.alarm[:k0 - 1]])))
    if kind == "dropout":
        detected = bool(np.any(res.validity[k0:k0 + 20] != Validity.NOMINAL))
    else:
        detected = bool(np.any(res.alarm[k0:]))
    first = after[0].sample if after else None
    flagged_at = next((e.sample for e in ev if e.kind == "detected_not_isolable" and e.sample >= k0), None)
    end_iso = {names[j] for j in np.flatnonzero(mgr.isolated)}
    wrong = any(e.sensor not in fset for e in after)
    if kind in ("intermittent", "dropout"):
        correct = (not wrong) and not end_iso and (kind == "dropout" or bool(after))
        flagged = kind == "intermittent" and not after and flagged_at is not None
        missed = kind == "intermittent" and not after and not flagged
    else:
        correct = end_iso == fset
        flagged = (not correct) and mgr.health.fault_not_isolable
        missed = not correct and not flagged and not wrong
    delay = [(s - k0) / fs for s in ((first,) if first is not None else (flagged_at,)) if s is not None]
    return {
        "geometry": geometry, "scenario": kind, "run": run, "seed": seed, "faulty": sorted(fset),
        "detected": detected, "correct": bool(correct), "wrong": bool(wrong), "missed": bool(missed),
        "flagged": bool(flagged), "delay_s": min(delay) if delay else None,
        "false_alarm_episodes": alarms_before, "false_isolations": len(before), "pre_fault_s": k0 / fs,
        "degraded_share": float(np.mean(res.validity[k0:] != Validity.NOMINAL)),
        "readmitted_at_end": not end_iso, "isolations": len(after),
        "biased_while_nominal": biased, "undetectable_samples": int(undetectable.size),
        "undetectable_max_bias": float(undetectable.max()) if undetectable.size else 0.0,
        # a number wherever there is an estimate, NaN exactly where there is none (unobservable)
        "finite": bool(np.array_equal(np.isfinite(res.x).all(axis=1), res.validity != 2)
                       and not np.isinf(res.x).any()),
    }


_CACHE: dict[Any, Any] = {}


def _setup(spec: ScenarioSpec, geometry: str) -> tuple[Any, RedundancyManager]:
    """The truth calibration of ``geometry`` and its manager, made once per geometry (in each worker)."""
    from .campaign import simulated_truth  # the campaign module is the one fdi module allowed to use rimu.sim

    key = (geometry, spec.sample_rate, spec.base_seed, spec.p_fa, spec.confirm, spec.readmit_after)
    if key not in _CACHE:
        cal = simulated_truth(geometry, "gyro", spec.sample_rate, spec.base_seed)
        mgr = RedundancyManager(InstrumentPipeline(cal), p_fa=spec.p_fa, confirm=spec.confirm,
                                readmit_after=spec.readmit_after, sample_rate=spec.sample_rate)
        _CACHE.clear()
        _CACHE[key] = (cal, mgr)
    return _CACHE[key]


def _run_task(spec: ScenarioSpec, task: tuple[str, str, int]) -> dict[str, Any]:
    geometry, kind, run = task
    cal, mgr = _setup(spec, geometry)
    return _one_run(spec, geometry, kind, run, cal, mgr)


def run_scenarios(spec: ScenarioSpec, workers: int | None = 0,
                  progress: bool | Callable[[int, int], None] = False) -> list[dict[str, Any]]:
    """Every (geometry, scenario, run) of ``spec``, in order; one dict per run.

    ``workers`` and ``progress`` as in :func:`rimu.experiments.campaign.run_campaign` (the same loop): 0, the default,
    runs in this process; the rows do not depend on it (every run is seeded on its own).
    """
    tasks = [(g, kind, r) for g in spec.geometries for kind in spec.scenarios for r in range(spec.runs)]
    return run_tasks(_run_task, spec, tasks, workers, progress=progress)[0]


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One line per (geometry, scenario)."""
    out = []
    keys = []
    for r in rows:
        k = (r["geometry"], r["scenario"])
        if k not in keys:
            keys.append(k)
    for g, s in keys:
        rr = [r for r in rows if r["geometry"] == g and r["scenario"] == s]
        n = len(rr)
        d = [r["delay_s"] for r in rr if r["delay_s"] is not None]
        hours = sum(r["pre_fault_s"] for r in rr) / 3600.0
        und = [r["undetectable_max_bias"] for r in rr if r["undetectable_samples"]]
        out.append({
            "geometry": g, "scenario": s, "runs": n,
            "detected": sum(r["detected"] for r in rr) / n, "correct": sum(r["correct"] for r in rr) / n,
            "wrong": sum(r["wrong"] for r in rr) / n, "missed": sum(r["missed"] for r in rr) / n,
            "flagged": sum(r["flagged"] for r in rr) / n, "delay_s": float(np.mean(d)) if d else None,
            "false_alarms_per_h": sum(r["false_alarm_episodes"] for r in rr) / hours,
            "false_isolations": sum(r["false_isolations"] for r in rr),
            "degraded_share": float(np.mean([r["degraded_share"] for r in rr])),
            "readmitted_at_end": sum(r["readmitted_at_end"] for r in rr) / n,
            "max_isolations": max(r["isolations"] for r in rr),
            "biased_while_nominal": sum(r["biased_while_nominal"] for r in rr),
            "undetectable_runs": len(und), "undetectable_max_bias": max(und) if und else 0.0,
            "all_finite": all(r["finite"] for r in rr),
        })
    return out


def scenario_table(summary: list[dict[str, Any]], p_fa: float = 1e-3, sample_rate: float = 100.0) -> str:
    """The summary as a markdown table (the design false-alarm rate per hour in the header)."""
    head = ("| geometry | fault | runs | detected | correct | wrong | missed | flagged not isolable | delay s | "
            f"false alarms/h (design {p_fa * sample_rate * 3600:.0f}) | false isolations | degraded after onset | "
            "back in at end | max isolations | biased while nominal | below detection size: runs (max bias, sigma) |")
    lines = [head, "|" + "---|" * 16]
    for s in summary:
        dl = f"{s['delay_s']:.2f}" if s["delay_s"] is not None else "-"
        und = f"{s['undetectable_runs']} ({s['undetectable_max_bias']:.1f})" if s["undetectable_runs"] else "0"
        lines.append(f"| {s['geometry']} | {s['scenario']} | {s['runs']} | {100 * s['detected']:.0f} % | "
                     f"{100 * s['correct']:.0f} % | {100 * s['wrong']:.0f} % | {100 * s['missed']:.0f} % | "
                     f"{100 * s['flagged']:.0f} % | {dl} | {s['false_alarms_per_h']:.0f} | {s['false_isolations']} | "
                     f"{100 * s['degraded_share']:.0f} % | {100 * s['readmitted_at_end']:.0f} % | "
                     f"{s['max_isolations']} | {s['biased_while_nominal']} | {und} |")
    return "\n".join(lines)
