"""What the array report decides from the data before and after its steps: the units of the input, the low-pass
cut-off from the vibration spectrum, and whether a step made the agreement worse.

* **Units.** The array works in SI (rad/s, m/s^2). Rates in deg/s read as rad/s are 57 times too fast: a median
  rotation rate above 10 rad/s (570 deg/s) or a 99th percentile of the rate norm above 70 rad/s (4000 deg/s, beyond
  the full scale of MEMS gyros) is refused. Specific force in g or milli-g read as m/s^2 gives a median norm near 1 or
  1000 instead of 9.8: refused outside 0.5 g to 2 g.
* **Low-pass.** The rigid-body model holds where the triads agree: in the band where the array-mean (common)
  signal dominates the triads' disagreement (parity). The cut-off is the lowest frequency at which the power of
  the gyros' common signal falls below :data:`SNR_MIN` times their parity power per triad (Welch spectra); none
  when the triads agree up to 0.4 of the sample rate.
* **Never worse.** A step whose parity rms in motion (mean over triads) is above its input's is not applied; the
  report names it and the figures.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> w = np.radians(30) * rng.standard_normal((2000, 4, 3))
>>> check_units(w, None), bool(check_units(np.degrees(w), None))
([], True)
"""

from __future__ import annotations

import numpy as np

from ..units import G0, RAD_TO_DEG

__all__ = ["SNR_MIN", "check_units", "choose_lowpass", "worse"]

#: common-to-parity power ratio below which a frequency band is vibration, not rigid-body motion
SNR_MIN = 10.0
#: a step raising the mean parity rms by more than this fraction of it is refused
WORSE_TOL = 1e-3


def check_units(gyro: np.ndarray, accel: "np.ndarray | None") -> list[str]:
    """Reasons the data cannot be rad/s and m/s^2 (empty when plausible). ``gyro``/``accel``: (N, k, 3)."""
    out = []
    w = np.linalg.norm(np.asarray(gyro, dtype=float), axis=-1)
    w = w[np.isfinite(w)]
    if w.size:
        med, p99 = float(np.median(w)), float(np.percentile(w, 99))
        if med > 10.0 or p99 > 70.0:
            out.append(f"gyro rates of median {med:.3g} and 99th percentile {p99:.3g} 'rad/s' ({med * RAD_TO_DEG:.3g} "
                       f"and {p99 * RAD_TO_DEG:.3g} deg/s) are beyond any vehicle or MEMS full scale: the values look "
                       "like deg/s; declare it with --gyro-unit deg/s (or convert to rad/s)")
    if accel is not None:
        f = np.linalg.norm(np.asarray(accel, dtype=float), axis=-1)
        f = f[np.isfinite(f)]
        if f.size:
            med = float(np.median(f))
            if not 0.5 * G0 < med < 2.0 * G0:
                likely = "g" if 0.5 < med < 2.0 else "mg" if 500 < med < 2000 else None
                out.append(f"accelerometer norm of median {med:.4g} 'm/s^2' is not about one gravity (9.81 m/s^2)"
                           + (f": the values look like {likely}; declare it with --accel-unit {likely}" if likely else
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
    fc = float(max(f[low[0]], 1.0))
    return fc, (f"every triad low-passed at {fc:.3g} Hz (zero phase), chosen from the spectrum: above it the {what}' "
                f"common signal falls below {SNR_MIN:g} times their disagreement (vibration, not rigid-body motion); "
                "--lowpass-hz overrides")


def worse(before: np.ndarray, after: np.ndarray) -> bool:
    """Whether a step raised the mean parity rms (by more than a relative 1e-3)."""
    b, a = float(np.mean(before)), float(np.mean(after))
    return bool(a > b * (1.0 + WORSE_TOL))
