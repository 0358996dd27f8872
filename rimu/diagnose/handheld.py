"""Diagnosis of sessions whose poses have unknown attitude (hand-held recordings, ``rimu detect``'s sessions).

Such a session knows no input at all: the accelerometers see gravity of unknown direction, the gyros turn by
unknown angles. The model is compared with the measurement in two ways:

1. the residuals of the hand-held calibration itself (:class:`~rimu.calibration.handheld.HandHeld`): the norm
   of the calibrated specific force minus g for every pose (in m/s^2 and in units of its standard deviation),
   and the misfit of the gravity direction after every motion (the integrated rotation against the change of
   the calibrated gravity direction, deg);
2. the missing-effect ranking of :func:`rimu.diagnose.diagnose`, on the session with its attitudes *resolved*:
   each pose becomes a static segment whose specific force is the calibrated estimate. The accelerometers are
   then tested with the full model (the inputs are estimated from the same data, so an effect must stand out
   beyond what the norm fit already absorbed: the tests are conservative), the gyros at rest with their bias
   (the rate is zero, scale and misalignment do not act), so that effects seen at rest, g-sensitivity first,
   can be ranked. The motions carry no known input and are left out of this part.

>>> from rimu.sim.handheld import handheld_run
>>> run = handheld_run(n_poses=16, seed=4)
>>> res, d = diagnose_handheld(run.session, candidates=["g_sensitivity"])
>>> len(res.norm_residual), sorted(d.instruments), d.summary().startswith("hand-held session")
(16, ['accel', 'gyro'], True)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calibration.estimate import CalibrationResult
from ..calibration.handheld import STATIC_KINDS, HandHeld
from ..calibration.model import ErrorModel
from ..session import Segment, Session
from .api import _one, diagnose, format_p, register_session_kind
from .candidates import f_logsf

__all__ = ["MOTION_CANDIDATES", "HandHeldResiduals", "MotionTest", "diagnose_handheld", "rank_motion_effects",
           "resolve_attitude", "unknown_attitude"]

#: gyro effects tested on the rotation residuals of the motions: name -> what it adds to gyro i's output
MOTION_CANDIDATES = {
    "g_sensitivity": "g_i . f: output proportional to the specific force (three coefficients per gyro)",
    "sf_quadratic": "k2_i (a_i . w)^2: scale nonlinearity, even in the rate along the axis",
    "sf_asymmetry": "k_i |a_i . w|: different scale for positive and negative rates",
}


def unknown_attitude(session: Session) -> bool:
    """True when the session has poses of unknown attitude and no segment with a known input (so that the
    ordinary diagnosis has nothing to compare with)."""
    kinds = {s.kind for s in session.segments}
    known = any((s.kind == "static" and (s.specific_force_mb is not None or s.mat_ln_mb is not None))
                or s.kind == "rate" for s in session.segments)
    return "static_unknown" in kinds and not known


@dataclass
class HandHeldResiduals:
    """Residuals of a hand-held calibration, per pose and per motion."""

    pose_labels: list[str]
    norm_residual: np.ndarray  # m/s^2
    norm_sigma: np.ndarray  # m/s^2, white noise (plus the pose-to-pose variance when the fit needed one)
    motion_labels: list[str]
    rotation_residual_deg: np.ndarray
    rotation_sigma_deg: float
    result: CalibrationResult = field(repr=False)
    motion_tests: list[MotionTest] = field(default_factory=list)

    @property
    def norm_z(self) -> np.ndarray:
        return self.norm_residual / self.norm_sigma

    def lines(self, worst: int = 5) -> list[str]:
        out = [(f"hand-held session: {len(self.pose_labels)} poses of unknown attitude, "
               f"{len(self.motion_labels)} motions between them; attitudes resolved by the hand-held calibration")]
        rms = float(np.sqrt(np.mean(self.norm_residual**2)))
        out.append(f"  gravity norm per pose: rms {rms * 1e6 / 9.80665:.4g} micro-g ({rms:.3g} m/s^2), "
                   f"chi2/pose {float(np.mean(self.norm_z**2)):.3g}")
        order = np.argsort(-np.abs(self.norm_z))[:worst]
        out.append("    largest: " + ", ".join(f"{self.pose_labels[k]} {self.norm_z[k]:+.1f} sigma" for k in order))
        if self.motion_labels:
            r = self.rotation_residual_deg
            out.append(f"  integrated rotation per motion: gravity-direction misfit rms {float(np.sqrt(np.mean(r**2))):.3g}"
                       f" deg (scatter {self.rotation_sigma_deg:.3g} deg per component)")
            order = np.argsort(-r)[:worst]
            out.append("    largest: " + ", ".join(f"{self.motion_labels[k]} {r[k]:.3g} deg" for k in order))
        if self.motion_tests:
            sig = [t for t in self.motion_tests if t.significant]
            out.append("  missing from the gyro model on the motions: "
                       + (", ".join(t.name for t in sig) if sig else "nothing (Holm, alpha as below)"))
            for t in self.motion_tests:
                out.append("    " + t.line())
        for n in self.result.notes:
            out.append(f"  note: {n}")
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"poses": self.pose_labels, "norm_residual_m_s2": self.norm_residual.tolist(),
                "norm_sigma_m_s2": self.norm_sigma.tolist(), "motions": self.motion_labels,
                "rotation_residual_deg": self.rotation_residual_deg.tolist(),
                "rotation_sigma_deg": self.rotation_sigma_deg, "notes": list(self.result.notes),
                "motion_tests": [{"effect": t.name, "F": t.f_stat, "log10_p_holm": t.log10_p_holm,
                                  "explained": t.explained, "significant": t.significant} for t in self.motion_tests]}


@dataclass
class MotionTest:
    """A candidate effect tested on the rotation residuals of the motions (nested F-test, fitted parameters
    projected out)."""

    name: str
    description: str
    n_columns: int
    f_stat: float
    log10_p: float
    explained: float  # fraction of the residual sum of squares the effect explains
    log10_p_holm: float = 0.0
    significant: bool = False

    def line(self) -> str:
        return (f"{self.name}: explains {100 * self.explained:.0f}% of the motion residual, F = {self.f_stat:.3g}, "
                f"{format_p(self.log10_p_holm)} after Holm" + (" (significant)" if self.significant else ""))


def rank_motion_effects(result: CalibrationResult, alpha: float = 0.01,
                        candidates: Sequence[str] | None = None) -> list[MotionTest]:
    """Which gyro effect explains the gravity-direction misfit of the motions (:data:`MOTION_CANDIDATES`).

    For each candidate, its columns in the whitened rotation residual are found by shifting the raw gyro samples
    of every motion by the effect's output (rate from the calibrated gyros, specific force from the calibrated
    accelerometers, sample by sample) and integrating again; the Jacobian of the fitted parameters is projected
    out and the residual regressed on what is left (nested F-test, Holm-corrected over the candidates).
    """
    fits = getattr(result, "fits", {})
    if not fits.get("gyro"):
        return []
    gf = fits["gyro"][0]
    pr = gf.problem
    n = len(gf.members)
    theta = gf.theta
    W = theta[:3 * n].reshape(n, 3)
    c = theta[3 * n:]
    Gm = np.linalg.pinv(W)
    cal = result.to_calibration()
    acc = cal["accel"]
    A_acc = np.linalg.pinv(acc.axes_mb())
    nrot = int(pr["n_rot"])
    r0 = pr["rot_resid_shift"](theta, [np.zeros_like(y) for y in pr["ys"]])
    J = pr["jac"](theta)[:nrot]
    Q, sv, _ = np.linalg.svd(J, full_matrices=False)
    Q = Q[:, sv > 1e-10 * sv[0]]
    dof = nrot - Q.shape[1]
    rss = float(r0 @ r0)
    wn = np.linalg.norm(W, axis=1)
    axes = W / wn[:, None]
    rates = [(y - c) @ Gm.T for y in pr["ys"]]
    forces = [None if ya is None else acc.compensate(ya) @ A_acc.T for ya in pr["accel_ys"]]
    names = [k for k in MOTION_CANDIDATES if candidates is None or k in candidates]
    tests = []
    for name in names:
        cols = []
        for i in range(n):
            if name == "g_sensitivity":
                if any(f is None for f in forces):
                    break
                feats = [[f[:, j] for f in forces] for j in range(3)]
            elif name == "sf_quadratic":
                feats = [[(w @ axes[i]) ** 2 for w in rates]]
            else:
                feats = [[np.abs(w @ axes[i]) for w in rates]]
            for per_window in feats:
                h = 1.0 / max(float(max(np.abs(x).max() for x in per_window)) * wn[i], 1e-300)
                deltas = []
                for y, x in zip(pr["ys"], per_window):
                    d = np.zeros_like(y)
                    d[:, i] = h * wn[i] * x  # raw = SI / SF
                    deltas.append(d)
                cols.append((pr["rot_resid_shift"](theta, deltas) - r0) / h)
        if not cols:
            continue
        X = np.column_stack(cols)
        X = X - Q @ (Q.T @ X)
        U, sx, _ = np.linalg.svd(X, full_matrices=False)
        U = U[:, sx > 1e-9 * max(sx[0], 1e-300)]
        k = U.shape[1]
        if k == 0 or dof - k < 1:
            continue
        drss = float(np.sum((U.T @ r0) ** 2))
        F = (drss / k) / max((rss - drss) / (dof - k), 1e-300)
        lp = f_logsf(F, k, dof - k) / float(np.log(10))
        tests.append(MotionTest(name, MOTION_CANDIDATES[name], k, float(F), lp, drss / max(rss, 1e-300)))
    tests.sort(key=lambda t: t.log10_p)
    m = len(tests)
    running = -np.inf
    for r, t in enumerate(tests):  # Holm step-down
        running = max(running, min(0.0, t.log10_p + np.log10(m - r)))
        t.log10_p_holm = running
        t.significant = running < np.log10(alpha)
    return tests


def resolve_attitude(session: Session, result: CalibrationResult | None = None,
                     **handheld: Any) -> tuple[Session, HandHeldResiduals]:
    """The session with each pose's specific force resolved by the hand-held calibration (``result``, or a new
    :class:`~rimu.calibration.handheld.HandHeld` fit with keyword arguments ``handheld``), and the residuals."""
    res = result if result is not None else HandHeld(**handheld).fit(session)
    cal = res.to_calibration()
    acc = cal["accel"]
    A = acc.axes_mb()
    segs: list[Segment] = []
    labels = []
    for s in session.segments:
        if s.kind not in STATIC_KINDS:
            continue
        z = acc.compensate(s.raw["accel"].mean(axis=0))
        f = np.linalg.lstsq(A, z, rcond=None)[0]
        segs.append(Segment(s.label, "static", s.t, dict(s.raw), s.temperature, specific_force_mb=f,
                            meta={**s.meta, "specific_force": "resolved by the hand-held calibration"}))
        labels.append(s.label)
    resolved = Session(segs, dict(session.geometries), session.sample_rate, None, session.gravity,
                       session.raw_unit, {**session.meta, "resolved_from": "unknown attitude (hand-held)"})
    ex = res.extra
    sig = np.asarray(ex.get("norm_sigma_accel", np.full(len(labels), np.nan)), float)
    rr = np.asarray(ex.get("rotation_residual_deg", []), float)
    out = HandHeldResiduals(labels, np.asarray(ex["norm_residual_accel"], float), sig,
                            list(ex.get("motion_labels", [])), rr, float(ex.get("rotation_sigma_deg", np.nan)), res)
    return resolved, out


def diagnose_handheld(session: Session, model: ErrorModel | str | Mapping[str, Any] | None = None,
                      candidates: Sequence[str] | None = None, alpha: float = 0.01,
                      result: CalibrationResult | None = None, **kwargs: Any):
    """Residuals per pose and per motion, and the missing-effect ranking on the resolved session (module
    docstring). Returns ``(HandHeldResiduals, Diagnosis)``; the Diagnosis' summary starts with the residuals."""
    resolved, hh = resolve_attitude(session, result)
    hh.motion_tests = rank_motion_effects(hh.result, alpha)
    if isinstance(model, Mapping):
        models = {k: _one(v) for k, v in model.items()}
    else:
        models = {k: _one(model) for k in session.instruments}
    if "gyro" in models:  # at rest the rate is zero: scale and misalignment do not act
        g = models["gyro"]
        names = [e.name for e in g.effects if e.name != "scale_misalignment"]
        models["gyro"] = ErrorModel.from_names(",".join(names) or "bias")
    kwargs.pop("include_earth_rate", None)
    scale = dict(kwargs.pop("scale", None) or {})
    if "gyro" in hh.result.instruments:  # bias-only model at rest: residuals in SI through the calibration's scales
        scale.setdefault("gyro", np.asarray(hh.result.to_calibration()["gyro"].scale, dtype=float))
    d = diagnose(resolved, models, candidates=candidates, alpha=alpha, include_earth_rate=False, scale=scale, **kwargs)
    d.settings["preamble"] = hh.lines()
    d.settings["handheld"] = hh.to_dict()
    return hh, d


register_session_kind(unknown_attitude, diagnose_handheld)
