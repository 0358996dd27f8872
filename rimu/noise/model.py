"""The noise model of a unit: IEEE Std 952 / 1554 terms per sensor, with units, a type tag and a version.

Per sensor, the rate-type output (rad/s, m/s^2) has the Allan variance (IEEE Std 952-1997, Annex C;
IEEE Std 1554-2005)::

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3

with Q the quantisation noise (rad, m/s), N the angle / velocity random walk (rad/sqrt(s), (m/s)/sqrt(s)),
B the bias instability (rad/s, m/s^2) and K the rate random walk ((rad/s)/sqrt(s), (m/s^2)/sqrt(s)). SI
inside; :meth:`InstrumentNoise.table` reports in the field's units (deg/sqrt(h), deg/h, (deg/h)/sqrt(h),
arcsec; m/s/sqrt(h), micro-g/sqrt(Hz), micro-g, micro-g/sqrt(h), m/s).

Variance of a window mean (what the detectors of :mod:`rimu.fdi` need). The integrated output
``phi(t)`` (angle, velocity) has the structure function ``D(t) = E[(phi(s + t) - phi(s))^2]``::

    D(t) = 2 Q^2 [t != 0] + N^2 |t| - (B^2 / pi) t^2 ln|t| - K^2 |t|^3 / 6       (+ c t^2, which cancels)

and any combination ``X = sum_k a_k phi(t_k)`` with ``sum_k a_k = 0`` and ``sum_k a_k t_k = 0`` (a difference
of two window means is one) has ``Var X = -1/2 sum_kl a_k a_l D(t_k - t_l)``. For two windows of ``tau``
at lag T this gives back the Allan variance at T = tau (``Var = 2 AVAR``) and, for the flicker term,
``(B^2 / pi) g(T / tau)`` with ``g(r) = (r + 1)^2 ln(r + 1) + (r - 1)^2 ln|r - 1| - 2 r^2 ln r``
(``g(1) = 4 ln 2``, ``g(r) -> 2 ln r + 3``); for the rate random walk ``K^2 (T - tau / 3)``.
:meth:`InstrumentNoise.window_variance` is the variance of the mean over a window of ``tau`` that ends
``horizon`` after a reference window of ``reference`` (the bias estimate the detector compares against).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CalibrationFileError, ShapeError, UnsupportedVersionError
from ..units import ARCSEC_TO_RAD, ARW_DSQH_TO_RSQS, DH_TO_RS, UG_TO_MS2

__all__ = [
    "FLICKER_AVAR",
    "NOISE_FORMAT_TAG",
    "NOISE_FORMAT_VERSION",
    "TERMS",
    "InstrumentNoise",
    "NoiseModel",
    "structure_function",
    "window_mean_difference_variance",
]

#: the terms of the model, in the order of the fit's design matrix
TERMS = ("quantization", "white", "bias_instability", "rate_random_walk")
#: AVAR of the flicker floor per B^2: 2 ln 2 / pi (sigma = 0.664 B)
FLICKER_AVAR = 2.0 * math.log(2.0) / math.pi
NOISE_FORMAT_TAG = "rimu.noise"
NOISE_FORMAT_VERSION = 1

#: SI unit of each term per instrument, and (label, factor SI -> field unit) for the reports
SI_TERM_UNITS = {
    "gyro": {"quantization": "rad", "white": "rad/sqrt(s)", "bias_instability": "rad/s",
             "rate_random_walk": "rad/s/sqrt(s)"},
    "accel": {"quantization": "m/s", "white": "m/s/sqrt(s)", "bias_instability": "m/s^2",
              "rate_random_walk": "m/s^2/sqrt(s)"},
}
FIELD_UNITS = {
    "gyro": {"quantization": ("arcsec", 1.0 / ARCSEC_TO_RAD), "white": ("deg/sqrt(h)", 1.0 / ARW_DSQH_TO_RSQS),
             "bias_instability": ("deg/h", 1.0 / DH_TO_RS),
             "rate_random_walk": ("deg/h/sqrt(h)", 60.0 / DH_TO_RS)},
    "accel": {"quantization": ("mm/s", 1e3), "white": ("m/s/sqrt(h)", 60.0),
              "bias_instability": ("micro-g", 1.0 / UG_TO_MS2),
              "rate_random_walk": ("micro-g/sqrt(h)", 60.0 / UG_TO_MS2)},
}


def structure_function(t: np.ndarray, terms: dict[str, np.ndarray]) -> np.ndarray:
    """``D(t)`` of the integrated output (module docstring) for lags t (m,) and terms (n,): (m, n), SI^2 s^2.

    The ``c t^2`` part of the flicker term is dropped: it cancels in every combination this module uses.
    """
    t = np.abs(np.asarray(t, dtype=float))[:, None]
    q, w, b, k = (np.asarray(terms[name], dtype=float)[None, :] for name in TERMS)
    with np.errstate(divide="ignore", invalid="ignore"):
        tlnt = np.where(t > 0, t * t * np.log(np.where(t > 0, t, 1.0)), 0.0)
    return 2 * q * q * (t > 0) + w * w * t - (b * b / math.pi) * tlnt - k * k * t ** 3 / 6.0


def window_mean_difference_variance(tau: float, reference: float, lag: float,
                                    terms: dict[str, np.ndarray]) -> np.ndarray:
    """Variance of ``mean(y over [lag, lag + tau]) - mean(y over [-reference, 0])`` per sensor, SI^2.

    ``lag`` is from the end of the reference window to the start of the current one (>= 0). Exact for the
    four power-law terms (module docstring).

    >>> z = {"quantization": [0.0], "white": [0.0], "bias_instability": [0.0], "rate_random_walk": [1.0]}
    >>> round(float(window_mean_difference_variance(1.0, 1.0, 0.0, z)[0]), 6)   # 2 AVAR = 2 K^2 tau / 3
    0.666667
    """
    if not (tau > 0 and reference > 0 and lag >= 0):
        raise ValueError(f"tau and reference must be positive and lag >= 0, got {tau}, {reference}, {lag}")
    tk = np.array([-reference, 0.0, lag, lag + tau])
    a = np.array([1.0 / reference, -1.0 / reference, -1.0 / tau, 1.0 / tau])
    dt = tk[:, None] - tk[None, :]
    D = structure_function(dt.ravel(), terms).reshape(4, 4, -1)
    return np.maximum(-0.5 * np.einsum("k,l,kln->n", a, a, D), 0.0)


def _vec(v: Any, n: int, name: str) -> np.ndarray:
    a = np.array(np.broadcast_to(np.asarray(v, dtype=float), (n,)), dtype=float)
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ShapeError(f"noise term {name} must be finite and non-negative, got {a.tolist()}")
    return a


@dataclass
class InstrumentNoise:
    """Noise terms of every sensor of one instrument kind (SI; see the module docstring).

    Attributes
    ----------
    instrument : str
        ``"gyro"`` or ``"accel"``.
    names : list of str
        Sensor names (the geometry's).
    terms : dict[str, ndarray (n,)]
        ``quantization``, ``white``, ``bias_instability``, ``rate_random_walk`` in SI.
    sigma : dict[str, ndarray (n,)]
        1-sigma uncertainty of each term, SI (0 where not estimated).
    sample_rate : float
        Hz of the recording the terms came from (the per-sample sigma uses it unless told otherwise).
    allan : dict, optional
        The measured Allan deviation: ``tau`` (m,), ``adev``, ``lo``, ``hi`` (n, m), SI.

    Examples
    --------
    >>> from rimu.units import ARW_DSQH_TO_RSQS
    >>> m = InstrumentNoise.from_terms("gyro", ["x1", "y1"], 100.0, white=0.1 * ARW_DSQH_TO_RSQS)
    >>> round(float(m.table_rows()[0]["white"]), 6)
    0.1
    >>> round(float(m.sample_sigma()[0] / (0.1 * ARW_DSQH_TO_RSQS * 10)), 9)    # N sqrt(fs)
    1.0
    """

    instrument: str
    names: list[str]
    terms: dict[str, np.ndarray]
    sigma: dict[str, np.ndarray]
    sample_rate: float
    allan: dict[str, Any] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.instrument not in SI_TERM_UNITS:
            raise ValueError(f"instrument must be 'gyro' or 'accel', got {self.instrument!r}")
        n = len(self.names)
        missing = [t for t in TERMS if t not in self.terms]
        if missing:
            raise ShapeError(f"noise model of {self.instrument} lacks the terms {missing}; give all of {TERMS}")
        self.terms = {t: _vec(self.terms[t], n, t) for t in TERMS}
        self.sigma = {t: _vec(self.sigma.get(t, 0.0), n, t + " sigma") for t in TERMS}
        if not (self.sample_rate > 0 and math.isfinite(self.sample_rate)):
            raise ShapeError(f"sample_rate must be a positive number of Hz, got {self.sample_rate}")

    @classmethod
    def from_terms(cls, instrument: str, names: list[str], sample_rate: float, quantization: Any = 0.0,
                   white: Any = 0.0, bias_instability: Any = 0.0, rate_random_walk: Any = 0.0) -> InstrumentNoise:
        """Terms given by hand (SI), e.g. from a data sheet; uncertainties zero."""
        return cls(instrument, list(names), {"quantization": quantization, "white": white,
                                             "bias_instability": bias_instability,
                                             "rate_random_walk": rate_random_walk}, {}, float(sample_rate))

    @property
    def n(self) -> int:
        return len(self.names)

    # ------------------------------------------------------------------ model
    def avar(self, tau: np.ndarray) -> np.ndarray:
        """Model Allan variance (n, m) at the averaging times tau (m,), s (IEEE Std 952, Annex C)."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))[None, :]
        q, w, b, k = (self.terms[t][:, None] for t in TERMS)
        return 3 * q * q / tau ** 2 + w * w / tau + FLICKER_AVAR * b * b + k * k * tau / 3.0

    def sample_sigma(self, sample_rate: float | None = None) -> np.ndarray:
        """Per-sample standard deviation of the white part, SI: ``sqrt(N^2 fs + 2 Q^2 fs^2)``.

        White rate noise of density N sampled at fs has variance ``N^2 fs``; angle quantisation of variance
        Q^2 differenced over one sample adds ``2 Q^2 fs^2``.
        """
        fs = self.sample_rate if sample_rate is None else float(sample_rate)
        return np.sqrt(self.terms["white"] ** 2 * fs + 2 * self.terms["quantization"] ** 2 * fs * fs)

    def window_variance(self, tau_s: float, horizon_s: float = 0.0, reference_s: float | None = None) -> np.ndarray:
        """Variance (n,), SI^2, of a window mean of ``tau_s`` against a bias set ``horizon_s`` earlier.

        * ``horizon_s = 0``: the white part only, ``N^2 / tau + 2 Q^2 / tau^2`` (a window mean of white noise
          and quantisation);
        * ``horizon_s > 0`` and ``reference_s`` given: :func:`window_mean_difference_variance`, exactly: the
          window mean minus the mean of a reference window of ``reference_s`` (the bias estimate) that ended
          ``horizon_s`` before the window began, every term of both windows included;
        * ``horizon_s > 0`` without ``reference_s``: a long reference whose white error is stated elsewhere
          (the calibration's covariance): the window's white part plus the slow terms' wander against a
          reference of ``tau_s`` (longer references wander less, so this is conservative).
        """
        if not tau_s > 0:
            raise ValueError(f"tau_s must be positive, got {tau_s}")
        q, w = self.terms["quantization"], self.terms["white"]
        white = w * w / tau_s + 2 * q * q / tau_s ** 2
        if not horizon_s > 0:
            return white
        if reference_s is not None:
            return window_mean_difference_variance(tau_s, float(reference_s), float(horizon_s), self.terms)
        slow = {"quantization": np.zeros(self.n), "white": np.zeros(self.n),
                "bias_instability": self.terms["bias_instability"], "rate_random_walk": self.terms["rate_random_walk"]}
        return white + window_mean_difference_variance(tau_s, tau_s, float(horizon_s), slow)

    # ------------------------------------------------------------------ reports
    def table_rows(self) -> list[dict[str, Any]]:
        """One dict per sensor: every term and its sigma in the field's units."""
        units = FIELD_UNITS[self.instrument]
        rows = []
        for i, name in enumerate(self.names):
            r: dict[str, Any] = {"sensor": name}
            for t in TERMS:
                f = units[t][1]
                r[t] = float(self.terms[t][i] * f)
                r[t + "_sigma"] = float(self.sigma[t][i] * f)
            rows.append(r)
        return rows

    def table(self) -> str:
        """Plain-text table in the field's units."""
        units = FIELD_UNITS[self.instrument]
        head = f"{self.instrument:<6}" + "".join(f"  {t.replace('_', ' ') + ' [' + units[t][0] + ']':>34}" for t in TERMS)
        lines = [head]
        for r in self.table_rows():
            cells = "".join(f"  {r[t]:>20.4g} +/- {r[t + '_sigma']:<9.2g}" for t in TERMS)
            lines.append(f"{r['sensor']:<6}{cells}")
        return "\n".join(lines)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        units = SI_TERM_UNITS[self.instrument]
        d: dict[str, Any] = {
            "instrument": self.instrument,
            "names": list(self.names),
            "sample_rate": self.sample_rate,
            "units": {t: units[t] for t in TERMS},
            "terms": {t: self.terms[t].tolist() for t in TERMS},
            "sigma": {t: self.sigma[t].tolist() for t in TERMS},
            "field_units": {t: FIELD_UNITS[self.instrument][t][0] for t in TERMS},
            "field": self.table_rows(),
            "meta": self.meta,
        }
        if self.allan is not None:
            d["allan"] = {k: np.asarray(v).tolist() for k, v in self.allan.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InstrumentNoise:
        try:
            allan = d.get("allan")
            return cls(d["instrument"], list(d["names"]), {t: np.array(d["terms"][t], float) for t in TERMS},
                       {t: np.array(d.get("sigma", {}).get(t, 0.0), float) for t in TERMS}, float(d["sample_rate"]),
                       None if allan is None else {k: np.array(v, float) for k, v in allan.items()},
                       dict(d.get("meta") or {}))
        except (KeyError, TypeError) as exc:
            raise CalibrationFileError(f"malformed noise model ({exc!r}); it needs instrument, names, "
                                       f"sample_rate and terms {TERMS}") from exc


@dataclass
class NoiseModel:
    """The noise of a unit: one :class:`InstrumentNoise` per instrument, and the parity-space whiteness checks.

    Saved as versioned JSON (``format: rimu.noise``), written atomically.
    """

    instruments: dict[str, InstrumentNoise]
    parity: dict[str, dict[str, Any]] = field(default_factory=dict)
    created: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, instrument: str) -> InstrumentNoise:
        try:
            return self.instruments[instrument]
        except KeyError:
            raise KeyError(f"this noise model has no {instrument!r}; it has {sorted(self.instruments)}") from None

    def __contains__(self, instrument: object) -> bool:
        return instrument in self.instruments

    def to_document(self) -> dict[str, Any]:
        return {"format": NOISE_FORMAT_TAG, "version": NOISE_FORMAT_VERSION, "created": self.created,
                "meta": self.meta, "instruments": {k: v.to_dict() for k, v in self.instruments.items()},
                "parity": self.parity}

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (temporary file in the same folder, then rename)."""
        path = Path(path)
        text = json.dumps(self.to_document(), indent=1, allow_nan=False)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> NoiseModel:
        """Read a noise file; a damaged, foreign or newer file raises a specific error."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CalibrationFileError(f"cannot read noise file {path} ({exc}); write it with `rimu noise`") from exc
        return cls.from_document(doc, str(path))

    @classmethod
    def from_document(cls, doc: Any, source: str = "<document>") -> NoiseModel:
        if not isinstance(doc, dict) or doc.get("format") != NOISE_FORMAT_TAG:
            raise CalibrationFileError(f"{source} is not a rimu noise file (no 'format': '{NOISE_FORMAT_TAG}')")
        v = doc.get("version")
        if not isinstance(v, int) or not 1 <= v <= NOISE_FORMAT_VERSION:
            raise UnsupportedVersionError(f"{source}: noise format version {v!r} is not known to this rimu "
                                          f"(it reads 1..{NOISE_FORMAT_VERSION}); upgrade rimu")
        insts = {k: InstrumentNoise.from_dict(d) for k, d in (doc.get("instruments") or {}).items()}
        return cls(insts, dict(doc.get("parity") or {}), str(doc.get("created", "")), dict(doc.get("meta") or {}))


def _flicker_g(r: float) -> float:
    """g(r) of the module docstring (for the docs' closed form; the code uses the structure function)."""
    def f(x: float) -> float:
        return x * x * math.log(x) if x > 0 else 0.0

    return f(r + 1) + f(abs(r - 1)) - 2 * f(r)

