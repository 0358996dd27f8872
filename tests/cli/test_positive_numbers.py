"""The command line's positive-number options take any positive normal double: a tactical-grade drift rate is a
value, not a typing mistake (the old floor of 1e-12 refused ``--selfcal-bias-rw 1e-28`` (rad/s)^2/s, the random walk
of a bias of about 0.01 deg/h over an hour)."""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import build_parser, main
from rimu.cli._common import nonnegative_float, positive_float
from rimu.geometry import cone6
from rimu.units import DH_TO_RS


@pytest.mark.parametrize("text", ["1e-14", "1e-28", "2.5e-300", repr(sys.float_info.min), "1e12"])
def test_tiny_and_large_positive_values_are_taken_exactly(text):
    assert positive_float(text) == float(text)
    assert nonnegative_float(text) == float(text)


@pytest.mark.parametrize("text", ["0", "-1e-30", "1e-320", "1.1e12", "inf", "nan"])
def test_zero_negative_subnormal_and_huge_are_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(text)):
        positive_float(text)
    if text != "0":
        with pytest.raises(argparse.ArgumentTypeError):
            nonnegative_float(text)
    assert nonnegative_float("0") == 0.0


def test_a_tactical_grade_drift_rate_reaches_the_exported_tracker(tmp_path):
    q = (0.01 * DH_TO_RS) ** 2 / 3600.0        # a 0.01 deg/h wander over one hour: 7.5e-20 (rad/s)^2/s
    assert q < 1e-12
    cal = tmp_path / "cal.json"
    Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=1e-5)}, "rad/s",
                "nominal").save(cal)
    args = build_parser().parse_args(["replay", "log.npz", "--calibration", str(cal), "--selfcal",
                                      "--selfcal-bias-rw", repr(q)])
    assert args.selfcal_bias_rw == q
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["export-c", str(cal), "-o", str(tmp_path / "c"), "--selfcal", "--sample-rate", "200",
                     "--selfcal-bias-rw", repr(q), "--selfcal-no-scale"]) == 0
    code = (tmp_path / "c" / "rimu_gyro_sc.c").read_text()
    body = re.search(r"rimu_gyro_sc_q\[\d+\] = \{([^}]*)\}", code).group(1)
    assert np.array_equal(np.array([float(v) for v in body.replace("\n", " ").split(",")]), np.full(6, q))
