"""Hand-held path on real recordings (MPU-6050 hand-held session with its authors' result; imucal's Ferraris
session) and end to end from a raw file: rimu detect -> rimu calibrate --method handheld."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from rimu.calibration.detect import detect_poses, detect_session
from rimu.calibration.handheld import HandHeld
from rimu.cli import main
from rimu.errors import IdentifiabilityError
from rimu.io.rawtext import read_raw_text
from rimu.units import G0


def shared_data(name: str) -> Path:
    """A folder of ../shared/data beside the repository, or skip."""
    for base in (Path(__file__).resolve().parents[2] / ".." / "shared" / "data", Path("/work/shared/data")):
        if (base / name).exists():
            return (base / name).resolve()
    pytest.skip(f"shared data {name!r} is not available")


def independent_full_fit(Y, weights=None, g=G0, scale=1.0, full=True):
    """Tedaldi et al. 2014's accelerometer model, a = T K (y + b), T upper triangular with unit diagonal,
    fitted by scipy least_squares on the norms from a nominal start (nothing shared with rimu's code)."""
    w = np.ones(len(Y)) if weights is None else weights

    def res(p):
        T = np.array([[1, -p[0], p[1]], [0, 1, -p[2]], [0, 0, 1]]) if full else np.eye(3)
        a = (Y + p[6:9]) @ (T @ np.diag(p[3:6])).T
        return (np.linalg.norm(a, axis=1) - g) * w

    p0 = np.r_[0, 0, 0, np.full(3, scale), -Y.mean(axis=0)]
    sol = least_squares(res, p0, method="lm", xtol=1e-15, ftol=1e-15, x_scale=np.r_[1e-3, 1e-3, 1e-3,
                        np.full(3, scale * 1e-2), np.full(3, g / scale * 1e-2)])
    return np.sqrt(np.mean((sol.fun / w) ** 2 * w**2 / np.mean(w**2)))


def pose_means(session):
    st = [s for s in session.segments if s.kind == "static_unknown"]
    return np.array([s.raw["accel"].mean(axis=0) for s in st]), np.array([s.n_samples for s in st], float)


@pytest.fixture(scope="module")
def mpu():
    folder = shared_data("mpu6050_handheld_session")
    log = read_raw_text(folder / "calibration_data" / "example_data_calibration.csv")
    session, det = detect_session(log.t, log.raw, log.sample_rate, init_still_s=log.meta["Initialization time"])
    return folder, log, session, det


def test_mpu6050_poses_match_the_authors_intervals(mpu):
    folder, log, _session, det = mpu
    ref = np.loadtxt(folder / "reference_result" / "static_intervals.csv", delimiter=",").astype(int)
    assert log.sample_rate == 100.0 and len(det.static) >= 9
    for s, e in ref.T:
        if e - s < 50:  # two of their intervals are 2 and 28 samples long: too short to be poses
            continue
        best = max(min(e, iv.end) - max(s, iv.start) for iv in det.static)
        assert best >= 0.8 * (e - s), (s, e, best)


def test_mpu6050_static_norm_matches_an_independent_fit_and_the_authors(mpu):
    folder, _log, session, _det = mpu
    Y, N = pose_means(session)
    # equal pose weights (as imu_tk): the same criterion as the independent fit
    eq = HandHeld(pose_weights="equal").fit(session)
    ind = independent_full_fit(Y, scale=G0 / 16384)
    assert eq.extra["norm_rms_accel"] <= 1.2 * ind
    # default: poses weighted by their length; compared with the independent fit under the same weights
    res = HandHeld().fit(session)
    w = np.sqrt(N)
    ours_w = np.sqrt(np.mean((res.extra["norm_residual_accel"] * w) ** 2) / np.mean(w**2))
    assert ours_w <= 1.2 * independent_full_fit(Y, w, scale=G0 / 16384)
    # the authors' parameters (Tedaldi model, their own static intervals) on our poses: ours fit them better
    pa = np.loadtxt(folder / "reference_result" / "params_acc.csv")
    T = np.array([[1, -pa[0], pa[1]], [0, 1, -pa[2]], [0, 0, 1]])
    theirs = np.sqrt(np.mean((np.linalg.norm((Y + pa[6:9]) @ (T @ np.diag(pa[3:6])).T, axis=1) - G0) ** 2))
    assert eq.extra["norm_rms_accel"] < theirs
    # scale factors agree with theirs: within 1 % (accelerometers), within 3 of our sigma (gyros; 2 motions clip)
    cal = res.to_calibration()
    assert np.all(np.abs(cal["accel"].scale / pa[3:6] - 1) < 0.01)
    pg = np.loadtxt(folder / "reference_result" / "params_gyro.csv")
    sd = np.array([res.std("gyro")[f"{a}.scale"] for a in "xyz"])
    assert np.all(np.abs(cal["gyro"].scale - pg[6:9]) < 3 * sd)  # 7 usable motions: sd 0.3 to 2.5 %
    assert len(res.extra["clipped_motions"]) == 2 and any("clip" in n for n in res.notes)


def test_ferraris_full_model_refused_scale_bias_matches_independent_fit():
    folder = shared_data("imucal_ferraris_session")
    log = read_raw_text(folder / "example_ferraris_session.csv", sample_rate=102.4)
    session, _det = detect_session(log.t, log.raw, 102.4)
    with pytest.raises(IdentifiabilityError, match="6 distinct orientations"):
        HandHeld().fit(session)
    res = HandHeld(accel_model="scale_bias", pose_weights="equal").fit(session)
    Y, _ = pose_means(session)
    assert res.extra["norm_rms_accel"] <= 1.2 * independent_full_fit(Y, full=False)
    # the file's gyros are in deg/s: scales near one degree per raw unit
    assert np.all(np.abs(res.to_calibration()["gyro"].scale / np.radians(1.0) - 1) < 0.05)


def test_detect_and_calibrate_from_a_raw_file(tmp_path, capsys):
    """A simulated hand-held logger file (metadata row, header, counts) through both commands."""
    from rimu.calibration import Calibration
    from rimu.sim.handheld import handheld_run

    run = handheld_run(n_poses=24, static_s=2.5, initial_still_s=5.0, seed=5)
    raw = tmp_path / "log.csv"
    data = np.column_stack([np.arange(len(run.t)), run.raw["accel"], run.raw["gyro"]])
    with raw.open("w") as fh:
        fh.write("Fs,100\nn,ax,ay,az,gx,gy,gz\n")
        np.savetxt(fh, data, fmt="%d", delimiter=",")
    sess = tmp_path / "s.csv"
    assert main(["detect", str(raw), "-o", str(sess), "--init-still", "4", "--report", str(tmp_path / "rep"),
                 "--json", str(tmp_path / "d.json")]) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].startswith("session written to")
    summary = json.loads((tmp_path / "d.json").read_text())
    assert summary["poses"] == 24 and summary["motions"] == 23
    assert (tmp_path / "rep" / "detection.png").stat().st_size > 10_000
    det_poses = [s for s in summary["segments"] if s["kind"] == "static_unknown"]
    for sl, d in zip(run.pose_slices, det_poses):  # each detected pose lies inside its true pose
        assert sl.start <= d["start"] < d["end"] <= sl.stop
    assert main(["calibrate", str(sess), "--method", "handheld", "-o", str(tmp_path / "cal.json")]) == 0
    cal = Calibration.load(tmp_path / "cal.json")
    for k in ("accel", "gyro"):
        assert np.all(np.abs(cal[k].scale / run.truth[k].scale - 1) < 2e-3), k
    # bad input: one line on stderr, exit 1, never a traceback
    bad = tmp_path / "bad.csv"
    bad.write_text("ax,ay,az\n1,2,3\n1,2,x\n")
    assert main(["detect", str(bad), "-o", str(tmp_path / "b.csv"), "--rate", "100"]) in (1, 2)
    assert "line 3" in capsys.readouterr().err


def test_detection_thresholds_adapt_per_axis():
    """A quiet initial period on the table, then hand-held poses 50x noisier: a fixed multiple of the table
    noise finds nothing, the automatic factor finds every pose."""
    rng = np.random.default_rng(2)
    fs = 100.0
    parts = [rng.normal(0, 1, (1000, 3)) + [0, 0, 16384]]
    for _ in range(12):
        parts.append(rng.normal(0, 400, (150, 3)) + [0, 0, 16384])  # a move
        u = rng.normal(size=3)
        parts.append(rng.normal(0, 7, (300, 3)) + 16384 * u / np.linalg.norm(u))  # a pose held by hand
    a = np.vstack(parts)
    assert len(detect_poses({"accel": a}, fs, init_still_s=8.0, factor=8.0).static) == 1
    det = detect_poses({"accel": a}, fs, init_still_s=8.0)
    assert len(det.static) == 13 and det.settings["factor"] == "auto"


def test_mpu6050_validation_turn(mpu):
    """The authors' separate validation recording (one hand turn of about 90 deg, z up -> y up): the calibrated
    gyros, integrated over the turn, must bring the calibrated gravity direction of the start onto that of the
    end. Datasheet scales: 10.2 deg off; ours 2.4 deg (the calibration recording leaves the gyros weakly
    determined: 7 usable motions, scale sd up to 2.5 %); the authors' 1.4 deg. Bias from the turn's still start."""
    from rimu.calibration.handheld import quat_exp, quat_mul, quat_to_matrix

    folder, _log, session, _det = mpu
    cal = HandHeld().fit(session).to_calibration()
    v = read_raw_text(folder / "results_test_data" / "imu_90_x_rot.csv")
    ya, yg = v.raw["accel"], v.raw["gyro"]
    (a0, a1), (b0, b1) = (0, 1431), (2413, 2634)  # still before and after the turn (rimu detect finds them)
    assert any(iv.start <= a0 + 50 and iv.end >= a1 - 50 for iv in detect_poses(v.raw, 100.0).static)
    bias = yg[a0:a1].mean(axis=0)

    def misfit(accel, rate):
        ua, ub = (accel(ya[a:b].mean(axis=0)) for a, b in ((a0, a1), (b0, b1)))
        ua, ub = ua / np.linalg.norm(ua), ub / np.linalg.norm(ub)
        q = quat_exp(rate(yg[a1:b0] - bias) * 0.01)
        while len(q) > 1:
            q = quat_mul(q[0::2], q[1::2]) if len(q) % 2 == 0 else np.vstack([quat_mul(q[:-1:2], q[1::2]), q[-1:]])
        return float(np.degrees(np.arccos(np.clip((quat_to_matrix(q[0]).T @ ua) @ ub, -1, 1))))

    acc, gyr = cal["accel"], cal["gyro"]
    ours = misfit(lambda y: np.linalg.solve(acc.axes_mb(), acc.compensate(y)),
                  lambda d: (d * gyr.scale) @ np.linalg.inv(gyr.axes_mb()).T)
    nominal = misfit(lambda y: y, lambda d: d / 131.0 * np.pi / 180.0)
    assert ours < 3.0 and ours < nominal / 3.0, (ours, nominal)
