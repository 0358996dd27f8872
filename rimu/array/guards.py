"""What the array report decides from the data before and after its steps: the units of the input, the low-pass
cut-off from the vibration spectrum, and whether a step made the agreement worse.

* **Units.** The array works in SI (rad/s, m/s^2). Rates in deg/s read as rad/s are 57 times too large: beyond
  any MEMS full scale, or triads disagreeing by far more than their noise at rest (:func:`check_units`).
  Specific force in g or milli-g read as m/s^2 gives a norm near 1 or 1000 at rest instead of 9.8.
* **Low-pass.** The rigid-body model holds where the triads agree: in the band where the array-mean (common)
  signal dominates the triads' disagreement (parity). The cut-off is the lowest frequency at which the power of
  the gyros' common signal falls below :data:`SNR_MIN` times their parity power per triad (Welch spectra), and
  at least :data:`MARGIN` times the top of the motion band (where :data:`MOTION_POWER` of the common power
  lies below), clear of the motion; none when the triads agree up to 0.4 of the
  sample rate, or when less than :data:`VIBRATION_SHARE` of the parity power lies above the motion band (nothing
  to remove: a clean recording's disagreement is its gains and misalignments, in the motion band). The cut-off
  also lies at least :data:`MARGIN` times above the motion's whole band: the frequency under which
  :data:`MOTION_BAND_SHARE` of the array-mean rate's power lies (:func:`motion_band`), whatever the ratio does
  below it; none where that is beyond 0.45 of the sample rate. The edge can lie inside the motion: on the
  MIMU4444's hand rotation (triads disagreeing from 1.5 Hz on: clipping, 16 ms sampling) the rule cut at 1.46 Hz,
  which passes 2.6 % of the rate's power and 0.1 % of the angular acceleration's, and the accelerometer positions
  came out about 13 mm from nominal, all near the centre (0.29-1.03 mm without it). An explicit cut-off below the
  band is the user's choice: the array report applies it, refuses its position step and says why.
* **Never worse.** A step whose parity rms in motion (mean over triads) is above its input's is not applied; the
  report names it and the figures.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> w = np.radians(30) * rng.standard_normal((2000, 1, 3)) + 1e-3 * rng.standard_normal((2000, 4, 3))
>>> check_units(w, None), bool(check_units(np.degrees(w), None))
([], True)
"""

from __future__ import annotations

import numpy as np

from ..units import G0, RAD_TO_DEG

__all__ = ["MARGIN", "MOTION_BAND_SHARE", "MOTION_POWER", "SNR_MIN", "VIBRATION_SHARE", "check_units",
           "band_share", "choose_lowpass", "motion_band", "worse"]

#: common-to-parity power ratio below which a frequency band is vibration, not rigid-body motion
SNR_MIN = 10.0
#: the cut-off lies this factor above the top of the motion band (a 4th-order Butterworth passes 0.4 % less at
#: 1/1.5 of its cut-off, -3 dB at it)
MARGIN = 1.5
#: the motion band holds this share of the common signal's power
MOTION_POWER = 0.99
#: a low-pass is chosen only when the parity power above the motion band is at least this share of all of it
#: (vibration to remove); a clean recording's disagreement lies in the motion band (gains, misalignments)
VIBRATION_SHARE = 0.25
#: a step raising the mean parity rms by more than this fraction of it is refused
WORSE_TOL = 1e-3
#: the motion's band holds this share of the array-mean rate's power (:func:`motion_band`); a low-pass below it cuts
#: the motion (and the lever arms the positions are fitted from)
MOTION_BAND_SHARE = 0.9


def motion_band(t: np.ndarray, gyro: np.ndarray) -> tuple[float, float]:
    """(frequency below which :data:`MOTION_BAND_SHARE` of the array-mean rate's power lies, Hz; the same for
    the angular acceleration, its derivative), from Welch spectra of the mean over the triads (invalid samples as 0).

    >>> t = np.arange(4000) / 100.0
    >>> w = np.sin(2 * np.pi * 2.0 * t)[:, None, None] * np.ones((1, 3, 3))   # every triad turning at 2 Hz
    >>> [round(f) for f in motion_band(t, w)]
    [2, 2]
    """
    out = []
    for f, p in _mean_rate_spectra(t, gyro):
        c = np.cumsum(p)
        out.append(float(f[min(int(np.searchsorted(c, MOTION_BAND_SHARE * c[-1])), len(f) - 1)]))
    return out[0], out[1]


def _mean_rate_spectra(t: np.ndarray, gyro: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Welch power spectra ``(f, p)`` (summed over the three axes) of the array-mean rate and of its derivative,
    the angular acceleration: what :func:`motion_band` and :func:`band_share` both read."""
    from scipy.signal import welch

    t = np.asarray(t, dtype=float)
    fs = 1.0 / float(np.median(np.diff(t)))
    x = np.asarray(gyro, dtype=float)
    m = np.where(np.isfinite(x), x, 0.0).mean(axis=1)
    nper = int(min(512, max(8, len(m) // 4)))
    out = []
    for sig in (m, np.gradient(m, 1.0 / fs, axis=0)):
        f, p = welch(sig, fs=fs, nperseg=nper, axis=0)
        out.append((f, p.sum(axis=-1)))
    return out


def band_share(t: np.ndarray, gyro: np.ndarray, cutoff_hz: float) -> tuple[float, float]:
    """Shares of the array-mean rate's and angular acceleration's power at or below ``cutoff_hz`` (Welch, as
    :func:`motion_band`)."""
    out = []
    for f, p in _mean_rate_spectra(t, gyro):
        out.append(float(p[f <= cutoff_hz].sum() / max(float(p.sum()), 1e-300)))
    return out[0], out[1]


def check_units(gyro: np.ndarray, accel: "np.ndarray | None") -> list[str]:
    """Reasons the data cannot be rad/s and m/s^2 (empty when plausible). ``gyro``/``accel``: (N, k, 3).

    Rates: a per-axis 99.9th percentile above 70 rad/s (4000 deg/s, beyond the full scale of MEMS gyros), or, in a
    recording with quiet parts, triads that disagree by more than 0.5 rad/s rms while the array is quietest (the
    10 % of samples of least rotation; white noise and quantisation of MEMS gyros are near 1e-3 rad/s). Specific
    force: the median norm over those quiet samples outside 0.5 g to 2 g.
    """
    out = []
    g = np.asarray(gyro, dtype=float)
    ok = np.all(np.isfinite(g), axis=(1, 2))
    g = g[ok]
    quiet = None
    if len(g):
        p999 = float(np.percentile(np.abs(g), 99.9))
        w = np.linalg.norm(g.mean(axis=1), axis=1)
        quiet = w <= np.percentile(w, 10)
        par = g[quiet] - g[quiet].mean(axis=1, keepdims=True)
        spread = float(np.sqrt(np.mean(par**2))) if g.shape[1] > 1 else 0.0
        if p999 > 70.0:
            out.append(f"gyro outputs up to {p999:.4g} 'rad/s' on an axis (99.9th percentile; {p999 * RAD_TO_DEG:.4g} "
                       "deg/s) are beyond the full scale of any MEMS gyro: the values look like deg/s; declare it with "
                       "--gyro-unit deg/s (or convert to rad/s)")
        elif float(np.median(w)) < 1.0 and spread > 0.5:
            out.append(f"the gyro triads disagree by {spread:.3g} 'rad/s' rms while the array is quietest (MEMS noise "
                       "is near 0.001 rad/s): the values look like deg/s; declare it with --gyro-unit deg/s")
    if accel is not None:
        a = np.asarray(accel, dtype=float)[ok]
        f = np.linalg.norm(a[quiet] if quiet is not None and quiet.any() else a, axis=-1)
        f = f[np.isfinite(f)]
        if f.size:
            med = float(np.median(f))
            if not 0.5 * G0 < med < 2.0 * G0:
                likely = "g" if 0.5 < med < 2.0 else "mg" if 500 < med < 2000 else None
                out.append(f"accelerometer norm of median {med:.4g} 'm/s^2' while the array is quietest is not about "
                           "one gravity (9.81 m/s^2)" + (f": the values look like {likely}; declare it with "
                                                          f"--accel-unit {likely}" if likely else
                                                          ": check the unit of the accelerometer columns"))
    return out


def choose_lowpass(t: np.ndarray, gyro: np.ndarray, accel: "np.ndarray | None" = None) -> tuple[float | None, str]:
    """(cut-off in Hz or None, the reason) from the common and parity spectra (module docstring)."""
    from scipy.signal import welch

    t = np.asarray(t, dtype=float)
    fs = 1.0 / float(np.median(np.diff(t)))
    # the gyros: their triads differ by about 1 % before calibration, so the common-to-parity ratio is large
    # wherever the motion is rigid; the accelerometers also differ by the lever arms and their gains, which
    # would read as vibration at every frequency
    x = np.asarray(gyro, dtype=float)
    what = "gyros"
    if x.shape[0] < 256 or x.shape[1] < 2:
        return None, "too short or a single triad: no spectrum to choose a low-pass from"
    x = np.where(np.isfinite(x), x, 0.0)
    m = x.mean(axis=1)
    nper = int(min(512, x.shape[0] // 4))
    f, pm = welch(m, fs=fs, nperseg=nper, axis=0)
    _, pp = welch(x - m[:, None], fs=fs, nperseg=nper, axis=0)
    pm = pm.sum(axis=-1)
    pp = pp.sum(axis=(-1, -2)) / x.shape[1]
    k = np.ones(3) / 3
    ratio = np.convolve(pm, k, "same") / np.maximum(np.convolve(pp, k, "same"), 1e-300)
    band = (f >= 1.0) & (f <= 0.4 * fs)
    low = np.flatnonzero(band & (ratio < SNR_MIN))
    if low.size == 0:
        return None, (f"the {what} agree up to {0.4 * fs:.3g} Hz (common power above {SNR_MIN:g} times the parity "
                      "power per triad): no low-pass")
    edge = float(max(f[low[0]], 1.0))
    # the motion band: below the edge, where MOTION_POWER of the common signal's power lies (the common signal above
    # the edge holds the rotors' vibration too); the cut-off at least MARGIN above its top, clear of the motion
    below = f < edge
    cum = np.cumsum(pm[below]) / max(float(pm[below].sum()), 1e-300)
    top = float(f[below][min(int(np.searchsorted(cum, MOTION_POWER)), int(below.sum()) - 1)]) if below.any() else 0.0
    # and clear of the motion's whole band (MOTION_BAND_SHARE of the common rate's power, at every frequency): the
    # edge can lie inside it (the MIMU4444's triads disagree from 1.5 Hz on in the fast rotation, whose band reaches
    # 6.8 Hz); a cut-off that fits nowhere below 0.45 of the rate: none
    f_band, _ = motion_band(t, gyro)
    fc = float(max(edge, MARGIN * top, MARGIN * f_band))
    if fc > 0.45 * fs:
        return None, (f"the motion fills the band: {100 * MOTION_BAND_SHARE:g} % of the {what}' common rate power lies below "
                      f"{f_band:.3g} Hz, and a cut-off {MARGIN:g} times above it passes 0.45 of the sample rate: no low-pass")
    share = float(pp[f >= fc].sum() / max(pp.sum(), 1e-300))
    if share < VIBRATION_SHARE:
        return None, (f"the {what}' motion band ends near {max(top, f_band):.3g} Hz and their disagreement above {fc:.3g} Hz is "
                      f"{100 * share:.2g} % of all of it (below {100 * VIBRATION_SHARE:g} %: no vibration to remove): "
                      "no low-pass")
    return fc, (f"every triad low-passed at {fc:.3g} Hz (zero phase), chosen from the spectrum: above {edge:.3g} Hz the "
                f"{what}' common signal falls below {SNR_MIN:g} times their disagreement (vibration, not rigid-body "
                f"motion: {100 * share:.2g} % of the disagreement lies above the cut-off), and {100 * MOTION_POWER:g} % "
                f"of the motion below it lies below {top:.3g} Hz and {100 * MOTION_BAND_SHARE:g} % of all of it below "
                f"{f_band:.3g} Hz (the cut-off at least {MARGIN:g} times above both); --lowpass-hz overrides")


def worse(before: np.ndarray, after: np.ndarray) -> bool:
    """Whether a step raised the mean parity rms (by more than a relative 1e-3)."""
    b, a = float(np.mean(before)), float(np.mean(after))
    return bool(a > b * (1.0 + WORSE_TOL))
