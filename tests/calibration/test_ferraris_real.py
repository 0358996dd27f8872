"""Real data: imucal's Ferraris recording of a hand-moved triad, calibrated by rimu's generic least squares with
known attitudes (accelerometer) and integrated turns (gyro), and compared with imucal's own Ferraris result."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rimu.calibration import LeastSquares
from rimu.session import load_ferraris
from rimu.units import DEG_TO_RAD, G0
from tests.conftest import shared_data

# imucal 2.x FerrarisCalibration (grav=9.81, expected_angle=-360) on the same file; reproduced by
# benchmarks/imucal_reference.py. Model: raw = K R true + b (K diagonal, R unit rows).
IMUCAL_ACC_K = [0.9967458650887003, 1.0024376185894108, 1.0233953475452096]
IMUCAL_ACC_R = [[0.9998620291746435, -0.014830571004926794, -0.007481763056406514],
                [0.008576740442555632, 0.9999615197419686, 0.0018435180263559792],
                [0.01333118773067902, 0.002003617949970859, 0.9999091283455711]]
IMUCAL_GYR_K = [1.0279243264288036, 0.9824277738468916, 0.9983104874451514]
IMUCAL_GYR_R = [[0.999979342528037, -0.00045421361799804057, -0.006411568231274507],
                [-0.00022220540636464124, 0.9999961009525417, -0.002783649487862618],
                [0.009714004498496572, 0.0076410932929403316, 0.9999236229882218]]
IMUCAL_GRAV = 9.81


def _folder() -> Path:
    return shared_data("imucal_ferraris_session", "example_ferraris_session.csv")


@pytest.fixture(scope="module")
def session():
    return load_ferraris(_folder())


@pytest.fixture(scope="module")
def cal(session):
    return LeastSquares().fit(session).to_calibration()


def _inputs(c, y):
    """Calibrated input in MB from raw outputs: A^-1 (SF y - b) (Cho & Park Eq. 20 for a triad)."""
    return np.linalg.solve(c.axes_mb(), c.compensate(y).T).T


def test_static_norms_within_half_percent(session, cal):
    for seg in session.segments:
        if seg.kind != "static":
            continue
        f = _inputs(cal["accel"], seg.raw["accel"]).mean(axis=0)
        assert abs(np.linalg.norm(f) / G0 - 1) < 0.005, seg.label
        # and it points along the axis the section names
        assert np.dot(f / np.linalg.norm(f), seg.specific_force_mb / G0) > 0.999


def test_turns_integrate_to_360_deg(session, cal):
    for seg in session.segments:
        if seg.kind != "angle":
            continue
        w = _inputs(cal["gyro"], seg.raw["gyro"])
        ang = np.rad2deg(np.linalg.norm(w.sum(axis=0) / session.sample_rate))
        assert abs(ang / 360.0 - 1) < 0.01, (seg.label, ang)


def test_leave_one_static_section_out(session):
    statics = [s.label for s in session.segments if s.kind == "static"]
    for out in statics:
        keep = [x for x in statics if x != out] + ["x_rot", "y_rot", "z_rot"]
        c = LeastSquares(instruments=["accel"], segments=keep).fit(session).to_calibration()["accel"]
        f = _inputs(c, session.segment(out).raw["accel"]).mean(axis=0)
        assert abs(np.linalg.norm(f) / G0 - 1) < 0.01, (out, np.linalg.norm(f) / G0)


def test_agrees_with_imucal(cal):
    acc, gyr = cal["accel"], cal["gyro"]
    # scale factors: rimu SF (SI per raw) = 1 / K; the gravity constants differ by 9.81 / 9.80665
    assert np.allclose(acc.scale, (G0 / IMUCAL_GRAV) / np.array(IMUCAL_ACC_K), rtol=0.01)
    assert np.allclose(gyr.scale / DEG_TO_RAD, 1 / np.array(IMUCAL_GYR_K), rtol=0.01)
    # misalignment: angle between each calibrated sensing axis and imucal's R row, within 0.5 deg
    for c, R in ((acc, IMUCAL_ACC_R), (gyr, IMUCAL_GYR_R)):
        A = c.axes_mb()
        for i in range(3):
            r = np.array(R[i]) / np.linalg.norm(R[i])
            ang = np.rad2deg(np.arccos(min(1.0, float(A[i] @ r))))
            assert ang < 0.5, (c.instrument, i, ang)


def test_loader_parses_with_numpy_and_still_names_a_bad_cell(tmp_path, session):
    """load_ferraris parses with numpy's reader (issue 28): the same numbers as Python's float() of every cell of
    the real file; a file with one bad cell is refused with its row and column named, and one with a short row too."""
    import csv
    import shutil

    from rimu.errors import SessionFormatError

    folder = _folder()
    with (folder / "example_ferraris_session.csv").open(newline="") as fh:
        rows = list(csv.reader(fh))
    cols = [rows[0].index(c) for c in ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")]
    ref = np.array([[float(r[c]) for c in cols] for r in rows[1:]])
    got = np.concatenate([np.hstack([s.raw["gyro"], s.raw["accel"]]) for s in session.segments])
    sections = {}
    import json
    for name, v in json.loads((folder / "example_ferraris_session_list.json").read_text()).items():
        sections[name] = (int(v["start"]), int(v["end"]))
    want = np.concatenate([ref[s:e] for s, e in (sections[k] for k in (s.label for s in session.segments))])
    np.testing.assert_array_equal(got, want)
    for bad_row, edit in ((7, lambda r: r.__setitem__(cols[4], "1.2.3")), (9, lambda r: r.__delitem__(slice(3, None)))):
        d = tmp_path / f"bad{bad_row}"
        d.mkdir()
        shutil.copy(folder / "example_ferraris_session_list.json", d)
        rr = [list(r) for r in rows]
        edit(rr[bad_row - 1])
        with (d / "example_ferraris_session.csv").open("w", newline="") as fh:
            csv.writer(fh).writerows(rr)
        with pytest.raises(SessionFormatError, match=f"row {bad_row}, column '(acc_y|gyr_z)' is missing or not a"):
            load_ferraris(d)
