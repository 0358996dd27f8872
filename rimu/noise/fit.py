"""Noise terms from the Allan variance: a weighted fit of the IEEE Std 952 / 1554 model, with uncertainties.

The model (IEEE Std 952-1997, Annex C, Eq. C.17-C.26; see :mod:`rimu.noise.model`) is linear in the squared
terms ``c = (Q^2, N^2, B^2, K^2)``::

    AVAR(tau_j) = sum_t A_jt c_t,   A_j = (3 / tau_j^2, 1 / tau_j, 2 ln 2 / pi, tau_j / 3)

The estimate of ``AVAR(tau_j)`` is a scaled chi-square with ``edf_j`` degrees of freedom (Greenhall & Riley),
so its variance is ``2 AVAR_j^2 / edf_j``. The fit minimises ``sum_j w_j (avar_j - A_j c)^2`` with
``w_j = edf_j / (2 model_j^2)``, non-negative c (``scipy.optimize.nnls``), iterating the weights on the
model (not on the noisy estimate, which would pull the fit low) and the edf on the model's dominant term
at each tau. Estimates at neighbouring taus of one record are positively correlated (the clusters overlap);
the covariance of c is ``(A^T W A)^-1`` times :data:`CORRELATION_INFLATION`, the ratio of the actual to the
nominal variance at the grid of :func:`rimu.noise.allan.tau_grid` (8 taus per decade), measured by Monte
Carlo on white, flicker and random-walk noise (the tests check it: normalised errors of recovered terms).
Term sigma by the delta method, ``sigma_T = sigma_c / (2 T)``; a term fitted at zero reports 0 with
``sqrt(sigma_c)`` as its sigma (an upper scale, not a Gaussian interval).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from ..errors import IdentifiabilityError
from .allan import ALPHA_OF_TERM, AllanDeviation
from .model import FLICKER_AVAR, TERMS, InstrumentNoise

__all__ = ["CORRELATION_INFLATION", "design_matrix", "fit_instrument", "fit_terms"]

#: variance inflation of the fitted c for the correlation of overlapping AVAR estimates (8 taus per decade)
CORRELATION_INFLATION = 4.5


def design_matrix(tau: np.ndarray) -> np.ndarray:
    """``A`` (m, 4): AVAR per unit of Q^2, N^2, B^2, K^2 at each tau (IEEE Std 952, Annex C).

    >>> design_matrix(np.array([1.0])).round(4).tolist()
    [[3.0, 1.0, 0.4413, 0.3333]]
    """
    tau = np.asarray(tau, dtype=float)
    return np.column_stack([3.0 / tau ** 2, 1.0 / tau, np.full_like(tau, FLICKER_AVAR), tau / 3.0])


def fit_terms(ad: AllanDeviation, terms: tuple[str, ...] = TERMS, iterations: int = 6,
              inflation: float = CORRELATION_INFLATION) -> tuple[np.ndarray, np.ndarray, AllanDeviation]:
    """Fit the terms of every sensor of an Allan deviation.

    Parameters
    ----------
    ad : AllanDeviation
    terms : tuple of str
        Terms to fit (the others are held at zero), a subset of :data:`rimu.noise.model.TERMS`.
    iterations : int
        Reweighting passes.
    inflation : float
        Variance inflation for the correlation between taus (module docstring).

    Returns
    -------
    values, sigma : ndarray (n, 4)
        Terms Q, N, B, K and their one-sigma uncertainties, SI.
    ad : AllanDeviation
        The input with its confidence intervals recomputed for the model's dominant term at each tau.
    """
    unknown = set(terms) - set(TERMS)
    if unknown:
        raise ValueError(f"unknown noise terms {sorted(unknown)}; choose from {TERMS}")
    cols = [TERMS.index(t) for t in terms]
    A_full = design_matrix(ad.tau)
    A = A_full[:, cols]
    n, m = ad.adev.shape
    if m < len(cols):
        raise IdentifiabilityError(f"{m} averaging times cannot determine {len(cols)} noise terms; "
                                   "record longer or fit fewer terms", list(terms))
    values = np.zeros((n, 4))
    sigma = np.zeros((n, 4))
    alpha = np.array(ad.alpha, dtype=int)
    term_alpha = np.array([ALPHA_OF_TERM[t] for t in TERMS])
    for i in range(n):
        a = ad.adev[i] ** 2
        model = a.copy()
        dof = ad.dof[i]
        c = np.zeros(len(cols))
        for _ in range(iterations):
            w = dof / (2.0 * np.maximum(model, 1e-300) ** 2)
            sw = np.sqrt(w)
            scale = np.abs(A * sw[:, None]).max(axis=0)  # column scaling: the columns span many decades
            scale[scale == 0] = 1.0
            cs, _ = nnls((A * sw[:, None]) / scale, a * sw)
            c = cs / scale
            model = A @ c
            if not np.any(model > 0):
                model = a.copy()
            contrib = A * c[None, :]
            dom = np.argmax(contrib, axis=1)
            alpha[i] = term_alpha[np.asarray(cols)[dom]]
            dof = np.array([_edf(int(al), int(mm), ad.n_samples) for al, mm in zip(alpha[i], ad.cluster)])
        w = dof / (2.0 * np.maximum(model, 1e-300) ** 2)
        F = (A * w[:, None]).T @ A
        cov = np.linalg.pinv(F) * inflation
        sc = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        for k, col in enumerate(cols):
            if c[k] > 0:
                values[i, col] = np.sqrt(c[k])
                sigma[i, col] = sc[k] / (2.0 * values[i, col])
            else:
                sigma[i, col] = np.sqrt(sc[k])
    return values, sigma, ad.with_alpha(alpha)


def _edf(alpha: int, m: int, n_samples: int) -> float:
    from .allan import edf

    return edf(alpha, m, n_samples)


def fit_instrument(ad: AllanDeviation, instrument: str, terms: tuple[str, ...] = TERMS) -> InstrumentNoise:
    """:func:`fit_terms` packed as an :class:`rimu.noise.model.InstrumentNoise` (with the measured curve)."""
    values, sigma, ad2 = fit_terms(ad, terms)
    return InstrumentNoise(instrument, list(ad.names), {t: values[:, k] for k, t in enumerate(TERMS)},
                           {t: sigma[:, k] for k, t in enumerate(TERMS)}, ad.sample_rate, ad2.to_dict(),
                           {"fitted_terms": list(terms), "n_samples": ad.n_samples})
