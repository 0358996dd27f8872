"""Issue 32: the noise ``rimu setup`` stores is that of the epochs it measured it on (its 0.1 s averages), and a
replay at another rate converts it (white noise: ``sigma sqrt(T_noise / T)``), rather than taking the noise of
10-sample averages as the noise of one sample (sqrt(10) = 3.16 times too small: two thirds of the samples
alarmed: 2598 of 4000). Two IMUs at rest, 100 Hz, white gyro noise of 0.01 rad/s: the per-sample plain GLT (3 parity degrees of
freedom, p_fa 1e-3 per sample) must alarm on about 1e-3 of 4000 samples (Poisson mean 4; the bound 15 has a
probability below 1e-5), and the stored period must round-trip through the unit file.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import main
from rimu.errors import ShapeError
from rimu.geometry import triads


def _log(path, n=4000, sigma=0.01, fs=100.0, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    parts = [t]
    for _ in range(2):
        parts += [sigma * rng.standard_normal((n, 3)), [0, 0, 9.81] + 0.05 * rng.standard_normal((n, 3)),
                  np.full(n, 30.0)]
    cols = ["t_s"] + [f"imu{k}_{q}" for k in (0, 1) for q in ("gx", "gy", "gz", "ax", "ay", "az", "tempC")]
    np.savetxt(path, np.column_stack(parts), delimiter=",", header=",".join(cols), comments="", fmt="%.6f")


def test_a_unit_set_up_on_averages_replays_a_full_rate_log_at_its_design_alarm_rate(tmp_path, capsys):
    log, unit, out = tmp_path / "px.csv", tmp_path / "unit.json", tmp_path / "r.json"
    _log(log)
    assert main(["setup", str(log), "-o", str(unit), "--average", "0.1"]) == 0
    g = Calibration.load(unit)["gyro"]
    assert g.noise_period_s == pytest.approx(0.1)                       # 10 samples of 0.01 s
    np.testing.assert_allclose(g.noise_sigma, 0.01 / math.sqrt(10), rtol=0.2)   # the noise of the averages
    assert main(["replay", str(log), "--calibration", str(unit), "--instrument", "gyro", "--json", str(out)]) == 0
    said = capsys.readouterr().out
    assert "stated for epochs of 0.1 s" in said and "x3.16 per sample" in said, said
    doc = json.loads(out.read_text())["gyro"]
    assert doc["isolations"] == 0
    assert doc["alarms"] <= 15, doc["alarms"]                            # 2598 of 4000 before the conversion


def test_the_noise_period_round_trips_and_converts():
    cal = InstrumentCalibration.nominal("gyro", triads(3), noise_sigma=0.002)
    assert cal.noise_sigma_at(0.01) is cal.noise_sigma                    # no period stated: as it is
    assert "noise_period_s" not in cal.to_dict()                          # old files read and write as before
    cal.noise_period_s = 0.16
    np.testing.assert_allclose(cal.noise_sigma_at(0.016), 0.002 * math.sqrt(10))
    np.testing.assert_allclose(cal.noise_sigma_at(0.16), 0.002)
    again = InstrumentCalibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert again.noise_period_s == 0.16
    with pytest.raises(ShapeError, match="noise_period_s"):
        InstrumentCalibration.nominal("gyro", triads(3)).__class__(
            "gyro", cal.geometry, cal.scale, cal.misalignment, cal.bias, cal.noise_sigma, noise_period_s=-1.0)
