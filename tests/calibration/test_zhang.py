"""Zhang et al. 2010: closed-form steps on exact data, and their Tables 3 and 4 reproduced with fewer runs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root, for benchmarks/

from benchmarks.zhang_tables import PAPER, zhang_mc
from rimu.calibration import Zhang
from rimu.calibration.zhang import lower_factor, platform_frame, solve_ma, wahba, zhang_parameters
from rimu.errors import IdentifiabilityError, SessionFormatError
from rimu.geometry import triad3
from rimu.session import rotation_matrix
from rimu.sim import Simulator, zhang_scheme


def test_lower_factor_is_the_reversed_cholesky():
    rng = np.random.default_rng(0)
    L = np.tril(rng.standard_normal((3, 3))) + 3 * np.eye(3)
    A = lower_factor(L.T @ L)
    assert np.allclose(A, L) and np.allclose(np.triu(A, 1), 0)


def test_solve_ma_recovers_exact_parameters_from_nine_positions():
    """Eq. 12-14 with nine positions (one free direction fixed by det M^A = 0) on noise-free data."""
    rng = np.random.default_rng(1)
    KT = np.tril(rng.normal(0, 0.003, (3, 3)), -1) + np.diag([100.0, 101.0, 99.0])
    b = np.array([0.6, -2.0, -1.0])
    r = np.sqrt(0.5)
    ups = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (r, r, 0), (r, 0, r),
                    (0, r, r)]) * 9.8
    y = ups @ KT.T + b
    A, bb = solve_ma(y, 9.8)
    assert np.allclose(np.linalg.inv(A), KT, rtol=1e-8, atol=1e-8)
    assert np.allclose(bb, b, atol=1e-8)


def test_wahba_recovers_a_rotation():
    R = rotation_matrix(np.array([1e-3, -2e-3, 5e-4]))
    lp = np.array([[1, 0, 0], [0, 1, 0], [0.6, 0.8, 0], [0, 0.6, 0.8]], float)
    assert np.allclose(wahba(lp @ R.T, lp), R)


def test_platform_frame_mapping_is_documented_by_numbers():
    """MB of a Zhang result is the p frame: the accelerometer x axis is MB x and y lies in the x-y plane."""
    g = triad3()
    run = Simulator({"gyro": g, "accel": g}, arw_deg_sqrt_h=0.01, vrw_ug_sqrt_hz=50, seed=4).run(
        zhang_scheme(static_duration=10.0, rotation_duration=36.0))
    cal = Zhang().fit(run.session).to_calibration()
    A = cal["accel"].axes_mb()
    assert np.allclose(A[0], [1, 0, 0]) and abs(A[1, 2]) < 1e-15
    assert np.allclose(platform_frame(cal["accel"]), np.eye(3))
    # the truth, rotated into its own p frame, has the same Zhang parameters as itself (frame-free)
    zt = zhang_parameters(run.truth)
    ze = zhang_parameters(cal)
    assert np.allclose(ze["k_a"], zt["k_a"], rtol=1e-4)
    assert np.all(np.abs(ze["alpha"] - zt["alpha"]) < 3e-5)  # rad, ~6 arcsec at this noise


def test_refuses_non_triads_and_too_few_positions():
    run = Simulator(seed=1).run(zhang_scheme(static_duration=2.0, rotation_duration=36.0))
    with pytest.raises(SessionFormatError, match="triad"):
        Zhang().fit(run.session)
    g = triad3()
    short = Simulator({"gyro": g, "accel": g}, seed=1).run(zhang_scheme(static_duration=2.0, rotation_duration=36.0))
    sub = short.session.subset([s.label for s in short.session.segments if s.label not in ("A7", "A8", "A9")])
    with pytest.raises(IdentifiabilityError) as exc:
        Zhang().fit(sub)
    assert exc.value.parameters


@pytest.mark.parametrize("table", [3, 4])
def test_zhang_tables_reproduced_with_fewer_runs(table):
    """Our Monte Carlo standard deviations are within a factor 1.5 of Zhang's Table 3 / 4, or better
    (pooled over the x, y, z of each parameter group; 10 seeded runs; the benchmark runs 100+)."""
    errs = zhang_mc(table, 10, seed0=100, show=False)
    for k, paper in PAPER[table].items():
        ours = float(np.sqrt(np.mean(errs[k] ** 2)))
        ref = float(np.sqrt(np.mean(np.square(paper))))
        assert ours <= 1.5 * ref, (k, ours, ref)
        assert ours >= 0.25 * ref, (k, ours, ref)  # not suspiciously better: the noise is really simulated
