"""kalibr's imu.yaml from rimu's noise identification: on a simulated static triad with known white noise and bias
random walk, each of the four kalibr numbers lies within its confidence interval of the truth; the file seeds
rimu's noise model back."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.cli import main
from rimu.geometry import triads
from rimu.noise.kalibr import noise_from_kalibr, read_kalibr
from rimu.session import Segment, Session, save_session

pytest.importorskip("allantools")
yaml = pytest.importorskip("yaml")

FS = 50.0
TRUTH = {"gyroscope_noise_density": 2e-3, "gyroscope_random_walk": 2e-4,
         "accelerometer_noise_density": 4e-3, "accelerometer_random_walk": 3e-4}


def _static(n: int, white: float, rrw: float, rng: np.random.Generator) -> np.ndarray:
    """White noise of density N (sigma N sqrt(fs) per sample) plus a bias random walk of density K."""
    w = rng.standard_normal((n, 3)) * white * np.sqrt(FS)
    b = np.cumsum(rng.standard_normal((n, 3)) * rrw / np.sqrt(FS), axis=0)
    return w + b


def test_kalibr_yaml_within_confidence_of_known_noise(tmp_path):
    rng = np.random.default_rng(7)
    n = int(2000 * FS)
    t = np.arange(n) / FS
    gyro = _static(n, TRUTH["gyroscope_noise_density"], TRUTH["gyroscope_random_walk"], rng)
    accel = _static(n, TRUTH["accelerometer_noise_density"], TRUTH["accelerometer_random_walk"], rng) + [0, 0, 9.80665]
    geo = triads(1)
    s = Session([Segment("rest", "static_unknown", t, {"gyro": gyro, "accel": accel})], {"gyro": geo, "accel": geo},
                FS, raw_unit="SI")
    save_session(s, tmp_path / "rest.npz")
    assert main(["noise", str(tmp_path / "rest.npz"), "-o", str(tmp_path / "noise.json"), "--terms",
                 "white,rate_random_walk", "--kalibr", str(tmp_path / "imu.yaml")]) == 0
    doc = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    assert doc["update_rate"] == FS
    model = json.loads((tmp_path / "noise.json").read_text())["instruments"]
    key = {"gyroscope": ("gyro",), "accelerometer": ("accel",)}
    for name, truth in TRUTH.items():
        inst = key[name.split("_")[0]][0]
        term = "white" if name.endswith("noise_density") else "rate_random_walk"
        # the 1-sigma of the rms over the three sensors (rimu.noise.kalibr._rms) from the fitted sigmas
        v = np.array(model[inst]["terms"][term])
        sg = np.array(model[inst]["sigma"][term])
        sigma = float(np.sqrt(np.sum((v * sg) ** 2)) / (3 * np.sqrt(np.mean(v ** 2))))
        assert doc[name] == pytest.approx(float(np.sqrt(np.mean(v ** 2))), rel=1e-5)
        assert abs(doc[name] - truth) <= 3 * sigma, f"{name}: {doc[name]:.4g} vs {truth:.4g} +- {sigma:.2g}"
        assert sigma < 0.2 * truth  # an interval that says something
    # the file seeds rimu's noise model: per-sample sigma N sqrt(fs)
    seeded = noise_from_kalibr(read_kalibr(tmp_path / "imu.yaml"), "gyro", ["x", "y", "z"])
    np.testing.assert_allclose(seeded.sample_sigma(), doc["gyroscope_noise_density"] * np.sqrt(FS), rtol=1e-6)
