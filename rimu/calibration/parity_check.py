"""The parity vectors of a calibration on its +w / -w rate pairs: de Oliveira et al. 2012, Eq. 21-25.

This is the one implementation of de Oliveira's parity-based calibration check. The estimator
:class:`rimu.calibration.Oliveira` attaches its raw figures to its result; :func:`rimu.experiments.quality.parity_quality`
(the check a user runs, ``rimu check``) turns them into a chi-square verdict that also carries the
calibration's own uncertainty.

For each pair of consecutive rate segments with opposite commanded rates (+w, -w about one MB direction; de
Oliveira's Table 1 pairs 1-2, 3-4, ...), with ``g_n`` the mean raw output of sequence n:

* ``g_b = 1/2 SF (g_n + g_n+1) - B``: bias residue and Earth rate, the commanded rate removed (Eq. 21);
* ``g_w = 1/2 SF (g_n - g_n+1)``: the commanded rate only, bias and Earth rate removed (Eq. 22-23);
* ``v g_w`` with the nominal parity vector v of H (Eq. 23, 24) and ``v_c g_w`` with the parity vector of the
  calibrated axes M H (Eq. 22, 25).

With a correct calibration ``v_c`` annihilates the calibrated axes, so ``v_c g_w`` is noise only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import SessionFormatError
from ..geometry import null_space_rows
from ..session import Session, SessionStatistics
from .result import InstrumentCalibration

__all__ = ["PairParity", "opposite_rate_pairs", "pair_parity"]


def _rate(seg: Any) -> np.ndarray | None:
    if seg.rate_mb is not None:
        return np.asarray(seg.table_rate(), dtype=float)
    c = seg.meta.get("commanded_rate_mb")
    return None if c is None else np.asarray(c, dtype=float)


def opposite_rate_pairs(session: Session) -> list[tuple[int, int]]:
    """Indices of consecutive rate segments with opposite commanded rates (+w, -w)."""
    segs = session.segments
    out = []
    k = 0
    while k + 1 < len(segs):
        ra, rb = _rate(segs[k]), _rate(segs[k + 1])
        if (ra is not None and rb is not None and np.linalg.norm(ra) > 0
                and np.allclose(ra, -rb, atol=1e-9 + 1e-6 * np.linalg.norm(ra))):
            out.append((k, k + 1))
            k += 2
        else:
            k += 1
    return out


@dataclass
class PairParity:
    """Parity figures of every +w / -w pair (SI units).

    Attributes
    ----------
    v, v_c : ndarray (n - 3, n)
        Nominal (Eq. 24) and calibrated (Eq. 25) parity matrices, v_c with the sign convention of v.
    labels : list of (str, str)
    rate_mb : ndarray (K, 3)
        Commanded rate w of each pair's first segment, rad/s.
    nominal, corrected : ndarray (K, n - 3)
        ``v g_w`` (Eq. 23) and ``v_c g_w`` (Eq. 22).
    bias_parity : ndarray (K, n - 3)
        ``v_c g_b`` (Eq. 21 residue through the calibrated parity).
    var_g_w : ndarray (K, n)
        Noise variance of each sensor's ``g_w`` (white noise of the means).
    """

    v: np.ndarray
    v_c: np.ndarray
    labels: list[tuple[str, str]]
    rate_mb: np.ndarray
    nominal: np.ndarray
    corrected: np.ndarray
    bias_parity: np.ndarray
    var_g_w: np.ndarray

    @property
    def noise_std(self) -> np.ndarray:
        """(K, n - 3) standard deviation of ``corrected`` from white noise alone."""
        return np.sqrt(self.var_g_w @ (self.v_c**2).T)


def pair_parity(session: Session, calibration: InstrumentCalibration,
                stats: SessionStatistics | None = None) -> PairParity:
    """de Oliveira et al. 2012, Eq. 21-25 on every +w / -w pair of ``session`` (see the module docstring).
    ``stats``: a :class:`~rimu.session.SessionStatistics` of the session whose segment means to use (an
    estimator's own), default a new one.

    Raises
    ------
    SessionFormatError
        Fewer than four sensors (no parity space), no ``noise_sigma`` in the calibration, or no pair of
        consecutive rate segments with opposite commanded rates.
    """
    cal = calibration
    inst, g = cal.instrument, cal.geometry
    if g.n < 4:
        raise SessionFormatError(f"a parity check needs at least four sensors; {g.name} has {g.n} (no parity space)")
    if cal.noise_sigma is None:
        raise SessionFormatError("the calibration states no noise_sigma; the check needs the noise of each sensor")
    pairs = opposite_rate_pairs(session)
    if not pairs:
        raise SessionFormatError("the session has no pair of consecutive rate segments with opposite commanded "
                                 "rates (+w, -w); the parity check needs them (de Oliveira Table 1)")
    v = null_space_rows(g.H)                    # Eq. 24 (nominal)
    vc = null_space_rows(cal.axes_mb())         # Eq. 25 (calibrated)
    for k in range(min(len(v), len(vc))):       # the sign convention of v, so the two compare entry by entry
        if vc[k] @ v[k] < 0:
            vc[k] = -vc[k]
    sig2 = cal.noise_sigma**2
    stats = stats or SessionStatistics(session)
    labels, rates, nom, cor, bpar, var = [], [], [], [], [], []
    for a, b in pairs:
        sa, sb = session.segments[a], session.segments[b]
        ya, yb = sa.raw[inst], sb.raw[inst]
        ma, mb = stats.mean(sa, inst), stats.mean(sb, inst)
        g_w = 0.5 * cal.scale * (ma - mb)             # Eq. 22-23: commanded rate only
        g_b = 0.5 * cal.scale * (ma + mb) - cal.bias  # Eq. 21: bias (and Earth rate) with the rate removed
        labels.append((sa.label, sb.label))
        rates.append(_rate(sa))
        nom.append(v @ g_w)
        cor.append(vc @ g_w)
        bpar.append(vc @ g_b)
        var.append(0.25 * sig2 * (1.0 / len(ya) + 1.0 / len(yb)))
    return PairParity(v, vc, labels, np.array(rates), np.array(nom), np.array(cor), np.array(bpar), np.array(var))
