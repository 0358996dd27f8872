"""The noise file and the calibration's noise section round-trip; old files still load; the CLI runs on a
simulated static recording of every geometry and its figures match the simulated truth."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.cli import main
from rimu.errors import CalibrationFileError, ShapeError, UnsupportedVersionError
from rimu.geometry import cone6, tetrad4
from rimu.noise import InstrumentNoise, NoiseModel
from rimu.session import save_session
from rimu.sim import Simulator, static
from rimu.units import ARW_DSQH_TO_RSQS, DH_TO_RS, UG_TO_MS2


def _noise() -> InstrumentNoise:
    return InstrumentNoise.from_terms("gyro", cone6().names, 100.0, quantization=1e-6, white=1e-4,
                                      bias_instability=2e-5, rate_random_walk=1e-7)


def test_noise_file_round_trip(tmp_path) -> None:  # type: ignore[no-untyped-def]
    m = NoiseModel({"gyro": _noise()}, parity={"gyro": {"white": True}})
    m.save(tmp_path / "n.json")
    back = NoiseModel.load(tmp_path / "n.json")
    for t in back["gyro"].terms:
        assert np.array_equal(back["gyro"].terms[t], m["gyro"].terms[t])
    assert back.parity == m.parity
    doc = json.loads((tmp_path / "n.json").read_text())
    assert doc["format"] == "rimu.noise" and doc["version"] == 1
    assert doc["instruments"]["gyro"]["units"]["white"] == "rad/sqrt(s)"
    assert not list(tmp_path.glob(".*tmp"))          # atomic write left no temporary file
    doc["version"] = 99
    (tmp_path / "v.json").write_text(json.dumps(doc))
    with pytest.raises(UnsupportedVersionError, match="upgrade"):
        NoiseModel.load(tmp_path / "v.json")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(CalibrationFileError, match="not a rimu noise file"):
        NoiseModel.load(tmp_path / "x.json")


def test_field_units() -> None:
    m = InstrumentNoise.from_terms("gyro", ["a"], 100.0, white=0.3 * ARW_DSQH_TO_RSQS, bias_instability=2 * DH_TO_RS)
    r = m.table_rows()[0]
    assert math.isclose(r["white"], 0.3) and math.isclose(r["bias_instability"], 2.0)
    a = InstrumentNoise.from_terms("accel", ["a"], 100.0, white=0.06 / 60, bias_instability=20 * UG_TO_MS2)
    r = a.table_rows()[0]
    assert math.isclose(r["white"], 0.06) and math.isclose(r["bias_instability"], 20.0)   # m/s/sqrt(h), micro-g


def test_calibration_noise_section_round_trips_and_old_files_load(tmp_path) -> None:  # type: ignore[no-untyped-def]
    ic = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0, noise_sigma=1e-3)
    assert "noise" not in ic.to_dict()                 # files without a noise model are unchanged
    Calibration({"gyro": ic}).save(tmp_path / "old.json")
    assert Calibration.load(tmp_path / "old.json")["gyro"].noise is None
    ic.noise = _noise()
    Calibration({"gyro": ic}).save(tmp_path / "new.json")
    back = Calibration.load(tmp_path / "new.json")["gyro"].noise
    assert back is not None and np.array_equal(back.terms["white"], ic.noise.terms["white"])
    with pytest.raises(ShapeError, match="identify the noise of this unit"):
        InstrumentCalibration.nominal("gyro", tetrad4(), scale=1.0).__class__(
            "gyro", tetrad4(), np.ones(4), tetrad4().nominal_rows(), np.zeros(4), noise=_noise())


@pytest.fixture(scope="module")
def recording(tmp_path_factory):  # type: ignore[no-untyped-def]
    """A simulated cone6 static recording of 300 s at 100 Hz with white noise and bias instability."""
    d = tmp_path_factory.mktemp("rec")
    sim = Simulator(arw_deg_sqrt_h=0.3, vrw_ug_sqrt_hz=50.0, gyro_bias_instability_deg_h=20.0,
                    accel_bias_instability_ug=100.0, seed=4)
    run = sim.run([static("rest", (0, 0, -1), duration=300.0)])
    save_session(run.session, d / "rest.npz")
    run.truth.save(d / "truth.json")
    return d


def test_cli_figures_match_truth(recording, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "noise.json"
    code = main(["noise", str(recording / "rest.npz"), "--calibration", str(recording / "truth.json"), "-o", str(out),
                 "--report", str(tmp_path / "rep"), "--json", str(tmp_path / "s.json"),
                 "--write-calibration", str(tmp_path / "cal.json"),
                 "--terms", "white,bias_instability"])
    assert code == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("noise of gyro (6 sensors), accel (6 sensors) ->")
    m = NoiseModel.load(out)
    truth = {("gyro", "white"): 0.3, ("gyro", "bias_instability"): 20.0,
             ("accel", "white"): 50.0 * 1e-6 * 9.80665 * 60, ("accel", "bias_instability"): 100.0}
    for (inst, term), v in truth.items():
        rows = m[inst].table_rows()
        for r in rows:
            assert abs(r[term] - v) < 3.5 * r[term + "_sigma"], (inst, term, r[term], r[term + "_sigma"], v)
    assert m.parity["gyro"]["independent"] is True
    assert (tmp_path / "rep" / "allan-gyro.png").stat().st_size > 10_000
    assert (tmp_path / "rep" / "parity-accel.png").exists() and (tmp_path / "rep" / "noise.md").exists()
    cal = Calibration.load(tmp_path / "cal.json")
    assert cal["gyro"].noise is not None and cal["accel"].noise is not None


def test_cli_bad_input(recording, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["noise", str(recording / "rest.npz"), "-o", str(tmp_path / "n.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rimu noise: error:") and "--calibration" in err and len(err.splitlines()) == 1
    assert main(["noise", str(tmp_path / "missing.npz")]) == 2
    assert main(["noise", str(recording / "rest.npz"), "--calibration", str(recording / "truth.json"),
                 "--segment", "nope", "-o", str(tmp_path / "n.json")]) == 2
    assert "no segment labelled 'nope'" in capsys.readouterr().err


def test_cli_plain_recording(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    z = 0.01 * rng.standard_normal((20_000, 4))
    np.save(tmp_path / "z.npy", z)
    assert main(["noise", str(tmp_path / "z.npy"), "--sample-rate", "100", "--geometry", "tetrad4",
                 "--terms", "white", "-o", str(tmp_path / "n.json")]) == 0
    m = NoiseModel.load(tmp_path / "n.json")
    assert np.allclose(m["gyro"].terms["white"], 1e-3, rtol=0.03)
    assert m.parity["gyro"]["white"] is True
    assert main(["noise", str(tmp_path / "z.npy")]) == 2     # no sample rate


def test_a_moving_recording_is_refused_with_its_reason(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """Slow motion (0.5 rad/s at 0.05 Hz) over white noise of 1e-4 rad/s per sample hides the -1/2 slope at every
    averaging time: no white noise is identified, and the parity check, which needs it, is refused with the
    reason, not a shape error (the Pixhawk flight log did this from the command line)."""
    from rimu.errors import IdentifiabilityError
    from rimu.noise import identify

    t = np.arange(60000) / 100.0
    rng = np.random.default_rng(0)
    z = 0.5 * np.stack([np.sin(2 * np.pi * 0.05 * t + i) for i in range(6)], 1) + 1e-4 * rng.standard_normal((60000, 6))
    with pytest.raises(IdentifiabilityError, match="no white noise could be identified for 6 of 6 gyro.*static"):
        identify({"gyro": z}, 100.0, {"gyro": cone6().H}, terms=("white", "bias_instability", "rate_random_walk"))
    still = 1e-4 * rng.standard_normal((60000, 6))
    model = identify({"gyro": still}, 100.0, {"gyro": cone6().H}, terms=("white",))
    assert np.allclose(model["gyro"].terms["white"], 1e-5, rtol=0.05)  # 1e-4 per sample at 100 Hz: 1e-5 rad/sqrt(s)
