"""Issue 32, items 2 and 3, on simulated units: biases from the rest, rotations from the motion, the static
recording of level units refused with its reason, placeholder samples invalid, and isolation only on evidence
that points at one sensor (common invalidity, motion beyond the fitted model)."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration.alignment import rotvec_of
from rimu.calibration.multi_imu import setup_multi_imu
from rimu.calibration.result import InstrumentCalibration
from rimu.errors import IdentifiabilityError
from rimu.fdi import MotionAwareGlt, MotionNoiseModel, RedundancyManager
from rimu.fusion import InstrumentPipeline
from rimu.geometry import triads
from rimu.io.multiimu import ImuStream, MultiImuRecording
from rimu.session.model import rotation_matrix
from rimu.units import DEG_TO_RAD, G0


def _rest_then_motion(seed=3, k=4, rate=62.5, rest_s=60.0, move_s=20.0, bias_dps=3.0, level_only=False):
    """k triads: rest (one pose, or level) then hand-like motion; gyro biases up to ``bias_dps`` (above the
    setup's 0.05 rad/s motion threshold), rotations of a few degrees, a placeholder first record of zeros."""
    rng = np.random.default_rng(seed)
    n_rest, n_move = int(rest_s * rate), int(move_s * rate)
    N = n_rest + n_move
    t = np.arange(N) / rate
    w = np.zeros((N, 3))
    if n_move:
        tm = t[n_rest:] - t[n_rest]
        f = rng.uniform(0.3, 1.5, (3, 2))
        w[n_rest:] = np.column_stack([sum(np.sin(2 * np.pi * f[i, j] * tm + j) for j in range(2)) for i in range(3)])
        w[n_rest:] *= np.minimum(1.0, tm / 1.0)[:, None]            # the motion starts smoothly
    g_mb = np.tile([0.0, 0.0, G0], (N, 1))
    tilt = 2.0 if level_only else 4.0
    rots = [np.eye(3)] + [rotation_matrix(np.radians(rng.uniform(-tilt, tilt, 3))) for _ in range(k - 1)]
    biases = [rng.uniform(-bias_dps, bias_dps, 3) * DEG_TO_RAD for _ in range(k)]
    sig = rng.uniform(0.1, 0.2, k) * DEG_TO_RAD
    units = []
    for j in range(k):
        g = w @ rots[j].T + biases[j] + sig[j] * rng.normal(size=(N, 3))
        a = g_mb @ rots[j].T + 0.03 * rng.normal(size=(N, 3))
        g[0], a[0] = 0.0, 0.0                                        # a placeholder record
        units.append(ImuStream(f"u{j}", t.copy(), g, a))
    return MultiImuRecording(units, {}), rots, biases, sig


def test_biases_come_from_the_rest_and_rotations_from_the_motion():
    rec, rots, biases, sig = _rest_then_motion()
    su = setup_multi_imu(rec, average_s=None)
    assert su.spans["still_s"] > 50 and su.spans["motion_s"] > 10          # the spans the setup used
    assert su.full_block.meta["placeholder_samples"] == 4                   # the zero record: invalid
    assert not su.full_block.valid["gyro"][0].any()
    gyro = su.calibration["gyro"]
    s = su.bias_sigma["gyro"]
    for j, a in enumerate(su.alignments, start=1):
        phi = rotvec_of(rots[j] @ a.mat_unit_ref.T)
        assert np.all(np.abs(phi) < 4 * np.sqrt(np.diag(a.covariance))), (j, phi, a.sigma_deg)
        # the bias difference (triad minus the rotated reference) within 4 of its stated sigma
        want = biases[j] - rots[j] @ biases[0]
        err = gyro.bias[3 * j:3 * j + 3] - want
        assert np.all(np.abs(err) < 4 * s[3 * j:3 * j + 3] + 2e-5), (j, err / s[3 * j:3 * j + 3])
    # noise from the rest within 10 % of the truth
    assert np.allclose(gyro.noise_sigma.reshape(-1, 3), sig[:, None], rtol=0.1)
    assert "at rest" in su.report()


def test_static_recording_of_level_units_is_refused_with_its_reason():
    rec, _rots, _biases, _sig = _rest_then_motion(move_s=0.0, level_only=True)
    with pytest.raises(IdentifiabilityError, match="no motion in the fit window") as exc:
        setup_multi_imu(rec, average_s=None)
    assert "one direction" in str(exc.value)
    # kept parallel on request: the biases (up to 3 deg/s, above the motion threshold) come from the rest
    su = setup_multi_imu(rec, average_s=None, align_axes=False)
    assert su.spans["motion_s"] == 0.0 and not su.alignments
    pipe = InstrumentPipeline(su.calibration["gyro"])
    mgr = RedundancyManager(pipe, p_fa=1e-3, confirm=3)
    res = mgr.run(su.block.raw["gyro"], su.block.valid["gyro"], su.block.t)
    # the level units are tilted up to 2 deg against each other: 2 deg of a rate of 0 is nothing, so a
    # parallel model holds at rest and nothing is isolated
    assert not mgr.isolated.any()
    assert res.alarm.mean() < 0.01


def test_gravity_in_two_poses_gives_the_rotation_without_motion():
    rec, rots, _biases, _sig = _rest_then_motion(move_s=0.0)
    # a second pose: the whole unit turned by 90 deg about x for the second half
    R2 = rotation_matrix(np.radians([90.0, 0.0, 0.0]))
    for j, u in enumerate(rec.units):
        h = len(u.t) // 2
        g_mb = R2 @ np.array([0.0, 0.0, G0])
        u.accel[h:] = g_mb @ rots[j].T + 0.03 * np.random.default_rng(j).normal(size=(len(u.t) - h, 3))
        u.accel[h:h + 200] += 5.0                      # handling between the poses: not rest
        u.gyro[h:h + 200] += 0.5
    su = setup_multi_imu(rec, average_s=None)
    assert su.spans["motion_s"] < 5.0
    for j, a in enumerate(su.alignments, start=1):
        phi = rotvec_of(rots[j] @ a.mat_unit_ref.T)
        assert np.all(np.abs(phi) < 4 * np.sqrt(np.diag(a.covariance))), (j, phi, a.sigma_deg)
        assert a.sigma_deg.max() < 1.0


def _cal(k=3, sigma=0.01):
    return InstrumentCalibration.nominal("gyro", triads(k), 1.0, noise_sigma=sigma)


def test_invalidity_of_several_triads_at_once_isolates_nothing():
    rng = np.random.default_rng(0)
    N = 200
    Y = 0.01 * rng.normal(size=(N, 12))
    V = np.ones((N, 12), bool)
    V[50:80, 0:3] = False            # triads 1 and 2 clip together for 30 samples
    V[50:80, 3:6] = False
    mgr = RedundancyManager(InstrumentPipeline(_cal(4)), p_fa=1e-3, confirm=3, invalid_persist=10,
                            common_cause=True)
    res = mgr.run(Y, V)
    assert not mgr.isolated.any()
    assert [e.kind for e in res.events].count("common_invalid") == 1
    # one triad alone invalid for as long: that points at it
    V2 = np.ones((N, 12), bool)
    V2[50:80, 6:9] = False
    mgr = RedundancyManager(InstrumentPipeline(_cal(4)), p_fa=1e-3, confirm=3, invalid_persist=10,
                            common_cause=True)
    res = mgr.run(Y, V2)
    assert sorted(e.sensor for e in res.events if e.kind == "invalid_isolated") == ["imu2_x", "imu2_y", "imu2_z"]
    assert res.events[0].t == 59          # after invalid_persist = 10 samples alone


def test_alarm_beyond_the_fitted_motion_isolates_nothing():
    cal = _cal(3)
    det = MotionAwareGlt(MotionNoiseModel(cal, scale_rel=0.001), sample_rate=100.0)
    det.envelope = (1.0, 50.0)                 # fitted on rates up to 1 rad/s
    rng = np.random.default_rng(1)
    N = 300
    w = np.zeros((N, 3))
    w[100:200, 2] = 5.0                        # 5 rad/s: beyond the fitted motion
    Y = np.tile(w, (1, 3)) + 0.01 * rng.normal(size=(N, 9))
    Y[100:200, 0] += 0.3 * w[100:200, 2]       # one sensor disagrees while the model is exceeded
    mgr = RedundancyManager(InstrumentPipeline(cal), det, p_fa=1e-3, confirm=3)
    res = mgr.run(Y)
    assert not mgr.isolated.any()
    kinds = [e.kind for e in res.events]
    assert "model_exceeded" in kinds and "isolated" not in kinds
    assert res.alarm[110:190].mean() > 0.5     # the alarms are reported (output DEGRADED), not used to isolate
    # the same disagreement within the envelope is isolated
    det.envelope = (10.0, 1e4)
    mgr = RedundancyManager(InstrumentPipeline(cal), det, p_fa=1e-3, confirm=3)
    res = mgr.run(Y)
    assert [(e.sensor, e.t) for e in res.events if e.kind == "isolated"] == [("imu0_x", 102)]


def test_replay_states_what_the_motion_thresholds_assume(tmp_path, capsys):
    from rimu.cli import main
    from rimu.sim import Simulator

    assert main(["simulate", "--procedure", "cho_park_table2", "--sample-rate", "10", "-o",
                 str(tmp_path / "t2.npz")]) == 0
    Simulator(seed=0, sample_rate=10.0).truth_calibration().save(tmp_path / "cal.json")
    assert main(["replay", str(tmp_path / "t2.npz"), "--calibration", str(tmp_path / "cal.json"),
                 "--motion-fit", "12"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "thresholds assume the motion of the fit span" in ln)
    rate = float(line.split("|rate| up to ")[1].split(" deg/s")[0])
    assert 0 < rate < 1e4 and "model_exceeded" in line


def test_accelerometer_gains_from_the_poses_at_rest(monkeypatch):
    """Issue 32: accelerometer triads with relative gains (1 % scale, 10 mrad misalignment) placed in six poses:
    the setup's gains against the reference come out as the truth's (``G_j G_0^-1``), the noise as the
    accelerometers' own and a plain GLT on them at rest alarms below 1 %; with biases only (the gains refused)
    the pose-dependent error (0.1 m/s^2) is taken for noise, more than three times the true 0.01 m/s^2."""
    import rimu.calibration.multi_imu as mi

    rng = np.random.default_rng(11)
    k, rate, per = 4, 50.0, 600
    poses = [rotation_matrix(v) for v in np.radians([[0, 0, 0], [90, 0, 0], [-90, 0, 0], [0, 90, 0], [0, -90, 0],
                                                     [180, 0, 0]])]
    g_mb = np.vstack([np.tile(P.T @ [0.0, 0.0, G0], (per, 1)) for P in poses])
    N = len(g_mb)
    t = np.arange(N) / rate
    gains = [np.eye(3) + rng.normal(0, 0.01, (3, 3)) for _ in range(k)]
    units = []
    for j in range(k):
        a = g_mb @ gains[j].T + rng.normal(0, 0.05, 3) + 0.01 * rng.normal(size=(N, 3))
        units.append(ImuStream(f"u{j}", t.copy(), 0.002 * rng.normal(size=(N, 3)), a))
    rec = MultiImuRecording(units, {})
    su = setup_multi_imu(rec, average_s=None, align_axes=False)
    assert su.spans["accel_gains_from_rest"]
    acc = su.calibration["accel"]
    fitted = (acc.axes_mb() / acc.scale[:, None]).reshape(k, 3, 3)
    for j in range(k):
        np.testing.assert_allclose(fitted[j], gains[j] @ np.linalg.inv(gains[0]), atol=1e-3)

    def rest_alarm_rate(cal):
        mgr = RedundancyManager(InstrumentPipeline(cal), p_fa=1e-3, confirm=3)
        res = mgr.run(su.block.raw["accel"], su.block.valid["accel"], su.block.t)
        return float(np.asarray(res.alarm)[su.still].mean())

    assert rest_alarm_rate(acc) < 0.01
    # the noise (scaled so that the rest is chi-square) is the accelerometers' own: 0.01 m/s^2
    assert np.allclose(acc.noise_sigma, 0.01, rtol=0.2), acc.noise_sigma
    monkeypatch.setattr(mi, "MIN_POSE_SPREAD_M_S2", 1e9)             # gains refused: biases only, as before
    su0 = setup_multi_imu(rec, average_s=None, align_axes=False)
    assert not su0.spans["accel_gains_from_rest"]
    # the pose-dependent error is taken for noise: thresholds several times too wide (a fault that size unseen)
    assert np.median(su0.calibration["accel"].noise_sigma) > 3 * 0.01, su0.calibration["accel"].noise_sigma


def test_accelerometer_test_takes_the_motion_from_the_gyros():
    """Issue 32: an accelerometer MotionAwareGlt (``input_is_rate=False``) in a Runtime gets the gyro manager's
    rate epoch by epoch: an accelerometer that disagrees while the gyros turn beyond the envelope is
    ``model_exceeded`` (nothing isolated); the same disagreement at rest is isolated."""
    from rimu.calibration.result import Calibration
    from rimu.fdi import Runtime
    from rimu.fusion import Pipeline

    geo = triads(3)
    cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", geo, 1.0, noise_sigma=0.01),
                       "accel": InstrumentCalibration.nominal("accel", geo, 1.0, noise_sigma=0.01)}, raw_unit="SI")
    pipe = Pipeline(cal)
    rng = np.random.default_rng(2)
    N = 400
    w = np.zeros((N, 3))
    w[100:200, 2] = 5.0                                          # the gyros turn at 5 rad/s: beyond 1 rad/s
    G = np.tile(w, (1, 3)) + 0.01 * rng.normal(size=(N, 9))
    A = np.tile([0.0, 0.0, G0], (N, 3)) + 0.01 * rng.normal(size=(N, 9))
    A[100:200, 0] += 0.5                                         # one accelerometer off while turning ...
    A[300:350, 0] += 0.5                                         # ... and at rest
    det = MotionAwareGlt(MotionNoiseModel(cal["accel"]), sample_rate=100.0, input_is_rate=False)
    det.envelope = (1.0, 1e4)
    mgrs = {"gyro": RedundancyManager(pipe["gyro"], p_fa=1e-3, confirm=3),
            "accel": RedundancyManager(pipe["accel"], det, p_fa=1e-3, confirm=3, sample_rate=100.0)}
    from rimu.epoch import EpochBlock

    blk = EpochBlock(np.arange(N) / 100.0, {"gyro": G, "accel": A}, {"gyro": np.ones((N, 9), bool),
                                                                       "accel": np.ones((N, 9), bool)})
    res = Runtime(pipe, mgrs).run(blk)
    ev = [(e.kind, e.sensor, e.sample) for e in res["accel"].events]
    assert any(k == "model_exceeded" and 100 <= s < 200 for k, _, s in ev), ev
    iso = [(n, s) for k, n, s in ev if k == "isolated"]
    assert iso and iso[0][0] == "imu0_x" and 300 <= iso[0][1] < 310, ev
    assert not any(100 <= s < 300 for _, s in iso)
