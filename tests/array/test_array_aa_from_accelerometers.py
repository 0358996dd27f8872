"""The angular acceleration taken per epoch from the accelerometers themselves (Skog et al. 2016, Sec. II), the
last accelerometer step of ``rimu array`` (issue 32): known truth on a simulated rigid body whose angular
acceleration is not in the gyro samples."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.array import aa_from_accelerometers_refusal, accel_angular_acceleration, skew
from rimu.errors import IdentifiabilityError

SIGMA = 0.05  # m/s^2 per accelerometer axis


def _body(k: int, n: int, rng: np.random.Generator):
    """k triads at random positions (+-30 mm), a random rate (up to ~20 rad/s) and an angular acceleration per
    epoch independent of it (white, 300 rad/s^2 rms: what coarse gyro samples cannot give), specific force s."""
    r = rng.uniform(-0.03, 0.03, (k, 3))
    r -= r.mean(axis=0)
    w = rng.normal(0, 12.0, (n, 3))
    wd = rng.normal(0, 300.0, (n, 3))
    s = rng.normal(0, 20.0, (n, 3)) + [0, 0, 9.81]
    W = skew(w)
    f = s[:, None] + np.einsum("nab,kb->nka", W @ W, r) + np.cross(wd[:, None], r[None])
    return r, w, wd, f + rng.normal(0, SIGMA, f.shape)


@pytest.mark.parametrize("k", [4, 5, 6, 8])
def test_recovers_angular_acceleration_within_its_covariance_and_leaves_white_noise(k):
    rng = np.random.default_rng(100 + k)
    n = 4000
    r, w, wd, f = _body(k, n, rng)
    out = accel_angular_acceleration(f, w, r, sigma_m_s2=SIGMA)
    assert out["dof"] == 3 * k - 6
    # normalised error of w' per epoch against its least-squares covariance: chi-square with 3 dof per epoch
    err = out["angular_acceleration_rad_s2"] - wd
    P = np.linalg.inv(out["covariance"][3:, 3:])
    nees = np.einsum("ni,ij,nj->n", err, P, err)
    assert 0.8 < np.sqrt(nees.mean() / 3) < 1.25, np.sqrt(nees.mean() / 3)
    # the parity per dof is the accelerometers' sigma (within 5 %), and the scaled per-triad figure is what the
    # plain model's parity (each triad minus the array mean) gives on noise alone: sigma sqrt((k - 1)/k)
    assert abs(out["per_dof_m_s2"] / SIGMA - 1) < 0.05, out["per_dof_m_s2"]
    plain = SIGMA * np.sqrt((k - 1) / k)
    assert np.all(np.abs(out["parity_rms_m_s2"] / plain - 1) < 0.05), out["parity_rms_m_s2"] / plain
    # the plain model given the true w' (noise only left) agrees with the extended one like for like
    W = skew(w)
    e = f - np.einsum("nab,kb->nka", W @ W, r) - np.cross(wd[:, None], r[None])
    y = e - e.mean(axis=1, keepdims=True)
    assert abs(np.sqrt(np.mean(y**2)) / np.sqrt(np.mean(out["parity_rms_m_s2"] ** 2)) - 1) < 0.05
    # the returned parity is white: its lag-1 autocorrelation within 4/sqrt(N) of zero on every component
    p = out["parity_m_s2"].reshape(n, 3 * k)
    assert np.abs(p.reshape(n, k, 3).sum(axis=1)).max() < 1e-9      # in the left null space of H: sum_j e_j = 0
    rho = np.sum(p[1:] * p[:-1], axis=0) / np.sum(p**2, axis=0)
    assert np.abs(rho).max() < 4 / np.sqrt(n), rho


def test_the_gyros_central_difference_leaves_far_more():
    """The same body sampled coarsely: the angular acceleration from the gyro samples' central difference misses the
    per-epoch one, and the plain parity with it is far above the accelerometers' noise."""
    rng = np.random.default_rng(7)
    r, w, _wd, f = _body(6, 2000, rng)
    wd_cd = np.gradient(w, 0.016, axis=0)
    W = skew(w)
    e = f - np.einsum("nab,kb->nka", W @ W, r) - np.cross(wd_cd[:, None], r[None])
    plain = np.sqrt(np.mean((e - e.mean(axis=1, keepdims=True)) ** 2))
    own = np.sqrt(np.mean(accel_angular_acceleration(f, w, r)["parity_rms_m_s2"] ** 2))
    assert plain > 20 * own and abs(own / (SIGMA * np.sqrt(5 / 6)) - 1) < 0.08


@pytest.mark.parametrize("r, word", [(np.array([[0.0, 0, 0], [0.02, 0, 0]]), "3 triads at least"),
                                     (np.array([[0.0, 0, 0], [0.01, 0, 0], [0.03, 0, 0]]), "one line")])
def test_refused_where_not_identifiable(r, word):
    assert word in aa_from_accelerometers_refusal(r)
    with pytest.raises(IdentifiabilityError, match=word):
        accel_angular_acceleration(np.zeros((5, len(r), 3)), np.zeros((5, 3)), r)
    assert aa_from_accelerometers_refusal(np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]])) is None


def test_never_worse_on_the_held_out_half():
    """The step is taken out, with the figures, where it raises the held-out parity; kept where it lowers it."""
    from rimu.array.report import AA_STEP, _aa_held_out_rule

    for after, kept in ((np.array([0.9, 1.1]), True), (np.array([1.2, 1.3]), False)):
        steps = {"raw": np.array([8.0, 8.0]), "+ positions": np.array([4.0, 4.0]), AA_STEP: np.array([1.0, 1.0])}
        held = {"raw": np.array([8.0, 8.0]), "+ positions": np.array([1.1, 1.1]), AA_STEP: after}
        refused: dict = {}
        _aa_held_out_rule(steps, held, refused)
        assert (AA_STEP in steps) == kept and (AA_STEP in held) == kept and (AA_STEP in refused) != kept
    assert "from 1.1 to 1.25 m/s^2" in refused[AA_STEP]


def test_an_intermediate_step_that_raises_the_held_out_parity_is_reported():
    """A step between two others that raises the held-out parity (beyond the 1e-3 tolerance) gets a note with both
    figures and the whole chain's; one within the tolerance, or one that lowers it, gets none."""
    from rimu.array.report import _held_out_raises

    ho = {"raw": np.array([8.0, 8.2]), "+ a": np.array([4.0, 4.0]), "+ b": np.array([4.1, 4.1]),
          "+ c": np.array([1.5, 1.5])}
    notes = _held_out_raises(ho, "m/s^2")
    assert len(notes) == 1 and "'+ b'" in notes[0] and "4 to 4.1 m/s^2" in notes[0] and "8.1 -> 1.5" in notes[0]
    ho["+ b"] = np.array([4.002, 4.002])
    assert _held_out_raises(ho, "m/s^2") == []
