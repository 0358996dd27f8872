"""Issue 32: the MIMU4444 journey of docs/real-units.md, from the command line, on every shared run (skipped when
the data is absent), with 0.1 s averages and at the full 62.5 Hz.

The commands are read from the documentation (the fenced block after ``<!-- mimu4444 journey -->``), the log and
the output names put in, ``--average`` set to the rate under test, and the ``--inject`` options built as the
page says (one 1 deg/s bias for 2 s per triad, on the axis ``triad % 3``, 1 s into the spans at rest of the
held-out half that setup's JSON lists). Fit on the first half (``--fit-window :50%``), judged on the second:

* fault-free: the replay ends nominal, every gyro active, no isolation; the alarm rate at rest of the held-out
  half is at most twice the design rate (p_fa 0.1 %);
* every 1 deg/s bias is isolated on its own sensor within 1 s of its onset;
* the accelerometers too (issue 32): fault-free no isolation, nominal, rest alarm rate at most twice the design
  rate; a 0.3 m/s^2 bias per triad at rest in the held-out half isolated on its own sensor within 1 s (no case
  is excused: exp_6 and exp_9 at 0.1 s alarmed on 0.24 % and 0.23 % at rest, and imu4's x accelerometer was not
  isolated within 1 s at 62.5 Hz on exp_5, exp_6 and exp_9, until the setup stated the offset at a new pose and
  the window gains below 1 were kept; docs/real-units.md);
* the PX4-style rule on the same samples flags no triad within the faults (its dead band is 7 deg/s); its
  smallest flagged bias, from 5, 7.5, 10 and 15 deg/s for 10 s later in the same replay (full rate only: the
  rule is a full-rate rule), is printed beside it.
"""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from rimu.cli import main
from tests.conftest import ROOT, shared_data

RUNS = ["exp_5", "exp_6", "exp_7", "exp_8", "exp_9"]
DEG = np.pi / 180.0
#: the accelerometer fault, m/s^2 (0.03 g): about 15 sigma of the noisiest accelerometer per 0.1 s (exp_5's setup:
#: 0.013-0.026 m/s^2), chosen on exp_5 (0.1 m/s^2, 5 sigma there, was isolated within 1 s on 5 of 8 triads)
ACCEL_BIAS = 0.3


def _documented() -> list[list[str]]:
    """The journey's commands as docs/real-units.md shows them (``rimu`` dropped, continuation lines joined)."""
    text = (ROOT / "docs" / "real-units.md").read_text()
    block = text.split("<!-- mimu4444 journey -->", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    lines = [ln.strip() for ln in block.replace("\\\n", " ").splitlines()]
    return [shlex.split(ln)[1:] for ln in lines if ln.startswith("rimu ")]


def _put(cmd: list[str], files: dict[str, str], average: str) -> list[str]:
    out = [files.get(a, a) for a in cmd]
    if "--average" in out:
        out[out.index("--average") + 1] = average
    while "--inject" in out:  # the page's example fault: the test places its own
        i = out.index("--inject")
        del out[i:i + 2]
    return out


def _slots(setup: dict, lengths: list[float]) -> list[float]:
    """Onsets (s) of faults lasting ``lengths`` (s), in turn, 1 s into the spans at rest of the held-out half,
    each followed by 1 s at rest before the next."""
    half = setup["fit_window_s"][1]
    spans = [s for s in setup["rest_spans_s"] if s[0] >= half]
    out: list[float] = []
    for a, b in spans:
        t = a + 1.0
        while len(out) < len(lengths) and t + lengths[len(out)] + 0.5 <= b:
            out.append(round(t, 3))
            t += lengths[len(out) - 1] + 1.0
    assert len(out) == len(lengths), (lengths, spans)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("average", ["0.1", "0"])
@pytest.mark.parametrize("run", RUNS)
def test_the_documented_journey(run, average, tmp_path, capsys):
    log = shared_data("mimu4444_array", f"{run}.bin.xz") / f"{run}.bin.xz"
    setup_cmd, free_cmd, fault_cmd = _documented()
    files = {"exp_5.bin.xz": str(log), "unit.json": str(tmp_path / "unit.json"),
             "unit.npz": str(tmp_path / "unit.npz"), "setup.json": str(tmp_path / "setup.json"),
             "replay.json": str(tmp_path / "replay.json"), "faults.json": str(tmp_path / "faults.json")}
    assert main(_put(setup_cmd, files, average)) == 0
    setup = json.loads((tmp_path / "setup.json").read_text())
    half = setup["fit_window_s"][1]
    names = setup["imus"]

    # fault-free: no isolation, every gyro active at the end, the rest alarm rate of the held-out half
    assert main(_put(free_cmd, files, average)) == 0
    free = json.loads((tmp_path / "replay.json").read_text())
    rest_rate = {}
    for inst in ("gyro", "accel"):                    # both instruments (issue 32: the accelerometers too)
        g = free[inst]
        kinds = {e["kind"] for e in g["events"]}
        assert g["isolations"] == 0 and "isolated" not in kinds and "invalid_isolated" not in kinds, inst
        # the manager's state at the end and the sensors isolated then (on exp_6 the accelerometers' final_state,
        # the last sample's state, reads fault_isolated although nothing was isolated and the manager ends nominal)
        assert g["final_state"] == "nominal" and g["isolated_at_end"] == [], inst
        held = [s for s in g["segments"] if s["kind"] == "static_unknown" and s["t_start_s"] >= half]
        a, n = sum(s["alarms"] for s in held), sum(s["samples"] for s in held)
        assert n > 1000, (inst, n)
        assert a / n <= 2e-3, (inst, a, n)
        rest_rate[inst] = (a, n)
    a, n = rest_rate["gyro"]

    # a 1 deg/s bias on one sensor of each triad, at rest in the held-out half; at the full rate (where the PX4
    # rule runs), then 5, 7.5, 10 and 15 deg/s for 10 s on the x gyros of the first four triads
    sizes = [5.0, 7.5, 10.0, 15.0] if average == "0" else []
    # the accelerometer faults 2 s each, then 4 s at rest (the previous triad re-admitted before the next fault:
    # a single fault each; with 1 s, a 62.5 Hz bias on imu4 while imu3 was still out alarmed 57 times unconfirmed)
    slots = _slots(setup, [2.0] * 8 + [5.0] * 8 + [10.0] * len(sizes))
    onsets, a_onsets, grid_on = slots[:8], slots[8:16], slots[16:]
    sensors = [f"{names[j]}_{'xyz'[j % 3]}" for j in range(8)]
    inject = [f"--inject=bias:gyro:{s}:{t}:{DEG:.9g}:2" for s, t in zip(sensors, onsets)]
    inject += [f"--inject=bias:accel:{s}:{t}:{ACCEL_BIAS}:2" for s, t in zip(sensors, a_onsets)]
    inject += [f"--inject=bias:gyro:{names[j]}_x:{t}:{v * DEG:.9g}:10" for j, (v, t) in enumerate(zip(sizes, grid_on))]
    assert main(_put(fault_cmd, files, average) + inject) == 0
    doc = json.loads((tmp_path / "faults.json").read_text())
    a_delays = []
    for s, t in zip(sensors, a_onsets):                # the accelerometer bias, on its own sensor within 1 s
        first = [e for e in doc["accel"]["events"] if e["kind"] == "isolated" and t <= e["t"] < t + 2.0]
        assert first and first[0]["sensor"] == s and first[0]["t"] - t <= 1.0, (s, t, first[:2])
        a_delays.append(first[0]["t"] - t)
    ev = doc["gyro"]["events"]
    delays = []
    for s, t in zip(sensors, onsets):
        first = [e for e in ev if e["kind"] == "isolated" and t <= e["t"] < t + 2.0]
        assert first and first[0]["sensor"] == s and first[0]["t"] - t <= 1.0, (s, t, first[:2])
        delays.append(first[0]["t"] - t)
    px4 = doc["px4"]["flags"]
    assert not [f for f in px4 if any(t <= f["t"] < t + 2.0 for t in onsets)], px4
    line = f"{run} at {'62.5 Hz' if average == '0' else average + ' s averages'}: rest alarms {1e2 * a / n:.3g} % " \
           f"of {n} held-out samples; 1 deg/s isolated in {min(delays):.3g}-{max(delays):.3g} s on 8 of 8 triads; " \
           "PX4-style rule: none flagged; accelerometers: rest alarms " \
           f"{1e2 * rest_rate['accel'][0] / rest_rate['accel'][1]:.3g} % of {rest_rate['accel'][1]}, {ACCEL_BIAS} m/s^2 " \
           f"isolated in {min(a_delays):.3g}-{max(a_delays):.3g} s on 8 of 8 triads"
    if sizes:
        hit = [v for j, (v, t) in enumerate(zip(sizes, grid_on))
               if any(f["triad"] == names[j] and t <= f["t"] < t + 10.0 for f in px4)]
        assert 5.0 not in hit                       # the rule's dead band: nothing below 7 deg/s
        line += f" (smallest it flags within 10 s: {min(hit, default=float('nan')):g} deg/s)"
    with capsys.disabled():
        print("\n  " + line)
