"""Detectors with a sensor noise model keep their design false-alarm rate under bias instability; the
white-noise-only design does not. Each realisation is an independent unit: a reference window (the bias
estimate), then the detector's statistic ``horizon`` later (the exact marginal the design targets)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from rimu.calibration import Calibration, InstrumentCalibration
from rimu.fdi import CusumBank, GltSnapshot, GltWindow, ParityKalman
from rimu.fdi.whitening import NoiseSettings, window_covariance
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6
from rimu.noise import InstrumentNoise, NoiseModel
from rimu.noise.parity import normalised_parity_matrix
from rimu.sim.noise import FlickerSource

FS, SIG, N_SENS = 100.0, 0.01, 6
B = SIG / 20          # bias instability: 1/20 of the per-sample white sigma
T_REF, HORIZON = 2.0, 300.0
BAND = (0.1, 3000.0)  # flicker time constants, s: the 1/f band covers the windows (1-20 s) and the horizon
P_FA = 0.05


def _model(b: float = B) -> InstrumentNoise:
    return InstrumentNoise.from_terms("gyro", cone6().names, FS, white=SIG / np.sqrt(FS), bias_instability=b)


VZ = normalised_parity_matrix(cone6().H, np.full(N_SENS, SIG))


def realisations(R: int, L: int, seed: int) -> np.ndarray:
    """Parity (L, R, 3) of the L samples ending HORIZON after a reference of T_REF, bias removed by it."""
    rng = np.random.default_rng(seed)
    src = FlickerSource(N_SENS * R, FS, B, band_s=BAND, per_decade=4, rng=rng)
    nr = int(T_REF * FS)
    ref = (src.draw(nr) + SIG * rng.standard_normal((nr, N_SENS * R))).mean(axis=0)
    src.skip(int(HORIZON * FS) - L)
    z = src.draw(L) + SIG * rng.standard_normal((L, N_SENS * R)) - ref
    return z.reshape(L, R, N_SENS) @ VZ.T


@pytest.fixture(scope="module")
def settings() -> NoiseSettings:
    return NoiseSettings(_model(), horizon_s=HORIZON, reference_s=T_REF)


@pytest.fixture(scope="module")
def glt_data() -> np.ndarray:
    return realisations(1000, 200, 1)


def _rate_at_end(det, P: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """Alarm rate of the statistic at the last sample of each realisation (realisations back to back: the
    window and the Kalman estimate forget the previous realisation, (1 - K)^200 < 1e-4 for K = 0.05)."""
    L, R, d = P.shape
    flat = P.transpose(1, 0, 2).reshape(R * L, d)
    stat, thr, _ = det.block(flat, VZ, d)
    return float(np.mean(stat[L - 1::L] > thr))


@pytest.mark.parametrize("make, white_fails", [
    (lambda nz: GltSnapshot(P_FA, noise=nz), False),
    (lambda nz: GltWindow(100, P_FA, noise=nz), True),
    (lambda nz: ParityKalman(20, P_FA, engine="steady", noise=nz), True),
])
def test_glt_and_kalman_hold_design_rate(make, white_fails, settings, glt_data) -> None:  # type: ignore[no-untyped-def]
    R = glt_data.shape[1]
    lo, hi = binom.ppf(0.0005, R, P_FA) / R, binom.isf(0.0005, R, P_FA) / R    # two-sided 99.9 %
    with_model = _rate_at_end(make(settings), glt_data)
    white_only = _rate_at_end(make(None), glt_data)
    assert lo <= with_model <= hi, (with_model, lo, hi)
    if white_fails:
        assert white_only > 2 * hi, white_only     # measured 0.27 (window of 100), 0.20 (Kalman, tau 20)
    else:
        assert white_only <= 1.5 * hi              # one sample: the wander is 1 % of the variance


def test_cusum_holds_design_rate_white_design_does_not(settings) -> None:  # type: ignore[no-untyped-def]
    """Bank ARL0 = 1000 samples; 250 realisations of 2000 samples each end at the horizon (renewal after
    every alarm). Siegmund's formula and the quasi-static wander are approximations: the measured rate must be
    within [0.4, 1.25] of the design with the model, and beyond 2.5 times it without."""
    R, w, arl0 = 250, 2000, 1000.0
    P = realisations(R, w, 2)
    rates = {}
    for name, nz in (("white", None), ("model", settings)):
        bank = CusumBank(0.5 * SIG, arl0, noise=nz)
        U, d, thr, _ = bank.design(VZ, 3)
        # the bank's own block() on one realisation agrees with the vectorised loop below
        X = P @ U
        S = np.zeros((2, R, N_SENS))
        alarms = 0
        first = []
        for t in range(w):
            S[0] += d * (X[t] - d / 2)
            S[1] += d * (-X[t] - d / 2)
            np.maximum(S, 0.0, out=S)
            r = (S / thr).max(axis=(0, 2))
            first.append(r[0])
            hit = r > 1.0
            alarms += int(hit.sum())
            S[:, hit, :] = 0.0
        ref, _, _ = bank.block(P[:, 0, :], VZ, 3)
        assert np.allclose(ref, first)
        rates[name] = alarms / (R * w) * arl0
    assert 0.4 <= rates["model"] <= 1.25, rates      # measured 0.45
    assert rates["white"] > 2.5, rates                 # measured 4.9


def test_white_model_at_pipeline_levels_changes_nothing() -> None:
    """A noise model of white noise at the pipeline's own sigma and horizon 0 whitens with the identity."""
    m = _model(0.0)
    rng = np.random.default_rng(3)
    P = rng.standard_normal((400, 3))
    for make in (lambda nz: GltSnapshot(1e-3, noise=nz), lambda nz: GltWindow(10, 1e-3, noise=nz),
                 lambda nz: ParityKalman(20, 1e-3, engine="steady", noise=nz),
                 lambda nz: CusumBank(0.5 * SIG, 1e4, noise=nz)):
        a = make(None).block(P, VZ, 3)[0]
        b = make(NoiseSettings(m, horizon_s=0.0)).block(P, VZ, 3)[0]
        assert np.allclose(a, b, rtol=1e-9, atol=1e-12)
    C = window_covariance(VZ, 3, NoiseSettings(m, horizon_s=0.0), 25)
    assert np.allclose(C, np.eye(3))


def test_manager_detectors_agree_with_block(settings) -> None:  # type: ignore[no-untyped-def]
    """The per-sample path (update) gives the statistics of block() with the noise model."""
    rng = np.random.default_rng(4)
    P = rng.standard_normal((300, 3)) + 0.3
    for det in (GltSnapshot(1e-3, noise=settings), GltWindow(20, 1e-3, noise=settings),
                ParityKalman(20, 1e-3, engine="steady", noise=settings), CusumBank(0.5 * SIG, 1e4, noise=settings)):
        det.configure(VZ, 3)
        seq = np.array([det.update(p)[0] for p in P])
        blk, _, _ = det.block(P, VZ, 3)
        if isinstance(det, CusumBank):
            k = int(np.argmax(blk > 1.0)) if np.any(blk > 1.0) else len(P)  # block() restarts after an alarm
            assert np.allclose(seq[:k], blk[:k])
        else:
            assert np.allclose(seq, blk)


def test_fdi_reads_the_noise_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The noise file -> the calibration's noise section -> the pipeline's sigma and the detectors' model."""
    nm = NoiseModel({"gyro": _model()})
    nm.save(tmp_path / "noise.json")
    loaded = NoiseModel.load(tmp_path / "noise.json")
    ic = InstrumentCalibration.nominal("gyro", cone6(), scale=1.0)
    ic.noise = loaded["gyro"]
    Calibration({"gyro": ic}).save(tmp_path / "cal.json")
    cal = Calibration.load(tmp_path / "cal.json")
    pipe = InstrumentPipeline(cal["gyro"])
    assert np.allclose(pipe.table.sigma, SIG)             # per-sample sigma N sqrt(fs) from the model
    det = GltWindow(100, P_FA, noise=NoiseSettings(cal["gyro"].noise, horizon_s=HORIZON, reference_s=T_REF))
    det.configure(pipe.table.Vz[pipe.table.lookup(pipe.table.full_code)], 3)
    ref = GltWindow(100, P_FA, noise=NoiseSettings(_model(), horizon_s=HORIZON, reference_s=T_REF))
    ref.configure(VZ, 3)
    # the same whitening up to the parity basis: equal statistic for the same window sum
    assert np.isclose(np.linalg.det(det._L) ** 2, np.linalg.det(ref._L) ** 2, rtol=1e-9)


def test_manager_default_detector_reads_the_calibration_noise() -> None:
    from rimu.fdi import RedundancyManager
    from rimu.sim import Simulator

    truth = Simulator(gyro_bias_instability_deg_h=3.0, seed=0).truth_calibration()
    assert truth["gyro"].noise is not None and truth["accel"].noise is None
    assert np.allclose(truth["gyro"].noise.sample_sigma(), truth["gyro"].noise_sigma)
    mgr = RedundancyManager(InstrumentPipeline(truth["gyro"]))
    assert mgr.detector.noise is not None and mgr.detector.noise.noise is truth["gyro"].noise
    assert RedundancyManager(InstrumentPipeline(truth["accel"])).detector.noise is None
