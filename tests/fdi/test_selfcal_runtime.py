"""The runtime owns the in-flight self-calibration (issue 30): ``rimu.fdi.Runtime(..., selfcal=...)`` compensates
with the tracked terms on every backend and path, decides as the one-instrument loop does, and its thresholds carry
the tracker's covariance; a calibrated effect is compensated first (numpy and compiled backends agree to 1e-12)."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration import Calibration
from rimu.epoch import Epoch, EpochBlock
from rimu.fdi import RedundancyManager, Runtime
from rimu.fdi.selfcal import SelfCalibratingRun, SelfCalTracker, TrackedGltWindow
from rimu.fusion import InstrumentPipeline, Pipeline
from rimu.fusion.backend import numba_available
from rimu.geometry import cone6
from rimu.units import DH_TO_RS
from tests.fdi.selfcal_flight import flight

FS = 10.0
TC1 = np.array([5.0, -3.0, 2.0, -4.0, 1.0, 3.0]) * DH_TO_RS     # a calibrated first-order effect, (deg/h)/K


@pytest.fixture(scope="module")
def data():
    F = flight(cone6(), hours=0.1, fs=FS, seed=4)                 # 6 min, drifting
    cal = F.cal
    cal_eff = Calibration({"gyro": cal}, raw_unit="rad/s")
    c = cal_eff["gyro"]
    c.effects = {"bias_temperature": {f"{nm}.bias_tc1": float(v) for nm, v in zip(c.geometry.names, TC1)}}
    Y = F.Y + (F.temperature[:, None] - 25.0) * TC1[None, :]      # the calibrated effect on top of the drift
    Y[1500:, 2] += 30 * F.sigma                                    # a fault at 150 s
    return F, cal_eff, Y


def _runtime(cal, backend: str = "numpy") -> Runtime:
    pipe = Pipeline(cal, temperature=True, backend=backend)
    mgr = RedundancyManager(pipe["gyro"], TrackedGltWindow(20, 1e-6), p_fa=1e-6, confirm=3, sample_rate=FS)
    return Runtime(pipe, managers={"gyro": mgr}, selfcal={"gyro": SelfCalTracker(cal["gyro"], _settings())})


def _settings():
    from tests.fdi.selfcal_flight import unit

    return unit(cone6(), FS)[1]


def test_the_runtime_decides_as_the_loop_of_one_instrument(data):
    """Runtime.run with selfcal (the calibrated effect compensated by the pipeline) against SelfCalibratingRun on
    the outputs with that effect taken out: the same estimates, alarms and isolations to 1e-12, the same tracked
    terms; the fault is isolated, nothing else is."""
    F, cal, Y = data
    rt = _runtime(cal)
    out = rt.run(EpochBlock(F.t, {"gyro": Y}, temperature=F.temperature))["gyro"]
    Yc = Y - (F.temperature[:, None] - 25.0) * TC1[None, :]
    ref = SelfCalibratingRun(RedundancyManager(InstrumentPipeline(F.cal), TrackedGltWindow(20, 1e-6), p_fa=1e-6,
                                               confirm=3), SelfCalTracker(F.cal, _settings()))
    r = ref.run(Yc, None, F.t, F.temperature)
    np.testing.assert_allclose(out.x, r.replay.x, rtol=0, atol=1e-12)
    assert np.array_equal(out.alarm, r.replay.alarm)
    assert [(e.kind, e.sensor, e.sample) for e in out.events] == [(e.kind, e.sensor, e.sample) for e in r.replay.events]
    iso = [e for e in out.events if e.kind == "isolated"]
    assert [e.sensor for e in iso] == ["z1"] and 150.0 < iso[0].t < 160.0, iso
    loop = rt.selfcal["gyro"]
    np.testing.assert_allclose(loop.state.theta, ref.state.theta, rtol=0, atol=1e-12 * np.abs(ref.state.theta).max())
    assert loop.accepted == r.accepted and loop.accepted > 100
    # the tracked terms hold no common mode (equal noise: A^T b = 0)
    b, _ = rt.selfcal_terms()["gyro"]["bias"]
    assert np.abs(b).max() > 0 and np.abs(cal["gyro"].axes_mb().T @ b).max() < 1e-12 * np.abs(b).max()


def test_step_equals_run_and_backends_agree(data):
    """Epoch by epoch (Runtime.step) equals the block run; the compiled backend (numba) equals numpy to 1e-12 in
    estimates and tracked terms and exactly in decisions."""
    F, cal, Y = data
    N = 1200
    rt_run = _runtime(cal)
    a = rt_run.run(EpochBlock(F.t[:N], {"gyro": Y[:N]}, temperature=F.temperature[:N]))["gyro"]
    rt_step = _runtime(cal)
    x = np.array([rt_step.step(Epoch(F.t[k], {"gyro": Y[k]}, temperature=F.temperature[k]))["gyro"].x.copy()
                  for k in range(N)])
    np.testing.assert_allclose(x, a.x, rtol=0, atol=1e-12)
    assert np.array_equal(rt_step.selfcal["gyro"].state.theta, rt_run.selfcal["gyro"].state.theta)
    if not numba_available():
        pytest.skip("numba not installed: the compiled backend is not available")
    rt_c = _runtime(cal, "numba")
    c = rt_c.run(EpochBlock(F.t[:N], {"gyro": Y[:N]}, temperature=F.temperature[:N]))["gyro"]
    np.testing.assert_allclose(c.x, a.x, rtol=0, atol=1e-12)
    assert np.array_equal(c.alarm, a.alarm)
    np.testing.assert_allclose(rt_c.selfcal["gyro"].state.theta, rt_run.selfcal["gyro"].state.theta, rtol=0,
                               atol=1e-12 * np.abs(rt_run.selfcal["gyro"].state.theta).max())


def test_default_managers_get_thresholds_with_the_tracker_covariance(data):
    """Runtime(pipeline, sample_rate=..., selfcal={...}): the default manager's detector is the window GLT of the
    tracker's window whose thresholds carry its covariance (a persistent uncertainty lowers the whitened statistic);
    without the sample rate the runtime says what it needs."""
    F, cal, Y = data
    pipe = Pipeline(cal, temperature=True)
    rt = Runtime(pipe, sample_rate=FS, p_fa=1e-6, selfcal={"gyro": SelfCalTracker(cal["gyro"], _settings())})
    det = rt.managers["gyro"].detector
    assert isinstance(det, TrackedGltWindow) and det.window == 20 and rt.selfcal["gyro"].detector is det
    r = rt.run(EpochBlock(F.t[:1200], {"gyro": Y[:1200]}, temperature=F.temperature[:1200]))["gyro"]
    assert not r.alarm.any() and rt.selfcal["gyro"].accepted > 40
    # the thresholds hold the covariance: whitening L with L L^T = (I + M Vz Sigma_c Vz^T)^-1, not the identity
    L = det.whitening(pipe["gyro"].table.get(63).Vz, 3)
    assert L is not None and np.linalg.eigvalsh(L @ L.T).min() < 1.0
    with pytest.raises(ValueError, match="sample_rate"):
        Runtime(Pipeline(cal, temperature=True), selfcal={"gyro": SelfCalTracker(cal["gyro"], _settings())})
