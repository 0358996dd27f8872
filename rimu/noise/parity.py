"""Allan deviation of the normalised parity vector: are the sensors' noises white, and are they independent?

With the calibrated axes A (n, 3) and the per-sample white sigma of every sensor, ``W = diag(1 / sigma)`` and
``V_w`` the orthonormal left null space of ``W A`` (de Oliveira et al. 2012, Eq. 6-11, with weights), the
normalised parity ``p = V_w W z`` of a static recording removes the input (the Earth rate, gravity, and any
motion common to the unit, since ``V_w W A = 0``) and keeps only sensor errors. Two references:

* **white**: independent white noise of the stated sigmas gives ``Cov p = I`` and, per component,
  ``AVAR(tau = m / fs) = 1 / m``: the normalised deviation ``adev * sqrt(m)`` is 1 at every tau;
* **independent**: sensors with independent noise of the fitted models ``AVAR_i(tau)`` give, per parity
  component k, ``AVAR_k(tau) = sum_i (V_w W)_ki^2 AVAR_i(tau)``. A term shared by several sensors (a common
  temperature or supply effect on every bias, electrical cross-talk) breaks this: it adds the cross terms
  ``sum_{i != j} (V_w W)_ki (V_w W)_kj Cov_ij``, which the independent prediction lacks.

Each measured AVAR is tested against each reference with its chi-square distribution
(``edf AVAR_hat / AVAR ~ chi2(edf)``, Greenhall's edf for the local noise type), two-sided, at the level
``p_fa`` shared by all components and taus (Bonferroni). The verdict names the worst departure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2

from ..errors import ShapeError
from ..geometry.base import null_space_rows
from .allan import ALPHA_OF_TERM, AllanDeviation, allan_deviation
from .model import TERMS, InstrumentNoise

__all__ = ["ParityWhiteness", "normalised_parity_matrix", "parity_allan"]


def normalised_parity_matrix(axes_mb: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """``V_w W`` (n - 3, n): rows of the left null space of ``W A`` times ``W = diag(1 / sigma)``.

    >>> from rimu.geometry import cone6
    >>> Vn = normalised_parity_matrix(cone6().H, np.full(6, 2.0))
    >>> np.allclose(Vn @ np.diag(np.full(6, 4.0)) @ Vn.T, np.eye(3))
    True
    """
    A = np.asarray(axes_mb, dtype=float)
    s = np.asarray(sigma, dtype=float)
    if A.ndim != 2 or A.shape[1] != 3 or s.shape != (A.shape[0],):
        raise ShapeError(f"axes must be (n, 3) and sigma (n,), got {A.shape} and {s.shape}")
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise ShapeError("every sensor needs a positive finite white-noise sigma to normalise the parity")
    W = 1.0 / s
    V = null_space_rows(A * W[:, None])
    return V * W[None, :]


@dataclass
class ParityWhiteness:
    """The parity vector's Allan deviation and the two verdicts (module docstring).

    Attributes
    ----------
    instrument : str
    allan : AllanDeviation
        Of the parity components (dimensionless, unit per-sample variance when white).
    normalised : ndarray (dof, m)
        ``adev * sqrt(m)``: 1 for white noise.
    predicted : ndarray (dof, m) or None
        Normalised deviation predicted from independent sensors with the fitted models.
    white, independent : bool or None
        Whether every tau of every component is consistent with the reference at ``p_fa``.
    worst_white, worst_independent : dict
        Component, tau (s) and ratio measured/reference of the largest departure.
    p_fa : float
    """

    instrument: str
    allan: AllanDeviation
    normalised: np.ndarray
    predicted: np.ndarray | None
    white: bool
    independent: bool | None
    worst_white: dict[str, Any]
    worst_independent: dict[str, Any] | None
    p_fa: float

    def verdict(self) -> str:
        """One line per reference."""
        w = self.worst_white
        s = (f"{self.instrument} parity: {'white' if self.white else 'NOT white'} (largest departure: component "
             f"{w['component']} at tau = {w['tau']:.3g} s, deviation x{w['ratio']:.3g} of white)")
        if self.independent is not None and self.worst_independent is not None:
            d = self.worst_independent
            s += (f"; sensors {'independent' if self.independent else 'NOT independent (a common error term)'}"
                  f" (component {d['component']} at tau = {d['tau']:.3g} s: x{d['ratio']:.3g} of the prediction)")
        return s

    def to_dict(self) -> dict[str, Any]:
        return {
            "instrument": self.instrument,
            "tau": self.allan.tau.tolist(),
            "normalised_adev": self.normalised.tolist(),
            "normalised_lo": (self.allan.lo * np.sqrt(self.allan.cluster)).tolist(),
            "normalised_hi": (self.allan.hi * np.sqrt(self.allan.cluster)).tolist(),
            "predicted_independent": None if self.predicted is None else self.predicted.tolist(),
            "white": self.white,
            "independent": self.independent,
            "worst_white": self.worst_white,
            "worst_independent": self.worst_independent,
            "p_fa": self.p_fa,
            "verdict": self.verdict(),
        }


def _test(ad: AllanDeviation, ref_avar: np.ndarray, p_fa: float) -> tuple[bool, dict[str, Any]]:
    """Two-sided chi-square test of every measured AVAR against ``ref_avar`` (dof, m), Bonferroni at p_fa;
    ``ad.dof`` must be the degrees of freedom of the reference's noise type."""
    a = ad.adev ** 2
    stat = ad.dof * a / ref_avar
    level = p_fa / a.size
    lo = chi2.ppf(level / 2, ad.dof)
    hi = chi2.isf(level / 2, ad.dof)
    ok = (stat >= lo) & (stat <= hi)
    # the worst departure: the smallest two-sided tail probability
    tail = np.minimum(chi2.cdf(stat, ad.dof), chi2.sf(stat, ad.dof))
    k, j = np.unravel_index(int(np.argmin(tail)), tail.shape)
    return bool(ok.all()), {"component": int(k), "tau": float(ad.tau[j]),
                            "ratio": float(np.sqrt(a[k, j] / ref_avar[k, j]))}


def parity_allan(z: np.ndarray, axes_mb: np.ndarray, sample_rate: float, noise: InstrumentNoise | None = None,
                 sigma: np.ndarray | None = None, instrument: str = "gyro", p_fa: float = 1e-3,
                 per_decade: int = 8, max_fraction: float = 0.25) -> ParityWhiteness:
    """Allan deviation of the normalised parity of a static recording, with the white and independence verdicts.

    Parameters
    ----------
    z : ndarray (N, n)
        Compensated outputs (``SF y - b``), SI.
    axes_mb : ndarray (n, 3)
        Calibrated sensing axes.
    sample_rate : float
        Hz.
    noise : InstrumentNoise, optional
        The sensors' fitted models: give the per-sample sigma (unless ``sigma``) and the independence
        prediction.
    sigma : ndarray (n,), optional
        Per-sample white sigma, SI (default ``noise.sample_sigma(sample_rate)``).
    p_fa : float
        Probability of a false "not white" / "not independent" verdict for the whole curve.
    """
    z = np.asarray(z, dtype=float)
    if sigma is None:
        if noise is None:
            raise ShapeError("give the per-sample sigma of every sensor, or their noise model")
        sigma = noise.sample_sigma(sample_rate)
    Vn = normalised_parity_matrix(axes_mb, sigma)
    if Vn.shape[0] < 1:
        raise ShapeError(f"{Vn.shape[1]} sensors have no parity space (need 4 or more)")
    P = (z - z.mean(axis=0)) @ Vn.T
    ad = allan_deviation(P, sample_rate, [f"p{k}" for k in range(Vn.shape[0])], per_decade, max_fraction)
    white_avar = np.broadcast_to(1.0 / ad.cluster, ad.adev.shape)
    white, worst_w = _test(ad.with_alpha(np.zeros(ad.adev.shape, int)), white_avar, p_fa)
    predicted = independent = worst_i = None
    if noise is not None:
        per_term = []
        for t in TERMS:
            only = InstrumentNoise.from_terms(noise.instrument, noise.names, noise.sample_rate,
                                              **{t: noise.terms[t]})
            per_term.append((Vn ** 2) @ only.avar(ad.tau))  # (dof, m)
        per_term_a = np.array(per_term)
        pred_avar = per_term_a.sum(axis=0)
        alpha = np.array([ALPHA_OF_TERM[t] for t in TERMS])[np.argmax(per_term_a, axis=0)]
        independent, worst_i = _test(ad.with_alpha(alpha), pred_avar, p_fa)
        predicted = np.sqrt(pred_avar * ad.cluster[None, :])
    return ParityWhiteness(instrument, ad, ad.adev * np.sqrt(ad.cluster)[None, :], predicted, white, independent,
                           worst_w, worst_i, p_fa)
