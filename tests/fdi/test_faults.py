"""Fault types: each one does to the raw column what it says, in SI sizes through the scale factor."""

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.epoch import EpochBlock
from rimu.errors import ShapeError
from rimu.experiments.faults import FAULTS, Injection, inject, parse_injection
from rimu.geometry import cone6

SCALE = 0.002  # SI per count


@pytest.fixture()
def data():
    cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), SCALE, noise_sigma=0.01)})
    t = np.arange(1000) / 100.0
    rng = np.random.default_rng(0)
    Y = 100.0 + 50.0 * np.sin(t)[:, None] + rng.standard_normal((1000, 6))
    return cal, EpochBlock(t, {"gyro": Y})


def _one(cal, blk, kind, size=0.05, start=5.0, duration=None, **params):
    out = inject(blk, [Injection(kind, "gyro", "y1", start, size, False, duration, params)], cal, seed=1)
    return out.raw["gyro"][:, 1], out.valid["gyro"][:, 1], blk.raw["gyro"][:, 1]


def test_each_type(data):
    cal, blk = data
    before = blk.t < 5.0
    y, v, y0 = _one(cal, blk, "bias")
    np.testing.assert_allclose(y[~before] - y0[~before], 0.05 / SCALE)
    np.testing.assert_array_equal(y[before], y0[before])
    y, v, y0 = _one(cal, blk, "ramp", ramp_time=2.0)
    np.testing.assert_allclose((y - y0)[blk.t >= 5.0], 0.05 * (blk.t[blk.t >= 5.0] - 5.0) / 2.0 / SCALE)
    y, v, y0 = _one(cal, blk, "stuck")
    k = int(np.searchsorted(blk.t, 5.0))
    np.testing.assert_allclose(y[k:], y0[k - 1] + 0.05 / SCALE)
    y, v, y0 = _one(cal, blk, "scale", factor=1.01)
    np.testing.assert_allclose(y[k:], 1.01 * y0[k:])
    y, v, y0 = _one(cal, blk, "noise", size=0.2)
    assert np.std(y[k:] - y0[k:]) == pytest.approx(0.2 / SCALE, rel=0.1)
    y, v, y0 = _one(cal, blk, "spikes", size=0.5, rate=10.0)
    hits = np.flatnonzero(np.abs(y - y0) > 1e-9)
    assert 25 < len(hits) < 80 and np.allclose(np.abs(y - y0)[hits], 0.5 / SCALE)
    y, v, y0 = _one(cal, blk, "dropout", duration=0.1)
    assert (~v).sum() == 10 and np.all(y[~v] == 0.0)
    y, v, y0 = _one(cal, blk, "zero")
    assert np.all(y[k:] == 0.0) and v.all()
    y, v, y0 = _one(cal, blk, "saturation", limit=120.0)
    assert y[k:].max() <= 120.0 and np.all(y[before] == y0[before])
    y, v, y0 = _one(cal, blk, "nonfinite", duration=0.3)
    assert (~np.isfinite(y)).sum() == 30 and np.isinf(y).sum() == 10


def test_every_registered_type_is_tested():
    assert set(FAULTS) == {"bias", "ramp", "stuck", "scale", "noise", "spikes", "dropout", "zero", "saturation",
                           "nonfinite"}


def test_sizes_in_sigma_and_specs(data):
    cal, blk = data
    inj = parse_injection("bias:gyro:y1:5:10sigma:1.5")
    assert (inj.size, inj.in_sigma, inj.duration) == (10.0, True, 1.5)
    out = inject(blk, [inj], cal)
    d = out.raw["gyro"][:, 1] - blk.raw["gyro"][:, 1]
    np.testing.assert_allclose(d[(blk.t >= 5) & (blk.t < 6.5)], 10 * 0.01 / SCALE)
    assert np.all(d[blk.t >= 6.5] == 0)
    for bad in ("bias:gyro", "warp:gyro:y1:5", "bias:gyro:y1:soon"):
        with pytest.raises(ShapeError):
            parse_injection(bad)
    with pytest.raises(ShapeError, match="no gyro sensor named"):
        inject(blk, [Injection("bias", "gyro", "q9", 1.0, 1.0)], cal)
