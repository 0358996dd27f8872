"""The README's "Real data" commands run as written on every recording of ../shared/data, from the raw files,
with no script; the figures they write are checked against what the recordings' READMEs state."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from rimu.cli import main
from tests.conftest import ROOT, shared_data


def _commands() -> list[list[str]]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Real data\n.*?```sh\n(.*?)```", text, re.S).group(1)
    return [shlex.split(ln) for ln in block.splitlines() if ln.strip() and not ln.startswith(("#", "D="))]


@pytest.fixture(scope="module")
def journey(tmp_path_factory):
    data = shared_data(".")  # skips cleanly when ../shared/data is absent
    for need in ("mpu6050_handheld_session", "imucal_ferraris_session", "pixhawk1_dual_imu_flight",
                 "quadrotor_4x_xsens_dot"):
        shared_data(need)
    pytest.importorskip("pymavlink")
    pytest.importorskip("allantools")
    out = tmp_path_factory.mktemp("real")
    import os

    cwd = os.getcwd()
    os.chdir(out)
    codes = []
    try:
        for cmd in _commands():
            assert cmd[0] == "rimu"
            args = [a.replace("$D", str(data)) for a in cmd[1:]]
            codes.append((" ".join(cmd[1:3]), main(args)))
    finally:
        os.chdir(cwd)
    return out, codes


def test_every_command_succeeds(journey):
    _, codes = journey
    assert len(codes) >= 25
    assert [(k, v) for k, v in codes if v != 0] == []


def test_imports_read_every_imu_at_its_rate_in_si(journey):
    out, _ = journey
    px = json.loads((out / "px4log.json").read_text())
    csv = json.loads((out / "pixhawk_csv.json").read_text())
    # the README of the flight: two IMUs, 5741 CSV rows over 70.5 s (the log holds one record more), ~83 Hz
    assert [i["name"] for i in px["imus"]] == ["imu0", "imu1"]
    assert [i["samples"] for i in px["imus"]] == [5742, 5742] and [i["samples"] for i in csv["imus"]] == [5741, 5741]
    for i in px["imus"]:
        assert i["duration_s"] == pytest.approx(70.5, abs=0.1) and 78 < i["mean_rate_hz"] < 84
    h10 = json.loads((out / "h10.json").read_text())
    assert len(h10["imus"]) == 4 and all(i["mean_rate_hz"] == pytest.approx(120.0, rel=1e-3) for i in h10["imus"])
    assert all("deg/s" in i["units_from"]["gyro"] for i in h10["imus"])
    v30 = json.loads((out / "v30.json").read_text())
    assert len(v30["imus"]) == 1


def test_calibrated_mpu6050_log_measures_one_gravity(journey):
    from rimu.io.formats import read_log

    out, _ = journey
    rec = read_log(out / "mpu_rot_si.npz")
    a = np.linalg.norm(rec.units[0].accel[:300], axis=1)  # the log starts at rest
    assert np.median(a) == pytest.approx(9.81, rel=0.02)


def test_pixhawk_replay_detects_the_injected_fault_and_no_fault_without(journey):
    out, _ = journey
    clean = json.loads((out / "px_events.json").read_text())
    fault = json.loads((out / "px_fault.json").read_text())
    # two parallel triads (the autopilot logs both in the body frame): a fault is detected, never pinned on one
    found = [e for e in fault["gyro"]["events"] if e["t"] >= 40.0 and e["kind"] == "detected_not_isolable"]
    assert found and found[0]["t"] < 41.0, "the 0.2 rad/s bias injected at 40 s was not detected within 1 s"
    assert not [e for e in fault["gyro"]["events"] if e["kind"] == "isolated"]
    assert not [e for e in clean["gyro"]["events"] if e["kind"] in ("isolated", "detected_not_isolable")]
    assert (out / "px_replay" / "replay.png").exists() and (out / "h10_replay" / "replay.png").exists()


def test_kalibr_yaml_and_setup_figures(journey):
    out, _ = journey
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load((out / "mpu_imu.yaml").read_text())
    # the MPU-6050's gyro noise density is 0.005 deg/s/sqrt(Hz) by its data sheet: 8.7e-5 rad/s/sqrt(Hz)
    assert 3e-5 < doc["gyroscope_noise_density"] < 3e-4 and doc["update_rate"] == 100.0
    seeded = json.loads((out / "mpu_seeded.json").read_text())["instruments"]["gyro"]["terms"]["white"]
    assert seeded == pytest.approx([doc["gyroscope_noise_density"]] * 3, rel=1e-5)  # kalibr seeds rimu's model
    setup = json.loads((out / "h10_setup.json").read_text())
    assert setup["imus"] == ["imu1", "imu2", "imu3", "imu4"]
    assert all(abs(o) < 0.05 for o in setup["offsets_s"])  # the units' clocks agree within a few samples
    assert all(0.1 < r < 5.0 for r in setup["rotation_deg"])  # nominally parallel, misaligned by degrees
    assert Path(out / "ferraris_diag" / "report.md").exists()
