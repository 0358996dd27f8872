"""Fault-injection campaigns: fault type x sensor x size x seed, on any executor, with confidence intervals.

Every task simulates a short manoeuvre (:mod:`rimu.sim`), injects one fault (:mod:`rimu.experiments.faults`) and
replays it through the runtime pipeline twice:

* open loop (vectorised, :meth:`InstrumentPipeline.process` and the detector's ``block``): per-sample
  detection on fault-free samples (false alarms) and on fault samples (detection), and the sensor the test
  isolates at each detection. Windowed statistics are counted every ``window`` samples, so the counted
  trials are independent and binomial confidence intervals (Clopper-Pearson) are exact;
* closed loop (:class:`RedundancyManager`, sample by sample): the first isolation, its delay from the fault's
  onset, whether it named the right sensor, isolations before the fault (false isolations), the final state,
  and that no output is non-finite.

Seeds are deterministic per task (``SeedSequence([base_seed, fault, sensor, size, repetition])``), so a
campaign gives the same numbers on one process, on a ``concurrent.futures`` pool or on a dask.distributed
cluster (``scheduler="tcp://host:8786"``, through ``Client.get_executor()``: the same code path).

The theory column is the detection probability of the chi-square test for a step bias
(``ncx2.sf(threshold, dof, window * size^2 |v_wj|^2)``, Daly, Gai & Harrison 1979), averaged over the sensors.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import beta as _beta
from scipy.stats import ncx2

from ..fdi.detectors import DETECTORS  # the runtime's names, re-exported here
from ..fdi.detectors import make_detector as _make_detector
from ..fdi.glt import glt_threshold
from ..fdi.manager import HealthState, RedundancyManager
from ..fdi.settings import DEFAULTS as _D
from ..fusion import InstrumentPipeline
from .faults import FAULTS

__all__ = ["CampaignSpec", "CampaignResult", "run_campaign", "run_task", "run_tasks", "clopper_pearson", "make_detector",
           "simulated_truth", "campaign_unit"]



def clopper_pearson(k: int, n: int, level: float = 0.99) -> tuple[float, float]:
    """Exact binomial confidence interval of k successes in n trials.

    >>> lo, hi = clopper_pearson(10, 10000)
    >>> round(lo, 5), round(hi, 5)
    (0.00037, 0.00214)
    """
    if n <= 0:
        return 0.0, 1.0
    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(_beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(_beta.ppf(1 - a, k + 1, n - k))
    return lo, hi


@dataclass
class CampaignSpec:
    """What a campaign runs. Sizes are in units of the sensor's noise sigma.

    Attributes
    ----------
    geometry, instrument : str
        A preset name and ``"gyro"`` or ``"accel"``.
    faults : list of str
        Fault types (:data:`rimu.experiments.faults.FAULTS`).
    sensors : list of int or None
        Faulty sensor indices (None: all).
    sizes : list of float
        Fault sizes, sigma.
    repetitions : int
        Seeds per (fault, sensor, size).
    detector : str
        One of ``glt``, ``glt_window``, ``cusum``, ``kalman``, ``baseline``.
    window, p_fa, arl0, cusum_bias, tau, dead_band : detector settings
        (cusum_bias in sigma; tau in samples; dead_band in sigma).
    confirm : int
        Confirmation of the manager (closed loop).
    duration, fault_start, sample_rate : float
        s, s, Hz.
    rate_dps : float
        Constant manoeuvre rate about MB (1, 1, 1)/sqrt(3), deg/s (exercises scale, stuck and saturation faults).
    closed_loop : bool
        Also run the manager sample by sample.
    arw, vrw : float
        Simulated noise densities (deg/sqrt(h), micro-g/sqrt(Hz)).
    base_seed : int
    """

    geometry: str = "cone6"
    instrument: str = "gyro"
    faults: list[str] = field(default_factory=lambda: ["bias"])
    sensors: list[int] | None = None
    sizes: list[float] = field(default_factory=lambda: [4.0, 6.0, 8.0, 10.0, 12.0])
    repetitions: int = 5
    detector: str = "glt"
    window: int = 5
    p_fa: float = _D.p_fa
    arl0: float = 1e5
    cusum_bias: float = 1.0
    tau: float = 20.0
    dead_band: float = 2.0
    confirm: int = _D.confirm
    duration: float = 10.0
    fault_start: float = 5.0
    sample_rate: float = 100.0
    rate_dps: float = 30.0
    closed_loop: bool = True
    arw: float = 3.0
    vrw: float = 200.0
    base_seed: int = 0

    def __post_init__(self) -> None:
        check_spec("fault types", self.faults, sorted(FAULTS), "fault_start", self.fault_start, self.duration)
        if self.detector not in DETECTORS:
            raise ValueError(f"unknown detector {self.detector!r}; known: {DETECTORS}")

    def tasks(self) -> list[tuple[int, int, int, int]]:
        """(fault index, sensor, size index, repetition) for every task, in a fixed order."""
        from ..geometry import preset

        n = preset(self.geometry).n
        sensors = self.sensors if self.sensors is not None else list(range(n))
        return [(f, s, z, r) for f in range(len(self.faults)) for s in sensors
                for z in range(len(self.sizes)) for r in range(self.repetitions)]


def check_spec(what: str, names: Sequence[str], known: Sequence[str], start_name: str, start: float,
               duration: float) -> None:
    """ValueError for names outside ``known`` or a fault onset outside the run (both campaigns' specs)."""
    unknown = [f for f in names if f not in known]
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; known: {list(known)}")
    if not 0 < start < duration:
        raise ValueError(f"{start_name} must lie inside the run")


def split_isolations(events: Sequence[Any], onset: float, at: Callable[[Any], float] = lambda e: e.t
                     ) -> tuple[list[Any], list[Any]]:
    """The isolations among a manager's events (``isolated`` and ``invalid_isolated``), before and after the
    fault's onset (``at(event)``: its time by default)."""
    isol = [e for e in events if e.kind in ("isolated", "invalid_isolated")]
    return [e for e in isol if at(e) < onset], [e for e in isol if at(e) >= onset]


# ---------------------------------------------------------------------- one task (runs in a worker)
_CACHE: dict[Any, Any] = {}


def campaign_unit(spec: CampaignSpec) -> tuple[Any, InstrumentPipeline, float]:
    """The simulated unit a campaign runs on: the simulator's truth calibration, the instrument's pipeline on it
    and the simulated white-noise sigma (cached for the last spec's geometry, instrument, seed and noise)."""
    from ..geometry import preset
    from ..sim import Simulator

    key = (spec.geometry, spec.instrument, spec.base_seed, spec.arw, spec.vrw, spec.sample_rate)
    if key not in _CACHE:
        g = preset(spec.geometry)
        sim = Simulator({spec.instrument: g}, arw_deg_sqrt_h=spec.arw, vrw_ug_sqrt_hz=spec.vrw,
                        sample_rate=spec.sample_rate, seed=spec.base_seed)
        truth = sim.truth_calibration()
        _CACHE.clear()
        _CACHE[key] = (truth, InstrumentPipeline(truth[spec.instrument]), sim.noise_sigma(spec.instrument))
    return _CACHE[key]


def simulated_truth(geometry: str, instrument: str, sample_rate: float, seed: int) -> Any:
    """The simulator's truth calibration of one instrument of a preset geometry (Cho & Park-like coefficients,
    noise_sigma of the simulated white noise); used by the fault-management campaign (:mod:`rimu.experiments.scenarios`)."""
    from ..geometry import preset
    from ..sim import Simulator

    sim = Simulator({instrument: preset(geometry)}, sample_rate=sample_rate, seed=seed)
    return sim.truth_calibration()[instrument]


def make_detector(spec: CampaignSpec, sigma: float | np.ndarray) -> Any:
    """The detector a spec names, with its design settings (the runtime's factory,
    :func:`rimu.fdi.detectors.make_detector`)."""
    return _make_detector(spec.detector, sigma, p_fa=spec.p_fa, window=spec.window, arl0=spec.arl0,
                          cusum_bias=spec.cusum_bias, tau=spec.tau, dead_band=spec.dead_band)


def task_seed(spec: CampaignSpec, task: Sequence[int]) -> int:
    return int(np.random.SeedSequence([spec.base_seed, *[int(x) for x in task]]).generate_state(1)[0])


def run_task(spec: CampaignSpec, task: Sequence[int]) -> dict[str, Any]:
    """Run one (fault, sensor, size, repetition) task; a plain dict of counts and outcomes."""
    from ..sim import Simulator, rotation
    from .faults import Injection, inject

    f_i, sensor, z_i, rep = (int(x) for x in task)
    truth, pipe, _sigma = campaign_unit(spec)
    cal = truth[spec.instrument]
    seed = task_seed(spec, task)
    sim = Simulator({spec.instrument: cal.geometry}, truth=truth, arw_deg_sqrt_h=spec.arw,
                    vrw_ug_sqrt_hz=spec.vrw, sample_rate=spec.sample_rate, seed=seed)
    w = np.ones(3) / np.sqrt(3) * math.radians(spec.rate_dps)
    run = sim.run([rotation("campaign", w, duration=spec.duration)])
    fault = spec.faults[f_i]
    size = float(spec.sizes[z_i])
    inj = Injection(fault, spec.instrument, sensor, spec.fault_start, size, True)
    block = inject(run.block, [inj], truth, seed=seed)
    Y, V = block.raw[spec.instrument], block.valid[spec.instrument]
    t = block.t
    out: dict[str, Any] = {"fault": fault, "sensor": sensor, "size": size, "repetition": rep, "seed": seed}

    # open loop: one active set (the full one), samples the pipeline had to route around are left out
    det = make_detector(spec, pipe.table.sigma)
    res = pipe.process(Y, V)
    e0 = pipe.table.lookup(pipe.table.full_code)
    full = res.entry == e0
    dof = int(pipe.table.dof[e0])
    stat, thr, iso = det.block(np.where(full[:, None], res.parity, 0.0), pipe.table.Vz[e0], dof)
    alarm = stat > thr
    step = spec.window if spec.detector == "glt_window" else 1
    k0 = int(np.searchsorted(t, spec.fault_start))
    idx = np.arange(len(t))
    clean = (idx >= step - 1) & (idx < k0) & (((idx - (step - 1)) % step) == 0)
    faulty = (idx >= k0 + step - 1) & (((idx - (k0 + step - 1)) % step) == 0)
    if step > 1:  # a window must lie entirely inside the full set
        okw = np.convolve(full.astype(int), np.ones(step, int))[: len(t)] == step
        clean &= okw
        faulty &= okw
    else:
        clean &= full
        faulty &= full
    out["n_clean"] = int(clean.sum())
    out["fa_clean"] = int((alarm & clean).sum())
    out["n_fault"] = int(faulty.sum())
    out["det_fault"] = int((alarm & faulty).sum())
    out["iso_correct"] = int((alarm & faulty & (iso == sensor)).sum())
    out["iso_wrong"] = int((alarm & faulty & (iso >= 0) & (iso != sensor)).sum())
    first = np.flatnonzero(alarm & (idx >= k0))
    out["first_alarm_delay_samples"] = int(first[0] - k0 + 1) if first.size else None
    nz = pipe.table.Vz[e0, :dof, sensor] * pipe.table.sigma[sensor]
    out["noncentrality_per_sample"] = float(size**2 * (nz @ nz))

    # closed loop
    if spec.closed_loop:
        mgr = RedundancyManager(pipe, make_detector(spec, pipe.table.sigma), p_fa=spec.p_fa,
                                confirm=1 if spec.detector == "cusum" else spec.confirm,
                                sample_rate=spec.sample_rate)
        rr = mgr.run(Y, V, t)
        name = cal.geometry.names[sensor]
        before, after = split_isolations(rr.events, spec.fault_start)
        out["false_isolations"] = len(before)
        out["isolated"] = after[0].sensor if after else None
        out["isolation_correct"] = bool(after and after[0].sensor == name)
        out["isolation_delay_s"] = (after[0].t - spec.fault_start) if after else None
        out["isolated_at_end"] = bool(mgr.isolated[sensor])
        out["transient_events"] = sum(1 for e in rr.events if e.t >= spec.fault_start
                                      and e.kind in ("transient", "invalid_transient") and e.sensor == name)
        out["final_state"] = mgr.state.value
        # an estimate is a finite number wherever there is one (NaN exactly where the set is unobservable)
        obs = rr.validity != 2
        out["finite"] = bool(np.all(np.isfinite(rr.x[obs])) and np.all(np.isnan(rr.x[~obs]))
                             and np.all(np.isfinite(rr.statistic)))
        mgr.reset()
    return out


def _run_chunk(fn: Callable[[Any, Any], dict[str, Any]], spec: Any, tasks: list[Any]) -> list[dict[str, Any]]:
    return [fn(spec, t) for t in tasks]


# ---------------------------------------------------------------------- results
@dataclass
class CampaignResult:
    """Per-task rows and their summary per (fault, size)."""

    spec: CampaignSpec
    rows: list[dict[str, Any]]
    elapsed_s: float = 0.0
    workers: int = 1

    def summary(self, level: float = 0.99) -> list[dict[str, Any]]:
        """One row per (fault, size): Pd, Pfa, isolation rates and delays with confidence intervals."""
        out = []
        spec = self.spec
        for fault in spec.faults:
            for size in spec.sizes:
                rows = [r for r in self.rows if r["fault"] == fault and r["size"] == size]
                if not rows:
                    continue
                nf = sum(r["n_fault"] for r in rows)
                kd = sum(r["det_fault"] for r in rows)
                nc = sum(r["n_clean"] for r in rows)
                kc = sum(r["fa_clean"] for r in rows)
                ic = sum(r["iso_correct"] for r in rows)
                iw = sum(r["iso_wrong"] for r in rows)
                s: dict[str, Any] = {
                    "fault": fault, "size_sigma": size, "tasks": len(rows),
                    "pd": kd / nf if nf else None, "pd_ci": clopper_pearson(kd, nf, level), "n_fault": nf,
                    "pfa": kc / nc if nc else None, "pfa_ci": clopper_pearson(kc, nc, level), "n_clean": nc,
                    "wrong_isolation": iw / kd if kd else None, "wrong_isolation_ci": clopper_pearson(iw, kd, level),
                    "correct_isolation": ic / kd if kd else None,
                }
                if fault == "bias" and spec.detector in ("glt", "glt_window"):
                    lam = np.array([r["noncentrality_per_sample"] for r in rows])
                    win = spec.window if spec.detector == "glt_window" else 1
                    dof = _dof(spec)
                    s["pd_theory"] = float(np.mean(ncx2.sf(glt_threshold(spec.p_fa, dof), dof, win * lam)))
                if spec.closed_loop:
                    d = [r["isolation_delay_s"] for r in rows if r.get("isolation_delay_s") is not None]
                    s["closed_loop_isolated"] = sum(1 for r in rows if r.get("isolated")) / len(rows)
                    s["closed_loop_correct"] = sum(1 for r in rows if r.get("isolation_correct")) / len(rows)
                    s["closed_loop_isolated_at_end"] = sum(1 for r in rows if r.get("isolated_at_end")) / len(rows)
                    s["false_isolations"] = sum(r.get("false_isolations", 0) for r in rows)
                    s["delay_mean_s"] = float(np.mean(d)) if d else None
                    s["delay_ci_s"] = (_mean_ci(d, level) if len(d) > 1 else None)
                    s["all_finite"] = all(r.get("finite", True) for r in rows)
                    s["transient_events"] = sum(r.get("transient_events", 0) for r in rows)
                d1 = [r["first_alarm_delay_samples"] for r in rows if r["first_alarm_delay_samples"] is not None]
                s["first_alarm_delay_samples"] = float(np.mean(d1)) if d1 else None
                out.append(s)
        return out

    def table(self) -> str:
        """The summary as a readable table."""
        from ..units import fmt

        lines = [f"campaign: {self.spec.geometry} {self.spec.instrument}, detector {self.spec.detector}, "
                 f"{len(self.rows)} tasks in {self.elapsed_s:.1f} s on {self.workers} worker(s)",
                 f"{'fault':>10} {'size':>5} | {'Pd':>7} {'99% CI':>17} {'theory':>7} | {'Pfa':>8} {'99% CI':>19} | "
                 f"{'wrong iso':>9} | {'closed loop: correct':>20} {'delay':>10}"]
        for s in self.summary():
            ci = s["pd_ci"]
            fci = s["pfa_ci"]
            th = f"{s['pd_theory']:.4f}" if "pd_theory" in s else "   -   "
            # the figures with a unit through the one formatter (rimu.units.fmt)
            wi = fmt(s["wrong_isolation"], "ratio", "%", decimals=3) if s["wrong_isolation"] is not None else "-"
            cl = fmt(s["closed_loop_correct"], "ratio", "%", decimals=0) if "closed_loop_correct" in s else "-"
            dl = fmt(s["delay_mean_s"], "time", "s", decimals=3) if s.get("delay_mean_s") is not None else "-"
            pd = f"{s['pd']:.4f}" if s["pd"] is not None else "-"
            pfa = f"{s['pfa']:.2e}" if s["pfa"] is not None else "-"
            lines.append(f"{s['fault']:>10} {s['size_sigma']:>5g} | {pd:>7} [{ci[0]:.4f}, {ci[1]:.4f}] {th:>7} | "
                         f"{pfa:>8} [{fci[0]:.2e}, {fci[1]:.2e}] | {wi:>9} | {cl:>20} {dl:>10}")
        return "\n".join(lines)

    def to_json(self, path: str | Path | None = None) -> str:
        doc = {"spec": asdict(self.spec), "elapsed_s": self.elapsed_s, "workers": self.workers,
               "summary": self.summary(), "rows": self.rows}
        text = json.dumps(doc, indent=1, default=_jsonable)
        if path is not None:
            from ..atomic import write_text

            write_text(path, text)
        return text

    def plot(self, path: str | Path) -> Path | None:
        """Detection probability against size per fault type, with the chi-square theory curve for biases."""
        from ..plotting import pyplot, save_figure

        plt = pyplot(optional=True)
        if plt is None:
            return None
        spec = self.spec
        summ = self.summary()
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for fault in spec.faults:
            ss = [s for s in summ if s["fault"] == fault and s["pd"] is not None]
            if not ss:
                continue
            x = np.array([s["size_sigma"] for s in ss])
            y = np.array([s["pd"] for s in ss])
            lo = y - np.array([s["pd_ci"][0] for s in ss])
            hi = np.array([s["pd_ci"][1] for s in ss]) - y
            ax.errorbar(x, y, yerr=[lo, hi], fmt="o", capsize=3, label=f"{fault}: measured (99% CI)")
        if "bias" in spec.faults and spec.detector in ("glt", "glt_window"):
            xs = np.linspace(0, max(spec.sizes) * 1.05, 200)
            rows = [r for r in self.rows if r["fault"] == "bias"]
            unit = np.mean([r["noncentrality_per_sample"] / r["size"] ** 2 for r in rows])
            win = spec.window if spec.detector == "glt_window" else 1
            dof = _dof(spec)
            ax.plot(xs, ncx2.sf(glt_threshold(spec.p_fa, dof), dof, np.maximum(win * unit * xs**2, 1e-12)), "k-",
                    lw=1, label=f"theory: noncentral chi2({dof}), P_FA={spec.p_fa:g}")
        ax.set_xlabel("fault size, sigma")
        ax.set_ylabel("detection probability per test")
        ax.set_title(f"{spec.geometry} {spec.instrument}: {spec.detector}"
                     + (f" (window {spec.window})" if spec.detector == "glt_window" else ""))
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        fig.tight_layout()
        return save_figure(fig, path)


def _dof(spec: CampaignSpec) -> int:
    from ..geometry import preset

    return preset(spec.geometry).n - 3


def _mean_ci(d: list[float], level: float) -> tuple[float, float]:
    from scipy.stats import t as _t

    a = np.asarray(d, dtype=float)
    h = float(_t.ppf(0.5 + level / 2, len(a) - 1) * a.std(ddof=1) / np.sqrt(len(a)))
    return float(a.mean() - h), float(a.mean() + h)


def _jsonable(o: Any) -> Any:
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, HealthState):
        return o.value
    raise TypeError(f"not JSON serialisable: {type(o)}")


# ---------------------------------------------------------------------- runner
def run_campaign(spec: CampaignSpec, workers: int | None = None, scheduler: str | None = None,
                 executor: Executor | None = None, progress: bool | Callable[[int, int], None] = False,
                 chunks_per_worker: int = 4) -> CampaignResult:
    """Run every task of ``spec`` and collect the results (in task order, whatever the executor).

    Parameters
    ----------
    workers : int, optional
        Processes of the default ``ProcessPoolExecutor``; 0 runs in this process (no pool).
        Default: the number of CPUs.
    scheduler : str, optional
        Address of a dask.distributed scheduler; the tasks then run on that cluster through
        ``Client.get_executor()`` (needs the ``distributed`` extra).
    executor : concurrent.futures.Executor, optional
        Any executor of your own (takes precedence).
    progress : bool or callable
        Show progress (tqdm if installed, else a counter on stderr), or call ``progress(done, total)``.
    """
    import time

    t0 = time.perf_counter()
    rows, workers = run_tasks(run_task, spec, spec.tasks(), workers, scheduler, executor, progress, chunks_per_worker)
    return CampaignResult(spec, rows, time.perf_counter() - t0, workers)


def run_tasks(fn: Callable[[Any, Any], dict[str, Any]], spec: Any, tasks: Sequence[Any], workers: int | None = None,
              scheduler: str | None = None, executor: Executor | None = None,
              progress: bool | Callable[[int, int], None] = False, chunks_per_worker: int = 4
              ) -> tuple[list[dict[str, Any]], int]:
    """``fn(spec, task)`` for every task, in task order whatever the executor, and the number of workers used:
    the one loop of both campaigns (this module's and :func:`rimu.experiments.scenarios.run_scenarios`). ``fn`` must be
    a module-level function (pickled to the workers); the options are those of :func:`run_campaign`."""
    import os

    tasks = list(tasks)
    client = None
    own = None
    if executor is None and scheduler is not None:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - optional extra
            raise ImportError("a dask scheduler needs the 'distributed' extra: pip install rimu[distributed]") from exc
        client = Client(scheduler)
        executor = client.get_executor()
        workers = len(client.scheduler_info().get("workers", {})) or 1
    if executor is None and workers != 0:
        workers = workers or os.cpu_count() or 1
        own = executor = ProcessPoolExecutor(max_workers=workers)
    report = _progress(progress, len(tasks))
    rows: list[dict[str, Any]] = []
    try:
        if executor is None:
            for k, task in enumerate(tasks):
                rows.append(fn(spec, task))
                report(k + 1)
            workers = 1
        else:
            size = max(1, len(tasks) // (max(workers or 1, 1) * chunks_per_worker))
            chunks = [tasks[i:i + size] for i in range(0, len(tasks), size)]
            futures = [executor.submit(_run_chunk, fn, spec, c) for c in chunks]
            done = 0
            results: list[list[dict[str, Any]]] = []
            for fut in futures:  # in submission order: deterministic
                results.append(fut.result())
                done += len(results[-1])
                report(done)
            rows = [r for chunk in results for r in chunk]
    finally:
        report(-1)
        if own is not None:
            own.shutdown()
        if client is not None:
            client.close()
    return rows, int(workers or 1)


def _progress(progress: bool | Callable[[int, int], None], total: int) -> Callable[[int], None]:
    """A tqdm bar on a terminal when tqdm is installed (extra ``progress``); nothing otherwise."""
    import sys

    from .. import progress as _bars

    if callable(progress):
        return lambda k: progress(k, total) if k >= 0 else None
    if not progress or not _bars.enabled():
        return lambda k: None
    try:
        from tqdm import tqdm
    except ImportError:
        return lambda k: None
    bar = tqdm(total=total, desc="campaign", unit="task", file=sys.stderr, disable=None, leave=False)
    state = {"n": 0}

    def upd(k: int) -> None:
        if k < 0:
            bar.close()
            return
        bar.update(k - state["n"])
        state["n"] = k

    return upd
