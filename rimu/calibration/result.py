"""The calibration result: per-sensor coefficients with units, bound to a geometry, saved as versioned JSON.

Model (Cho & Park 2005, Eq. 1-3), per sensor i of sub-unit j::

    SF_i * y_i = m_i . (C_j u) + b_i + v_i

``y_i`` raw output (counts), ``u`` the true input in MB (rad/s or m/s^2), ``C_j`` the sub-unit basis
(``mat_sb_mb``), ``m_i`` the misalignment row in the sub-unit basis with |m_i| = 1 (Eq. 10), ``b_i`` the bias
in SI units, ``SF_i`` the scale factor in SI per raw unit. The calibrated sensing axis in MB is
``a_i = C_j^T m_i`` and compensation is ``z_i = SF_i y_i - b_i = a_i . u + v_i``.

The estimator (``rimu.calibration`` procedures) and this result are separate things (as in imucal): the
result is plain data with explicit units, a type tag and a format version, and a checksum over its content.
Further effects (g-sensitivity, temperature terms, ...) ride along in ``effects`` as named parameters, so the
file grows without a format change.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..epoch import INSTRUMENTS
from ..errors import (
    CalibrationFileError,
    ChecksumError,
    GeometryMismatchError,
    ShapeError,
    UnsupportedVersionError,
)
from ..geometry import Geometry
from ..noise.model import InstrumentNoise

__all__ = ["InstrumentCalibration", "Calibration", "FORMAT_TAG", "FORMAT_VERSION", "SI_UNITS"]

FORMAT_TAG = "rimu.calibration"
FORMAT_VERSION = 1
#: SI unit of the input of each instrument
SI_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
#: migrations: version -> function turning a payload of that version into one of version + 1
MIGRATIONS: dict[int, Callable[[dict[str, Any]], dict[str, Any]]] = {}


@dataclass
class InstrumentCalibration:
    """Coefficients of one instrument kind (all gyros, or all accelerometers) of a unit.

    Attributes
    ----------
    instrument : str
        ``"gyro"`` or ``"accel"``.
    geometry : Geometry
    scale : ndarray (n,)
        Scale factor SF, SI unit per raw unit (rad/s per count, m/s^2 per count).
    misalignment : ndarray (n, 3)
        Misalignment rows m_i in each sensor's sub-unit basis, unit norm (Cho & Park Eq. 2, 10).
    bias : ndarray (n,)
        Bias b, SI units (rad/s, m/s^2), on the output side: ``SF y = m.(C u) + b``.
    noise_sigma : ndarray (n,) or None
        Per-sample white-noise standard deviation of ``SF y``, SI units.
    covariance : ndarray (p, p) or None
        Covariance of the parameters named in ``param_names`` (SI; misalignment as the two off-axis
        components of m_i, in rad).
    param_names : list of str
        Names of the covariance's rows, e.g. ``"x1.scale"``, ``"x1.mis_y"``, ``"x1.bias"``.
    effects : dict
        Further named effects: ``{effect_name: {param_name: value}}`` in SI units.
    range_raw : ndarray (n,) or None
        Range limit of each sensor in RAW output units (the units of y, before SF and B): a raw value with
        ``|y_i| >= range_raw_i`` is clipped (saturated) and the runtime routes around it for that sample.
        None: no limit known. For a sensor whose raw output is already in SI, this is the range in SI.
    noise : InstrumentNoise or None
        Optional noise terms of every sensor (IEEE Std 952: quantisation, random walk, bias instability,
        rate random walk; :mod:`rimu.noise`), e.g. from ``rimu noise``; the detectors of :mod:`rimu.fdi` take
        them as ``noise=``. Saved only when present, so files without it read and write as before.
    noise_period_s : float or None
        The sample period (s) ``noise_sigma`` was measured at, e.g. the 0.1 s block averages of ``rimu setup``;
        None: the period of the data the calibration is used on. Data at another period take
        :meth:`noise_sigma_at` (white noise). Saved only when set.
    """

    instrument: str
    geometry: Geometry
    scale: np.ndarray
    misalignment: np.ndarray
    bias: np.ndarray
    noise_sigma: np.ndarray | None = None
    covariance: np.ndarray | None = None
    param_names: list[str] = field(default_factory=list)
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    range_raw: np.ndarray | None = None
    noise: InstrumentNoise | None = None
    noise_period_s: float | None = None

    def __post_init__(self) -> None:
        if self.instrument not in INSTRUMENTS:
            raise ValueError(f"instrument must be one of {INSTRUMENTS}, got {self.instrument!r}")
        n = self.geometry.n
        vecs = [self.scale, self.bias] if self.noise_sigma is None else [self.scale, self.bias, self.noise_sigma]
        if all(type(v) is np.ndarray and v.shape == (n,) and v.dtype == np.float64 for v in vecs):
            # (the common case, a fit's arrays: copied together, one row each, and checked as Python floats, which
            # for a few sensors is several times faster than numpy's reductions)
            V = np.array(vecs)
            flat = V.ravel().tolist()
            if not all(map(math.isfinite, flat)):
                for v, name in zip(vecs, ("scale", "bias", "noise_sigma")):
                    _vec(v, n, name)  # (raises, naming the vector)
            self.scale, self.bias = V[0], V[1]
            if self.noise_sigma is not None:
                self.noise_sigma = V[2]
            zero_scale = 0.0 in flat[:n]
            bad_noise = self.noise_sigma is not None and not all(x > 0.0 for x in flat[2 * n:])
        else:
            self.scale = _vec(self.scale, n, "scale")
            self.bias = _vec(self.bias, n, "bias")
            if self.noise_sigma is not None:
                self.noise_sigma = _vec(self.noise_sigma, n, "noise_sigma")
            zero_scale = bool(_any(self.scale == 0))
            bad_noise = self.noise_sigma is not None and bool(_any(self.noise_sigma <= 0))
        m = np.array(self.misalignment, dtype=float)
        if m.shape != (n, 3):
            raise ShapeError(f"misalignment must have shape ({n}, 3), got {m.shape}")
        # row norms as numpy's add.reduce of the squares gives them (the same IEEE operations in the same order)
        norms = [math.sqrt(a * a + b * b + c * c) for a, b, c in m.tolist()]
        dev = [abs(x - 1.0) for x in norms]
        if not all(d <= 1e-3 for d in dev):  # (false for a non-finite entry too: its norm is inf or nan)
            if not _all(np.isfinite(m), axis=None):
                raise ShapeError("misalignment has non-finite entries")
            i = int(np.argmax(dev))
            raise ShapeError(
                f"misalignment row {i} ({self.geometry.names[i]}) has norm {norms[i]:.6f}; rows are unit vectors "
                "(Cho & Park Eq. 10). Normalise it, moving the norm into the scale factor"
            )
        for i, d in enumerate(dev):
            if d > 4e-16:
                m[i] /= norms[i]
        self.misalignment = m
        if zero_scale:
            raise ShapeError("a scale factor is zero; the sensor's output would carry no information")
        if bad_noise:
            raise ShapeError("noise_sigma must be positive")
        if self.noise_period_s is not None:
            self.noise_period_s = float(self.noise_period_s)
            if not (np.isfinite(self.noise_period_s) and self.noise_period_s > 0):
                raise ShapeError(f"noise_period_s must be a positive time (s), got {self.noise_period_s}")
        if self.range_raw is not None:
            self.range_raw = _vec(self.range_raw, n, "range_raw")
            if np.any(self.range_raw <= 0):
                raise ShapeError("range_raw must be positive: the largest |raw output| each sensor can report")
        if self.covariance is not None:
            c = np.array(self.covariance, dtype=float)
            p = len(self.param_names)
            if c.shape != (p, p):
                raise ShapeError(f"covariance has shape {c.shape}, but {p} param_names are given")
            self.covariance = c
        if self.noise is not None:
            if isinstance(self.noise, dict):
                self.noise = InstrumentNoise.from_dict(self.noise)
            if list(self.noise.names) != list(self.geometry.names) or self.noise.instrument != self.instrument:
                raise ShapeError(
                    f"the noise model is for {self.noise.instrument} sensors {self.noise.names}, this calibration for "
                    f"{self.instrument} sensors {list(self.geometry.names)}; identify the noise of this unit")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def nominal(
        cls, instrument: str, geometry: Geometry, scale: Any = 1.0, bias: Any = 0.0, noise_sigma: Any = None
    ) -> "InstrumentCalibration":
        """Coefficients with no misalignment (m_i = nominal row), given scale and bias."""
        n = geometry.n
        return cls(
            instrument,
            geometry,
            np.broadcast_to(np.asarray(scale, dtype=float), (n,)).copy(),
            geometry.nominal_rows(),
            np.broadcast_to(np.asarray(bias, dtype=float), (n,)).copy(),
            None if noise_sigma is None else np.broadcast_to(np.asarray(noise_sigma, dtype=float), (n,)).copy(),
        )

    # ------------------------------------------------------------------ model
    def axes_mb(self) -> np.ndarray:
        """Calibrated sensing axes in MB, (n, 3): a_i = C_j^T m_i (the rows of M H in Cho & Park Eq. 1)."""
        A = np.empty((self.geometry.n, 3))
        for su in self.geometry.subunits:
            idx = list(su.members)
            A[idx] = self.misalignment[idx] @ su.mat_sb_mb
        return A

    def compensate(self, y: np.ndarray) -> np.ndarray:
        """``SF * y - B`` for raw outputs ``y`` (..., n): the scale- and bias-compensated outputs, SI units."""
        return np.asarray(y, dtype=float) * self.scale - self.bias

    def raw_output(self, u: np.ndarray) -> np.ndarray:
        """Noise-free raw output for true inputs ``u`` (..., 3) in MB: ``(a.u + b) / SF``."""
        return (np.asarray(u, dtype=float) @ self.axes_mb().T + self.bias) / self.scale

    def noise_sigma_at(self, sample_period_s: float) -> np.ndarray | None:
        """``noise_sigma`` for samples of period ``sample_period_s`` (s): ``sigma sqrt(T_noise / T)``.

        The white noise of a mean of n samples has the variance ``sigma^2 / n``, so a sigma measured on n-sample
        averages (period ``T_noise = n T``) is ``sqrt(n)`` times too small for single samples. For noise that the
        chip's low-pass correlates between samples the converted per-sample sigma is an upper bound (the average
        kept more variance than ``sigma^2 / n``): conservative. Without ``noise_period_s`` the sigma is returned
        as it is.

        >>> from rimu.geometry import triads
        >>> cal = InstrumentCalibration.nominal("gyro", triads(3), noise_sigma=0.01)
        >>> cal.noise_period_s = 0.1                       # measured on 0.1 s averages
        >>> round(float(cal.noise_sigma_at(0.01)[0]), 5)   # at 100 Hz: sqrt(10) times larger
        0.03162
        """
        if self.noise_sigma is None or self.noise_period_s is None:
            return self.noise_sigma
        if not sample_period_s > 0:
            raise ValueError(f"sample_period_s must be positive (s), got {sample_period_s}")
        return self.noise_sigma * np.sqrt(self.noise_period_s / float(sample_period_s))

    def std(self) -> dict[str, float]:
        """Standard deviations of the parameters in ``param_names`` (SI), or {} without a covariance."""
        if self.covariance is None:
            return {}
        return dict(zip(self.param_names, np.sqrt(np.clip(np.diag(self.covariance), 0, None)).tolist()))

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        unit = SI_UNITS[self.instrument]
        return {
            "instrument": self.instrument,
            "geometry": self.geometry.to_dict(),
            "units": {
                "scale": f"{unit} per raw unit",
                "bias": unit,
                "misalignment": "unit row in sub-unit basis (off-axis components in rad)",
                "noise_sigma": f"{unit} per sample",
                "covariance": "SI, in the order of param_names",
                "range_raw": "raw output units; |y| >= range_raw is saturated",
            },
            "scale": self.scale.tolist(),
            "misalignment": self.misalignment.tolist(),
            "bias": self.bias.tolist(),
            "noise_sigma": None if self.noise_sigma is None else self.noise_sigma.tolist(),
            "param_names": list(self.param_names),
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "effects": self.effects,
            "range_raw": None if self.range_raw is None else self.range_raw.tolist(),
            **({} if self.noise is None else {"noise": self.noise.to_dict()}),
            **({} if self.noise_period_s is None else {"noise_period_s": self.noise_period_s}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "InstrumentCalibration":
        g = Geometry.from_dict(d["geometry"])
        stored = d["geometry"].get("fingerprint")
        if stored is not None and stored != g.fingerprint():
            raise CalibrationFileError(
                f"{d['instrument']}: the stored geometry fingerprint {stored} does not match its own H "
                f"({g.fingerprint()}); the geometry block was edited"
            )
        return cls(
            d["instrument"],
            g,
            np.array(d["scale"], dtype=float),
            np.array(d["misalignment"], dtype=float),
            np.array(d["bias"], dtype=float),
            None if d.get("noise_sigma") is None else np.array(d["noise_sigma"], dtype=float),
            None if d.get("covariance") is None else np.array(d["covariance"], dtype=float),
            list(d.get("param_names") or []),
            dict(d.get("effects") or {}),
            None if d.get("range_raw") is None else np.array(d["range_raw"], dtype=float),
            None if d.get("noise") is None else InstrumentNoise.from_dict(d["noise"]),
            d.get("noise_period_s"),
        )


@dataclass
class Calibration:
    """A unit's calibration: one :class:`InstrumentCalibration` per instrument kind.

    >>> from rimu.geometry import cone6
    >>> cal = Calibration({"gyro": InstrumentCalibration.nominal("gyro", cone6(), scale=0.01)})
    >>> cal.instruments
    ('gyro',)
    """

    instruments_cal: dict[str, InstrumentCalibration]
    raw_unit: str = "count"
    method: str = "nominal"
    created: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k, v in self.instruments_cal.items():
            if k != v.instrument:
                raise ValueError(f"key {k!r} holds a calibration of {v.instrument!r}")

    @property
    def instruments(self) -> tuple[str, ...]:
        return tuple(k for k in INSTRUMENTS if k in self.instruments_cal)

    def __getitem__(self, instrument: str) -> InstrumentCalibration:
        try:
            return self.instruments_cal[instrument]
        except KeyError:
            raise KeyError(f"this calibration has no {instrument!r}; it has {self.instruments}") from None

    def __contains__(self, instrument: object) -> bool:
        return instrument in self.instruments_cal

    def apply(self, raw: dict[str, Any] | None = None, **arrays: Any) -> dict[str, np.ndarray]:
        """Calibrated SI outputs of raw samples: the one call of imucal's ``cal_info.calibrate(acc, gyr, ...)``.

        ``raw`` (or keyword arrays ``gyro=``, ``accel=``) holds per instrument the raw outputs (N, n) in this
        calibration's raw unit. Each triad of the geometry (a sub-unit of three sensors) gives its vector in MB,
        ``u = A^-1 (SF y - B)`` with ``A`` its calibrated axes (Cho & Park Eq. 1 and 20), so a unit of k triads
        gives (N, 3k); any other geometry gives the least-squares vector of all its sensors, ``A^+ (SF y - B)``
        (Cho & Park Eq. 20), (N, 3). Effects beyond scale, misalignment and bias are not applied here: a file that
        holds them is refused (:class:`rimu.fusion.Compensator` compensates every effect).

        >>> from rimu.geometry import triad3
        >>> cal = Calibration({"accel": InstrumentCalibration.nominal("accel", triad3(), scale=2.0, bias=0.5)})
        >>> cal.apply(accel=np.array([[1.0, 1.0, 5.0]]))["accel"].tolist()
        [[1.5, 1.5, 9.5]]
        """
        from ..errors import NotCompensableError, ShapeError

        data = dict(raw or {}, **arrays)
        out = {}
        for k, y in data.items():
            c = self[k]
            if c.effects:
                raise NotCompensableError(f"the {k} calibration holds the effects {sorted(c.effects)}, which apply() "
                                          "does not compensate; use rimu.fusion.Compensator (rimu replay) for them")
            y = np.asarray(y, dtype=float)
            if y.ndim != 2 or y.shape[1] != c.geometry.n:
                raise ShapeError(f"{k}: raw outputs of shape {y.shape}; this calibration needs (N, {c.geometry.n})")
            z = c.compensate(y)
            A = c.axes_mb()
            subs = c.geometry.subunits
            if subs and all(len(su.members) == 3 for su in subs):
                out[k] = np.hstack([np.linalg.solve(A[list(su.members)], z[:, list(su.members)].T).T for su in subs])
            else:
                out[k] = z @ np.linalg.pinv(A).T
        return out

    def check_geometry(self, instrument: str, geometry: Geometry) -> None:
        """Raise GeometryMismatchError unless this calibration's geometry for ``instrument`` is ``geometry``."""
        mine = self[instrument].geometry
        if mine.fingerprint() != geometry.fingerprint():
            raise GeometryMismatchError(
                f"the {instrument} calibration belongs to geometry {mine.name!r} (fingerprint {mine.fingerprint()}), "
                f"not to {geometry.name!r} ({geometry.fingerprint()}); calibrate this unit, or load the file made for it"
            )

    # ------------------------------------------------------------------ file
    def to_payload(self) -> dict[str, Any]:
        return {
            "raw_unit": self.raw_unit,
            "method": self.method,
            "created": self.created,
            "metadata": self.metadata,
            "instruments": {k: self.instruments_cal[k].to_dict() for k in self.instruments},
        }

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write atomically (temporary file in the same folder, then rename) as versioned JSON."""
        from ..atomic import atomic_open

        path = Path(path)
        text = document_text(self.to_payload())
        with atomic_open(path, "w", encoding="utf-8") as fh:  # normal file mode, not mkstemp's 0600
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str], geometries: dict[str, Geometry] | None = None) -> "Calibration":
        """Read a calibration file; refuse a damaged, foreign or unknown-version file with a specific error.

        Parameters
        ----------
        geometries : dict, optional
            The unit's geometries per instrument; each present one must match the file's fingerprint.

        Raises
        ------
        CalibrationFileError
            Not JSON, not a rimu calibration, or malformed.
        ChecksumError
            Content altered after writing.
        UnsupportedVersionError
            Written by a newer rimu, or an unknown version.
        GeometryMismatchError
            Made for another geometry.
        """
        path = Path(path)
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise CalibrationFileError(f"cannot read calibration file {path}: {exc}") from exc
        try:
            text = raw.decode("utf-8")
            doc = json.loads(text)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CalibrationFileError(
                f"{path} is not valid JSON ({exc}); the file is damaged or not a calibration file. "
                "Restore it from a copy or calibrate again"
            ) from exc
        if not isinstance(doc, dict) or doc.get("format") != FORMAT_TAG:
            raise CalibrationFileError(f"{path} is not a rimu calibration file (no 'format': '{FORMAT_TAG}')")
        stored = doc.get("checksum")
        expected = _checksum(FORMAT_TAG, doc.get("version"), _payload_text(text))
        if stored != expected:
            raise ChecksumError(
                f"{path}: checksum mismatch (stored {stored!r}, content gives {expected!r}); "
                "the file was altered or damaged after it was written. Restore it or calibrate again"
            )
        cal = cls.from_document(doc, source=str(path))
        for inst, g in (geometries or {}).items():
            if inst in cal:
                cal.check_geometry(inst, g)
        return cal

    @classmethod
    def from_document(cls, doc: Any, source: str = "<document>") -> "Calibration":
        """Build from a parsed document (format tag and version checked; the byte checksum is :meth:`load`'s)."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT_TAG:
            raise CalibrationFileError(f"{source} is not a rimu calibration file (no 'format': '{FORMAT_TAG}')")
        version = doc.get("version")
        if not isinstance(version, int) or version < 1 or version > FORMAT_VERSION:
            raise UnsupportedVersionError(
                f"{source}: format version {version!r} is not known to this rimu (it reads versions 1..{FORMAT_VERSION}); "
                "upgrade rimu if the file is newer"
            )
        payload = doc["payload"]
        while version < FORMAT_VERSION:
            payload = MIGRATIONS[version](payload)
            version += 1
        try:
            insts = {k: InstrumentCalibration.from_dict(v) for k, v in payload["instruments"].items()}
            return cls(
                insts,
                raw_unit=payload.get("raw_unit", "count"),
                method=payload.get("method", "unknown"),
                created=payload.get("created", ""),
                metadata=dict(payload.get("metadata") or {}),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, CalibrationFileError):
                raise
            raise CalibrationFileError(f"{source}: malformed calibration content ({exc!r})") from exc


#: ``x.all()`` and ``x.any()`` of a boolean array as the ufunc reductions themselves (numpy's methods add a Python
#: layer: the validation of a result is a handful of these)
_all, _any = np.logical_and.reduce, np.logical_or.reduce


def _vec(v: Any, n: int, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    a = a.copy() if a.shape == (n,) else np.array(np.broadcast_to(a, (n,)), dtype=float)
    if not _all(np.isfinite(a), axis=None):
        raise ShapeError(f"{name} has non-finite entries: {a.tolist()}")
    return a


def _checksum(fmt: Any, version: Any, payload_text: str | None) -> str:
    """sha256 over the format tag, the version and the exact bytes of the payload as written."""
    blob = f"{fmt}\n{version}\n{payload_text}"
    return "sha256:" + hashlib.sha256(blob.encode("utf-8")).hexdigest()


_PAYLOAD_KEY = '\n"payload": '


def document_text(payload: dict[str, Any], version: int = FORMAT_VERSION) -> str:
    """The file's text: format, version and checksum first, then the payload (whose bytes the checksum covers)."""
    body = json.dumps(payload, indent=1, sort_keys=True, allow_nan=False)
    head = json.dumps({"format": FORMAT_TAG, "version": version, "checksum": _checksum(FORMAT_TAG, version, body)})
    return head[:-1] + "," + _PAYLOAD_KEY + body + "\n}\n"


def _payload_text(text: str) -> str | None:
    k = text.find(_PAYLOAD_KEY)
    end = text.rstrip().rfind("}")
    if k < 0 or end < 0:
        return None
    return text[k + len(_PAYLOAD_KEY):end].rstrip("\n")
