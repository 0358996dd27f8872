"""The hand-held gyro fit's component-plane quaternion helpers: bit-identical to quat_mul, quat_exp and
quat_to_matrix (the forms the fit used before), and those against scipy's Rotation (an independent
implementation)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from rimu.calibration.handheld import _qexp_planar, _qmat_planar, _qmul_planar, quat_exp, quat_mul, quat_to_matrix


def _planar(x):
    return np.ascontiguousarray(np.moveaxis(x, -1, 0))


def test_planar_helpers_equal_the_interleaved_ones_bit_for_bit():
    rng = np.random.default_rng(3)
    rv = rng.normal(0, 0.02, (7, 32, 3))
    rv[0, :5] = 0.0  # the small-angle branch
    rv[1, :5] = 1e-13
    q = quat_exp(rv)
    assert np.array_equal(np.moveaxis(_qexp_planar(_planar(rv)), 0, -1), q)
    p = quat_exp(rng.normal(0, 1.0, (7, 32, 3)))
    assert np.array_equal(np.moveaxis(_qmul_planar(_planar(p), _planar(q)), 0, -1), quat_mul(p, q))
    assert np.array_equal(_qmat_planar(_planar(p)), quat_to_matrix(p))
    # strided views (the pairwise and suffix products of the fit use them)
    assert np.array_equal(np.moveaxis(_qmul_planar(_planar(p)[:, :, 0::2], _planar(p)[:, :, 1::2]), 0, -1),
                          quat_mul(p[:, 0::2], p[:, 1::2]))


def test_quaternion_helpers_agree_with_scipy_rotation():
    rng = np.random.default_rng(4)
    rv = rng.normal(0, 1.0, (50, 3))
    q = quat_exp(rv)
    ref = Rotation.from_rotvec(rv)
    assert np.allclose(quat_to_matrix(q), ref.as_matrix(), atol=1e-14)
    rv2 = rng.normal(0, 1.0, (50, 3))
    assert np.allclose(quat_to_matrix(quat_mul(q, quat_exp(rv2))), (ref * Rotation.from_rotvec(rv2)).as_matrix(),
                       atol=1e-14)
