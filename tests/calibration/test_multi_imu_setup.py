"""Setting up a unit of triads from its own recording: a simulated unit with its own clocks, mountings, bias
differences and noise levels comes out with each within its stated uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration.alignment import rotvec_of
from rimu.calibration.multi_imu import average_block, setup_multi_imu, triad_noise
from rimu.epoch import EpochBlock
from rimu.errors import ShapeError
from rimu.fdi import RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.io.multiimu import ImuStream, MultiImuRecording
from rimu.session.model import rotation_matrix


def _unit(seed=5, k=3, N=4000, rate=100.0):
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.2, 2.0, (3, 3))
    ph = rng.uniform(0, 2 * np.pi, (3, 3))

    def w(tt):
        return np.column_stack([sum(np.sin(2 * np.pi * f[i, j] * tt + ph[i, j]) for j in range(3)) for i in range(3)])

    offsets = [0.0] + list(rng.uniform(-0.05, 0.05, k - 1))
    rots = [np.eye(3)] + [rotation_matrix(np.radians(rng.normal(0, 4, 3))) for _ in range(k - 1)]
    biases = [np.zeros(3)] + [rng.normal(0, 0.01, 3) for _ in range(k - 1)]
    sig = rng.uniform(0.002, 0.006, k)
    units = []
    t_true = np.arange(N) / rate + 0.3       # every unit samples at the same instants, stamped on its own clock
    for j in range(k):
        t = t_true + offsets[j]
        g = w(t_true) @ rots[j].T + biases[j] + sig[j] * rng.normal(size=(N, 3))
        a = np.tile(rots[j] @ [0, 0, 9.81], (N, 1)) + 0.01 * rng.normal(size=(N, 3))
        units.append(ImuStream(f"u{j}", t, g, a))
    return MultiImuRecording(units, {"own_clocks": True}), offsets, rots, biases, sig


def test_setup_recovers_clocks_axes_biases_and_noise():
    rec, offsets, rots, biases, sig = _unit()
    su = setup_multi_imu(rec, average_s=None)
    assert su.delivering == ["u0", "u1", "u2"]
    assert np.all(np.abs(su.timing.offsets_s - offsets)[1:] < 3 * su.timing.sigmas_s[1:])
    for a, j in zip(su.alignments, (1, 2)):
        phi = rotvec_of(rots[j] @ a.mat_unit_ref.T)
        assert np.all(np.abs(phi) < 3 * np.sqrt(np.diag(a.covariance))), (phi, a.sigma_deg)
        assert np.allclose(a.offsets["rate"], biases[j], atol=3 * 2 * sig.max() / np.sqrt(4000) + 1e-4)
    gyro = su.calibration["gyro"]
    assert np.allclose(gyro.geometry.subunits[1].mat_sb_mb, su.alignments[0].mat_unit_ref)
    s = gyro.noise_sigma.reshape(3, 3)
    # noise from the disagreement: within 10 % of the truth (4000 samples: 2.2 % 1-sigma per level, plus the
    # interpolation error of the resampling at the estimated offsets)
    assert np.allclose(s, sig[:, None], rtol=0.1), (s, sig)
    assert "clock offsets" in su.report() and "rotation u1" in su.report()
    # and the fault-free unit replays without an isolation
    mgr = RedundancyManager(InstrumentPipeline(gyro), p_fa=1e-3, confirm=3)
    res = mgr.run(su.block.raw["gyro"], su.block.valid["gyro"], su.block.t)
    assert not mgr.isolated.any() and res.alarm.mean() < 0.01


def test_average_block_keeps_gaps_invalid():
    t = np.arange(10.0)
    y = np.arange(20.0).reshape(10, 2)
    v = np.ones((10, 2), bool)
    v[3, 1] = False
    b = average_block(EpochBlock(t, {"gyro": y}, {"gyro": v}), 5)
    assert b.t.tolist() == [2.0, 7.0]
    assert b.valid["gyro"].tolist() == [[True, False], [True, True]]
    assert b.raw["gyro"][:, 0].tolist() == [4.0, 14.0] and b.raw["gyro"][0, 1] == 0.0
    with pytest.raises(ShapeError, match="cannot average"):
        average_block(b, 5)


def test_triad_noise_needs_two_triads():
    with pytest.raises(ShapeError, match="two triads"):
        triad_noise(np.zeros((100, 3)))
