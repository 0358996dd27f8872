"""Relative gyro calibration from motion: normalised errors against known truth, ranking, identifiability."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.array import ArrayLayout, fit_relative_gyro, to_array_gauge
from rimu.errors import GeometryError, IdentifiabilityError
from rimu.sim.array import HandheldMotion, random_array_truth, simulate_array


def _truth_vector(lay, tr, with_tau=True):
    R = lay.rotations
    Db = np.einsum("kij,kjl,kml->kim", R, tr.gyro_gain, R)
    cb = np.einsum("kij,kj->ki", R, tr.gyro_bias_rad_s)
    D, c, tau, _ = to_array_gauge(Db, cb, tr.sampling_offset_s)
    parts = [(D - np.eye(3)).reshape(-1, 9), c] + ([tau[:, None]] if with_tau else [])
    return np.hstack(parts)


@pytest.mark.parametrize("rows, cols, duration, seed", [(2, 2, 4.0, 2), (4, 4, 2.0, 3)])
def test_gain_bias_offset_within_three_sigma(rows, cols, duration, seed):
    """8 and 32 MEMS triads (two-sided board, raw: 1 % scale, 0.3 deg misalignment, 1 deg/s bias, 100 us offsets)."""
    lay = ArrayLayout.planar_grid(rows, cols, pitch_m=0.01, two_sided=True)
    tr = random_array_truth(lay, seed=seed)
    rec = simulate_array(tr, duration_s=duration, seed=seed)
    fit = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", "sampling_offset"))
    z = (fit.vector() - _truth_vector(lay, tr)) / fit.std()
    assert 0.8 < np.sqrt(np.mean(z**2)) < 1.25
    assert np.mean(np.abs(z) > 3) < 0.03 and np.abs(z).max() < 4.0  # 0.27 % expected beyond 3 sigma
    np.testing.assert_allclose(fit.sigma_rad_s / tr.gyro_noise_rad_s, 1.0, atol=0.1)
    # the parity rms in motion falls from degrees per second to the noise
    assert np.all(fit.parity_rms_rad_s["after"] < 0.1 * fit.parity_rms_rad_s["before"])
    assert fit.limiting_term() == "noise"
    # the gauge: relative to the array mean
    np.testing.assert_allclose(fit.gain.mean(axis=0), np.eye(3), atol=1e-12)
    assert abs(fit.sampling_offset_s.mean()) < 1e-12


@pytest.mark.parametrize(
    "effect, kwargs",
    [
        ("sampling_offset", {"sampling_offset_sigma_s": 300e-6}),
        ("aa_sensitivity", {"sampling_offset_sigma_s": 0.0, "aa_sensitivity_sigma_s": 2e-4}),
        ("rate_nonlinearity", {"sampling_offset_sigma_s": 0.0, "nonlinearity_sigma_s_rad": 2e-3}),
        ("g_sensitivity", {"sampling_offset_sigma_s": 0.0, "g_sensitivity_sigma_deg_s_per_g": 0.5}),
    ],
)
def test_ranking_names_the_missing_term(effect, kwargs):
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.01)
    tr = random_array_truth(lay, seed=11, **kwargs)
    rec = simulate_array(tr, duration_s=3.0, seed=11)
    fit = fit_relative_gyro(lay, rec.t, rec.gyro, specific_force=rec.specific_force)
    assert fit.limiting_term() == effect, fit.candidates
    # adding it (with the sampling offset, the isotropic part of a full angular-acceleration sensitivity) leaves
    # the noise; the g-sensitivity regressor is the specific force at the reference point, so the triads' own
    # lever-arm part of it (w' x r_j G) stays as a small angular-acceleration-like remainder
    extra = ("sampling_offset",) if effect == "aa_sensitivity" else ()
    fit2 = fit_relative_gyro(lay, rec.t, rec.gyro, terms=("scale_misalignment", "bias", effect) + extra,
                             specific_force=rec.specific_force)
    if effect != "g_sensitivity":
        assert fit2.limiting_term() == "noise", fit2.candidates
    assert np.mean(fit2.parity_rms_rad_s["after"]) < 0.8 * np.mean(fit.parity_rms_rad_s["after"])


def test_missing_excitation_is_named():
    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.01)
    tr = random_array_truth(lay, seed=1)
    # rotation about z only: scale/misalignment about x and y cannot be identified
    rec = simulate_array(tr, duration_s=1.0, seed=1, motion=HandheldMotion(seed=1))
    gyro = rec.gyro.copy()
    w = np.zeros_like(rec.omega)
    w[:, 2] = rec.omega[:, 2]
    R = lay.rotations
    for j in range(lay.k):
        gyro[:, j] = (w @ R[j]) @ tr.gyro_gain[j].T + tr.gyro_bias_rad_s[j]
    gyro += np.random.default_rng(0).normal(0, 1e-3, gyro.shape)
    with pytest.raises(IdentifiabilityError, match="angular rate about every axis") as ei:
        fit_relative_gyro(lay, rec.t, gyro)
    assert ei.value.parameters == ["scale_misalignment"]
    with pytest.raises(IdentifiabilityError, match="specific_force"):
        fit_relative_gyro(lay, rec.t, rec.gyro, terms=("g_sensitivity",))


def test_a_triad_mounted_otherwise_than_the_layout_says_is_named():
    lay = ArrayLayout.planar_grid(2, 4, pitch_m=0.01)
    tr = random_array_truth(lay, seed=8)
    rec = simulate_array(tr, duration_s=1.0, seed=8)
    gyro = rec.gyro.copy()
    gyro[:, 5, 1:] *= -1          # T6 is turned 180 deg about x on the board, the layout does not say so
    with pytest.raises(GeometryError, match=r"T6: turned 180 deg about body \[\+1\.00 [+-]0\.00 [+-]0\.00\]"):
        fit_relative_gyro(lay, rec.t, gyro)
