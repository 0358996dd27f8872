#!/usr/bin/env python3
"""The one runtime against the code before it, timed in the same run (issue 25: "the change costs nothing").

The reference is the rimu package of a git revision (default: the merge base with ``main``), extracted to a
temporary folder as the package ``rimu_ref`` and imported beside this tree's ``rimu`` in the same process. Each
round times every candidate once, new and old in turn; times are medians over rounds, ratios medians of the
per-round ratios (new / old; 1.00 is the same cost); new runs first in even rounds and second in odd ones (the
second of two runs over the same data is measurably faster: the order alone moves a 1.2 ms block call by 10 %). Both sides include the same work:

* ``pipeline step``: ``InstrumentPipeline.step(y)`` per sample (cone6 gyros, numpy backend), 20 000 samples;
* ``pipeline block``: ``InstrumentPipeline.process(Y)`` on 100 000 samples (numpy backend), ten calls a timing;
* ``manager step``: ``RedundancyManager.step(y)`` per sample (the per-sample FDI path: pipeline, GLT, state), with
  a 10-sigma fault isolated half way, 5 000 samples;
* ``unit run``: the unit's runtime on a block (``UnitManager.run`` before, ``Runtime.run`` now; gyros and
  accelerometers with g-sensitivity and a temperature effect: the compensation in the loop), 4 000 epochs;
* ``unit step``: the same unit epoch by epoch (``.step(epoch)``), 500 epochs; ``unit step numba``: the same with
  the numba backend (the runtime now steps an epoch through the compiled compensation stage).

Prints a table and one JSON line. With numba installed the compiled kernels of both sides are this tree's
(``rimu.fusion._kernels`` is imported by name); the numpy backend is timed so that both sides run their own code.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import interleaved_times, round_ratio  # noqa: E402


def _reference(rev: str) -> tuple[object, str]:
    """The ``rimu`` package of ``rev`` imported as ``rimu_ref``."""
    import importlib

    if rev == "merge-base":  # the code before this branch; on main itself (or without a main ref) HEAD
        mb = subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], capture_output=True, text=True)
        rev = mb.stdout.strip() if mb.returncode == 0 and mb.stdout.strip() else "HEAD"
    d = Path(tempfile.mkdtemp(prefix="rimu-ref-"))
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "rimu"], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(d)], input=tar, check=True)
    (d / "rimu").rename(d / "rimu_ref")
    sys.path.insert(0, str(d))
    return importlib.import_module("rimu_ref"), rev


def _cases(pkg: object) -> dict:
    """The timed calls of one package (rimu or rimu_ref), each a function of no argument."""
    import importlib

    name = pkg.__name__  # type: ignore[attr-defined]
    fusion = importlib.import_module(f"{name}.fusion")
    fdi = importlib.import_module(f"{name}.fdi")
    sim = importlib.import_module(f"{name}.sim")
    epoch = importlib.import_module(f"{name}.epoch")
    cal = sim.cho_park_table3(gyro_sigma=0.008)
    g = cal["gyro"]
    rng = np.random.default_rng(0)
    n = g.geometry.n
    u = 0.3 * np.sin(np.arange(100_000)[:, None] / np.array([70.0, 50.0, 110.0]))
    Y = g.raw_output(u) + 0.008 / g.scale * rng.standard_normal((len(u), n))
    Ys = [y.copy() for y in Y[:20_000]]
    Yf = Y[:5000].copy()
    Yf[2500:, 4] += 10 * 0.008 / g.scale[4]
    Yfs = list(Yf)

    def step():
        p = fusion.InstrumentPipeline(g, backend="numpy")
        for y in Ys:
            p.step(y)

    pb = fusion.InstrumentPipeline(g, backend="numpy")

    def block():  # ten calls a timing: one call (1 ms) is at the mercy of the machine's other load
        for _ in range(10):
            pb.process(Y)

    def manager():
        m = fdi.RedundancyManager(fusion.InstrumentPipeline(g, backend="numpy"))
        for y in Yfs:
            m.step(y)

    # a unit with every typical effect (rimu.sim.typical): the compensation runs in the loop
    typical = importlib.import_module(f"{name}.sim.typical")
    model = importlib.import_module(f"{name}.calibration.model")
    comp = importlib.import_module(f"{name}.fusion")
    base = sim.cho_park_table3(gyro_sigma=1e-3)
    for k in base.instruments:
        base[k].noise_sigma = np.full(6, 1e-3)
    ucal = typical.with_effects(base)
    N = 4000
    t = np.arange(N) * 0.01
    T = 30.0 + 5.0 * np.sin(t / 60.0)
    U = {"gyro": 0.5 * np.sin(t[:, None] / np.array([0.7, 0.5, 1.1])),
         "accel": np.array([0.0, 0.0, 9.81]) + 2.0 * np.sin(t[:, None] / np.array([0.3, 1.3, 1.7]))}
    inputs = model.RuntimeInputs(t=t, temperature=T, specific_force=U["accel"], angular_rate=U["gyro"])
    raw = {k: comp.EffectCompensation(ucal[k]).forward(U[k], inputs)
           + 1e-3 / ucal[k].scale * rng.standard_normal((N, 6)) for k in ("gyro", "accel")}
    raw["gyro"][2000:, 1] += 10e-3 / ucal["gyro"].scale[1]   # a 10-sigma fault, isolated
    blk = epoch.EpochBlock(t, raw, temperature=T)
    eps = list(epoch.EpochBlock(t[:500], {k: v[:500] for k, v in raw.items()}, temperature=T[:500]).epochs())
    unit_cls = getattr(fdi, "Runtime", None) or fdi.UnitManager

    def unit_run():
        unit_cls(fusion.Pipeline(ucal, temperature=True, backend="numpy")).run(blk)

    def unit_step():
        um = unit_cls(fusion.Pipeline(ucal, temperature=True, backend="numpy"))
        for e in eps:
            um.step(e)

    def unit_step_numba():
        um = unit_cls(fusion.Pipeline(ucal, temperature=True, backend="numba"))
        for e in eps:
            um.step(e)

    cases = {"pipeline step": (step, len(Ys)), "pipeline block": (block, 10 * len(Y)), "manager step": (manager, len(Yfs)),
            "unit run": (unit_run, N), "unit step": (unit_step, len(eps))}
    if comp.numba_available():
        cases["unit step numba"] = (unit_step_numba, len(eps))
    return cases


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="merge-base", help="git revision of the reference (default: merge base with main)")
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    os.environ.setdefault("RIMU_BACKEND", "numpy")
    import rimu

    ref, rev = _reference(args.ref)
    new, old = _cases(rimu), _cases(ref)
    fns = {}
    for k in new:
        fns[f"new {k}"] = new[k][0]
        fns[f"old {k}"] = old[k][0]
    for fn in fns.values():  # warm up (numba compilation, first-use imports)
        fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for r in range(args.rounds):  # new first in even rounds, old first in odd ones: the order's cache effect cancels
        for k in new:
            pair = [f"new {k}", f"old {k}"]
            for name in (pair if r % 2 == 0 else pair[::-1]):
                times[name] += interleaved_times({name: fns[name]}, 1)[name]
    rows = {}
    print(f"one runtime vs {rev[:10]} (numpy backend), medians of {args.rounds} interleaved rounds")
    print(f"{'case':16s} {'new us/sample':>14s} {'old us/sample':>14s} {'new/old':>8s}")
    for k, (_, count) in new.items():
        tn = statistics.median(times[f"new {k}"]) / count * 1e6
        to = statistics.median(times[f"old {k}"]) / count * 1e6
        r = round_ratio(times, f"new {k}", f"old {k}")
        rows[k] = {"new_us_per_sample": tn, "old_us_per_sample": to, "ratio": r}
        print(f"{k:16s} {tn:14.3f} {to:14.3f} {r:8.3f}")
    out = {"reference": rev, "rounds": args.rounds, "cases": rows}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
