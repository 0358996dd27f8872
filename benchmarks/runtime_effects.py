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

Per-sample cost of ``Pipeline.step`` (one epoch of both instruments) and of ``Pipeline.process`` per sample;
medians over repeats, ratios to ``base``. Target: ``all`` step within 2x of ``base`` step. Prints a table and
one JSON line.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time

from rimu.calibration.model import RuntimeInputs
from rimu.epoch import EpochBlock
from rimu.fusion import EffectCompensation, Pipeline
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


def main(quick: bool = False) -> dict:
    cfgs = configurations()
    M = 500 if quick else 3000
    N = 20_000 if quick else 200_000
    reps = 3 if quick else 7
    block = data(cfgs["all"], N)
    epochs = list(EpochBlock(block.t[:M], {k: v[:M] for k, v in block.raw.items()},
                             temperature=block.temperature[:M]).epochs())
    rows = {}
    for name, cal in cfgs.items():
        pipe = Pipeline(cal, temperature=True)

        def step_loop(pipe=pipe):
            step = pipe.step
            for e in epochs:
                step(e)

        def block_run(pipe=pipe):
            pipe.process(block)

        step_loop()
        t_step = median_time(step_loop, reps) / M
        t_block = median_time(block_run, max(3, reps // 2)) / N
        rows[name] = {"step_us": t_step * 1e6, "block_us": t_block * 1e6}
    b = rows["base"]
    for r in rows.values():
        r["step_ratio"] = r["step_us"] / b["step_us"]
        r["block_ratio"] = r["block_us"] / b["block_us"]
    res = {"benchmark": "runtime_effects", "geometry": "cone6 gyro + accel", "step_samples": M, "block_samples": N,
           "machine": {"cpus": os.cpu_count(), "load_1min": os.getloadavg()[0]},
           "configurations": rows, "target": {"all_step_ratio_max": 2.0}}
    print(f"{'configuration':<14}{'step us/epoch':>15}{'ratio':>8}{'block us/sample':>17}{'ratio':>8}")
    for name, r in rows.items():
        print(f"{name:<14}{r['step_us']:>15.1f}{r['step_ratio']:>8.2f}{r['block_us']:>17.3f}{r['block_ratio']:>8.1f}")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
