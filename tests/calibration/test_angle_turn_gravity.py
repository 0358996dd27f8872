"""An 'angle' segment (a known total turn at an unstated rate) with a known start attitude: the accelerometers read
gravity at that attitude only when the turn's axis is vertical (imucal's Ferraris turns). About any other axis
gravity moves through the turn at times nobody stated, so the accelerometers' input there is unknown and the
segment gives them no rows; before, it was fitted as if gravity stayed at the start attitude, biasing the fit
without a word."""

from __future__ import annotations

import dataclasses

import numpy as np

from rimu.calibration import LeastSquares
from rimu.session import Session
from tests.calibration.test_base_fast_path import _ferraris_session


def _params(session: Session, inst: str) -> np.ndarray:
    cal = LeastSquares().fit(session).to_calibration()[inst]
    return np.concatenate([np.ravel(cal.scale), np.ravel(cal.misalignment), np.ravel(cal.bias)])


def test_a_turn_about_a_horizontal_axis_gives_the_accelerometers_no_rows():
    s = _ferraris_session(2.0)
    i = next(j for j, seg in enumerate(s.segments) if seg.label == "x_rot")
    vertical = s.segments[i]
    assert vertical.fixed_under_turn(vertical.mat_ln_mb.T @ np.array([0.0, 0.0, 9.81]))
    # the same turn reported about x while x lies level (start attitude: MB = LN, gravity along MB z)
    level = dataclasses.replace(vertical, mat_ln_mb=np.eye(3))
    assert not level.fixed_under_turn(np.array([0.0, 0.0, 9.81]))
    assert level.specific_force(9.81) is None and level.attitude() is None
    tilted = dataclasses.replace(s, segments=[*s.segments[:i], level, *s.segments[i + 1:]])
    # the same turn with no attitude at all: the accelerometers read nothing there, the gyros the angle
    unknown = dataclasses.replace(vertical, mat_ln_mb=None)
    without = dataclasses.replace(s, segments=[*s.segments[:i], unknown, *s.segments[i + 1:]])
    # the accelerometers: exactly the fit without the segment (the old code read 9.81 m/s^2 along z throughout and
    # moved the x scale and the biases by the whole turn's gravity)
    np.testing.assert_allclose(_params(tilted, "accel"), _params(without, "accel"), rtol=1e-12, atol=1e-15)
    assert not np.allclose(_params(s, "accel"), _params(without, "accel"), rtol=1e-9, atol=0)  # the rows count
    # the gyros use the reported angle whatever the attitude
    np.testing.assert_allclose(_params(tilted, "gyro"), _params(s, "gyro"), rtol=1e-12, atol=1e-15)
