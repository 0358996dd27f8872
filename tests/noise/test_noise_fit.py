"""Noise terms recovered from simulated noise of known size, within their stated uncertainties; closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rimu.noise import InstrumentNoise, allan_deviation, fit_terms
from rimu.noise.model import FLICKER_AVAR, TERMS, _flicker_g, window_mean_difference_variance
from rimu.sim.noise import FlickerSource

FS = 100.0
ZERO = {t: [0.0] for t in TERMS}


def test_allan_deviation_matches_closed_form_of_each_term() -> None:
    """Model AVAR (IEEE Std 952, Annex C) against the structure-function form at lag = tau: 2 AVAR."""
    for term, value in (("white", 0.3), ("bias_instability", 0.7), ("rate_random_walk", 0.05), ("quantization", 0.2)):
        terms = dict(ZERO, **{term: [value]})
        m = InstrumentNoise.from_terms("gyro", ["a"], FS, **{term: value})
        for tau in (0.5, 3.0, 40.0):
            assert math.isclose(window_mean_difference_variance(tau, tau, 0.0, terms)[0], 2 * m.avar(tau)[0, 0],
                                rel_tol=1e-9)


def test_flicker_structure_closed_form() -> None:
    """Equal windows at lag T = r tau: (B^2 / pi) g(r), g(1) = 4 ln 2, g(r) -> 2 ln r + 3."""
    terms = dict(ZERO, bias_instability=[1.0])
    for r in (1.0, 2.0, 10.0, 1000.0):
        v = window_mean_difference_variance(1.0, 1.0, r - 1.0, terms)[0]
        assert math.isclose(v, _flicker_g(r) / math.pi, rel_tol=1e-9)
    assert math.isclose(_flicker_g(1.0), 4 * math.log(2), rel_tol=1e-12)
    assert abs(_flicker_g(1e4) - (2 * math.log(1e4) + 3)) < 1e-6
    assert math.isclose(FLICKER_AVAR * math.pi, 2 * math.log(2))


def test_difference_variance_term_by_term() -> None:
    """docs/noise.md: white N^2 (1/tau + 1/tau_ref), quantisation 2 Q^2 (1/tau^2 + 1/tau_ref^2), rate random walk
    K^2 (r tau - tau / 3) for equal windows whose starts are r tau apart."""
    tau, ref, lag = 2.0, 7.0, 30.0
    assert math.isclose(window_mean_difference_variance(tau, ref, lag, dict(ZERO, white=[0.3]))[0],
                        0.09 * (1 / tau + 1 / ref), rel_tol=1e-9)
    assert math.isclose(window_mean_difference_variance(tau, ref, lag, dict(ZERO, quantization=[0.2]))[0],
                        2 * 0.04 * (1 / tau ** 2 + 1 / ref ** 2), rel_tol=1e-9)
    for r in (1.0, 3.0, 50.0):
        v = window_mean_difference_variance(tau, tau, (r - 1) * tau, dict(ZERO, rate_random_walk=[0.1]))[0]
        assert math.isclose(v, 0.01 * (r * tau - tau / 3), rel_tol=1e-9)


@pytest.mark.parametrize("term, size", [("white", 0.3), ("bias_instability", 1.0), ("rate_random_walk", 0.05)])
def test_window_difference_variance_against_monte_carlo(term: str, size: float) -> None:
    """3000 independent realisations: variance of (mean over 1 s, 50 s after) - (mean over 10 s), 3 sigma."""
    fs, R = 10.0, 3000
    ref, lag, tau = 10.0, 50.0, 1.0
    nr, nl, nt = int(ref * fs), int(lag * fs), int(tau * fs)
    N = nr + nl + nt
    rng = np.random.default_rng(7)
    if term == "white":
        y = size * math.sqrt(fs) * rng.standard_normal((N, R))
    elif term == "bias_instability":
        y = FlickerSource(R, fs, size, band_s=(0.05, 1e4), per_decade=6, rng=rng).draw(N)
    else:
        y = np.cumsum(rng.standard_normal((N, R)), axis=0) * size / math.sqrt(fs)
    d = y[nr + nl:].mean(axis=0) - y[:nr].mean(axis=0)
    pred = window_mean_difference_variance(tau, ref, lag, dict(ZERO, **{term: [size]}))[0]
    ratio = d.var() / pred
    assert abs(ratio - 1) < 3 * math.sqrt(2 / R) + 0.02, ratio   # + 2 %: the discrete simulation of each process


def _simulate(seed: int, N: int, n: int, truth: dict[str, float]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = truth["white"] * math.sqrt(FS) * rng.standard_normal((N, n))
    z += FlickerSource(n, FS, truth["bias_instability"], band_s=(0.05, 1e5), rng=rng).draw(N)
    z += np.cumsum(rng.standard_normal((N, n)), axis=0) * truth["rate_random_walk"] / math.sqrt(FS)
    if truth.get("quantization", 0.0) > 0:
        q = truth["quantization"] * math.sqrt(12.0)    # angle step whose rounding error has variance Q^2
        angle = np.cumsum(z, axis=0) / FS
        z = np.diff(np.round(angle / q) * q, axis=0, prepend=0.0) * FS
    return z


def test_terms_recovered_within_their_uncertainty() -> None:
    """White noise, flicker bias and rate random walk of known size, 6 seeds x 4 sensors of 1000 s: every
    term within 3.5 sigma, and rms(error / sigma) within the chi-square band of 24 samples per term."""
    truth = {"white": 0.01, "bias_instability": 0.002, "rate_random_walk": 0.0005}
    errs = []
    for seed in range(6):
        z = _simulate(seed, 100_000, 4, truth)
        v, s, _ = fit_terms(allan_deviation(z, FS), terms=("white", "bias_instability", "rate_random_walk"))
        errs.append((v[:, 1:] - np.array(list(truth.values()))) / s[:, 1:])
    e = np.concatenate(errs)
    assert np.all(np.abs(e) < 3.5), np.abs(e).max(axis=0)
    rms = np.sqrt((e ** 2).mean(axis=0))
    assert np.all((rms > 0.65) & (rms < 1.46)), rms    # 99.8 % band of sqrt(chi2(24) / 24): [0.65, 1.46]


def test_quantization_and_white_recovered() -> None:
    """Angle quantisation (white phase noise, AVAR = 3 Q^2 / tau^2) next to white rate noise. The angle step q
    is twice the per-sample angle increment's sigma, so that the rounding error is white with variance q^2 / 12."""
    q_step = 2 * 0.001 / math.sqrt(FS)
    truth = {"white": 0.001, "bias_instability": 0.0, "rate_random_walk": 0.0, "quantization": q_step / math.sqrt(12)}
    z = _simulate(11, 100_000, 4, truth)
    v, s, _ = fit_terms(allan_deviation(z, FS), terms=("quantization", "white"))
    for k, t in ((0, "quantization"), (1, "white")):
        assert np.all(np.abs(v[:, k] - truth[t]) < 3.5 * s[:, k]), (t, v[:, k], s[:, k])
    assert np.all(v[:, 0] > 5 * s[:, 0])     # detected, not merely bounded


def test_confidence_interval_covers_white_noise_truth() -> None:
    """The one-sigma interval of the Allan deviation covers the white-noise truth at about 68 % of taus."""
    rng = np.random.default_rng(5)
    ad = allan_deviation(rng.standard_normal((50_000, 20)), FS)
    truth = 1.0 / np.sqrt(ad.cluster)[None, :]
    cover = np.mean((ad.lo <= truth) & (truth <= ad.hi))
    assert 0.6 < cover < 0.76, cover


def test_bad_input_is_refused() -> None:
    from rimu.errors import NonFiniteError, ShapeError

    z = np.zeros((100, 2))
    z[5, 1] = np.nan
    with pytest.raises(NonFiniteError, match="non-finite"):
        allan_deviation(z, FS)
    with pytest.raises(ShapeError, match="16 samples"):
        allan_deviation(np.zeros((5, 2)), FS)
    with pytest.raises(ValueError, match="unknown noise terms"):
        fit_terms(allan_deviation(np.random.default_rng(0).standard_normal((1000, 1)), FS), terms=("pink",))
