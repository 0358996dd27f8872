"""A step of an estimator checked on held-out segments: applied only when it does not raise the residual.

Every estimator adds effects to a simpler model (the misalignment to scale and bias, ...). :class:`StepCheck`
holds the rms residual of the model without and with the step, on the segments it was fitted on and on held-out
segments (each position, pair or motion left out in turn and predicted from the others), decides whether the step
is applied (not when it raises the held-out residual) and words the one note every estimator and the console and
report print. :func:`linear_step_check` computes it for a per-sensor weighted linear least-squares problem
(Cho & Park 2005 Eq. 7 and 13, de Oliveira et al. 2012 Eq. 18) by leave-one-group-out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..units import field_unit, fmt

__all__ = ["StepCheck", "linear_step_check", "loo_linear"]

_SI = {"specific_force": "m/s^2", "rate": "rad/s", "angle": "rad"}


@dataclass(frozen=True)
class StepCheck:
    """One step checked in sample and on held-out segments (rms residuals in SI of ``quantity``).

    Examples
    --------
    >>> c = StepCheck("gyro", "misalignment", "scale and bias alone", "rate", (1e-3, 9e-4), (1.1e-3, 1.3e-3),
    ...               "+/- rate pairs", "scale and bias alone, axes nominal")
    >>> c.applied
    False
    >>> print(c.note())  # doctest: +NORMALIZE_WHITESPACE
    gyro: the misalignment step (against scale and bias alone) takes the residual on the +/- rate pairs it was
    fitted on 206.3 deg/h -> 185.6 deg/h, on held-out +/- rate pairs (each left out in turn) 226.9 deg/h ->
    268.1 deg/h; not applied: it raises the residual on held-out +/- rate pairs (it fits these +/- rate pairs, not
    the sensor): scale and bias alone, axes nominal
    """

    instrument: str
    step: str
    against: str
    quantity: str
    fitted: tuple[float, float]
    held_out: tuple[float, float]
    groups: str
    fallback: str
    residual: str = "residual"
    tol: float = 1e-3
    how: str = "each left out in turn"

    @property
    def applied(self) -> bool:
        """False when the step raises the held-out residual (by more than the relative ``tol``)."""
        return not self.held_out[1] > self.held_out[0] * (1.0 + self.tol)

    def note(self) -> str:
        """The one note (console, result notes, report): the four figures in one field unit and the verdict."""
        u = field_unit(self.quantity, max(*self.fitted, *self.held_out))[0]
        f = [fmt(x, self.quantity, u) for x in (*self.fitted, *self.held_out)]
        text = (f"{self.instrument}: the {self.step} step (against {self.against}) takes the {self.residual} on the "
                f"{self.groups} it was fitted on {f[0]} -> {f[1]}, on held-out {self.groups} ({self.how}) "
                f"{f[2]} -> {f[3]}")
        if self.applied:
            return text
        return (text + f"; not applied: it raises the {self.residual} on held-out {self.groups} (it fits these "
                f"{self.groups}, not the sensor): {self.fallback}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON view (SI, the unit named) for ``CalibrationResult.extra``."""
        return {"instrument": self.instrument, "step": self.step, "against": self.against,
                "in_sample": list(self.fitted), "held_out": list(self.held_out), "applied": self.applied,
                "unit": _SI.get(self.quantity, self.quantity)}


def loo_linear(X: np.ndarray, Y: np.ndarray, w: np.ndarray, groups: Sequence[int] | None = None
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """Weighted least squares ``Y ~ X b`` (``w`` the weight of each row): in-sample residuals and the residual of
    each group of rows predicted from the others (``groups``: a group index per row, default one row each).
    None when leaving a group out leaves ``X`` rank deficient."""
    X, Y, w = np.asarray(X, float), np.asarray(Y, float), np.asarray(w, float)
    g = np.arange(len(X)) if groups is None else np.asarray(groups)
    sw = np.sqrt(w)

    def solve(m: np.ndarray) -> np.ndarray | None:
        A = X[m] * sw[m, None]
        if A.shape[0] < A.shape[1] or np.linalg.matrix_rank(A) < A.shape[1]:
            return None
        return np.linalg.lstsq(A, Y[m] * sw[m], rcond=None)[0]

    b = solve(np.ones(len(X), bool))
    if b is None:
        return None
    ins = Y - X @ b
    out = np.empty_like(ins)
    for k in np.unique(g):
        m = g != k
        bk = solve(m)
        if bk is None:
            return None
        out[~m] = Y[~m] - X[~m] @ bk
    return ins, out


def linear_step_check(X_full: Sequence[np.ndarray], X_reduced: Sequence[np.ndarray], Y: Sequence[np.ndarray],
                      w: np.ndarray, to_si: Sequence[float], **describe: Any) -> StepCheck | None:
    """:class:`StepCheck` of a per-sensor linear step: for sensor ``i`` the rows ``X_full[i]`` (with the step) and
    ``X_reduced[i]`` (without) fit ``Y[i]`` with weights ``w``; residuals times ``to_si[i]`` (SI per raw unit),
    pooled over the sensors as rms. ``describe``: the text fields of :class:`StepCheck`. None when a row left out
    makes either model unidentifiable (too few positions or pairs to check)."""
    r = {"reduced": ([], []), "full": ([], [])}
    for key, Xs in (("reduced", X_reduced), ("full", X_full)):
        for X, y, s in zip(Xs, Y, to_si):
            res = loo_linear(X, y, w)
            if res is None:
                return None
            r[key][0].append(res[0] * s)
            r[key][1].append(res[1] * s)

    def rms(a: list[np.ndarray]) -> float:
        return float(np.sqrt(np.mean(np.square(np.concatenate(a)))))

    return StepCheck(fitted=(rms(r["reduced"][0]), rms(r["full"][0])),
                     held_out=(rms(r["reduced"][1]), rms(r["full"][1])), **describe)
