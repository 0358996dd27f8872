"""Close the loop at the runtime: a calibration session and a separate validation session of the same simulated
unit, which has an effect outside the base model. Base calibration -> replay of the validation session (error,
false alarms) -> diagnose -> add the effect -> recalibrate -> replay again: the systematic error falls to the
noise floor and the false alarms stop. One plot shows the runtime error before and after.

Run: python examples/close_the_loop.py [OUTPUT_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rimu.calibration import LeastSquares
from rimu.calibration.effects import GSensitivity
from rimu.calibration.model import ErrorModel
from rimu.diagnose import diagnose
from rimu.experiments.validate import validate
from rimu.fusion.validation import plot_segment_errors
from rimu.geometry import cone6
from rimu.sim import Simulator, TruthEffect
from rimu.sim.typical import validation_procedure
from rimu.units import DS_TO_RS, G0, RS_TO_DH


def main(out_dir: str = "close-the-loop") -> dict:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    g = cone6()
    gs = np.array([0.05, -0.03, 0.04]) * DS_TO_RS / G0   # (deg/s)/g on gyro x2: an ADXRS-class MEMS rate gyro
    sim_kw = {"sample_rate": 20.0, "arw_deg_sqrt_h": 0.15, "vrw_ug_sqrt_hz": 50.0,
                  "effects": {"gyro": [TruthEffect(GSensitivity(), {g.index("x2"): gs})]}}
    print("1. A cone6 unit (Cho & Park 2005, Table 3 coefficients) whose gyro x2 is g-sensitive,")
    print(f"   ({', '.join(f'{x * RS_TO_DH * G0:.0f}' for x in gs)}) (deg/h)/g: outside the base model.")
    cal = Simulator({"gyro": g, "accel": cone6()}, seed=1, **sim_kw).run(validation_procedure(45.0))
    val = Simulator({"gyro": g, "accel": cone6()}, seed=2, **sim_kw).run(validation_procedure(30.0))
    print(f"   calibration session: {len(cal.session)} segments; held-out validation session: {len(val.session)}")

    print("\n2. Base calibration (scale factor, misalignment, bias), replayed on the validation session:")
    sig = {k: cal.truth[k].noise_sigma / cal.truth[k].scale for k in ("gyro", "accel")}
    base = LeastSquares(ErrorModel.base(), sigma=sig).fit(cal.session).to_calibration()
    before = validate(val.session, base)
    _print(before)

    print("\n3. Diagnose the calibration session:")
    d = diagnose(cal.session, sigma=sig)
    top = d["gyro"].top()
    print(f"   gyro: missing {top} on {', '.join(d['gyro'].test(top).detected_sensors())}")

    print(f"\n4. Recalibrate with {top}, replay the validation session again:")
    gyro = LeastSquares(ErrorModel.base() + top, sigma=sig, instruments=["gyro"]).fit(cal.session).to_calibration()
    full = base
    full.instruments_cal["gyro"] = gyro["gyro"]
    after = validate(val.session, full)
    _print(after)
    ratio = before["gyro"].errors.segment_error_rms / after["gyro"].errors.segment_error_rms
    print(f"\n   the gyro segment error fell {ratio:.1f}x; isolations {before['gyro'].isolations} -> "
          f"{after['gyro'].isolations}")
    full.save(out / "calibration.json")
    png = plot_segment_errors({"base model": before["gyro"].errors, f"+ {top}": after["gyro"].errors},
                              out / "runtime_error.png", title="gyro runtime error on the held-out session")
    if png:
        print(f"   plot: {png}")
    return {"before": {k: v.to_dict() for k, v in before.items()}, "after": {k: v.to_dict() for k, v in after.items()},
            "ratio": ratio}


def _print(v: dict) -> None:
    for k, r in v.items():
        unit, f = ("deg/h", RS_TO_DH) if k == "gyro" else ("ug", 1e6 / G0)
        e = r.errors
        print(f"   {k:5s}: segment error {e.segment_error_rms * f:8.2f} {unit}, sample error "
              f"{e.sample_error_rms * f:8.1f} {unit}; samples alarmed {r.alarms}, isolations {r.isolations}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
