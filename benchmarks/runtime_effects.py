#!/usr/bin/env python3
"""Cost of compensating every calibrated effect at runtime, against the scale/misalignment/bias-only pipeline
timed in the same run (cone6 gyros + accelerometers, Cho & Park Table 3 coefficients).

Configurations (typical coefficients, ``rimu.sim.typical``):

* ``base``: scale factor, misalignment, bias only (the reference);
* ``exogenous``: effects that depend on the epoch's other inputs only (g-sensitivity, g^2, temperature
  bias terms, drift): one matrix-vector product per instrument in the raw domain;
* ``output_side``: nonlinearity, asymmetry, scale temperature terms, cross coupling: the exact inversion
  (3 rounds of projection + Newton step per instrument);
* ``all``: every compensable effect on both instruments, the g-sensitivity <-> size-effect cycle included
  (two extra rounds of both instruments per epoch).

Per-sample cost of ``Pipeline.step`` (one epoch of both instruments) and of ``Pipeline.process`` per sample, for
the numpy and (where installed) numba backends; medians over repeats, ratios to ``base`` of the same backend and
to the numpy ``base`` step, and the bare numpy ``G @ y`` of one instrument. Target: ``all`` step within 2x of
``base`` step. With numba, ``process`` with every effect is also timed against a C kernel of the same arithmetic
(``benchmarks/_ckernel.py``, ``-O3 -march=native``, on the compiled program's arrays) on blocks of 1e5 and 1e3
samples (targets: >= 0.7x and >= 0.5x its throughput). The C and numba runs alternate, as do the configurations'
runs, so that a change of the machine's load falls on both sides of a ratio; the C ratio is also given on the
thread's CPU time (``time.thread_time``), which preemption on a shared machine does not inflate. Prints a table
and one JSON line.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ckernel import build
from _timing import median_time

from rimu.calibration.model import RuntimeInputs
from rimu.epoch import EpochBlock
from rimu.fusion import EffectCompensation, Pipeline, numba_available
from rimu.sim import cho_park_table3
from rimu.sim.typical import TYPICAL_EFFECTS, with_effects
from rimu.units import DEG_TO_RAD, G0

EXOGENOUS = ("g_sensitivity", "g2_sensitivity", "bias_temperature", "bias_temperature2", "bias_drift")
OUTPUT_SIDE = ("sf_quadratic", "sf_cubic", "sf_asymmetry", "scale_temperature", "scale_temperature2", "cross_coupling")




def configurations():
    base = cho_park_table3(gyro_sigma=1e-3)
    for k in base.instruments:
        base[k].noise_sigma = np.full(6, 1e-3)
    pick = lambda names: {k: [e for e in names if e in TYPICAL_EFFECTS[k]] for k in base.instruments}  # noqa: E731
    return {
        "base": with_effects(base, {"gyro": [], "accel": []}),
        "exogenous": with_effects(base, pick(EXOGENOUS)),
        "output_side": with_effects(base, pick(OUTPUT_SIDE)),
        "all": with_effects(base),
    }


def data(cal, N: int, seed: int = 0) -> EpochBlock:
    """Noise-free raw outputs of the full model (every effect) for random rates and specific forces."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.01
    T = 30.0 + 5.0 * np.sin(t / 60.0)
    U = {"gyro": rng.standard_normal((N, 3)) * 100 * DEG_TO_RAD, "accel": rng.standard_normal((N, 3)) * 0.6 * G0}
    inputs = RuntimeInputs(t=t, temperature=T, specific_force=U["accel"], angular_rate=U["gyro"])
    raw = {k: EffectCompensation(cal[k]).forward(U[k], inputs) for k in ("gyro", "accel")}
    return EpochBlock(t, raw, temperature=T)


def _time_configurations(pipes, epochs, head, reps):
    """Per-sample ``step`` and ``process`` times of every configuration's pipeline, s; the configurations are
    timed in turn within each repeat, so that a change of the machine's load falls on all of them."""
    def step_loop(pipe):
        step = pipe.step
        for e in epochs:
            step(e)
    for pipe in pipes.values():
        step_loop(pipe)
        pipe.process(head)
    steps: dict = {name: [] for name in pipes}
    blocks: dict = {name: [] for name in pipes}
    for r in range(reps):
        for name, pipe in pipes.items():
            steps[name].append(median_time(lambda pipe=pipe: step_loop(pipe), 1) / len(epochs))
            if r < max(3, reps // 2):
                blocks[name].append(median_time(lambda pipe=pipe: pipe.process(head), 1) / len(head))
    return {name: (float(np.median(steps[name])), float(np.median(blocks[name]))) for name in pipes}


def _c_reference(ck, cal, block, sizes, reps):
    """The C kernel of the compiled stage's arithmetic (benchmarks/_ckernel.py) on the numba pipeline's program,
    and the numba pipeline's ``process`` on the same blocks, s/sample; checked to give the same outputs."""
    pipe = Pipeline(cal, temperature=True, backend="numba")
    pipe.process(block)
    prog = pipe._program
    order = pipe._order
    out = {}
    for N in sizes:
        sub = EpochBlock(block.t[:N], {k: v[:N] for k, v in block.raw.items()}, temperature=block.temperature[:N])
        inner = max(1, 20_000 // N)
        t = sub.t - pipe.t0
        dT = sub.temperature - pipe._t_ref
        Ys = [np.ascontiguousarray(sub.raw[k]) for k in order]
        Os = [np.empty((N, 3 + pipe[k].r)) for k in order]
        ref = pipe.process(sub)
        _, bad = ck.epoch_block(prog.F, prog.L, prog.W, Ys[0], Ys[-1], t, dT, Os[0], Os[-1], 1)
        assert bad == -1
        for k, O in zip(order, Os):
            np.testing.assert_allclose(O[:, :3], ref[k].x, rtol=0, atol=1e-12 * np.abs(ref[k].x).max())

        def run(sub=sub, inner=inner):
            for _ in range(inner):
                pipe.process(sub)
        ts, tn, cpu_c, cpu_nb = [], [], [], []
        for _ in range(reps):  # alternated, so that a change of the machine's load falls on both
            c0 = time.thread_time()
            ts.append(ck.epoch_block(prog.F, prog.L, prog.W, Ys[0], Ys[-1], t, dT, Os[0], Os[-1], inner)[0])
            c1 = time.thread_time()
            tn.append(median_time(run, 1))
            cpu_c.append(c1 - c0)
            cpu_nb.append(time.thread_time() - c1)
        t_nb = float(np.median(tn)) / (inner * N)
        t_c = float(np.median(ts)) / N
        # the same on the thread's CPU time: what a loaded (shared) machine does not inflate by preemption
        cpu_ratio = float(np.median(cpu_c)) / float(np.median(cpu_nb))
        out[str(N)] = {"c_us": t_c * 1e6, "numba_us": t_nb * 1e6, "numba_vs_c": t_c / t_nb,
                       "numba_vs_c_cpu_time": cpu_ratio}
    return out


def main(quick: bool = False) -> dict:
    cfgs = configurations()
    M = 500 if quick else 3000
    N = 20_000 if quick else 200_000
    reps = 3 if quick else 7
    backends = ["numpy"] + (["numba"] if numba_available() else [])
    block = data(cfgs["all"], max(N, 100_000))
    head = EpochBlock(block.t[:N], {k: v[:N] for k, v in block.raw.items()}, temperature=block.temperature[:N])
    epochs = list(EpochBlock(block.t[:M], {k: v[:M] for k, v in block.raw.items()},
                             temperature=block.temperature[:M]).epochs())
    rows: dict = {b: {} for b in backends}
    for b in backends:
        pipes = {name: Pipeline(cal, temperature=True, backend=b) for name, cal in cfgs.items()}
        for name, (t_step, t_block) in _time_configurations(pipes, epochs, head, reps).items():
            rows[b][name] = {"step_us": t_step * 1e6, "block_us": t_block * 1e6}
    # references timed in the same run: bare numpy G @ y (one instrument) per sample
    g = Pipeline(cfgs["base"], backend="numpy")["gyro"]
    G = g.table.G[0]
    ys = [e.raw["gyro"] for e in epochs]

    def bare():
        for y in ys:
            G @ y
    bare()
    t_bare = median_time(bare, reps) / M
    base_np = rows["numpy"]["base"]
    for b in backends:
        base = rows[b]["base"]
        for r in rows[b].values():
            r["step_ratio"] = r["step_us"] / base["step_us"]
            r["block_ratio"] = r["block_us"] / base["block_us"]
            r["step_ratio_to_numpy_base"] = r["step_us"] / base_np["step_us"]
            r["step_ratio_to_bare_matvec"] = r["step_us"] / (t_bare * 1e6)
    ck = build() if "numba" in backends else None
    cref = None if ck is None else _c_reference(ck, cfgs["all"], block, (100_000, 1_000) if not quick
                                                else (20_000, 1_000), 3 * reps)
    res = {"benchmark": "runtime_effects", "geometry": "cone6 gyro + accel", "step_samples": M, "block_samples": N,
           "machine": {"cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]}, "backends": backends,
           "bare_matvec_us": t_bare * 1e6, "configurations": rows["numpy"], "by_backend": rows,
           "c_reference_all_effects": cref, "c_compiler": None if ck is None else ck.compiler,
           "target": {"all_step_ratio_max": 2.0, "numba_block_vs_c_min": {"100000": 0.7, "1000": 0.5}}}
    print(f"bare numpy G @ y (one instrument): {t_bare * 1e6:.3f} us/sample; ratios to the same backend's base "
          "(scale/misalignment/bias only) pipeline")
    print(f"{'backend':<8}{'configuration':<14}{'step us/epoch':>15}{'ratio':>8}{'vs numpy base':>15}"
          f"{'block us/sample':>17}{'ratio':>8}")
    for b in backends:
        for name, r in rows[b].items():
            print(f"{b:<8}{name:<14}{r['step_us']:>15.2f}{r['step_ratio']:>8.2f}{r['step_ratio_to_numpy_base']:>15.2f}"
                  f"{r['block_us']:>17.3f}{r['block_ratio']:>8.1f}")
    print("target: all-effects step <= 2x the base step of the same backend")
    if cref:
        print(f"\nall effects, Pipeline.process (numba) vs a C kernel of the same arithmetic ({ck.compiler}), us/sample")
        for n_, r in cref.items():
            print(f"{n_:>9} samples  numba {r['numba_us']:.3f}  C {r['c_us']:.3f}  throughput ratio "
                  f"{r['numba_vs_c']:.2f} (on CPU time {r['numba_vs_c_cpu_time']:.2f})")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
