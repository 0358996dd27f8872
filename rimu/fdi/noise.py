"""Online estimate of each sensor's noise level from the parity vector (unequal noise, weighted parity).

The pipeline's parity ``p = Vz z`` is normalised with the noise levels it was built with (sigma_0). If the
true levels are sigma, then without a fault ``E[p p^T] = Vz diag(sigma^2) Vz^T``: linear in sigma^2. Each
entry (k, l) of the sample covariance gives one equation ``sum_i Vz[k, i] Vz[l, i] sigma_i^2``; with
``r (r + 1) / 2 >= n`` independent equations the levels follow by least squares (five or more sensors;
four sensors give one equation and only the weighted sum ``sum v_i^2 sigma_i^2``, which
:meth:`NoiseEstimator.sigma` refuses to split). Symmetric geometries can lose one more direction: in cone6
(two orthonormal triads) ``V_2 V_2^T = V_1 V_1^T``, so a common change of triad 1 against triad 2 is
invisible to the parity and only five combinations of the six levels are identified. Feed the result back as ``InstrumentPipeline(cal,
sigma=...)`` to whiten the parity with the right weights (de Oliveira et al. 2012, Eq. 11 with weights).
"""

from __future__ import annotations

import numpy as np

from ..errors import IdentifiabilityError

__all__ = ["NoiseEstimator"]


class NoiseEstimator:
    """Accumulate parity outer products of one active set and solve for per-sensor noise.

    Parameters
    ----------
    Vz : ndarray (r, n)
        Normalised parity rows the parity vectors were made with (``table.Vz[entry][:dof]``).

    Examples
    --------
    >>> from rimu.geometry import dodecahedron6
    >>> V = dodecahedron6().parity_matrix()   # built for sigma_0 = 1
    >>> true = np.array([1.0, 1.0, 2.0, 1.0, 1.0, 1.0])
    >>> rng = np.random.default_rng(0)
    >>> est = NoiseEstimator(V)
    >>> est.add((rng.standard_normal((200000, 6)) * true) @ V.T)
    >>> np.round(est.sigma(), 1).tolist()
    [1.0, 1.0, 2.0, 1.0, 1.0, 1.0]
    """

    def __init__(self, Vz: np.ndarray) -> None:
        V = np.asarray(Vz, dtype=float)
        self.V = V
        r, _n = V.shape
        iu = np.triu_indices(r)
        self._iu = iu
        self._A = V[iu[0]] * V[iu[1]]  # (r(r+1)/2, n)
        self._S = np.zeros((r, r))
        self.count = 0

    def add(self, P: np.ndarray) -> None:
        """Add parity vectors, (N, r) or (r,)."""
        P = np.atleast_2d(np.asarray(P, dtype=float))[:, : self.V.shape[0]]
        self._S += P.T @ P
        self.count += len(P)

    def sigma(self) -> np.ndarray:
        """Noise levels (n,), in the units sigma_0 was given in (multiply by sigma_0 when Vz was whitened)."""
        if self.count < 2:
            raise IdentifiabilityError("no parity samples yet", ["sigma"])
        act = np.linalg.norm(self.V, axis=0) > 1e-12
        A = self._A[:, act]
        if np.linalg.matrix_rank(A, tol=1e-9) < A.shape[1]:
            raise IdentifiabilityError(
                f"{int(act.sum())} sensors with parity dimension {self.V.shape[0]}: the individual noise levels "
                "cannot be separated (only their weighted sum); state them from the calibration", ["sigma"])
        C = self._S / self.count
        b = C[self._iu]
        s2, *_ = np.linalg.lstsq(A, b, rcond=None)
        out = np.full(self.V.shape[1], np.nan)
        out[act] = np.sqrt(np.clip(s2, 0.0, None))
        return out
