"""The compensation of every further effect of a calibration as C99, generated from the same compiled matrices as
the Python runtime (:class:`rimu.fusion.effects.EffectCompensation`), for :func:`rimu.export.export_c`.

Per epoch and per instrument with further effects (the module docstring of :mod:`rimu.fusion.effects` has the
model)::

    m = (1, t, dT, dT^2, f, f products, w, w products)         the epoch's monomials (22)
    K = D m                                                   exogenous error and output-side coefficients
    z_i = SF_i y_i - b_i - K_exo,i
    q_i <- q_i - (q_i + c_i(q) - z_i) / (1 + dc_i/dq_i)       Newton, ``newton_steps`` times, from q = z
    c_i = (k1_i + (k2_i + k3_i q_i) q_i) q_i + ka_i |q_i| + (h_i . u)(Hx_i . u)

with u the instrument's weighted least-squares estimate of q on its usable sensors, re-made before each step
where cross coupling needs it. The result is handed to the projection as the raw output of an ideal sensor,
``(q + b) / SF``; an instrument with exogenous effects only is corrected in the raw domain,
``y - (D_exo / SF) m``, as the Python runtime does.

Between instruments the order, the inputs and the rounds are those of :meth:`rimu.fusion.Pipeline.step`: the
accelerometers go first and their estimate of the epoch is the specific force of the gyros' g-sensitivity;
where the accelerometers' size effect needs the angular rate and the gyros need nothing from them, the gyros go
first; where both need the other, ``Pipeline.cycle_rounds`` rounds of accelerometers-then-gyros with estimates
(the fixed point of ``Pipeline._preliminary_rate``) give the angular rate the size effect uses.

Inside the compensation the C estimate of u and of the preliminary rounds uses the sensors that are not isolated,
flagged valid and finite, as the Python runtime (:meth:`rimu.fusion.InstrumentPipeline.usable`). In the fault
unit's epoch (``rimu_step`` and the fault managers' ``rimu_fdi_step``) a raw output at its range limit is, as in
Python, also left out of those estimates and handed on as it came, and each instrument's step routes it around as
saturated.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..calibration.model import MONOMIALS
from ..calibration.result import Calibration
from ..errors import CalibrationFileError, ExportError, NotCompensableError
from ..fusion.effects import EffectCompensation
from ..fusion.pipeline import Pipeline

__all__ = ["STEP_PARAMS", "EffectsPlan", "filter_call", "header", "needs_temperature", "plan", "source",
           "unit_declaration", "unit_step"]

_NAMES = {"exo": "kexo", 1: "k1", 2: "k2", 3: "k3", "abs": "kabs"}


@dataclass
class EffectsPlan:
    """What the generated C does per epoch: the instruments' compensations, their order and the rounds."""

    instruments: list[str]
    comps: dict[str, EffectCompensation] = field(default_factory=dict)
    order: list[str] = field(default_factory=list)
    cyclic: bool = False
    rounds: int = 2
    reference_temperature: float = 25.0

    @property
    def needs_temperature(self) -> bool:
        return any("temperature" in c.needs for c in self.comps.values())

    @property
    def needs_time(self) -> bool:
        return any("time" in c.needs for c in self.comps.values())

    def public_step(self, k: str) -> bool:
        """Whether ``rimu_<k>_step`` stays public: the instrument has no further effect (scale and bias only)."""
        return k not in self.comps


def plan(cal: Calibration) -> EffectsPlan:
    """The compensation plan of ``cal``, as :class:`rimu.fusion.Pipeline` would run it.

    Raises
    ------
    ExportError
        An effect without runtime compensation, or without a compiled form (its Python runtime evaluates
        ``runtime_columns``, which has no C counterpart); an effect needing the other instrument's estimate
        where the calibration has no such instrument; parameters that do not fit the geometry.

    Examples
    --------
    >>> from rimu.calibration.result import InstrumentCalibration
    >>> from rimu.geometry import triad3
    >>> g = InstrumentCalibration.nominal("gyro", triad3(), scale=0.01, noise_sigma=0.001)
    >>> a = InstrumentCalibration.nominal("accel", triad3(), scale=0.001, noise_sigma=0.01)
    >>> g.effects = {"g_sensitivity": {"x.gsens_x": 1e-5}}     # gyros need the specific force
    >>> p = plan(Calibration({"gyro": g, "accel": a}))
    >>> p.order, p.cyclic, p.public_step("accel")
    (['accel', 'gyro'], False, True)
    >>> a.effects = {"size_effect": {"x.r_x": 0.01}}           # and the accelerometers the rate: the cycle
    >>> p = plan(Calibration({"gyro": g, "accel": a}))
    >>> p.order, p.cyclic, p.rounds, p.needs_temperature
    (['accel', 'gyro'], True, 2, False)
    """
    meta = cal.metadata or {}
    t_ref = float(meta.get("reference_temperature", 25.0))
    comps: dict[str, EffectCompensation] = {}
    for k in cal.instruments:
        try:
            c = EffectCompensation(cal[k], t_ref)
        except (NotCompensableError, CalibrationFileError) as exc:
            raise ExportError(f"cannot export: {exc}") from exc
        if not c:
            continue
        if c.has_generic:
            names = sorted({t.effect.name for t in c._generic_exo + c._generic_out})
            raise ExportError(f"{k}: effect(s) {', '.join(names)} have no compiled runtime form (RuntimeForm), so "
                              "no C compensation; give the effect a runtime_form(), or export a calibration without "
                              "them")
        comps[k] = c
    have = {"specific_force": "accel" in cal.instruments, "angular_rate": "gyro" in cal.instruments}
    for k, c in comps.items():
        for need, ok in have.items():
            if need in c.needs and not ok:
                eff = c.effects_needing(need)[0]
                raise ExportError(f"{k} effect {eff!r} needs the {need.replace('_', ' ')}, and the calibration has "
                                  f"no {'accelerometers' if need == 'specific_force' else 'gyros'} to give it; "
                                  f"calibrate the {'accelerometers' if need == 'specific_force' else 'gyros'} too, "
                                  f"so that {eff!r} is compensated")
    # the order of Pipeline.__init__ (accelerometers first unless only the size effect needs the other's input)
    acc, gyr = comps.get("accel"), comps.get("gyro")
    acc_needs_w = acc is not None and "angular_rate" in acc.needs
    gyr_needs_f = gyr is not None and "specific_force" in gyr.needs
    first = ("gyro", "accel") if acc_needs_w and not gyr_needs_f else ("accel", "gyro")
    return EffectsPlan([k for k in ("gyro", "accel") if k in cal.instruments], comps, [k for k in first if k in cal.instruments],
                       acc_needs_w and gyr_needs_f, int(Pipeline.cycle_rounds), t_ref)


# ---------------------------------------------------------------------------------------------------- C text
_REAL_LITERAL = re.compile(r"(?<![\w.])(\d+\.\d+(?:e[-+]?\d+)?)(?![\w.])")


def reals(text: str, real: str) -> str:
    """C text whose floating constants (written ``1.0``, ``0.5``) are of type ``real``: suffixed ``f`` for a float
    build, so that no double constant meets a float (MISRA C:2012's essential types, rules 10.3 and 10.4).

    >>> reals("x = 1.0 / d + 2.5e-3; y[2] = 0;", "float")
    'x = 1.0f / d + 2.5e-3f; y[2] = 0;'
    """
    return text if real != "float" else _REAL_LITERAL.sub(r"\1f", text)


_FLT_MIN, _FLT_MAX = 1.1754943508222875e-38, 3.4028234663852886e+38


def _num(v: float, real: str) -> str:
    """A C literal of ``v``; in float, magnitudes below FLT_MIN are 0 (a literal that rounds to zero does not
    build with -Werror, and such a coefficient changes no float result) and above FLT_MAX refused."""
    if real == "float" and abs(v) < _FLT_MIN:
        v = 0.0
    if real == "float" and abs(v) > _FLT_MAX:
        raise ExportError(f"a compensation coefficient ({v:.3g}) exceeds the float range; export with real='double'")
    s = repr(float(v))
    if "e" not in s and "." not in s:
        s += ".0"
    return s + ("f" if real == "float" else "")


def _dot(row: np.ndarray, var: str, real: str) -> str:
    """``sum_m row[m] var[m]`` over the nonzero entries (``var[0]`` is the constant monomial 1)."""
    terms = []
    for m in np.flatnonzero(row):
        c = _num(row[m], real)
        terms.append(c if m == 0 else f"{c} * {var}[{m}]")
    return " + ".join(terms) if terms else _num(0.0, real)


def _arr(values: np.ndarray, real: str) -> str:
    return "{" + ", ".join(_num(v, real) for v in np.asarray(values, dtype=float).ravel()) + "}"


#: the per-instrument parameters of ``rimu_step`` (``{k}``: the instrument)
STEP_PARAMS = "const rimu_state *{k}_state, const rimu_real *{k}_y, const unsigned char *{k}_valid, rimu_output *{k}_out"


def _per(template: str | dict[str, str], k: str) -> str:
    """A per-instrument template: one for all (``{k}`` templated) or one per instrument."""
    return (template[k] if isinstance(template, dict) else template).format(k=k)


def unit_declaration(cal: Calibration, name: str, params: str | dict[str, str], lead: str = "") -> str:
    """The prototype of a unit step made by :func:`unit_step` (``params`` per instrument, ``{k}`` templated, or a
    template per instrument; ``lead`` further parameters after the temperature)."""
    args = ", ".join(_per(params, k) for k in plan(cal).instruments)
    return f"void {name}(rimu_real t, rimu_real temperature, {lead}{args});"


def header(cal: Calibration, real: str) -> str:
    """Declarations for ``rimu_unit.h``: what the unit step needs and its prototype."""
    p = plan(cal)
    effects = {k: sorted(t.effect.name for t in c.terms) for k, c in p.comps.items()}
    desc = "; ".join(f"{k}: {', '.join(v)}" for k, v in effects.items()) or "none (scale factor and bias only)"
    lines = [
        f"/* further effects compensated: {desc} */",
        f"#define RIMU_NEEDS_TEMPERATURE {int(p.needs_temperature)}  /* rimu_step reads temperature */",
        f"#define RIMU_NEEDS_TIME {int(p.needs_time)}  /* rimu_step reads t (drift) */",
        f"#define RIMU_REFERENCE_TEMPERATURE {_num(p.reference_temperature, real)}  /* degC, T_ref of the "
        "temperature effects */",
        "",
        "/* One epoch of the whole unit, every calibrated effect compensated: t = time since switch-on (s; the origin",
        " * of the drift terms), temperature = unit temperature (degC; read only when RIMU_NEEDS_TEMPERATURE), then",
        " * per instrument its state, raw outputs (device units), valid flags (NULL: all) and output. The",
        " * instruments run in the order of rimu's Python pipeline, each fed the other's estimate of the epoch. */",
        unit_declaration(cal, "rimu_step", STEP_PARAMS),
    ]
    return "\n".join(lines) + "\n"


_COMMON = r"""
/* ---- further effects (rimu.export.c_effects; rimu.fusion.effects is the reference) ---- */
#define RIMU_NMONO 22

/* the epoch's monomials (rimu.calibration.model.MONOMIALS): 1, t, dT, dT^2, f, f_xx f_xy f_xz f_yy f_yz f_zz,
   w, w products */
static void rimu_monomials(rimu_real t, rimu_real dT, const rimu_real *f, const rimu_real *w, rimu_real *m)
{
    int k;
    const rimu_real *v;
    rimu_real *o;
    m[0] = 1; m[1] = t; m[2] = dT; m[3] = dT * dT;
    for (k = 0; k < 2; ++k) {
        v = k == 0 ? f : w;
        o = m + 4 + 9 * k;
        o[0] = v[0]; o[1] = v[1]; o[2] = v[2];
        o[3] = v[0] * v[0]; o[4] = v[0] * v[1]; o[5] = v[0] * v[2];
        o[6] = v[1] * v[1]; o[7] = v[1] * v[2]; o[8] = v[2] * v[2];
    }
}
"""

_WLS = r"""
/* The weighted least-squares estimate x of outputs z on the sensors in use (not isolated, valid, finite); 0 when
   they do not span 3-D: the estimate the compensation feeds its cross coupling and the other instrument. The
   normal matrix depends only on which sensors are in use, so the Newton steps of one instrument set it up once
   (rimu_wls_setup) and apply it to each new q (rimu_wls_next): a q that is non-finite where z was finite (which
   the steps do not make) is set up afresh. With every sensor in use, x = G z with G the export-time
   weighted least-squares matrix of the full set (as InstrumentPipeline.estimate does). */
typedef struct {
    unsigned char use[RIMU_NMAX];
    rimu_real P00, P01, P02, P11, P12, P22;
    int observable;
    const rimu_real *G;  /* the full set's 3 x n estimator when every sensor is in use, else 0 */
} rimu_wls_set;

static void rimu_wls_setup(int n, const rimu_real *ax, const rimu_real *w, const rimu_real *G,
                           const unsigned char *iso, const unsigned char *valid, const rimu_real *z, rimu_wls_set *s)
{
    rimu_real N00 = 0.0, N01 = 0.0, N02 = 0.0, N11 = 0.0, N12 = 0.0, N22 = 0.0, scale = 0.0, det, id;
    int i, m = 0;
    for (i = 0; i < n; ++i) {
        s->use[i] = ((iso[i] == 0u) && ((valid == NULL) || (valid[i] != 0u)) && (isfinite(z[i]) != 0)) ? 1u : 0u;
        if (s->use[i] != 0u) {
            ++m;
        }
    }
    s->G = (m == n) ? G : NULL;
    s->observable = 0;
    if (s->G != NULL) {
        s->observable = 1;
        return;
    }
    m = 0;
    for (i = 0; i < n; ++i) {
        const rimu_real *a = ax + 3 * i;
        if (s->use[i] == 0u) {
            continue;
        }
        N00 += w[i] * a[0] * a[0]; N01 += w[i] * a[0] * a[1]; N02 += w[i] * a[0] * a[2];
        N11 += w[i] * a[1] * a[1]; N12 += w[i] * a[1] * a[2]; N22 += w[i] * a[2] * a[2];
        scale += w[i];
        ++m;
    }
    s->P00 = N11 * N22 - N12 * N12;
    s->P01 = N02 * N12 - N01 * N22;
    s->P02 = N01 * N12 - N02 * N11;
    det = N00 * s->P00 + N01 * s->P01 + N02 * s->P02;
    if ((m < 3) || !(det > (RIMU_RANK_TOL * scale * scale * scale))) {
        return;  /* not observable */
    }
    s->observable = 1;
    id = 1.0 / det;
    s->P11 = (N00 * N22 - N02 * N02) * id;
    s->P12 = (N01 * N02 - N00 * N12) * id;
    s->P22 = (N00 * N11 - N01 * N01) * id;
    s->P00 *= id; s->P01 *= id; s->P02 *= id;
}

/* x from the set s; 0 (x untouched) when some sensor of the set has a non-finite z */
static int rimu_wls_apply(int n, const rimu_real *ax, const rimu_real *w, const rimu_wls_set *s,
                          const rimu_real *z, rimu_real *x)
{
    rimu_real h0 = 0.0, h1 = 0.0, h2 = 0.0;
    int i;
    if (s->G != NULL) {
        const rimu_real *G = s->G;
        for (i = 0; i < n; ++i) {
            if (isfinite(z[i]) == 0) {
                return 0;
            }
            h0 += G[i] * z[i]; h1 += G[n + i] * z[i]; h2 += G[2 * n + i] * z[i];
        }
        x[0] = h0; x[1] = h1; x[2] = h2;
        return 1;
    }
    for (i = 0; i < n; ++i) {
        const rimu_real *a = ax + 3 * i;
        if (s->use[i] == 0u) {
            continue;
        }
        if (isfinite(z[i]) == 0) {
            return 0;
        }
        h0 += w[i] * z[i] * a[0]; h1 += w[i] * z[i] * a[1]; h2 += w[i] * z[i] * a[2];
    }
    x[0] = x[1] = x[2] = 0.0;
    if (s->observable == 0) {
        return 1;
    }
    x[0] = s->P00 * h0 + s->P01 * h1 + s->P02 * h2;
    x[1] = s->P01 * h0 + s->P11 * h1 + s->P12 * h2;
    x[2] = s->P02 * h0 + s->P12 * h1 + s->P22 * h2;
    return 1;
}
"""

_WLS_NEXT = r"""
static void rimu_wls_next(int n, const rimu_real *ax, const rimu_real *w, const rimu_real *G,
                          const unsigned char *iso, const unsigned char *valid, rimu_wls_set *s, const rimu_real *z,
                          rimu_real *x)
{
    if (rimu_wls_apply(n, ax, w, s, z, x) != 0) {
        return;
    }
    rimu_wls_setup(n, ax, w, G, iso, valid, z, s);  /* the sensors in use changed */
    (void)rimu_wls_apply(n, ax, w, s, z, x);
}
"""

_WLS_ONE = r"""
static void rimu_wls(int n, const rimu_real *ax, const rimu_real *w, const rimu_real *G,
                     const unsigned char *iso, const unsigned char *valid, const rimu_real *z, rimu_real *x)
{
    rimu_wls_set s;
    rimu_wls_setup(n, ax, w, G, iso, valid, z, &s);
    (void)rimu_wls_apply(n, ax, w, &s, z, x);
}
"""


def _full_set_estimator(c: EffectCompensation) -> np.ndarray | None:
    """G = (A^T W A)^-1 A^T W (3, n) of the full set (W = 1/sigma^2), or None where it does not span 3-D (the
    generated code then takes the general path; the C test of observability is the same as rimu_solve's)."""
    A = c.calibration.axes_mb()
    sigma = np.broadcast_to(np.asarray(c.calibration.noise_sigma, dtype=float), (c.n,))
    w = 1.0 / sigma**2
    N = (A * w[:, None]).T @ A
    if not np.linalg.det(N) > 1e-9 * np.sum(w) ** 3:
        return None
    return np.linalg.solve(N, (A * w[:, None]).T)


def _instrument(k: str, c: EffectCompensation, real: str, with_q: bool) -> str:
    """``<k>_q`` (effect-free compensated outputs q, EffectCompensation.solve_one) and ``<k>_raw`` (the raw
    outputs of an ideal SF/M/B sensor, EffectCompensation.raw_one) of one instrument."""
    n, P = c.n, f"RIMU_{k.upper()}_N"
    names = sorted({t.effect.name for t in c.terms})
    out = [f"/* {k}: {', '.join(names)} */"]
    keys = list(c._dyn_keys) + [key for key in c._const]
    for key in c._const:
        out.append(f"static const rimu_real {k}_{_NAMES[key]}[{P}] = {_arr(c._const[key], real)};")
    if c._needs_u or with_q:
        G = _full_set_estimator(c)
        out.append(f"static const rimu_real *const {k}_G = NULL;  /* the full set does not span 3-D */" if G is None
                   else f"static const rimu_real {k}_G[3 * {P}] = {_arr(G, real)};  /* full set: x = G q */")
    if c._Hx is not None:
        out.append(f"static const rimu_real {k}_hnom[3 * {P}] = {_arr(c._H, real)};  /* nominal axes */")
        out.append(f"static const rimu_real {k}_hx[3 * {P}] = {_arr(c._Hx, real)};  /* cross coupling */")
    ref = {key: (f"{_NAMES[key]}[i]" if key in c._dyn_keys else f"{k}_{_NAMES[key]}[i]") for key in keys}
    dyn_decl = ", ".join(f"{_NAMES[key]}[{P}]" for key in c._dyn_keys)
    body = [f"static void {k}_q(const unsigned char *iso, const unsigned char *valid, const rimu_real *y, "
            "const rimu_real *m, rimu_real *q)", "{"]
    if dyn_decl:
        body.append(f"    rimu_real {dyn_decl};")
    if c.output_side:
        body.append(f"    rimu_real z[{P}], s, cc, dc;")
        body.append("    int it;")
    if c._Hx is not None:
        body.append("    rimu_real u[3];")
        body.append("    rimu_wls_set ws;")
    body.append("    int i;")
    if not c._dyn_keys:
        body.append("    (void)m;")
    if not c._needs_u:
        body.append("    (void)iso; (void)valid;")
    nm = len(MONOMIALS)
    for j, key in enumerate(c._dyn_keys):
        D = c._dyn[j * n:(j + 1) * n]
        assert D.shape == (n, nm)
        body.append(f"    /* {_NAMES[key]}: the epoch's monomials times the compiled coefficients */")
        for i in range(n):
            body.append(f"    {_NAMES[key]}[{i}] = {_dot(D[i], 'm', real)};")
    zt = f" - {ref['exo']}" if "exo" in ref else ""
    dst = "z" if c.output_side else "q"
    body += [f"    for (i = 0; i < {P}; ++i) {{", f"        {dst}[i] = {k}_sf[i] * y[i] - {k}_b[i]{zt};", "    }"]
    if c.output_side:
        k1, k2, k3, ka = (ref.get(x) for x in (1, 2, 3, "abs"))
        body += [f"    for (i = 0; i < {P}; ++i) {{", "        q[i] = z[i];", "    }"]
        if c._Hx is not None:
            body.append(f"    rimu_wls_setup({P}, {k}_axes, {k}_w, {k}_G, iso, valid, z, &ws);  /* the sensors in use */")
        body += [
                 f"    for (it = 0; it < {c.newton_steps}; ++it) {{  /* Newton on each sensor's own input */"]
        if c._Hx is not None:
            body.append(f"        rimu_wls_next({P}, {k}_axes, {k}_w, {k}_G, iso, valid, &ws, q, u);  /* the instrument's input */")
        body += [f"        for (i = 0; i < {P}; ++i) {{", "            s = q[i];"]
        lin = k1 if k1 is not None else None
        # the arithmetic of EffectCompensation._output_poly, term by term
        if k3 is not None:
            quad = f"({k3} * s + {k2})" if k2 is not None else f"{k3} * s"
            slope2 = f"(2.0 * {k2} + 3.0 * ({k3} * s))" if k2 is not None else f"3.0 * ({k3} * s)"
        elif k2 is not None:
            quad, slope2 = k2, f"2.0 * {k2}"
        else:
            quad = slope2 = None
        lin_s = lin if lin is not None else "0.0"
        if quad is not None:
            body.append(f"            cc = ({lin_s} + {quad} * s) * s;")
            body.append(f"            dc = {lin_s} + {slope2} * s;")
        else:
            body.append(f"            cc = {lin_s} * s;")
            body.append(f"            dc = {lin_s};")
        if ka is not None:
            body.append(f"            cc += {ka} * {'fabsf' if real == 'float' else 'fabs'}(s);")
            body.append(f"            dc += {ka} * ((s > 0.0) ? 1.0 : ((s < 0.0) ? -1.0 : 0.0));  /* sign(s) */")
        if c._Hx is not None:
            h, x = f"{k}_hnom + 3 * i", f"{k}_hx + 3 * i"
            body.append(f"            {{ const rimu_real *h = {h}, *g = {x};")
            body.append("              cc += (h[0] * u[0] + h[1] * u[1] + h[2] * u[2]) "
                        "* (g[0] * u[0] + g[1] * u[1] + g[2] * u[2]); }")
        body += ["            q[i] = s - (s + cc - z[i]) / (1.0 + dc);", "        }", "    }"]
    body.append("}")
    # the raw outputs handed to the projection
    raw = [f"static void {k}_raw(const unsigned char *iso, const unsigned char *valid, const rimu_real *y, "
           "const rimu_real *m, rimu_real *yr)", "{"]
    if c._raw_exo is not None:  # exogenous effects only: y - (D_exo / SF) m in the raw domain
        raw += ["    (void)iso; (void)valid;"]
        if not np.any(c._raw_exo):
            raw += ["    (void)m;"]
        raw += [f"    yr[{i}] = y[{i}] - ({_dot(c._raw_exo[i], 'm', real)});" for i in range(n)]
    else:
        raw += ["    int i;", f"    {k}_q(iso, valid, y, m, yr);",
                f"    for (i = 0; i < {P}; ++i) {{", f"        yr[i] = (yr[i] + {k}_b[i]) / {k}_sf[i];", "    }"]
    raw.append("}")
    if c._raw_exo is not None and not with_q:
        body = []  # the raw path does not use q (and C warns about unused static functions)
    return "\n".join(out + body + raw) + "\n"


def source(cal: Calibration, real: str) -> str:
    """C text for the end of ``rimu_unit.c`` (after the instruments' constants and steps): the compensation of
    each instrument and ``rimu_step``."""
    p = plan(cal)
    parts = [_COMMON] if p.comps else []
    needs_u = any(c._needs_u for c in p.comps.values())
    if p.cyclic or needs_u:
        parts.append(_WLS)
    if needs_u:
        parts.append(_WLS_NEXT)
    if p.cyclic:
        parts.append(_WLS_ONE)
    for k, c in p.comps.items():
        parts.append(_instrument(k, c, real, p.cyclic))
    parts.append(unit_step(cal, "rimu_step", STEP_PARAMS, "{k}_state->isolated",
                           "rimu_{k}_step({k}_state, {y}, {k}_valid, {k}_out);", "{k}_out->x", clip=True))
    return "\n".join(parts)


def unit_step(cal: Calibration, name: str, params: str | dict[str, str], iso: str, call: str | dict[str, str],
              x: str, clip: bool = False, lead: str = "") -> str:
    """A C function ``void name(rimu_real t, rimu_real temperature, <params per instrument>)`` that runs one
    epoch of the unit through the compensation and a per-instrument step, in the order and rounds of
    :meth:`rimu.fusion.Pipeline.step`. Templates (``{k}``: the instrument): ``params`` its parameters (with
    ``{k}_y`` the raw outputs and ``{k}_valid`` the flags), ``iso`` its isolated flags (unsigned char[n]),
    ``call`` its step on raw outputs ``{y}``, ``x`` its estimate of the epoch (rimu_real[3]) after the step.

    ``clip``: a raw output at its range limit (``|y| >= <k>_range``, an instrument with ``range_raw``) is judged
    before the compensation, as the Python runtime does: it stays out of the compensation's estimates and is
    handed to the step as it came (the step then routes it around as saturated), not compensated into the range.
    ``params`` and ``call`` may be one template per instrument (a dict); ``lead``: further parameters after the
    temperature.
    """
    p = plan(cal)
    args = ", ".join(_per(params, k) for k in p.instruments)
    b = [f"void {name}(rimu_real t, rimu_real temperature, {lead}{args})", "{"]
    ranged = [k for k in p.comps if clip and getattr(cal[k], "range_raw", None) is not None]
    vname = {k: (f"{k}_use" if k in ranged else f"{k}_valid") for k in p.instruments}
    if p.comps:
        b += ["    rimu_real f[3] = {0, 0, 0}, w[3] = {0, 0, 0}, m[RIMU_NMONO], yr[RIMU_NMAX], dT, tm;"]
        if p.cyclic:
            b += ["    rimu_real zero[3] = {0, 0, 0}, fp[3];", "    int r;"]
        if ranged:
            b += ["    int i;"]
            b += [f"    unsigned char {k}_use[RIMU_{k.upper()}_N];" for k in ranged]
            for k in ranged:
                b += [f"    for (i = 0; i < RIMU_{k.upper()}_N; ++i) {{  /* usable: flagged valid and inside the range */",
                      f"        {k}_use[i] = ((({k}_valid == NULL) || ({k}_valid[i] != 0u)) "
                      f"&& !(RIMU_FABS({k}_y[i]) >= {k}_range[i])) ? 1u : 0u;", "    }"]
        b += [f"    dT = {'temperature - RIMU_REFERENCE_TEMPERATURE' if p.needs_temperature else '(rimu_real)0'};"]
        if not p.needs_time:
            b += ["    tm = (rimu_real)0;  /* no drift term: the time is not read */", "    (void)t;"]
        else:
            b += ["    tm = t;"]
        if not p.needs_temperature:
            b += ["    (void)temperature;"]
        if p.cyclic:
            # Pipeline._preliminary_rate: accelerometers with zero rate, gyros with their force, then rounds
            q = {k: f"{k}_q({iso.format(k=k)}, {vname[k]}, {k}_y, m, yr);" for k in p.comps}
            est = {k: f"rimu_wls(RIMU_{k.upper()}_N, {k}_axes, {k}_w, {k}_G, {iso.format(k=k)}, {vname[k]}, yr, "
                   for k in p.comps}
            b += ["    /* the gyro <-> accelerometer fixed point (Pipeline._preliminary_rate) */",
                  "    rimu_monomials(tm, dT, zero, zero, m);",
                  f"    {q['accel']}",
                  f"    {est['accel']}fp);",
                  "    rimu_monomials(tm, dT, fp, zero, m);",
                  f"    {q['gyro']}",
                  f"    {est['gyro']}w);",
                  f"    for (r = 1; r < {p.rounds}; ++r) {{",
                  "        rimu_monomials(tm, dT, zero, w, m);",
                  f"        {q['accel']}",
                  f"        {est['accel']}fp);",
                  "        rimu_monomials(tm, dT, fp, zero, m);",
                  f"        {q['gyro']}",
                  f"        {est['gyro']}w);",
                  "    }"]
        for k in p.order:
            if k in p.comps:
                b += ["    rimu_monomials(tm, dT, f, w, m);",
                      f"    {k}_raw({iso.format(k=k)}, {vname[k]}, {k}_y, m, yr);"]
                if k in ranged:
                    b += [f"    for (i = 0; i < RIMU_{k.upper()}_N; ++i) {{  /* a clipped output stays clipped */",
                          f"        if (RIMU_FABS({k}_y[i]) >= {k}_range[i]) {{", f"            yr[i] = {k}_y[i];",
                          "        }", "    }"]
                b += ["    " + _call(call, k, "yr")]
            else:
                b += ["    " + _call(call, k, f"{k}_y")]
            if k != p.order[-1]:  # the estimate of the epoch feeds the next instrument
                v, xk = ("f" if k == "accel" else "w"), x.format(k=k)
                b += [f"    if (isfinite({xk}[0]) != 0) {{ {v}[0] = {xk}[0]; {v}[1] = {xk}[1]; {v}[2] = {xk}[2]; }}"
                      "  /* no estimate (NaN): no input */"]
    else:
        b += ["    (void)t; (void)temperature;"]
        b += ["    " + _call(call, k, f"{k}_y") for k in p.instruments]
    b.append("}")
    return "\n".join(b) + "\n"


def _call(call: str | dict[str, str], k: str, y: str) -> str:
    return (call[k] if isinstance(call, dict) else call).format(k=k, y=y)


def filter_call(cal: Calibration, name: str = "rimu_step", args: str = "&st_{k}, y_{k}, v_{k}, &o_{k}") -> str:
    """The filter's call of a unit step (``tt``: time since the first row; ``temp``: the temperature column;
    ``args`` per instrument, ``{k}`` templated)."""
    p = plan(cal)
    return f"        {name}((rimu_real)tt, (rimu_real)temp, {', '.join(args.format(k=k) for k in p.instruments)});"


def needs_temperature(cal: Calibration) -> bool:
    """Whether the filter reads a ``temperature`` column (after the raw values, as in the session format)."""
    return plan(cal).needs_temperature
