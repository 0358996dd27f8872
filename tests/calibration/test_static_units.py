"""Issue 32, Done-when "a static recording of several units": the setup finds their relative attitude from
gravity within its stated uncertainty, or refuses with the reason; a zero accelerometer vector is invalid.

Simulated static recordings of units with gyro biases up to 5 deg/s (above the setup's 0.05 rad/s = 2.9 deg/s
motion threshold, where the first setup aligned biases as if they were motion: 23-177 deg between units lying
level within 2 deg):

* ten level units (one direction of gravity): refused, the reason naming the missing motion and the single
  direction of gravity, never a rotation;
* four units in two poses (gravity in two directions), eight seeds: every rotation within 4 of its stated
  sigma per axis, and the normalised errors over 8 x 3 triads x 3 axes have an rms in [0.5, 1.6] (stated
  uncertainty neither hidden nor inflated; 72 values: the rms of a unit normal sample lies in [0.84, 1.16] with
  probability 0.99, widened for the estimated residual scale);
* a zero accelerometer vector in the middle of one triad's record is invalid in both of that triad's
  instruments at that sample and nowhere else; a vector of 1e-3 m/s^2 (not exactly zero) stays valid.
"""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration.alignment import rotvec_of
from rimu.calibration.multi_imu import setup_multi_imu
from rimu.errors import IdentifiabilityError
from rimu.io.multiimu import ImuStream, MultiImuRecording
from rimu.session.model import rotation_matrix
from rimu.units import DEG_TO_RAD, G0

RATE = 62.5


def _static(seed, k, poses, tilt_deg, bias_dps=5.0, rest_s=30.0):
    """k units at rest in ``poses`` (rotations of the whole unit, MB), handled for 2 s between poses."""
    rng = np.random.default_rng(seed)
    rots = [np.eye(3)] + [rotation_matrix(np.radians(rng.uniform(-tilt_deg, tilt_deg, 3))) for _ in range(k - 1)]
    biases = [rng.uniform(-bias_dps, bias_dps, 3) * DEG_TO_RAD for _ in range(k)]
    n_rest, n_move = int(rest_s * RATE), int(2.0 * RATE)
    f_mb, w_mb = [], []
    for p, P in enumerate(poses):
        f_mb.append(np.tile(P @ [0.0, 0.0, G0], (n_rest, 1)))
        w_mb.append(np.zeros((n_rest, 3)))
        if p < len(poses) - 1:                                   # handling: not rest, not a usable turn either
            f_mb.append(np.tile(P @ [0.0, 0.0, G0], (n_move, 1)) + 4.0)
            w_mb.append(np.full((n_move, 3), 0.4))
    f_mb, w_mb = np.vstack(f_mb), np.vstack(w_mb)
    t = np.arange(len(f_mb)) / RATE
    units = []
    for j in range(k):
        g = w_mb @ rots[j].T + biases[j] + 0.15 * DEG_TO_RAD * rng.normal(size=w_mb.shape)
        a = f_mb @ rots[j].T + 0.03 * rng.normal(size=f_mb.shape)
        units.append(ImuStream(f"u{j}", t.copy(), g, a))
    return MultiImuRecording(units, {}), rots


def test_ten_level_units_with_large_biases_are_refused_with_the_reason():
    rec, _ = _static(seed=11, k=10, poses=[np.eye(3)], tilt_deg=2.0, rest_s=40.0)
    with pytest.raises(IdentifiabilityError) as exc:
        setup_multi_imu(rec, average_s=None)
    msg = str(exc.value)
    assert "no motion in the fit window" in msg and "measured from the bias at rest" in msg
    assert "one direction" in msg and "align_axes=False" in msg


def test_two_poses_give_the_attitude_within_its_stated_uncertainty():
    poses = [np.eye(3), rotation_matrix(np.radians([90.0, 0.0, 0.0]))]
    z = []
    for seed in range(8):
        rec, rots = _static(seed, k=4, poses=poses, tilt_deg=4.0)
        su = setup_multi_imu(rec, average_s=None)
        assert len(su.alignments) == 3
        for j, a in enumerate(su.alignments, start=1):
            phi = rotvec_of(rots[j] @ a.mat_unit_ref.T)
            s = np.sqrt(np.diag(a.covariance))
            assert np.all(np.abs(phi) < 4 * s), (seed, j, phi / s)
            assert np.degrees(np.linalg.norm(phi)) < 0.5          # against 23-177 deg before
            z.append(phi / s)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.5 <= rms <= 1.6, rms


def test_a_zero_accelerometer_vector_is_invalid_where_it_is():
    rec, _ = _static(seed=3, k=3, poses=[np.eye(3), rotation_matrix(np.radians([0.0, 90.0, 0.0]))], tilt_deg=3.0)
    u = rec.units[1]
    i_zero, i_tiny = 700, 900
    u.accel[i_zero] = 0.0
    u.accel[i_tiny] = [1e-3, 0.0, 0.0]
    su = setup_multi_imu(rec, average_s=None)
    b = su.full_block
    assert b.meta["placeholder_samples"] == 1
    for inst in ("gyro", "accel"):
        v = b.valid[inst]
        assert not v[i_zero, 3:6].any()                          # the placeholder triad, both instruments
        assert v[i_zero, :3].all() and v[i_zero, 6:].all()       # the others keep the sample
        assert v[i_tiny].all()                                   # not exactly zero: a measurement
