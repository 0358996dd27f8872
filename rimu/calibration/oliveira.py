"""de Oliveira et al. 2012: calibration of a gyro tetrad from rate sequences only, with parity-vector checks.

The tetrad is partitioned into a triad and a fourth sensor (de Oliveira et al. 2012, Eq. 13-14): sub-unit
``T`` (g1, g2, g3, basis H_1) and sub-unit ``X`` (g4 alone, basis H_2 = I_3, so its misalignment row is
``[m4x, m4y, m4z]``) -- exactly the sub-units of :func:`rimu.geometry.tetrad4`, so the estimator works on any
geometry whose sub-units are given the same way.

* Scale factor and misalignment (Eq. 15-19): for each +w / -w pair of sequences, the difference of the mean
  outputs is ``[r_a r_b r_c] [m_i / SF_i]`` with ``r = H_j (w+ - w-)`` (Eq. 16-17); least squares over the
  pairs (Eq. 18) and the unit-norm constraint (Eq. 19). This is Cho & Park's rate test (their Eq. 11-15).
* Bias (Eq. 20): the mean over the sequences of the residue ``SF y_n - H~ w_n`` with the commanded rate
  only. Over whole turns of the outer (horizontal) axis the rotating Earth rate integrates to zero, so it
  drops out of the residue -- but the Earth-rate component *along* the turning axis does not: it cancels only
  when the sequences point each body direction North as often as South. rimu subtracts, per sequence, the
  mean Earth rate of its known attitude when the session's latitude is set (``earth_rate=True``); the notes of
  the result give the Earth rate Eq. 20 as printed would have left in the biases for the sequences used.
* Optional wavelet denoising (the paper's db4 at 8 levels): the outputs of each sequence are replaced by the
  level-8 approximation before averaging (:func:`denoise`). It removes the high-frequency noise from plots and
  from the Earth-rate modulation seen in their Fig. 3; the mean of a sequence, and so the estimates and their
  uncertainty, hardly change (white-noise theory, the uncertainties are computed from the raw noise).
* Parity check (Eq. 21-25): ``v`` is the parity vector of the nominal geometry (Eq. 24), ``v_c`` that of the
  calibrated axes ``M H`` (Eq. 25). Applied to the scale-corrected half differences of each pair (the rate
  alone, Eq. 22-23) the corrected vector leaves noise only, the nominal one the misalignment's imprint.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import IdentifiabilityError
from ..session import Session, SessionStatistics, column_sums, earth_rate_ln
from ..units import RS_TO_DH
from .cho_park import _named_rank_check, _subunit_rows, gyro_rows, rate_pairs, rate_step_check
from .estimate import CalibrationResult, _sigma_for, make_sensor_fit, segment_residuals
from .lsq import LsqResult
from .model import ErrorModel, contexts
from .parity_check import pair_parity

__all__ = ["Oliveira", "denoise", "parity_check"]


def denoise(y: np.ndarray, wavelet: str = "db4", level: int = 8) -> np.ndarray:
    """Wavelet denoising of de Oliveira et al. 2012: keep the level-``level`` approximation of a Daubechies
    ``wavelet`` decomposition (PyWavelets), zero every detail; columns are filtered separately.

    Raises ImportError with the extra to install when PyWavelets is missing."""
    try:
        import pywt
    except ImportError as exc:  # pragma: no cover - PyWavelets is in the test extra
        raise ImportError("wavelet denoising needs PyWavelets: pip install 'rimu[wavelets]'") from exc
    y = np.asarray(y, dtype=float)
    flat = y.reshape(y.shape[0], -1)
    out = np.empty_like(flat)
    lev = min(level, pywt.dwt_max_level(flat.shape[0], pywt.Wavelet(wavelet).dec_len))
    for k in range(flat.shape[1]):
        c = pywt.wavedec(flat[:, k], wavelet, level=max(lev, 1), mode="periodization")
        c = [c[0]] + [np.zeros_like(d) for d in c[1:]]
        out[:, k] = pywt.waverec(c, wavelet, mode="periodization")[: flat.shape[0]]
    return out.reshape(y.shape)


def parity_check(session: Session, result: CalibrationResult, instrument: str = "gyro",
                 stats: SessionStatistics | None = None) -> dict[str, Any]:
    """de Oliveira et al. 2012, Eq. 22-25 on the estimator's own result: the nominal (``v``, Eq. 24) and
    calibrated (``v_c``, Eq. 25) parity vectors applied to the scale-corrected half differences of every +/-
    pair, with the standard deviation expected from noise alone (SI). A plain-dict view of
    :func:`rimu.calibration.parity_check.pair_parity` (``stats``: the fit's segment sums); the chi-square verdict is
    :func:`rimu.experiments.quality.parity_quality`."""
    pp = pair_parity(session, result.instruments[instrument].to_calibration(), stats)
    return {"v": pp.v, "v_c": pp.v_c, "nominal": pp.nominal, "corrected": pp.corrected,
            "noise_std": pp.noise_std, "pairs": pp.labels}


class Oliveira:
    """de Oliveira et al. 2012 for a redundant gyro set from +/- rate sequences (their Table 1).

    Parameters
    ----------
    sigma : dict[str, float or array], optional
        Known per-sample raw noise; default estimated from the data (first differences).
    earth_rate : bool
        Subtract each sequence's mean Earth rate (known attitude and latitude) in Eq. 20.
    wavelet : bool
        Denoise each sequence (db4, 8 levels) before averaging.
    instrument : str
        Which instrument to calibrate (``"gyro"``).
    held_out : bool
        Check the misalignment step (Eq. 18 against the nominal axes times a scale) with each +/- pair left out in
        turn (:func:`rimu.calibration.cho_park.rate_step_check`); a step that raises the held-out residual is not
        applied and a note says why with the figures (default True).

    Examples
    --------
    >>> from rimu.geometry import tetrad4, triad3
    >>> from rimu.sim import Simulator, oliveira_table1
    >>> run = Simulator({"gyro": tetrad4(), "accel": triad3()}, seed=1).run(oliveira_table1(turns=1))
    >>> res = Oliveira().fit(run.session)
    >>> [round(float(x), 3) for x in res.extra["parity"]["v"][0]]
    [-0.408, -0.408, -0.408, 0.707]
    """

    method = "de Oliveira et al. 2012"

    def __init__(self, sigma: dict[str, Any] | None = None, earth_rate: bool = True, wavelet: bool = False,
                 instrument: str = "gyro", held_out: bool = True) -> None:
        self.sigma = sigma
        self.held_out = held_out
        self.earth_rate = earth_rate
        self.wavelet = wavelet
        self.instrument = instrument

    def fit(self, session: Session) -> CalibrationResult:
        inst = self.instrument
        if inst not in session.geometries:
            raise IdentifiabilityError(f"the session has no {inst} data")
        pairs, unpaired = rate_pairs(session.segments)
        seqs = [s for p in pairs for s in p]
        for ctx, R, full in _subunit_rows(contexts(session, inst), lambda C: gyro_rows(pairs, C)):
            if not full:  # one SVD per sub-unit; the named check for the sensor that fails
                _named_rank_check(R, ctx, inst, "+/- rate pairs about three independent axes (de Oliveira Eq. 18)",
                                  False)
        stats = SessionStatistics(session)  # each sequence's sums and rotation moments once
        sig = _sigma_for(self.sigma, session, inst, stats)
        means = {}
        for s in seqs:
            means[s.label] = column_sums(denoise(s.raw[inst])) / s.n_samples if self.wavelet else stats.mean(s, inst)
        N = np.array([s.n_samples for s in seqs], dtype=float)
        rates = np.array([s.table_rate() for s in seqs])
        we = np.zeros((len(seqs), 3))
        earth_known = 0
        if session.latitude is not None:
            e_ln = earth_rate_ln(session.latitude)
            for k, s in enumerate(seqs):
                if s.mat_ln_mb is None:
                    continue
                rm = stats.rotation(s)  # the mean Earth rate in MB over the turn, from the moments of its angle
                x = s.mat_ln_mb.T @ e_ln
                we[k] = x if rm is None else rm.mean_vector(x)
                earth_known += 1
        left = (N @ we) / N.sum()
        model = ErrorModel.base()
        fits = []
        cache: dict = {}
        Vp = np.array([1.0 / a.n_samples + 1.0 / b.n_samples for a, b in pairs])
        check = (rate_step_check(session, inst, pairs, np.array([means[a.label] - means[b.label] for a, b in pairs]),
                                 Vp) if self.held_out else None)
        reduce = check is not None and not check.applied
        for ctx in contexts(session, inst):
            i = ctx.index
            C = ctx.geometry.subunit_of(i).mat_sb_mb
            s2 = float(sig[i]) ** 2
            R = gyro_rows(pairs, C)  # Eq. 16
            G = np.array([means[a.label][i] - means[b.label][i] for a, b in pairs])  # Eq. 17-18, G-bar
            V = np.array([1.0 / a.n_samples + 1.0 / b.n_samples for a, b in pairs])
            A = np.linalg.inv(R.T @ (R / V[:, None]))
            m_sf = A @ R.T @ (G / V)  # Eq. 18
            if reduce:  # Eq. 18 with the nominal axis e (sub-unit coordinates): one coefficient, the scale
                e = ctx.geometry.nominal_rows()[i]
                re = R @ e
                m_sf = float(re @ (G / V) / (re @ (re / V))) * e
                A = np.outer(e, e) / float(re @ (re / V))
            chi2 = float(np.sum((G - R @ m_sf) ** 2 / V)) / s2
            w, cov_w = C.T @ m_sf, C.T @ (s2 * A) @ C
            # Eq. 20: mean residue over the sequences (raw domain: c = b / SF)
            u = rates + (we if self.earth_rate else 0.0)
            ybar = np.array([means[s.label][i] for s in seqs])
            ubar = (N @ u) / N.sum()
            c = float((N @ ybar) / N.sum() - w @ ubar)
            bcov = np.zeros((4, 4))
            bcov[:3, :3] = cov_w
            bcov[:3, 3] = bcov[3, :3] = -cov_w @ ubar
            bcov[3, 3] = s2 / N.sum() + ubar @ cov_w @ ubar
            chi2 += float(np.sum(N * (ybar - u @ w - c) ** 2)) / s2
            beta = np.concatenate([w, [c]])
            res = segment_residuals(model, ctx, seqs, beta, inst, cache)
            fits.append(make_sensor_fit(model, ctx, beta, bcov, np.sqrt(s2), self.sigma is not None,
                                        len(G) + len(seqs), chi2, res))
        notes = []
        left_dh = np.round(left * RS_TO_DH, 3).tolist()
        if self.earth_rate and earth_known == len(seqs):
            notes.append(f"{inst}: Earth rate subtracted per sequence in Eq. 20; Eq. 20 as printed would have left "
                         f"{left_dh} deg/h (MB) in the biases for these sequences")
        else:
            notes.append(f"{inst}: Eq. 20 as printed (Earth rate not subtracted: attitude or latitude unknown, or "
                         f"switched off); over these sequences the mean Earth rate left in the biases is "
                         f"{left_dh if earth_known == len(seqs) else 'unknown'} deg/h")
        notes.append(check.note() if check is not None else
                     f"{inst}: the misalignment step could not be checked on held-out segments (too few +/- rate "
                     "pairs: leaving one out leaves it unidentifiable); applied")
        if self.wavelet:
            notes.append(f"{inst}: outputs denoised (db4, 8 levels) before averaging")
        if unpaired:
            notes.append(f"{inst}: rate sequences without a -w partner, not used: {unpaired}")
        out = {inst: LsqResult(inst, model, fits, [s.label for s in seqs], {x: "no -w partner" for x in unpaired})}
        result = CalibrationResult(self.method, out, session.raw_unit, notes,
                                   {"steps": [check.to_dict()] if check is not None else []})
        result.extra["parity"] = parity_check(session, result, inst, stats)
        return result
