"""Generalized likelihood test on the normalised parity vector (Daly, Gai & Harrison 1979).

With the pipeline's normalised parity ``p = V_w W z`` (unit covariance without a fault, see
:mod:`rimu.fusion.projection`):

* detection: ``FD = p^T p`` against the chi-square quantile with ``dof = n_active - 3`` degrees of freedom
  at the design false-alarm probability;
* isolation: a bias ``b`` on sensor j adds ``b v_j`` to p, where v_j is column j of ``V_w W``; the
  likelihood ratio of "sensor j" is ``(v_j^T p)^2 / |v_j|^2`` and the isolated sensor is its argmax.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

__all__ = ["glt_threshold", "GltDecision", "glt_snapshot"]


def glt_threshold(p_fa: float, dof: int) -> float:
    """Chi-square threshold with false-alarm probability ``p_fa`` for ``dof`` degrees of freedom.

    >>> round(glt_threshold(1e-3, 3), 4)
    16.2662
    """
    if not 0 < p_fa < 1:
        raise ValueError(f"p_fa must be in (0, 1), got {p_fa}")
    if dof < 1:
        return float("inf")
    return float(chi2.isf(p_fa, dof))


@dataclass
class GltDecision:
    statistic: float
    threshold: float
    detected: bool
    isolated: int  # -1 when not isolable or not detected
    ratios: np.ndarray


def glt_snapshot(parity: np.ndarray, Vz: np.ndarray, dof: int, p_fa: float = 1e-3,
                 active: np.ndarray | None = None) -> GltDecision:
    """One-sample GLT decision.

    Parameters
    ----------
    parity : ndarray (n - 3,)
        Normalised parity vector (zero-padded past ``dof``).
    Vz : ndarray (n - 3, n)
        The parity matrix that produced it (``ProjectionTable.Vz[entry]``).
    dof : int
    p_fa : float
    active : ndarray of bool, optional
        Candidates for isolation (default: sensors with a non-zero parity column).
    """
    p = parity[:dof]
    V = Vz[:dof]
    fd = float(p @ p)
    thr = glt_threshold(p_fa, dof)
    norms2 = np.einsum("ij,ij->j", V, V)
    cand = norms2 > 1e-12 if active is None else (np.asarray(active, bool) & (norms2 > 1e-12))
    ratios = np.zeros(V.shape[1])
    ratios[cand] = (V[:, cand].T @ p) ** 2 / norms2[cand]
    detected = fd > thr
    iso = int(np.argmax(ratios)) if (detected and dof >= 2 and cand.any()) else -1
    return GltDecision(fd, thr, detected, iso, ratios)
