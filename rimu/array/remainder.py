"""What is left of the gyros' disagreement after the relative calibration: deterministic, or not?

After :func:`rimu.array.fit_relative_gyro` every triad's residual against the array (its compensated rate minus
the mean of the others) should be the triads' own noise. When it is not (the MIMU4444 in its fast hand rotation:
about 10 deg/s rms against a noise of 0.2 deg/s), the question a user of the array asks is whether some further
term would explain it. :func:`remainder_analysis` answers with figures, on the samples in motion:

* **held-out shares of deterministic candidates**: each candidate's columns (the array's angular acceleration:
  a time offset; its jerk; an FIR of the triad's own compensated rate over +-2 samples: a filter or delay
  difference; quadratic rate terms; cubic ones) fitted per triad on the first half of the motion and judged on
  the second: the share of the held-out residual sum of squares it removes (negative: it only adds noise);
* **whiteness**: the Ljung-Box statistic ``Q = N (N + 2) sum_{h=1..m} rho_h^2 / (N - h)`` (Ljung & Box 1978) of
  every triad axis over the contiguous runs in motion, with its chi-square p-value (m degrees of freedom),
  and the median lag-1 autocorrelation;
* **spectrum**: the ratio of the residual's amplitude spectrum to the array rate's (Welch), per frequency, and
  whether it rises towards the Nyquist frequency (a property of a filter or delay difference, or of motion
  above what the sampling resolves);
* **where it sits**: the share of the residual energy within ``halo`` samples of a gap in the samples (the
  opener keeps only samples where every triad is valid: a gap is a clipped or invalid sample), and the rms left
  without the samples within 1, 2 and ``halo`` samples of a gap (what invalidating a clipping "halo" would give:
  a chip's digital low-pass smears a clip over the next samples).

The verdict (:attr:`RemainderAnalysis.verdict`) names a term only if it explains at least ``min_share`` (10 %) of
the held-out residual; otherwise it says "not explained by a deterministic term" with the largest share, and
whether the remainder is white.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import welch
from scipy.stats import chi2

from ..errors import ShapeError
from ..units import RAD_TO_DEG

__all__ = ["RemainderAnalysis", "ljung_box", "remainder_analysis"]


def ljung_box(x: np.ndarray, lags: int = 10) -> tuple[float, float]:
    """Ljung-Box statistic of a series and its p-value (chi-square with ``lags`` degrees of freedom), Ljung &
    Box 1978: ``Q = N (N + 2) sum_h rho_h^2 / (N - h)``.

    >>> rng = np.random.default_rng(1)
    >>> q, p = ljung_box(rng.normal(size=2000))
    >>> bool(p > 0.01)
    True
    >>> e = rng.normal(size=2001)
    >>> q, p = ljung_box(e[1:] + 0.5 * e[:-1])        # MA(1): correlated at lag 1
    >>> bool(p < 1e-6)
    True
    """
    x = np.asarray(x, float)
    x = x - x.mean()
    n = len(x)
    if n <= lags + 1:
        raise ShapeError(f"the Ljung-Box test needs more than {lags + 1} samples, got {n}")
    d = float(x @ x)
    rho = np.array([float(x[h:] @ x[:-h]) / d for h in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    return q, float(chi2.sf(q, lags))


@dataclass
class RemainderAnalysis:
    """The figures of :func:`remainder_analysis` (rates in deg/s, frequencies in Hz)."""

    rms_deg_s: float
    #: candidate -> share of the held-out residual sum of squares it removes (fitted on the first half)
    shares: dict[str, float]
    #: median over triad axes of the Ljung-Box p-value, and the share of triad axes with p < 1e-3
    whiteness_p: float
    not_white_fraction: float
    lag1: float
    #: (frequency Hz, residual / rate amplitude ratio)
    spectrum: list[tuple[float, float]] = field(default_factory=list)
    rises_with_frequency: bool = False
    near_gap_share: float = float("nan")
    halo: int = 8
    #: residual rms in motion (deg/s) without the samples within h samples of a gap, h -> rms (a clipping halo)
    rms_beyond_deg_s: dict[int, float] = field(default_factory=dict)
    min_share: float = 0.1

    @property
    def best(self) -> tuple[str, float]:
        name = max(self.shares, key=lambda k: self.shares[k])
        return name, self.shares[name]

    @property
    def deterministic(self) -> bool:
        """Some candidate explains at least ``min_share`` of the held-out residual."""
        return self.best[1] >= self.min_share

    @property
    def verdict(self) -> str:
        name, s = self.best
        if self.deterministic:
            return f"{name} explains {100 * s:.3g} % of the remainder (held out)"
        white = "white" if self.not_white_fraction < 0.5 else (
            f"not white (Ljung-Box p < 1e-3 on {100 * self.not_white_fraction:.0f} % of the triad axes, lag-1 "
            f"autocorrelation {self.lag1:.2f})")
        rise = ", its spectrum rising towards the Nyquist frequency" if self.rises_with_frequency else ""
        return (f"not explained by a deterministic term (the best, {name}, {100 * s:.3g} % held out); the remainder "
                f"is {white}{rise}")

    def to_dict(self) -> dict:
        return {"rms_deg_s": self.rms_deg_s, "shares_held_out": dict(self.shares), "whiteness_p": self.whiteness_p,
                "not_white_fraction": self.not_white_fraction, "lag1": self.lag1,
                "spectrum_ratio": [[f, r] for f, r in self.spectrum], "rises_with_frequency": self.rises_with_frequency,
                "near_gap_share": self.near_gap_share, "halo_samples": self.halo,
                "rms_beyond_gap_deg_s": {str(h): v for h, v in self.rms_beyond_deg_s.items()}, "verdict": self.verdict}

    def to_markdown(self) -> str:
        out = ["## What remains of the gyro disagreement", "", f"**{self.verdict}**", "",
               f"Residual in motion {self.rms_deg_s:.3g} deg/s rms; within {self.halo} samples of a gap (clipped "
               f"samples) {100 * self.near_gap_share:.3g} % of its energy; without the samples within h samples of a gap: "
               + ", ".join(f"h = {h}: {v:.3g} deg/s" for h, v in self.rms_beyond_deg_s.items()) + ".", "",
               "| candidate (fitted on the first half, judged on the second) | share of the residual |", "|---|---|"]
        out += [f"| {k} | {100 * v:+.3g} % |" for k, v in self.shares.items()]
        out += ["", f"Whiteness (Ljung-Box, 10 lags): median p {self.whiteness_p:.2g}, "
                f"{100 * self.not_white_fraction:.0f} % of the triad axes below 1e-3; lag-1 autocorrelation "
                f"{self.lag1:.2f}.", "",
                "Residual / rate amplitude spectrum: " + ", ".join(f"{f:.3g} Hz {r:.3g}" for f, r in self.spectrum), ""]
        return "\n".join(out)


def remainder_analysis(t: np.ndarray, u: np.ndarray, motion_threshold_deg_s: float = 30.0, halo: int = 8,
                       min_share: float = 0.1, lags: int = 10) -> RemainderAnalysis:
    """The analysis of the module docstring on compensated body-frame rates ``u`` (N, k, 3), rad/s (what
    :meth:`rimu.array.RelativeFit.apply` returns), at times ``t`` (N,), s.

    Raises
    ------
    ShapeError
        Fewer than 200 samples in motion.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    if u.ndim != 3 or u.shape[2] != 3 or len(u) != len(t):
        raise ShapeError(f"rates must be (N, k, 3) with N = len(t), got {u.shape}")
    N, k, _ = u.shape
    dt = float(np.median(np.diff(t)))
    fs = 1.0 / dt
    w = u.mean(axis=1)
    E = np.stack([u[:, j] - np.delete(u, j, axis=1).mean(axis=1) for j in range(k)], axis=1)
    moving = np.linalg.norm(w, axis=1) > np.radians(motion_threshold_deg_s)
    # contiguous runs: no gap in time (the opener dropped the invalid samples) and in motion
    gap = np.concatenate([[True], np.diff(t) > 1.5 * dt])
    idx = np.flatnonzero(moving)
    if len(idx) < 200:
        raise ShapeError(f"only {len(idx)} samples in motion (above {motion_threshold_deg_s:g} deg/s): the "
                         "remainder needs at least 200")
    gi = np.flatnonzero(gap)
    pos = np.searchsorted(gi, np.arange(N), side="right")
    dist = np.minimum(np.arange(N) - gi[np.clip(pos - 1, 0, len(gi) - 1)],
                      np.where(pos < len(gi), gi[np.clip(pos, 0, len(gi) - 1)] - np.arange(N), 10**9))
    alpha = np.gradient(w, dt, axis=0)
    jerk = np.gradient(alpha, dt, axis=0)
    fit, test = idx[: len(idx) // 2], idx[len(idx) // 2:]

    def shift(x: np.ndarray, s: int) -> np.ndarray:
        return np.roll(x, s, axis=0)

    cands = {
        "angular acceleration (time offset)": lambda j: alpha,
        "jerk": lambda j: jerk,
        "FIR of the own rate, +-2 samples (filter or delay difference)": lambda j: np.column_stack(
            [shift(u[:, j], s) for s in (-2, -1, 1, 2)]),
        "rate^2 (nonlinearity)": lambda j: np.column_stack(
            [u[:, j] ** 2, u[:, j, [0]] * u[:, j, [1]], u[:, j, [1]] * u[:, j, [2]], u[:, j, [0]] * u[:, j, [2]]]),
        "rate^3 (nonlinearity)": lambda j: u[:, j] ** 3,
    }
    tot = float((E[test] ** 2).sum())
    shares = {}
    for name, build in cands.items():
        res = 0.0
        for j in range(k):
            R = np.column_stack([build(j), np.ones(N)])
            B = np.linalg.lstsq(R[fit], E[fit, j], rcond=None)[0]
            res += float(((E[test, j] - R[test] @ B) ** 2).sum())
        shares[name] = 1.0 - res / tot
    # whiteness and spectrum over the contiguous runs in motion of at least 64 samples
    key = np.where(moving, np.cumsum(gap), -1)  # a run: consecutive samples in motion between two gaps
    cut = np.flatnonzero(np.diff(key)) + 1
    runs = [(a, b) for a, b in zip(np.concatenate([[0], cut]), np.concatenate([cut, [N]])) if key[a] >= 0]
    p_vals, lag1 = [], []
    Pe = Pw = 0.0
    fr = np.zeros(0)
    for a, b in runs:
        if b - a < 64:
            continue
        X = E[a:b].reshape(b - a, -1)
        for c in range(X.shape[1]):
            p_vals.append(ljung_box(X[:, c], lags)[1])
        Xc = X - X.mean(axis=0)
        lag1.append((Xc[1:] * Xc[:-1]).sum(axis=0) / (Xc * Xc).sum(axis=0))
        fr, pe = welch(X, fs=fs, nperseg=64, axis=0)
        _, pw = welch(w[a:b], fs=fs, nperseg=64, axis=0)
        Pe, Pw = Pe + pe.mean(axis=1) * (b - a), Pw + pw.mean(axis=1) * (b - a)
    spectrum: list[tuple[float, float]] = []
    rises = False
    if p_vals:
        ratio = np.sqrt(Pe / np.maximum(Pw, 1e-300))
        spectrum = [(float(fr[i]), float(ratio[i])) for i in range(1, len(fr), max(1, len(fr) // 6))]
        lo, hi = ratio[1:len(fr) // 4].mean(), ratio[-len(fr) // 4:].mean()
        rises = bool(hi > 2.0 * lo)
    e2 = (E**2).sum(axis=(1, 2))
    near = float(e2[idx][dist[idx] <= halo].sum() / max(e2[idx].sum(), 1e-300))
    beyond = {h: float(np.sqrt((E[idx][dist[idx] > h] ** 2).mean()) * RAD_TO_DEG) for h in (1, 2, halo)
              if (dist[idx] > h).sum() > 10}
    return RemainderAnalysis(
        rms_deg_s=float(np.sqrt((E[idx] ** 2).mean()) * RAD_TO_DEG), shares=shares,
        whiteness_p=float(np.median(p_vals)) if p_vals else float("nan"),
        not_white_fraction=float(np.mean(np.array(p_vals) < 1e-3)) if p_vals else float("nan"),
        lag1=float(np.median(np.concatenate(lag1))) if lag1 else float("nan"), spectrum=spectrum,
        rises_with_frequency=rises, near_gap_share=near, halo=int(halo), min_share=float(min_share),
        rms_beyond_deg_s=beyond)
