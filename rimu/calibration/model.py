"""The error model: a sum of named physical effects (in the manner of lmfit's and pysindy's composite models).

For sensor i of an instrument, with true input u (MB, SI) and everything else the rig knows::

    SF_i y_i = a_i . u + b_i + sum_e  phi_e(segment, sensor) . theta_e  + v_i          (SI domain)

Dividing by SF_i gives a model that is linear in the raw domain::

    y_i = u . w_i + c_i + sum_e phi_e . beta_e + v_i / SF_i,
    w_i = a_i / SF_i,  c_i = b_i / SF_i,  beta_e = theta_e / SF_i

This is Cho & Park 2005 Eq. 5 (``[s 1] [m/SF; b/SF]``) extended by further columns. Scale factor and unit
axis follow from |w_i| = 1 / SF_i (the unit-norm constraint, Eq. 10), and every other physical parameter is
``beta * SF``.

An :class:`Effect` is one small class: it names its parameters (with units and the unit the field reports
them in) and, for a segment and a sensor, returns the regressor columns ``phi`` in SI (N x k), or ``None``
when the segment does not carry the inputs it needs. ``model + effect`` makes a composite; name clashes
raise :class:`~rimu.errors.ParameterNameError`. Adding an effect is a new file in ``rimu/calibration/effects``
plus one line in its registry.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..epoch import INSTRUMENTS
from ..errors import NotCompensableError, ParameterNameError
from ..geometry import Geometry
from ..session import Segment, Session

__all__ = ["ParamSpec", "SensorContext", "Effect", "ErrorModel", "EFFECTS", "register_effect", "effect",
           "RuntimeInputs", "RUNTIME_INPUTS", "RuntimeForm", "MONOMIALS", "monomial", "unit_axes", "axes_from_w"]


@dataclass(frozen=True)
class ParamSpec:
    """A parameter an effect owns.

    Attributes
    ----------
    name : str
        Local name, e.g. ``"bias"``, ``"gsens_x"``; the full name is ``"{sensor}.{name}"``.
    unit : str
        SI unit of the value (e.g. ``"rad/s"``, ``"(rad/s)/(m/s^2)"``).
    report_unit : str
        Unit the field reports it in (``"deg/h"``, ``"ppm"``, ``"arcsec"``, ``"ug"``, ...).
    to_report : float
        Factor from SI to the report unit.
    """

    name: str
    unit: str
    report_unit: str = ""
    to_report: float = 1.0


@dataclass(frozen=True)
class SensorContext:
    """What an effect may know about the sensor it builds columns for."""

    instrument: str
    index: int
    geometry: Geometry
    latitude: float | None = None
    gravity: float = 9.80665
    reference_temperature: float = 25.0
    #: gyros: whether the known input includes the Earth rate (where attitude and latitude are known). False
    #: leaves it out, so that the ``earth_rate`` effect can test whether the gyros see it.
    include_earth_rate: bool = True
    #: calibrated sensing axes of the instrument in MB (n, 3), unit rows; None: the nominal ones. The effects of
    #: the input along an axis (nonlinearity, asymmetry, scale temperature terms, cross coupling, size effect)
    #: act on what the sensor really senses, so fits, diagnosis and runtime evaluate them on these.
    axes: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def name(self) -> str:
        return self.geometry.names[self.index]

    @property
    def axis(self) -> np.ndarray:
        """Sensing axis in MB: the calibrated one where :attr:`axes` is given, else the nominal one."""
        return self.geometry.H[self.index] if self.axes is None else self.axes[self.index]

    def axis_of(self, j: int) -> np.ndarray:
        """Sensing axis of sensor ``j`` of the same instrument (calibrated where known)."""
        return self.geometry.H[j] if self.axes is None else self.axes[j]

    def input(self, segment: Segment) -> np.ndarray | None:
        """The known true input of this instrument in MB, (N, 3), or None when the segment does not know it.

        Gyros: table rate plus Earth rate where the attitude and latitude are known (a 'rate' segment without
        attitude gives the table rate alone; Earth rate then counts as a bias-like disturbance the procedure
        must cancel). Accelerometers: the specific force.
        """
        if self.instrument == "gyro":
            if segment.kind in ("rate", "static"):
                return segment.angular_rate(self.latitude, include_earth=self.include_earth_rate)
            return None
        return segment.specific_force(self.gravity)


#: What an effect may need at runtime (see :class:`RuntimeInputs` and :attr:`Effect.runtime_needs`).
RUNTIME_INPUTS = ("time", "temperature", "specific_force", "angular_rate", "axis_input", "input")


@dataclass
class RuntimeInputs:
    """What the runtime knows about N samples, SI, for evaluating effects outside a calibration session.

    Attributes
    ----------
    t : ndarray (N,)
        Time since the stream started, s (the calibration's session time runs from 0 too).
    axis_input : ndarray (N, n) or None
        Input of the instrument along each sensor's nominal axis, ``s_i = h_i . u`` (rad/s or m/s^2), with u
        the current estimate in MB. The compensation solves for it (output-side effects are inverted).
    temperature : ndarray (N,) or None
        Unit temperature, degC.
    specific_force : ndarray (N, 3) or None
        Specific force in MB, m/s^2 (the accelerometers' estimate of the same epoch).
    angular_rate : ndarray (N, 3) or None
        Angular rate in MB, rad/s (the gyros' estimate of the same epoch).
    input : ndarray (N, 3) or None
        The instrument's own input in MB (its current estimate u, which the inversion updates).
    """

    t: np.ndarray
    axis_input: np.ndarray | None = None
    temperature: np.ndarray | None = None
    specific_force: np.ndarray | None = None
    angular_rate: np.ndarray | None = None
    input: np.ndarray | None = None

    def temperature_offset(self, ctx: SensorContext) -> np.ndarray:
        """``T - T_ref`` (N,), K."""
        if self.temperature is None:
            raise NotCompensableError("this effect needs the temperature, and the inputs carry none")
        return np.asarray(self.temperature, dtype=float) - ctx.reference_temperature


def _monomials() -> tuple[str, ...]:
    out = ["1", "t", "dT", "dT2"]
    for v in ("f", "w"):
        out += [f"{v}_{a}" for a in "xyz"]
        out += [f"{v}_{a}{b}" for i, a in enumerate("xyz") for b in "xyz"[i:]]
    return tuple(out)


#: The exogenous monomials a :class:`RuntimeForm` is written in: 1, time since start t, dT = T - T_ref, dT^2,
#: the specific force f and the angular rate w in MB (components ``f_x`` and products ``f_xy``, ``w_zz``, ...).
MONOMIALS = _monomials()
_MONO_INDEX = {m: i for i, m in enumerate(MONOMIALS)}


def monomial(name: str, b: str | None = None) -> int:
    """Index of a monomial in :data:`MONOMIALS`; ``monomial("f", "yx")`` is the product f_x f_y.

    >>> MONOMIALS[monomial("w", "zx")]
    'w_xz'
    """
    if b is None:
        return _MONO_INDEX[name]
    return _MONO_INDEX[f"{name}_{''.join(sorted(b))}"]


@dataclass(frozen=True)
class RuntimeForm:
    """The structure of an effect's runtime regressors, for the compiled (per-sample fast) runtime path.

    For sensor i and column k::

        phi_ik = (sum_m F[i, k, m] * mono_m) * g_ik(s)

    with mono the exogenous monomials of :data:`MONOMIALS` and, by ``kind``: ``"exogenous"`` g = 1;
    ``"power"`` g = s_i**power; ``"absolute"`` g = |s_i|; ``"pair"`` g = (h_i . u)(d_ik . u) with h_i the
    nominal axis, d_ik = ``directions[i, k]`` and u the instrument's MB input.
    An effect that gives one (:meth:`Effect.runtime_form`) must give the same numbers as its
    :meth:`Effect.runtime_columns` (tested for every effect of the registry); one that does not is evaluated
    through :meth:`Effect.runtime_columns` (slower per sample, same result).
    """

    kind: str
    F: np.ndarray
    power: int = 0
    directions: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("exogenous", "power", "absolute", "pair"):
            raise ValueError(f"unknown runtime form kind {self.kind!r}")
        if np.ndim(self.F) != 3 or np.shape(self.F)[2] != len(MONOMIALS):
            raise ValueError(f"F must have shape (n, k, {len(MONOMIALS)}), got {np.shape(self.F)}")

    @classmethod
    def zeros(cls, kind: str, n: int, k: int, **kwargs: Any) -> "RuntimeForm":
        return cls(kind, np.zeros((n, k, len(MONOMIALS))), **kwargs)


class Effect:
    """Base class of a physical effect. Subclasses set the class attributes and implement two methods.

    Class attributes
    ----------------
    name : str
        Registry key (``"bias"``, ``"g_sensitivity"``, ...).
    instruments : tuple of str
        Which instruments it applies to.
    description : str
        One plain-language line.
    physics : str
        Where it comes from physically, and what test excites it.
    """

    name: ClassVar[str] = ""
    instruments: ClassVar[tuple[str, ...]] = INSTRUMENTS
    description: ClassVar[str] = ""
    physics: ClassVar[str] = ""
    #: What :meth:`runtime_columns` needs, from :data:`RUNTIME_INPUTS`. ``"axis_input"`` (and ``"input"``, the
    #: instrument's own MB input) make the effect output-side: the runtime inverts it exactly (Newton on each
    #: sensor's own input, with :meth:`runtime_slope`).
    runtime_needs: ClassVar[tuple[str, ...]] = ()

    def parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        """The linear (raw-domain) parameters, one per column."""
        raise NotImplementedError

    def physical_parameters(self, ctx: SensorContext) -> list[ParamSpec]:
        """The physical (SI) parameters reported to users; by default one per column (theta = beta * SF)."""
        return self.parameters(ctx)

    def columns(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        """Regressors phi (N, k) in SI for this segment and sensor, or None if the segment lacks the inputs."""
        raise NotImplementedError

    def applies_to(self, ctx: SensorContext) -> bool:
        return ctx.instrument in self.instruments

    # ------------------------------------------------------------------ runtime compensation
    def runtime_columns(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """Regressors of every sensor of an instrument at runtime, (N, n, k), SI.

        The output error of sensor i is ``runtime_columns[:, i] @ theta_i`` with theta_i its physical parameters
        (in the order of :meth:`physical_parameters`, zero-padded to k). The same numbers as :meth:`columns`
        where a segment's known inputs equal ``inputs``. The default: not compensable.
        """
        raise NotCompensableError(
            f"effect {self.name!r} has no runtime compensation; it can be fitted and diagnosed, but the runtime "
            "pipeline cannot undo it. Leave it out of the calibration used at runtime, or give the effect "
            "runtime_columns()")

    def runtime_slope(self, inputs: RuntimeInputs, ctxs: Sequence[SensorContext]) -> np.ndarray:
        """``d runtime_columns[:, i] / d s_i`` (N, n, k) for output-side effects (``"axis_input"`` in
        :attr:`runtime_needs`): the derivative against each sensor's own input, for the exact inversion."""
        raise NotCompensableError(f"effect {self.name!r} is output-side but gives no runtime_slope()")

    def runtime_form(self, ctxs: Sequence[SensorContext]) -> RuntimeForm | None:
        """The structure of :meth:`runtime_columns` for the compiled runtime path, or None (the default: the
        runtime evaluates :meth:`runtime_columns` itself)."""
        return None

    def __add__(self, other: "Effect | ErrorModel") -> "ErrorModel":
        return ErrorModel([self]) + other

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class ErrorModel:
    """A sum of effects. One level deep: adding two models concatenates their effects.

    >>> from rimu.calibration.effects import Bias, ScaleMisalignment
    >>> m = ScaleMisalignment() + Bias()
    >>> m
    ErrorModel(scale_misalignment + bias)
    >>> m + Bias()
    Traceback (most recent call last):
    ...
    rimu.errors.ParameterNameError: effect 'bias' is already in the model (scale_misalignment + bias)
    """

    def __init__(self, effects: Iterable[Effect]) -> None:
        effs: list[Effect] = []
        for e in effects:
            if any(x.name == e.name for x in effs):
                raise ParameterNameError(f"effect {e.name!r} is in the model twice")
            effs.append(e)
        self.effects: tuple[Effect, ...] = tuple(effs)

    @classmethod
    def base(cls) -> "ErrorModel":
        """Scale factor, misalignment and bias (Cho & Park Eq. 1-2)."""
        return cls([effect("scale_misalignment"), effect("bias")])

    @classmethod
    def from_names(cls, names: Sequence[str] | str) -> "ErrorModel":
        """Build from registry names, e.g. ``"bias,scale,misalignment,g_sensitivity"``.

        ``scale`` and ``misalignment`` both mean the joint scale/misalignment effect (they are one linear
        block: the axis w_i = a_i / SF_i).
        """
        if isinstance(names, str):
            names = [s.strip() for s in names.split(",") if s.strip()]
        effs: list[Effect] = []
        for nm in names:
            e = effect(nm)
            if not any(x.name == e.name for x in effs):
                effs.append(e)
        return cls(effs)

    def __add__(self, other: "Effect | ErrorModel | str") -> "ErrorModel":
        if isinstance(other, str):
            other = effect(other)
        new = list(other.effects) if isinstance(other, ErrorModel) else [other]
        for e in new:
            if any(x.name == e.name for x in self.effects):
                raise ParameterNameError(f"effect {e.name!r} is already in the model ({self.label})")
        return ErrorModel(list(self.effects) + new)

    def __contains__(self, name: object) -> bool:
        return any(e.name == name for e in self.effects)

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    @property
    def label(self) -> str:
        return " + ".join(e.name for e in self.effects)

    def __repr__(self) -> str:
        return f"ErrorModel({self.label})"

    # ------------------------------------------------------------------ design
    def effects_for(self, ctx: SensorContext) -> list[Effect]:
        return [e for e in self.effects if e.applies_to(ctx)]

    def parameter_names(self, ctx: SensorContext) -> list[str]:
        """Full names (``"x1.bias"``) of the linear parameters for one sensor, in column order."""
        names: list[str] = []
        for e in self.effects_for(ctx):
            names += [f"{ctx.name}.{p.name}" for p in e.parameters(ctx)]
        if len(set(names)) != len(names):
            dup = sorted({x for x in names if names.count(x) > 1})
            raise ParameterNameError(f"parameter names collide: {dup}")
        return names

    def design(self, segment: Segment, ctx: SensorContext) -> np.ndarray | None:
        """Regressor matrix (N, p) of one segment for one sensor, or None if some effect lacks inputs."""
        cols = []
        for e in self.effects_for(ctx):
            c = e.columns(segment, ctx)
            if c is None:
                return None
            cols.append(np.asarray(c, dtype=float).reshape(segment.n_samples, -1))
        return np.hstack(cols) if cols else np.zeros((segment.n_samples, 0))


def contexts(session: Session, instrument: str, reference_temperature: float = 25.0,
             include_earth_rate: bool = True, axes: np.ndarray | None = None) -> list[SensorContext]:
    """One :class:`SensorContext` per sensor of ``instrument`` in ``session`` (``axes``: calibrated axes)."""
    g = session.geometries[instrument]
    A = None if axes is None else unit_axes(axes)
    return [SensorContext(instrument, i, g, session.latitude, session.gravity, reference_temperature, include_earth_rate,
                          A) for i in range(g.n)]


def unit_axes(axes: np.ndarray) -> np.ndarray:
    """Rows normalised to unit length, read-only (the calibrated axes of :class:`SensorContext`)."""
    A = np.asarray(axes, dtype=float)
    A = A / np.linalg.norm(A, axis=1)[:, None]
    A.setflags(write=False)
    return A


def axes_from_w(w: np.ndarray) -> np.ndarray:
    """Calibrated axes (n, 3) from the raw-domain scale/misalignment rows w_i = a_i / SF_i (Cho & Park Eq. 10)."""
    return unit_axes(w)


#: registry: name -> Effect class
EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect], *aliases: str) -> type[Effect]:
    """Register an effect class under its ``name`` (and aliases). Returns the class (usable as a decorator)."""
    for key in (cls.name, *aliases):
        if key in EFFECTS and EFFECTS[key] is not cls:
            raise ParameterNameError(f"an effect called {key!r} is already registered ({EFFECTS[key].__name__})")
        EFFECTS[key] = cls
    return cls


def effect(name: str, **kwargs: Any) -> Effect:
    """An effect instance by registry name (the registry is filled by ``rimu.calibration.effects``, which
    ``rimu.calibration`` imports first)."""
    try:
        return EFFECTS[name](**kwargs)
    except KeyError:
        raise ParameterNameError(f"unknown effect {name!r}; known: {sorted(EFFECTS)}") from None
