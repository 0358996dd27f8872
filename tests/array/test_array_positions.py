"""Accelerometer positions, gains and biases from motion (Carlsson et al. 2021) against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.array import ArrayLayout, crb, fit_positions, fit_relative_gyro, ml_motion
from rimu.sim.array import random_array_truth, simulate_array


def _truth_in_gauge(lay, tr, true_pos):
    """Mean accelerometer scale exact (scales positions), sum of biases zero, mean position = mean nominal."""
    R = lay.rotations
    Db = np.einsum("kij,kjl,kml->kim", R, tr.accel_gain, R)
    cb = np.einsum("kij,kj->ki", R, tr.accel_bias_m_s2)
    eps = np.trace(Db.mean(axis=0)) / 3 - 1
    D = Db / (1 + eps)
    r = true_pos * (1 + eps)
    c = cb - D @ np.linalg.solve(D.sum(axis=0), cb.sum(axis=0))
    r = r - r.mean(axis=0) + lay.positions_m.mean(axis=0)
    return np.hstack([(D - np.eye(3)).reshape(-1, 9), c, r])


@pytest.mark.parametrize("rows, cols, duration", [(2, 2, 3.0), (4, 4, 1.0)])
def test_positions_gains_biases_within_three_sigma(rows, cols, duration):
    lay = ArrayLayout.planar_grid(rows, cols, pitch_m=0.01, two_sided=True)
    rng = np.random.default_rng(5)
    true_pos = lay.positions_m + rng.normal(0, 3e-4, lay.positions_m.shape)   # 0.3 mm placement error
    tr = random_array_truth(lay.with_positions(true_pos), seed=5, centre_gyro_common_mode=True)
    rec = simulate_array(tr, duration_s=duration, seed=5)
    gf = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", "sampling_offset"),
                           candidates=None)
    pf = fit_positions(lay, rec.t, rec.accel, gf, rec.gyro)
    truth = _truth_in_gauge(lay, tr, true_pos)
    z = (pf.vector() - truth) / pf.std()
    assert 0.8 < np.sqrt(np.mean(z**2)) < 1.25
    assert np.abs(z).max() < 3.5 and np.mean(np.abs(z) > 3) < 0.01
    np.testing.assert_allclose(pf.sigma_m_s2 / tr.accel_noise_m_s2, 1.0, atol=0.1)
    # positions land within tens of micrometres of the truth (in the gauge: the mean accelerometer scale, here
    # about 0.3 %, scales them); the nominal ones were 0.3 mm off
    assert pf.position_std_m().max() < 60e-6
    assert np.abs(pf.positions_m - truth[:, 12:15]).max() < 0.2e-3
    assert np.abs(pf.offset_from_nominal_m()).max() > 0.5e-3
    # each step lowers the accelerometer parity rms in motion
    p = {k: v.mean() for k, v in pf.parity_rms_m_s2.items()}
    assert p["raw"] > p["raw_nominal_lever_arms"] > p["gain_bias_nominal_lever_arms"] > p["positions"]
    assert p["positions"] < 1.1 * np.sqrt(np.mean(tr.accel_noise_m_s2**2))
    # end to end: the self-calibrated array at runtime, its ML angular rate and acceleration at the bound
    m = ml_motion(pf.layout, pf.apply(rec.t, rec.accel), gf.apply(rec.t, rec.gyro), pf.sigma_m_s2, gf.sigma_rad_s)
    inner = slice(20, -20)
    bound = crb(rec.omega[inner], pf.positions_m, gf.sigma_rad_s, pf.sigma_m_s2)
    for sl, truth_x in ((slice(0, 3), rec.omega), (slice(3, 6), rec.omega_dot)):
        err = (np.column_stack([m.omega, m.omega_dot])[:, sl] - truth_x)[inner]
        ratio = np.sqrt(np.mean(err**2, axis=0) / bound[:, sl, sl].diagonal(axis1=1, axis2=2).mean(axis=0))
        assert np.all(np.abs(ratio - 1) < 0.1), ratio


def test_accelerometer_sampling_offsets_of_separate_chips():
    """Accelerometers on their own time: their offsets (relative to their mean) from the motion, within 3 sigma."""
    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.01, two_sided=True)
    rng = np.random.default_rng(7)
    true_pos = lay.positions_m + rng.normal(0, 3e-4, lay.positions_m.shape)
    tr = random_array_truth(lay.with_positions(true_pos), seed=7, centre_gyro_common_mode=True,
                            sampling_offset_sigma_s=1e-3)
    rec = simulate_array(tr, duration_s=2.0, seed=7)
    gf = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", "sampling_offset"),
                           candidates=None)
    pf = fit_positions(lay, rec.t, rec.accel, gf, rec.gyro, align=False, offsets=True)
    truth = np.hstack([_truth_in_gauge(lay, tr, true_pos),
                       (tr.sampling_offset_s - tr.sampling_offset_s.mean())[:, None]])
    z = (pf.vector() - truth) / pf.std()
    assert 0.8 < np.sqrt(np.mean(z**2)) < 1.25 and np.abs(z).max() < 3.5
    assert np.abs(pf.accel_offset_s).max() > 10 * pf.std()[:, 15].max()     # offsets of ~1 ms, seen clearly
    # compensation moves every triad onto the array's time
    f = pf.apply(rec.t, rec.accel)
    assert f.shape == rec.accel.shape and np.all(np.isfinite(f))
