"""The exception tree of rimu.

Every error rimu raises on purpose derives from :class:`RimuError`; each member also subclasses the
built-in exception a caller would otherwise expect (python-can does the same), so ``except ValueError``
keeps working. Messages say what was wrong and what to do about it.
"""

from __future__ import annotations

__all__ = [
    "ExportError",
    "RimuError",
    "GeometryError",
    "RankDeficientError",
    "ShapeError",
    "NonFiniteError",
    "CalibrationFileError",
    "ChecksumError",
    "GeometryMismatchError",
    "UnsupportedVersionError",
    "IdentifiabilityError",
    "SessionFormatError",
    "ParameterNameError",
    "TransportError",
    "FrameError",
    "MissingNoiseError",
    "PlausibilityError",
    "OptionError",
    "OutputPathError",
    "NotApplicableError",
    "NotCompensableError",
    "MissingInputError",
    "BackendUnavailableError",
]


class RimuError(Exception):
    """Root of every error rimu raises on purpose."""


class GeometryError(RimuError, ValueError):
    """A sensor geometry is invalid (non-finite, not unit rows, wrong names, ...)."""


class RankDeficientError(GeometryError):
    """The sensing axes do not span three dimensions; the message names the unobservable directions."""

    def __init__(self, message: str, unobservable: "list[list[float]] | None" = None) -> None:
        super().__init__(message)
        self.unobservable = unobservable or []


class ShapeError(RimuError, ValueError):
    """An array has the wrong shape for the geometry or the call."""


class NonFiniteError(RimuError, ValueError):
    """Input contains NaN or infinity where rimu cannot route around it."""


class CalibrationFileError(RimuError, ValueError):
    """A calibration file cannot be used (corrupt, wrong geometry, unknown version, malformed)."""


class ChecksumError(CalibrationFileError):
    """The stored checksum does not match the content: the file was altered or damaged."""


class GeometryMismatchError(CalibrationFileError):
    """A calibration belongs to another geometry than the one it is used with."""


class UnsupportedVersionError(CalibrationFileError):
    """The file's format version is unknown to this rimu (newer, or never existed)."""


class IdentifiabilityError(RimuError, ValueError):
    """A test sequence cannot identify some parameters; ``parameters`` names them."""

    def __init__(self, message: str, parameters: "list[str] | None" = None) -> None:
        super().__init__(message)
        self.parameters = list(parameters or [])


class SessionFormatError(RimuError, ValueError):
    """A session file is missing something or malformed; the message gives row and column."""


class ParameterNameError(RimuError, KeyError):
    """Two effects claim the same parameter name, or a name is unknown."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0]) if self.args else ""


class TransportError(RimuError, IOError):
    """A data source failed (bus off, port closed, ...)."""


class FrameError(RimuError, ValueError):
    """A frame or packet could not be decoded."""


class MissingNoiseError(RimuError, ValueError):
    """A noise figure the computation needs (a calibration's ``noise_sigma``) is missing and was not given."""
class PlausibilityError(SessionFormatError):
    """Data that parse but cannot be what the file declares (values in m/s^2 under a column declared in g, a
    ``sample_rate_hz`` the time column contradicts, ...). The message names the column and the likely cause; where
    the data may still be right, the caller can override the check (``checks="warn"``, CLI ``--accept-implausible``).
    ``findings`` holds the :class:`rimu.session.checks.Finding` s that failed."""

    def __init__(self, message: str, findings: "list | None" = None) -> None:
        super().__init__(message)
        self.findings = list(findings or [])


class OptionError(RimuError, ValueError):
    """A command-line option or a function argument has a value outside its range (the message names the option
    and the accepted range)."""


class OutputPathError(RimuError, OSError):
    """An output path cannot be written (its folder is missing or read-only, it is a folder, or it would overwrite
    another output of the same run). Raised before any work is done."""


class NotApplicableError(RimuError, ValueError):
    """A check or method does not apply to this data (a parity check on a triad, a rate-pair check without rate
    pairs); the message says why and what would apply."""
class NotCompensableError(RimuError, ValueError):
    """An effect of the calibration has no runtime compensation (the message names it and says why)."""


class MissingInputError(RimuError, ValueError):
    """The runtime needs an input the data stream does not carry (the message names the effect and the input)."""

    def __init__(self, message: str, effect: str = "", input_name: str = "") -> None:
        super().__init__(message)
        self.effect = effect
        self.input_name = input_name


class ExportError(RimuError, ValueError):
    """A calibration cannot be exported as flight code (an effect without a C compensation, missing noise, ...)."""


class BackendUnavailableError(RimuError, ImportError):
    """A compiled backend was asked for (``backend="numba"``, ``RIMU_BACKEND=numba``) and is not installed."""
