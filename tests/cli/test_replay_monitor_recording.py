"""rimu replay reads the recordings rimu monitor writes (``# rimu epochs v1`` CSV, no sidecar) and decides on them
as rimu monitor does: the same estimates and decisions on every epoch, invalid samples included."""

from __future__ import annotations

import numpy as np

from rimu.calibration import ChoPark
from rimu.cli import main
from rimu.io.recorded import write_csv
from rimu.sim import Simulator, cho_park_procedure


def test_replay_of_a_monitor_recording_decides_as_monitor(tmp_path, capsys):
    run = Simulator(seed=4).run(cho_park_procedure(duration=4.0))
    cal = tmp_path / "cal.json"
    ChoPark().fit(run.session).to_calibration().save(cal)
    block = run.block
    raw = {k: np.array(v, dtype=float) for k, v in block.raw.items()}
    n = len(block.t)
    raw["gyro"][n // 3:n // 3 + 40, 1] += 2000.0       # a large step on one gyro: isolated
    raw["gyro"][n // 2:n // 2 + 25, :] = np.nan         # every gyro without data for 25 epochs: unobservable
    raw["accel"][n // 4, 2] = np.inf                    # one non-finite cell: that sample invalid, the epoch kept
    rec = tmp_path / "rec.csv"
    write_csv(rec, type(block)(block.t, raw, {}, block.temperature))
    assert main(["monitor", "--csv", str(rec), "--calibration", str(cal), "--estimates", str(tmp_path / "m.csv")]) == 0
    assert main(["replay", str(rec), "--calibration", str(cal), "-o", str(tmp_path / "out"),
                 "--estimates", str(tmp_path / "r.csv")]) == 0
    a, b = _read(tmp_path / "m.csv"), _read(tmp_path / "r.csv")
    assert list(a) == list(b) and len(a["t"]) == len(b["t"]) == n
    for name in a:
        x, y = a[name], b[name]
        if name.endswith("_isolated"):
            assert x == y, name
        else:
            x, y = np.array(x, dtype=float), np.array(y, dtype=float)
            assert np.array_equal(np.isnan(x), np.isnan(y)), name
            np.testing.assert_allclose(x[~np.isnan(x)], y[~np.isnan(y)], rtol=0, atol=1e-12, err_msg=name)
    gx = np.array(a["gyro_x"], dtype=float)
    assert np.isnan(gx[n // 2 + 2:n // 2 + 20]).all()    # nothing observable: NaN, never a plausible zero
    assert any(a["gyro_isolated"])                         # the step was isolated, in both


def _read(path):
    import csv

    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: [r[k] for r in rows] for k in rows[0]}
