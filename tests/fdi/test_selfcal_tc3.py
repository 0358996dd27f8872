"""The third-order bias temperature coefficient (issue 30): the ``bias_temperature3`` effect, its regressor against
finite differences of the calibrated model, its exact inversion by the runtime, and ``SelfCalTracker`` writing it."""

from __future__ import annotations

import numpy as np

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.calibration.model import RuntimeInputs, contexts, effect
from rimu.epoch import EpochBlock
from rimu.fdi.selfcal import SelfCalSettings, SelfCalTracker
from rimu.fusion import EffectCompensation, Pipeline
from rimu.geometry import cone6
from rimu.session import Segment, Session
from rimu.units import DEG_TO_RAD, DH_TO_RS

TC3 = np.array([0.01, -0.02, 0.015, 0.005, -0.01, 0.02]) * DH_TO_RS  # (deg/h)/K^3


def _cal(tc3: np.ndarray) -> InstrumentCalibration:
    c = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=1e-4)
    c.effects = {"bias_temperature3": {f"{nm}.bias_tc3": float(v) for nm, v in zip(c.geometry.names, tc3)}}
    return c


def _inputs(N: int = 200, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 0.1
    T = 25.0 + 30.0 * rng.uniform(-1, 1, N)
    U = rng.standard_normal((N, 3)) * 50 * DEG_TO_RAD
    return t, T, U


def test_regressor_is_the_finite_difference_jacobian_of_the_model():
    """d(raw output)/d(kb3_i) of the calibrated forward model, by central differences, equals the effect's column
    (calibration) and its runtime column, (T - 25)^3, on every sensor and sample (1e-9 of the largest, 27000 K^3)."""
    t, T, U = _inputs()
    h = 1e-3            # rad/s/K^3: the model is linear in kb3, so a large step has no truncation error
    inputs = RuntimeInputs(t=t, temperature=T)
    seg = Segment("s", "motion", t, {"gyro": np.zeros((len(t), 6))}, temperature=T)
    ctxs = contexts(Session([seg], {"gyro": cone6()}, 10.0), "gyro")
    eff = effect("bias_temperature3")
    rc = eff.runtime_columns(inputs, ctxs)
    for i in range(6):
        up, dn = TC3.copy(), TC3.copy()
        up[i] += h
        dn[i] -= h
        fd = (EffectCompensation(_cal(up)).forward(U, inputs) - EffectCompensation(_cal(dn)).forward(U, inputs)) / (2 * h)
        np.testing.assert_allclose(fd[:, i], eff.columns(seg, ctxs[i])[:, 0], rtol=1e-7, atol=1e-9 * 27000)
        np.testing.assert_allclose(fd[:, i], rc[:, i, 0], rtol=1e-7, atol=1e-9 * 27000)
        assert np.abs(np.delete(fd, i, axis=1)).max() < 1e-12     # only its own sensor
    np.testing.assert_allclose(rc[:, 0, 0], (T - 25.0) ** 3, rtol=1e-14)


def test_the_runtime_inverts_it_exactly():
    """Forward model with the cubic coefficients, then the pipeline: the input comes back to 1e-10 of its size
    (without the effect it is off by the cubic, up to 270 deg/h at 30 K)."""
    t, T, U = _inputs(seed=1)
    cal = _cal(TC3)
    raw = EffectCompensation(cal).forward(U, RuntimeInputs(t=t, temperature=T))
    x = Pipeline(Calibration({"gyro": cal}), temperature=True).process(EpochBlock(t, {"gyro": raw}, temperature=T))
    assert np.abs(x["gyro"].x - U).max() < 1e-10 * np.abs(U).max()
    base = Pipeline(Calibration({"gyro": _cal(np.zeros(6))}), temperature=True)
    off = np.abs(base.process(EpochBlock(t, {"gyro": raw}, temperature=T))["gyro"].parity).max()
    assert off > 10.0      # in sigma: the effect matters


def test_the_tracker_writes_the_third_order_into_the_effect():
    """``calibration_at`` adds the tracked (common-mode-free) tc3 to ``bias_temperature3``, and the pipeline of the
    written calibration subtracts ``tc3 (T - 25)^3``."""
    cal = _cal(np.zeros(6))
    trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-12, temperature_sigma=(1e-5, 1e-6, 1e-7)))
    st = trk.initial_state(0.0)
    th = st.theta.copy()
    th[trk.block("tc3")] = TC3
    st = type(st)(th, st.P, st.t)
    c2 = trk.calibration_at(st)
    got = np.array([c2.effects["bias_temperature3"][f"{nm}.bias_tc3"] for nm in cal.geometry.names])
    np.testing.assert_allclose(got, trk.Pi @ TC3, rtol=1e-12)
    t, T, U = _inputs(seed=2)
    raw = U @ cal.axes_mb().T + (T[:, None] - 25.0) ** 3 * got[None, :]
    x = Pipeline(Calibration({"gyro": c2}), temperature=True).process(EpochBlock(t, {"gyro": raw}, temperature=T))
    assert np.abs(x["gyro"].parity).max() < 1e-6
