"""The accelerometers' parity check at rest (rimu.experiments.static_quality): chi-square under a correct calibration,
and it fails on a miscalibrated one."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.errors import SessionFormatError
from rimu.experiments.static_quality import static_parity_quality
from rimu.geometry import triad3
from rimu.sim import Simulator, cho_park_table1


def test_statistic_is_chi_square_with_the_true_calibration():
    """With the true coefficients and noise the statistic of each static segment is chi2(n - 3): mean n - 3 = 3
    for cone6 (50 segments: the mean's std is sqrt(6 / 50) = 0.35)."""
    stats = []
    for seed in range(5):
        run = Simulator(seed=seed).run(cho_park_table1(duration=2.0))
        rep = static_parity_quality(run.session, run.truth["accel"], p_fa=1e-3)
        assert rep.dof == 3 and rep.good
        stats += [s.statistic for s in rep.segments]
    assert len(stats) == 50
    assert 3 - 3 * 0.35 < np.mean(stats) < 3 + 3 * 0.35
    assert 6 * 0.5 < np.var(stats) < 6 * 2.0          # chi2(3) variance 2 dof = 6


def test_a_scale_error_fails_and_shows_where():
    run = Simulator(seed=3).run(cho_park_table1(duration=2.0))
    cal = run.truth["accel"]
    cal.scale[0] *= 1 + 5e-4                           # 500 ppm on x1
    rep = static_parity_quality(run.session, cal, p_fa=1e-3)
    assert not rep.good and "BAD" in rep.summary()
    # the misfit is the scale error times x1's output (gravity along its axis and its raw offset alike),
    # q = v_c[:, 0] dSF/SF (SF y_x1), up to the noise of the means: the remainder is chi2(3) again
    from scipy.stats import chi2

    from rimu.geometry import null_space_rows

    vc = null_space_rows(cal.axes_mb())
    remainders = []
    for s, seg in zip(rep.segments, run.session.segments):
        y = seg.raw["accel"]
        pred = vc[:, 0] * 5e-4 * np.mean(y[:, 0]) * cal.scale[0] / (1 + 5e-4)
        C = (vc * cal.noise_sigma**2 / len(y)) @ vc.T
        r = s.parity - pred
        remainders.append(float(r @ np.linalg.solve(C, r)))
    assert max(remainders) < chi2.isf(1e-3 / len(remainders), 3)
    assert min(s.statistic for s in rep.segments) > 5 * np.mean(remainders)


def test_a_triad_has_no_parity_space():
    run = Simulator({"gyro": triad3(), "accel": triad3()}, seed=0).run(cho_park_table1(duration=1.0))
    with pytest.raises(SessionFormatError, match="no parity space"):
        static_parity_quality(run.session, run.truth["accel"])
