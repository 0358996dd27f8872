"""Model against measurement: diagnose, add the missing effect, refit, compare, iterate.

>>> # see examples/hidden_effect.py and docs/diagnostics.md for the whole loop
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import chdtrc

from ..calibration.model import EFFECTS, Effect, ErrorModel, effect
from ..errors import IdentifiabilityError, ParameterNameError, SessionFormatError
from ..session import Session
from .candidates import CandidateTest, conditional_log10_p, confounding, score_candidates
from .fitting import ModelFit, cached, fit_model
from .residuals import SensorStats, failures, residual_statistics

__all__ = [
    "DEFAULT_ALPHA",
    "Comparison",
    "Diagnosis",
    "Finding",
    "InstrumentDiagnosis",
    "Iteration",
    "effect_sensors",
    "candidate_effects",
    "compare",
    "diagnose",
    "format_p",
    "iterate",
]

#: default family-wise significance of "something is missing"
DEFAULT_ALPHA = 0.01


#: sessions that need a diagnosis of their own: (applies(session), diagnose(...) -> (residuals, Diagnosis)); the
#: modules that provide one register here (rimu.diagnose.handheld), so this module never imports them
SESSION_KINDS: list[tuple[Any, Any]] = []


def register_session_kind(applies: Any, special: Any) -> None:
    """Route sessions for which ``applies(session)`` holds to ``special`` (same arguments as :func:`diagnose`,
    returning ``(residuals, Diagnosis)``)."""
    if all(a is not applies for a, _ in SESSION_KINDS):
        SESSION_KINDS.append((applies, special))


def format_p(log10_p: float) -> str:
    """A p-value in words: ``p < 1e-12`` below 1e-12, else two significant digits.

    >>> format_p(-30.2), format_p(-2.5)
    ('p < 1e-12', 'p = 0.0032')
    """
    if log10_p < -12:
        return "p < 1e-12"
    return f"p = {10 ** log10_p:.2g}"


def candidate_effects(model: ErrorModel, names: Sequence[str] | None = None) -> list[Effect]:
    """Instances of the registered effects not in ``model`` (one per class; aliases skipped)."""
    out: list[Effect] = []
    seen: set[type] = set()
    keys = list(names) if names is not None else list(EFFECTS)
    for key in keys:
        if key not in EFFECTS:
            raise ParameterNameError(f"unknown effect {key!r}; known: {sorted(EFFECTS)}")
        cls = EFFECTS[key]
        if cls in seen or cls.name in model:
            continue
        seen.add(cls)
        out.append(cls())
    return out


@dataclass
class Finding:
    """One ranked answer to "which effect is missing": a single effect, or a group the session cannot
    tell apart (``confounded``)."""

    effects: list[str]
    tests: list[CandidateTest]

    @property
    def confounded(self) -> bool:
        return len(self.effects) > 1

    @property
    def best(self) -> CandidateTest:
        return self.tests[0]


@dataclass
class InstrumentDiagnosis:
    """Diagnosis of one instrument."""

    instrument: str
    fit: ModelFit
    stats: list[SensorStats]
    failures: dict
    tests: list[CandidateTest]
    groups: list[list[str]]
    alpha: float
    #: lower-ranked significant candidates that add nothing significant once the top finding is in
    secondary: dict[str, str] = field(default_factory=dict)

    @property
    def model(self) -> ErrorModel:
        return self.fit.model

    @property
    def nothing_missing(self) -> bool:
        return not any(c.significant for c in self.tests)

    @property
    def findings(self) -> list[Finding]:
        by = {c.name: c for c in self.tests}
        return [Finding(g, [by[n] for n in g]) for g in self.groups]

    @property
    def not_testable(self) -> list[CandidateTest]:
        """Candidates that apply to this instrument but cannot be estimated from the session."""
        return [c for c in self.tests if not c.testable and c.applicable]

    @property
    def not_applicable(self) -> list[CandidateTest]:
        return [c for c in self.tests if not c.applicable]

    def top(self) -> str | None:
        """The best clearly identified missing effect, or None (nothing missing, or only confounded groups)."""
        for f in self.findings:
            return None if f.confounded else f.effects[0]
        return None

    def test(self, name: str) -> CandidateTest:
        found = next((c for c in self.tests if c.name == name), None)
        if found is None:
            raise KeyError(f"{name!r} was not a candidate; candidates: {[c.name for c in self.tests]}")
        return found

    def lines(self) -> list[str]:
        """The diagnosis in plain language."""
        out = [f"{self.instrument}: model {self.model.label}; chi2/dof {self.fit.chi2_dof:.3g} over "
               f"{len(self.fit.sensors)} sensors and {len(self.fit.segment_labels)} segments"]
        unit, fac = self.fit.display()
        calibrated = " of the calibrated output" if unit != self.fit.raw_unit else " (raw: no scale factor is known)"
        for st, f in zip(self.stats, fac):
            out.append(f"  {st.name}: rms {st.rms_raw * f:.4g} {unit}{calibrated}, chi2/dof {st.chi2_dof:.3f}, "
                       f"lag-1 autocorrelation {st.lag1:+.3f}, Ljung-Box p = {st.ljung_box_p:.2g}")
            calibrated = ""
        p = max(s.n_par for s in self.fit.sensors)
        nseg = len(self.fit.segment_labels)
        if nseg - p < 5:
            out.append(f"  caution: {nseg} segments for {p} parameters per sensor leave {nseg - p} segment-level degrees of "
                       "freedom; an effect constant over each segment is tested against the noise within segments and "
                       "cannot be told from errors of the rig's positions (e.g. hand-held attitudes); add segments")
        infl = [s for s in self.fit.sensors if s.inflation > 1.0]
        if infl:
            out.append("  the noise is coloured (within-segment lag-1 autocorrelation "
                       + ", ".join(f"{s.name} {s.lag1_within:+.2f}" for s in infl[:6])
                       + "); the tests divide by its long-run variance inflation "
                       + ", ".join(f"{s.inflation:.1f}" for s in infl[:6]))
        fl = self.failures
        if fl["sensors"]:
            out.append(f"  the model fails on sensors {fl['sensors']} (chi2/dof above noise)")
        if fl["segments"]:
            worst = sorted(fl["segments"].items(), key=lambda kv: -max(abs(z) for _, z in kv[1]))[:5]
            out.append("  segments with a mean residual off zero: " + ", ".join(
                f"{lab} ({', '.join(f'{n} {z:+.1f} sigma' for n, z in v[:3])})" for lab, v in worst))
        if self.nothing_missing:
            out.append(f"  nothing is missing: no candidate effect explains the residual (Holm, alpha = {self.alpha:g})")
        for rank, f in enumerate(self.findings, start=1):
            if f.confounded:
                out.append(f"  {rank}. confounded, cannot be told apart with this session: {' or '.join(f.effects)} "
                           f"({format_p(f.best.log10_p_holm)}); to separate them: "
                           + "; ".join(f"{t.name}: {t.advice}" for t in f.tests if t.advice))
                continue
            c = f.best
            if c.name in self.secondary:
                out.append(f"  {rank}. {c.name} ({format_p(c.log10_p_holm)}) adds nothing significant once "
                           f"{self.secondary[c.name]} is in the model: probably a shadow of it; retest after adding it")
                continue
            det = [s for s in c.sensors if s.significant]
            det.sort(key=lambda s: s.log10_p)
            per = ", ".join(f"{s.sensor} (explains {100 * s.explained_excess:.0f}% of the residual excess over "
                            f"noise, {format_p(s.log10_p)})" for s in det[:6])
            out.append(f"  {rank}. missing: {c.name} on {self.instrument} {per}; dBIC {c.dbic:+.1f}; "
                       f"{format_p(c.log10_p_holm)} after Holm")
        for c in self.not_testable:
            adv = f"; to test it: {c.advice}" if c.advice else ""
            out.append(f"  not testable with this data: {c.name}: {c.reason}{adv}")
        for c in self.not_applicable:
            if c.name == "earth_rate" and self.instrument == "gyro":
                out.append(f"  not a candidate: {c.name}: {c.reason}")
        return out

    def to_dict(self) -> dict[str, Any]:
        unit, fac = self.fit.display()
        return {
            "instrument": self.instrument, "model": self.model.label, "chi2_dof": self.fit.chi2_dof,
            "raw_unit": self.fit.raw_unit, "rms_unit": unit,
            "rms": [float(s.rms_raw * f) for s, f in zip(self.stats, fac)],
            "bic": self.fit.bic, "nothing_missing": self.nothing_missing, "alpha": self.alpha,
            "sensors": [s.to_dict() for s in self.stats], "failures": json.loads(json.dumps(self.failures)),  # a plain copy
            "findings": [{"effects": f.effects, "confounded": f.confounded,
                          "secondary_to": self.secondary.get(f.effects[0])} for f in self.findings],
            "candidates": [c.to_dict() for c in self.tests], "skipped_segments": self.fit.skipped,
        }


@dataclass
class Diagnosis:
    """Diagnosis of a session against an error model, per instrument."""

    session: Session
    instruments: dict[str, InstrumentDiagnosis]
    settings: dict[str, Any]
    errors: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, instrument: str) -> InstrumentDiagnosis:
        return self.instruments[instrument]

    @property
    def nothing_missing(self) -> bool:
        return all(d.nothing_missing for d in self.instruments.values())

    @property
    def models(self) -> dict[str, ErrorModel]:
        return {k: d.model for k, d in self.instruments.items()}

    def summary(self) -> str:
        out = list(self.settings.get("preamble", []))
        for d in self.instruments.values():
            out += d.lines()
        for k, why in self.errors.items():
            out.append(f"{k}: not diagnosed: {why}")
        return "\n".join(out)

    def add(self, *effects: Effect | str, instrument: str | None = None) -> dict[str, Comparison]:
        """Add effects to the model, refit, and compare before and after.

        ``instrument`` None adds each effect to every instrument where it applies and was not already in.
        """
        out = {}
        for k, d in self.instruments.items():
            if instrument is not None and k != instrument:
                continue
            new = [effect(e) if isinstance(e, str) else e for e in effects]
            new = [e for e in new if e.name not in d.model and any(e.applies_to(c) for c in d.fit.contexts)]
            if not new:
                continue
            model = d.model
            for e in new:
                model = model + e
            out[k] = compare(self.session, d.fit, model, **self._fit_kwargs(k))
        return out

    def _fit_kwargs(self, instrument: str) -> dict[str, Any]:
        sig = self.settings.get("sigma") or {}
        return {"sigma": sig.get(instrument), "include_earth_rate": self.settings["include_earth_rate"],
                "reference_temperature": self.settings["reference_temperature"]}

    def to_dict(self) -> dict[str, Any]:
        return {"nothing_missing": self.nothing_missing,
                "instruments": {k: d.to_dict() for k, d in self.instruments.items()},
                "errors": self.errors,
                "settings": {k: v for k, v in self.settings.items() if k != "sigma"}}


def diagnose(
    session: Session,
    model: ErrorModel | str | Mapping[str, ErrorModel | str] | None = None,
    instruments: Sequence[str] | None = None,
    candidates: Sequence[str] | None = None,
    sigma: Mapping[str, Any] | None = None,
    alpha: float = DEFAULT_ALPHA,
    include_earth_rate: bool = True,
    reference_temperature: float = 25.0,
    method: str = "fast",
    scale: Mapping[str, Any] | None = None,
) -> Diagnosis:
    """Compare ``model`` with the measurement in ``session`` and find which effect is missing.

    Parameters
    ----------
    session : Session
    model : ErrorModel, str, or dict instrument -> model
        Default: bias + scale/misalignment (Cho & Park 2005, Eq. 1-2). A string is a comma list of effect names.
    instruments : sequence of str, optional
        Default: every instrument of the session.
    candidates : sequence of str, optional
        Effect names to test; default every registered effect not in the model.
    sigma : dict instrument -> float or (n,) array, optional
        Known white-noise level per sample in raw units. Default: from first differences within segments.
    alpha : float
        Family-wise significance of the missing-effect tests (Holm-corrected over candidates).
    include_earth_rate : bool
        Whether the gyro input includes the Earth rate; False makes ``earth_rate`` a candidate.
    reference_temperature : float
        T_ref of the temperature effects, degC.
    scale : dict instrument -> float or (n,) array, optional
        Known scale factor SI/raw per sensor (a calibration's) for models without a scale block, so that their
        residuals print in SI. Default: the session's declared raw unit (deg/s, g); counts stay counts.
    method : {"fast", "refit"}
        How the candidates are tested (:func:`~rimu.diagnose.candidates.score_candidates`): in the small space
        of one shared design (default), or by the straightforward refit of each (the reference; same numbers).

    Instruments whose model cannot be fitted from the session are reported in ``Diagnosis.errors``
    (with the reason) instead of raising, unless none can be fitted.
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if not isinstance(session, Session):
        hint = " (a simulation result: pass its .session)" if hasattr(session, "session") else ""
        raise SessionFormatError(f"diagnose needs a rimu.session.Session, got {type(session).__name__}{hint}")
    for applies, special in SESSION_KINDS:  # e.g. hand-held poses: attitudes resolved by their calibration first
        if applies(session):
            return special(session, model, candidates, alpha, instruments=instruments, sigma=sigma,
                           reference_temperature=reference_temperature, scale=scale)[1]
    session = cached(session)
    models = _models(model, session, instruments)
    settings = {"alpha": alpha, "include_earth_rate": include_earth_rate,
                "reference_temperature": reference_temperature, "sigma": dict(sigma or {}),
                "candidates": None if candidates is None else list(candidates)}
    out: dict[str, InstrumentDiagnosis] = {}
    errors: dict[str, str] = {}
    for k, m in models.items():
        try:
            fit = fit_model(session, m, k, (sigma or {}).get(k), include_earth_rate, reference_temperature,
                            scale=(scale or {}).get(k))
        except IdentifiabilityError as exc:
            errors[k] = str(exc)
            continue
        out[k] = diagnose_fit(session, fit, candidates, alpha, method)
    if not out:
        raise IdentifiabilityError("no instrument could be fitted: " + "; ".join(f"{k}: {v}" for k, v in errors.items()))
    return Diagnosis(session, out, settings, errors)


def diagnose_fit(session: Session, fit: ModelFit, candidates: Sequence[str] | None = None,
                 alpha: float = DEFAULT_ALPHA, method: str = "fast") -> InstrumentDiagnosis:
    """Diagnose an existing :class:`ModelFit` (residual statistics, candidate tests, confounding)."""
    st = residual_statistics(fit)
    tests = score_candidates(session, fit, candidate_effects(fit.model, candidates), alpha, method)
    groups = confounding(fit, tests, alpha)
    secondary: dict[str, str] = {}
    if groups:
        by = {c.name: c for c in tests}
        top = by[groups[0][0]]
        for g in groups[1:]:
            for name in g:
                if conditional_log10_p(fit, by[name], top) > np.log10(alpha):
                    secondary[name] = top.name
    return InstrumentDiagnosis(fit.instrument, fit, st, failures(st, alpha), tests, groups, alpha, secondary)


@dataclass
class Comparison:
    """Before and after adding effects: the error falls (or does not)."""

    instrument: str
    added: list[str]
    before: ModelFit
    after: ModelFit

    @property
    def chi2_before(self) -> float:
        return self.before.chi2_dof

    @property
    def chi2_after(self) -> float:
        return self.after.chi2_dof

    @property
    def dbic(self) -> float:
        return self.after.bic - self.before.bic

    @property
    def daic(self) -> float:
        return self.after.aic - self.before.aic

    def new_parameters(self) -> list[dict[str, Any]]:
        """The added effects' physical parameters per sensor, in SI and in field units, with 1-sigma."""
        rows = []
        for s in self.after.sensors:
            for e in self.after.model.effects_for(s.ctx):
                if e.name not in self.added:
                    continue
                for p in e.physical_parameters(s.ctx):
                    v, sd, spec = s.parameter(p.name)
                    rows.append({"effect": e.name, "sensor": s.name, "parameter": p.name, "value_si": v,
                                 "std_si": sd, "unit": spec.unit, "value": v * spec.to_report,
                                 "std": sd * spec.to_report, "report_unit": spec.report_unit or spec.unit,
                                 "z": v / sd if sd > 0 else None})
        return rows

    def rms(self) -> tuple[str, np.ndarray, np.ndarray]:
        """(unit, rms before, rms after) per sensor, both in one unit (raw where a scale factor is unknown)."""
        unit, fb = self.before.display()
        ua, fa = self.after.display(unit)
        if ua != unit:  # one side has no scale: both raw
            unit, fb, fa = self.before.raw_unit, np.ones(len(fb)), np.ones(len(fa))
        return unit, self.before.rms_raw() * fb, self.after.rms_raw() * fa

    def held_out(self) -> tuple[str, np.ndarray, np.ndarray] | None:
        """(unit, rms before, rms after) per sensor on held-out segments: both models fitted on every other
        segment (in time order) and evaluated on the rest, and the other way round. None when half of the
        segments cannot identify a model."""
        unit, fb = self.before.display()
        ua, fa = self.after.display(unit)
        if ua != unit:
            unit, fb, fa = self.before.raw_unit, np.ones(len(fb)), np.ones(len(fa))
        out = []
        for fit in (self.before, self.after):
            rms = []
            for s in fit.sensors:
                segs = np.unique(s.seg_index)
                if len(segs) < 4:
                    return None
                half = np.isin(s.seg_index, segs[::2])
                sq, n = 0.0, 0
                for train in (half, ~half):
                    X, y = s.X[train], s.y[train]
                    if np.linalg.matrix_rank(X) < X.shape[1]:
                        return None
                    beta = np.linalg.lstsq(X, y, rcond=None)[0]
                    r = s.y[~train] - s.X[~train] @ beta
                    sq, n = sq + float(r @ r), n + r.size
                rms.append(np.sqrt(sq / n))
            out.append(np.array(rms))
        return unit, out[0] * fb, out[1] * fa

    def worse_held_out(self) -> bool:
        """Whether the added effects raise the held-out residual (mean over the sensors): they fit the noise of
        these segments, not the instrument."""
        h = self.held_out()
        return h is not None and float(np.mean(h[2])) > float(np.mean(h[1])) * (1 + 1e-3)

    def lines(self) -> list[str]:
        unit, rb, ra = self.rms()
        out = [f"{self.instrument}: added {', '.join(self.added)}: chi2/dof {self.chi2_before:.4g} -> "
               f"{self.chi2_after:.4g}, BIC {self.dbic:+.1f}, AIC {self.daic:+.1f}"]
        for s, b, a in zip(self.before.sensors, rb, ra):
            out.append(f"  {s.name}: rms {b:.4g} -> {a:.4g} {unit} ({100 * (a - b) / b:+.1f}%)")
        h = self.held_out()
        if h is not None:
            out.append(f"  held out (fitted on every other segment, checked on the rest): rms {np.mean(h[1]):.4g} -> "
                       f"{np.mean(h[2]):.4g} {h[0]} (mean over the sensors)"
                       + ("; caution: worse on held-out data: it fits these segments' noise, not the instrument"
                          if self.worse_held_out() else ""))
        for r in self.new_parameters():
            out.append(f"  {r['sensor']}.{r['parameter']} = {r['value']:.4g} +- {r['std']:.2g} {r['report_unit']}")
        return out

    def to_dict(self) -> dict[str, Any]:
        unit, rb, ra = self.rms()
        return {"instrument": self.instrument, "added": self.added, "chi2_before": self.chi2_before,
                "chi2_after": self.chi2_after, "dbic": self.dbic, "daic": self.daic,
                "rms_before": rb.tolist(), "rms_after": ra.tolist(), "rms_unit": unit,
                "held_out": (None if (h := self.held_out()) is None else
                             {"rms_before": h[1].tolist(), "rms_after": h[2].tolist(), "rms_unit": h[0]}),
                "parameters": self.new_parameters()}


def compare(session: Session, before: ModelFit, model: ErrorModel, sigma: Any = None, include_earth_rate: bool = True,
            reference_temperature: float = 25.0) -> Comparison:
    """Refit ``model`` (usually ``before.model + effect``) and compare with ``before``."""
    base = {"scale_misalignment", "bias"}
    c0 = before.contexts[0]
    # the same first fit (scale, misalignment and bias on the nominal axes) as before's: its calibrated axes
    same_axes = (before.own_axes and "scale_misalignment" in model
                 and base & {e.name for e in model} == base & {e.name for e in before.model}
                 and (c0.reference_temperature, c0.include_earth_rate) == (reference_temperature, include_earth_rate))
    after = fit_model(session, model, before.instrument, sigma, include_earth_rate, reference_temperature,
                      ctxs=before.contexts if same_axes else None)
    after.own_axes = after.own_axes or same_axes
    added = [e.name for e in model.effects if e.name not in before.model]
    return Comparison(before.instrument, added, before, after)


@dataclass
class Iteration:
    """Rounds of diagnose -> add the top effect -> refit, until nothing real is missing."""

    rounds: list[tuple[Diagnosis, dict[str, Comparison]]]
    final: Diagnosis
    #: why the iteration stopped short of a significant finding, per instrument
    notes: dict[str, str] = field(default_factory=dict)

    @property
    def added(self) -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for _, comps in self.rounds:
            for k, c in comps.items():
                out.setdefault(k, []).extend(c.added)
        return out

    @property
    def sensors(self) -> dict[str, dict[str, list[str]]]:
        """Per instrument and added effect, the sensors that need it in the final model (Wald test of the effect's
        coefficients of each sensor, Bonferroni over the sensors at the diagnosis' alpha): a sensor named in an
        early round only because another effect was still missing drops out here."""
        out: dict[str, dict[str, list[str]]] = {}
        for k, names in self.added.items():
            idg = self.final[k]
            out[k] = {e: effect_sensors(idg.fit, e, idg.alpha) for e in names}
        return out

    def summary(self) -> str:
        lines = []
        for n, (d, comps) in enumerate(self.rounds, start=1):
            lines.append(f"--- round {n} ---")
            lines.append(d.summary())
            for c in comps.values():
                lines += c.lines()
        lines.append("--- final ---")
        lines.append(self.final.summary())
        for k, per in self.sensors.items():
            for e, sens in per.items():
                lines.append(f"{k}: {e} needed on {', '.join(sens) if sens else 'no sensor on its own'}")
        for k, note in self.notes.items():
            lines.append(f"{k}: stopped: {note}")
        return "\n".join(lines)


def effect_sensors(fit: ModelFit, name: str, alpha: float = DEFAULT_ALPHA) -> list[str]:
    """Sensors whose coefficients of effect ``name`` in ``fit`` differ from zero: Wald statistic
    ``theta^T Cov^-1 theta`` (chi-square with k degrees of freedom, divided by the noise inflation) against
    Bonferroni over the sensors at level ``alpha``."""
    eff = effect(name)
    out = []
    sens = [s for s in fit.sensors if eff.applies_to(s.ctx)]
    for s in sens:
        local = [p.name for p in eff.physical_parameters(s.ctx)]
        idx = [k for k, p in enumerate(s.specs) if p.name in local]
        if not idx:
            continue
        th = s.theta[idx]
        C = s.theta_cov[np.ix_(idx, idx)]
        w = float(th @ np.linalg.solve(C, th)) / s.inflation
        if chdtrc(len(idx), max(w, 0.0)) <= alpha / len(sens):  # the chi-square survival function
            out.append(s.name)
    return out


def _bic_gain(test: CandidateTest) -> float:
    """Change of the BIC if the candidate entered on the sensors it names (negative: supported)."""
    return float(sum(x.dbic for x in test.sensors if x.significant))


def iterate(session: Session, model: Any = None, max_rounds: int = 6, **kwargs: Any) -> Iteration:
    """Diagnose, add the best clearly identified missing effect of each instrument, refit; repeat until nothing
    real is missing (or only confounded groups remain, or ``max_rounds``). Keyword arguments go to
    :func:`diagnose`.

    An effect enters only when it is significant (Holm over the candidates), lowers the BIC on the
    sensors it names (Schwarz's criterion: its fit gain must pay ln(N) per parameter) *and* does not raise the
    residual on held-out segments (:meth:`Comparison.worse_held_out`); a significant finding that does not is
    reported in :attr:`Iteration.notes` and the iteration stops there. The candidates are
    evaluated on the calibrated axes (:func:`rimu.diagnose.fit_model`), so a nonlinearity on a misaligned
    sensor does not leave a cross-coupling-like residue."""
    rounds = []
    notes: dict[str, str] = {}
    d = diagnose(session, model, **kwargs)
    for _ in range(max_rounds):
        comps = {}
        for k, idg in d.instruments.items():
            top = idg.top()
            if top is None:
                continue
            gain = _bic_gain(idg.test(top))
            if gain >= 0.0:
                notes[k] = (f"{top} is significant ({format_p(idg.test(top).log10_p_holm)} after Holm) but does "
                            f"not lower the BIC on the sensors it names (dBIC {gain:+.1f}): not enough evidence to "
                            "add it")
                continue
            notes.pop(k, None)
            for kk, c in d.add(top, instrument=k).items():
                if c.worse_held_out():  # a step that makes the held-out answer worse is not taken
                    h = c.held_out()
                    notes[kk] = (f"{top} is not added: fitted on every other segment it raises the residual of the "
                                 f"others from {np.mean(h[1]):.4g} to {np.mean(h[2]):.4g} {h[0]}")
                    continue
                comps[kk] = c
        if not comps:
            break
        rounds.append((d, comps))
        if any(applies(session) for applies, _ in SESSION_KINDS):  # a session kind with a diagnosis of its own
            models = {k: (comps[k].after.model if k in comps else m) for k, m in d.models.items()}
            kw = dict(kwargs)
            kw.pop("instruments", None)
            d = diagnose(session, models, instruments=list(models), **kw)
            continue
        # the next round diagnoses the fits at hand (the refits of this round, the unchanged ones), not fits
        # made again from scratch: the same fits, since the refit used the calibrated axes a new fit would find
        d = Diagnosis(d.session, {k: diagnose_fit(d.session, comps[k].after if k in comps else idg.fit,
                                                  d.settings["candidates"], d.settings["alpha"],
                                                  kwargs.get("method", "fast"))
                                  for k, idg in d.instruments.items()}, dict(d.settings))
    return Iteration(rounds, d, notes)


def _models(model: Any, session: Session, instruments: Iterable[str] | None) -> dict[str, ErrorModel]:
    inst = list(instruments) if instruments is not None else list(session.instruments)
    for k in inst:
        if k not in session.geometries:
            raise IdentifiabilityError(f"the session has no {k} data; instruments: {list(session.geometries)}")
    if isinstance(model, Mapping):
        return {k: _one(model[k]) for k in inst if k in model} or {k: ErrorModel.base() for k in inst}
    return {k: _one(model) for k in inst}


def _one(m: Any) -> ErrorModel:
    if m is None:
        return ErrorModel.base()
    if isinstance(m, str):
        return ErrorModel.from_names(m)
    if isinstance(m, Effect):
        return ErrorModel([m])
    return m
