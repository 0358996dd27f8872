"""`rimu setup`: the noise figures it prints, parsed with their unit and converted, equal the closed-form truth
(issue 27). Two IMUs of a log in SI see the same motion plus white noise of known sigma (0.01 rad/s, 0.05 m/s^2);
the disagreement gives each sensor's noise: sigma / sqrt(n) per epoch of the n-sample averages the label states,
sigma itself without averaging (``--average 0``). Tolerance: the estimate's relative sd 1/sqrt(2 (epochs - 1)),
five of them.
"""

from __future__ import annotations

import math
import re

import numpy as np

from rimu.cli import main
from tests.cli.test_figures_per_command import to_si

SIG = {"rate": 0.01, "specific_force": 0.05}


def test_setup_prints_the_noise_of_its_epochs_in_their_unit(tmp_path, capsys):
    rng = np.random.default_rng(0)
    n = 3000
    t = np.arange(n) / 100.0
    w = np.column_stack([np.sin(2 * t), np.cos(3 * t), 0.5 * np.sin(t)])
    parts = [t]
    for _ in range(2):
        parts += [w + SIG["rate"] * rng.standard_normal(w.shape),
                  [0, 0, 9.81] + SIG["specific_force"] * rng.standard_normal(w.shape), np.full(n, 30.0)]
    cols = ["t_s"] + [f"imu{k}_{q}" for k in (0, 1) for q in ("gx", "gy", "gz", "ax", "ay", "az", "tempC")]
    np.savetxt(tmp_path / "px.csv", np.column_stack(parts), delimiter=",", header=",".join(cols), comments="",
               fmt="%.6f")
    for average, n_avg in (("0.1", 10), ("0", 1)):
        assert main(["setup", str(tmp_path / "px.csv"), "-o", str(tmp_path / "cal.json"), "--average", average]) == 0
        out = capsys.readouterr().out
        for inst, q in (("gyro", "rate"), ("accel", "specific_force")):
            m = re.search(rf"{inst} noise per sensor \((\S+?)(?:, per epoch of the (\d+)-sample averages.*?)?\): "
                          r"([-\d.e+ ]+?)(?:  \(|\n)", out)
            assert m, out
            assert int(m.group(2) or 1) == n_avg, m.group(0)
            got = np.array([to_si(float(v), m.group(1), q) for v in m.group(3).split()])
            assert len(got) == 6
            truth = SIG[q] / math.sqrt(n_avg)
            tol = 5 / math.sqrt(2 * (n // n_avg - 1))
            np.testing.assert_allclose(got, truth, rtol=tol, err_msg=f"{inst} --average {average}")
