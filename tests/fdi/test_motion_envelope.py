"""Issue 32: the motion-aware test's envelope is judged on the motion most sub-units see
(``MotionAwareGlt.motion``: the median over the triads of each one's own rate ``x + A_j^+ r_j``), so a fault on
one sensor is not taken for motion beyond the model, while a motion of the whole unit is.

Four parallel triads, white noise 0.002 rad/s, envelope 0.01 rad/s (the rest the model was fitted on):

* a 0.05 rad/s bias on one sensor moves the fused rate by 0.0125 rad/s (beyond the envelope): the motion the test
  reports stays within 4 sigma of the noise (0.004 rad/s), nothing is model_exceeded, the sensor is isolated;
* the same test judged on the fused rate (one sub-unit: the old rule) calls it model_exceeded and isolates nothing;
* a rotation of the whole unit at 0.05 rad/s is reported as motion of 0.05 rad/s (within 10 %).
"""

from __future__ import annotations

import numpy as np

from rimu.calibration import InstrumentCalibration
from rimu.fdi import MotionAwareGlt, MotionNoiseModel, RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.geometry import triads

SIG = 0.002


def _run(Y, cal):
    det = MotionAwareGlt(MotionNoiseModel(cal), sample_rate=10.0)
    det.envelope = (0.01, 1.0)
    mgr = RedundancyManager(InstrumentPipeline(cal), det, p_fa=1e-3, confirm=3, readmit_after=None)
    return mgr.run(Y), det


def test_a_fault_on_one_sensor_is_not_motion_but_the_unit_turning_is():
    cal = InstrumentCalibration.nominal("gyro", triads(4), 1.0, noise_sigma=SIG)
    rng = np.random.default_rng(2)
    N = 400
    Y = SIG * rng.standard_normal((N, 12))
    Y[200:, 4] += 0.05                                       # imu1_y: a bias of 25 sigma
    res, det = _run(Y, cal)
    kinds = [(e.kind, e.sensor) for e in res.events]
    assert ("isolated", "imu1_y") in kinds and not any(k == "model_exceeded" for k, _ in kinds), kinds[:5]
    iso = next(e.t for e in res.events if e.kind == "isolated")
    assert 200 <= iso <= 205

    # judged on the fused rate (as before): the fault is "motion beyond the model", nothing isolated
    class Fused(MotionAwareGlt):
        def motion(self):
            return float(np.linalg.norm(self._u)), float(np.linalg.norm(self._du))

    det2 = Fused(MotionNoiseModel(cal), sample_rate=10.0)
    det2.envelope = (0.01, 1.0)
    mgr = RedundancyManager(InstrumentPipeline(cal), det2, p_fa=1e-3, confirm=3, readmit_after=None)
    res2 = mgr.run(Y)
    assert "isolated" not in [e.kind for e in res2.events]
    assert "model_exceeded" in [e.kind for e in res2.events]

    # the motion the test reports: noise at rest with the fault, the rotation when the unit turns
    pipe = InstrumentPipeline(cal)
    det.configure(pipe.table.Vz[0], 9)                       # 12 sensors, 3 states: 9 parity dof
    blk = pipe.process(Y)
    w = []
    for t in range(200, 260):
        det.set_input(blk.x[t])
        det.update(blk.parity[t])
        w.append(det.motion()[0])
    assert max(w) < 4 * SIG, max(w)
    turn = Y.copy()
    turn[:, 2::3] += 0.05                                     # every z gyro: the unit turns at 0.05 rad/s
    blk = pipe.process(turn)
    det.configure(pipe.table.Vz[0], 9)
    det.set_input(blk.x[100])
    det.update(blk.parity[100])
    assert abs(det.motion()[0] - 0.05) < 0.005
