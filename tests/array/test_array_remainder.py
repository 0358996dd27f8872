"""rimu.array.remainder (issue 32, item 4): what is left of the gyro disagreement is judged deterministic only
when a candidate explains a stated share of it on held-out data, and its whiteness is measured (Ljung-Box)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from rimu.array import ljung_box, remainder_analysis

FS, K = 100.0, 8


def _rates(seed: int, tau: np.ndarray | None = None, ar: float = 0.0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(60 * FS)) / FS
    f = rng.uniform(0.2, 3.0, (6, 3))
    a = np.radians(rng.uniform(60, 150, (6, 3)))
    ph = rng.uniform(0, 2 * np.pi, (6, 3))

    def w(tt):
        return (a[None] * np.sin(2 * np.pi * f[None] * tt[:, None, None] + ph[None])).sum(axis=1)

    u = np.stack([w(t + (0.0 if tau is None else tau[j])) for j in range(K)], axis=1)
    e = rng.normal(0, np.radians(0.5), u.shape)
    if ar:
        e = lfilter([1.0], [1.0, -ar], e, axis=0)
    return t, u + e


def test_ljung_box_level():
    """Under white noise the p-value is uniform: about 1 % of series below 0.01."""
    rng = np.random.default_rng(0)
    p = np.array([ljung_box(rng.normal(size=500))[1] for _ in range(400)])
    assert 0.002 <= np.mean(p < 0.01) <= 0.03 and 0.4 < np.median(p) < 0.6


def test_white_noise_is_white_and_names_no_term():
    t, u = _rates(1)
    r = remainder_analysis(t, u)
    assert not r.deterministic and max(r.shares.values()) < 0.02, r.shares
    assert r.not_white_fraction < 0.05 and abs(r.lag1) < 0.05
    assert "white" in r.verdict and "not white" not in r.verdict
    assert r.rms_deg_s == pytest.approx(0.5 * np.sqrt(K / (K - 1)), rel=0.05)   # e_j - mean of the others


def test_correlated_noise_is_not_white_and_names_no_term():
    t, u = _rates(2, ar=0.6)
    r = remainder_analysis(t, u)
    assert not r.deterministic and r.not_white_fraction > 0.9 and r.lag1 == pytest.approx(0.6, abs=0.05)
    assert r.verdict.startswith("not explained by a deterministic term") and "not white" in r.verdict


def test_a_hidden_time_offset_is_named():
    tau = np.linspace(-2e-3, 2e-3, K)                    # +-2 ms between the triads
    t, u = _rates(3, tau=tau)
    r = remainder_analysis(t, u)
    assert r.deterministic and r.best[0].startswith("angular acceleration"), r.shares
    assert r.shares["angular acceleration (time offset)"] > 0.9
