"""examples/real_units.py on the quadrotor run: the claims of docs/real-units.md about it."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from tests.conftest import ROOT, shared_data


def test_real_units_example(tmp_path):
    data = shared_data("quadrotor_4x_xsens_dot").parent
    spec = importlib.util.spec_from_file_location("real_units_example", ROOT / "examples" / "real_units.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(["quadrotor", str(data), str(tmp_path), "--no-plot"])   # the figure takes seconds to draw
    clean, faulty = out["runs"].values()
    assert clean["final_state"] == "nominal" and clean["isolated"] == []
    assert out["accel"]["isolated"] == []
    # a 10 deg/s bias on imu4_x halfway: isolated within 0.3 s, the unit goes on with 11 sensors
    assert faulty["isolated"] == ["imu4_x"] and faulty["final_state"] == "fault_isolated"
    iso = next(e for e in faulty["events"] if e.kind == "isolated")
    t_fault = float(out["setup"].full_block.t[0] + 0.5 * (out["setup"].full_block.t[-1] - out["setup"].full_block.t[0]))
    assert 0 <= iso.t - t_fault <= 0.3
    assert faulty["n_active"][-1] == 11
    assert out["png"] is None and not list(Path(tmp_path).glob("*.png"))
