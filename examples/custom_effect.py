"""Write your own effect in a few lines, register it, and let the diagnosis test it like any other.

The effect here: a gyro bias proportional to the square of the table rate (e.g. a centrifugal load on the
sensing element, or heating of slip rings at high speed). An effect needs a name, its parameters (with
units) and its regressor columns for a segment and a sensor; the simulator evaluates the same columns, so
the new effect can be simulated at once.

Run: python examples/custom_effect.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rimu.calibration.model import Effect, ParamSpec, register_effect
from rimu.diagnose import diagnose
from rimu.geometry import tetrad4
from rimu.sim import Simulator, TruthEffect
from rimu.sim.procedures import oliveira_table1
from rimu.units import DEG_TO_RAD, RS_TO_DH


class RateSquaredBias(Effect):
    name = "rate_squared_bias"
    instruments = ("gyro",)
    description = "gyro bias proportional to the squared table rate |w|^2"
    physics = "Centrifugal load on the sensing element; error = k |w|^2, reported in (deg/h)/(deg/s)^2."
    excited_by = "rotations at several rates"

    def parameters(self, ctx):
        return [ParamSpec("k_w2", "(rad/s)/(rad/s)^2", "(deg/h)/(deg/s)^2", RS_TO_DH * DEG_TO_RAD**2)]

    def columns(self, segment, ctx):
        w = segment.table_rate()
        return np.full((segment.n_samples, 1), float(w @ w))


register_effect(RateSquaredBias)  # one line: now diagnose() tests it, ErrorModel.from_names knows it


def main() -> None:
    print("de Oliveira et al. 2012 Table 1 on a tetrad at 10 and 40 deg/s; gyro g2 has k = 0.05 (deg/h)/(deg/s)^2")
    k = 0.05 / (RS_TO_DH * DEG_TO_RAD**2)
    sim = Simulator({"gyro": tetrad4()}, arw_deg_sqrt_h=0.1, sample_rate=20.0, seed=3,
                    effects={"gyro": [TruthEffect(RateSquaredBias(), {1: [k]})]})
    proc = oliveira_table1(rate=10 * DEG_TO_RAD, turns=1) + oliveira_table1(rate=40 * DEG_TO_RAD, turns=2)
    for n, spec in enumerate(proc):
        spec.label = f"{spec.label}_{n}"
    session = sim.session(proc)
    d = diagnose(session, "bias,scale,misalignment")
    print("\n".join(d["gyro"].lines()[:12]))
    comp = d.add("rate_squared_bias")["gyro"]
    print("\n".join(comp.lines()))


if __name__ == "__main__":
    main()
