"""Shared fixtures of the io tests: a short simulated cone6 stream (rimu.sim is fine to import in tests)."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.sim import Simulator, rotation


@pytest.fixture(scope="session")
def cone6_block():
    """2 s of the cone6 unit rotating at 20 deg/s about MB y (200 samples at 100 Hz), Table 3 truth."""
    run = Simulator(seed=11).run([rotation("r", [0.0, np.radians(20.0), 0.0], duration=2.0)])
    return run.block


@pytest.fixture(scope="session")
def mm7_block():
    """A triad stream in the MM7 layout's raw units (deg/s, g): smooth motion plus noise, 1 s at 100 Hz."""
    from rimu.epoch import EpochBlock

    rng = np.random.default_rng(5)
    t = np.arange(100) / 100.0
    g = np.column_stack([10 * np.sin(t), -5 + t, 2 * np.cos(3 * t)]) + 0.05 * rng.standard_normal((100, 3))
    a = np.column_stack([0.1 * t, -0.2 + 0 * t, 1.0 + 0.01 * np.sin(t)]) + 1e-3 * rng.standard_normal((100, 3))
    return EpochBlock(t=t, raw={"gyro": g, "accel": a}, temperature=np.full(100, 31.0))
