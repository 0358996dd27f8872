"""A baseline like the autopilots use: disagreement from the mean, accumulated with a dead band.

PX4's sensor voting (``DataValidatorGroup``, and the IMU inconsistency check of its sensors module) compares
each sensor with the mean of all and accumulates the error over time. For skewed axes the "mean" is the
least-squares estimate ``x_hat`` of all active sensors, and each sensor's disagreement is its residual
``d_i = |z_i - a_i . x_hat| / sigma_i``. It is accumulated with a dead band ``c`` (in sigma)::

    E_i = max(0, E_i + d_i - c),   alarm when E_i > h, sensor i isolated

The residual is read from the parity vector: ``(z - A x_hat) / sigma = V_w^T p`` (whitened), so
``d_i = |(Vz^T p)_i| sigma_i``; without a fault ``d_i ~ |N(0, |v_wi|^2)|``. The threshold h comes from the
in-control ARL (mean samples between false alarms) by the Markov-chain method of Brook & Evans 1972
(:func:`rimu.fdi.cusum.markov_arl`), not by hand.

Unlike the GLT, the residual of a healthy sensor also moves when another sensor is faulty (the fault leaks
into x_hat), which is what makes this baseline isolate worse: the campaigns show by how much.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from .cusum import cached_design, markov_arl

__all__ = ["MeanDisagreement"]

#: thresholds already designed: (residual std, members, dead band, arl0) -> h (shared by all instances)
_H_CACHE: dict[tuple[float, int, float, float], float] = {}


class MeanDisagreement:
    """Dead-band accumulation of each sensor's disagreement with the mean (see module doc).

    Parameters
    ----------
    sigma : float or ndarray (n,)
        Noise of the compensated outputs, SI (the pipeline's ``table.sigma``).
    dead_band : float
        c, in sigma.
    arl0 : float
        In-control ARL of the whole bank, samples (each member is designed for ``n * arl0``).
    """

    name = "mean_disagreement"
    window = 1

    def __init__(self, sigma: float | np.ndarray, dead_band: float = 2.0, arl0: float = 1e5) -> None:
        self.sigma = np.asarray(sigma, dtype=float)
        self.dead_band = float(dead_band)
        self.arl0 = float(arl0)
        self._dof = 0

    def _h(self, s: float, members: int) -> float:
        s = round(s, 3)  # thresholds change negligibly below 0.1 % of sigma; designs are shared
        key = (s, members, self.dead_band, self.arl0)
        if key not in _H_CACHE:
            c = self.dead_band

            def cdf(x: np.ndarray) -> np.ndarray:  # increment |N(0, s^2)| - c
                y = np.maximum(x + c, 0.0)
                return 2 * ndtr(y / s) - 1

            target = members * self.arl0
            hi = 1.0
            while markov_arl(hi, cdf, 120) < target:
                hi *= 2
            from scipy.optimize import brentq  # imported where used: scipy.optimize is ~18 MB
            _H_CACHE[key] = float(brentq(lambda h: markov_arl(h, cdf, 120) - target, hi / 2 if hi > 1 else 1e-3, hi,
                                            xtol=1e-3))
        return _H_CACHE[key]

    def design(self, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return cached_design(self, Vz, dof)

    def _design(self, Vz: np.ndarray, dof: int):  # type: ignore[no-untyped-def]
        V = np.asarray(Vz)[:dof]
        n = V.shape[1]
        sig = np.broadcast_to(self.sigma, (n,))
        s = np.linalg.norm(V, axis=0) * sig  # residual std in sigma
        act = s > 1e-9
        h = np.full(n, np.inf)
        for j in np.flatnonzero(act):
            h[j] = self._h(float(s[j]), int(act.sum()))
        return V * sig[None, :], h, act

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        self._dof = int(dof)
        n = Vz.shape[1]
        self._E = np.zeros(n)
        if dof >= 1:
            self._M, self._h_all, self._act = self.design(Vz, dof)

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        if self._dof < 1:
            return 0.0, float("inf")
        d = np.abs(parity[:self._dof] @ self._M)
        E = self._E
        E += d - self.dead_band
        np.maximum(E, 0.0, out=E)
        r = E / self._h_all
        self._last = int(np.argmax(r))
        return float(r[self._last]), 1.0

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        return (self._last if self._dof >= 2 else -1), self._E / self._h_all

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int) -> tuple[np.ndarray, float, np.ndarray]:
        M, h, _act = self.design(Vz, dof)
        D = np.abs(P[:, :dof] @ M) - self.dead_band
        N, n = D.shape
        out = np.zeros(N)
        iso = np.full(N, -1)
        E = np.zeros(n)
        for t in range(N):
            E += D[t]
            np.maximum(E, 0.0, out=E)
            r = E / h
            k = int(np.argmax(r))
            out[t] = r[k]
            if r[k] > 1.0:
                iso[t] = k if dof >= 2 else -1
                E[:] = 0.0
        return out, 1.0, iso
