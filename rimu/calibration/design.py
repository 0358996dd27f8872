"""Test design: predicted uncertainties of a procedure before running it (Cho & Park 2005, Eq. 19 and Fig. 3),
named refusal of procedures that cannot identify the model, and a greedy D-optimal choice of static attitudes
and rotation axes for a two-axis turntable.

A procedure is described by what the rig imposes: the specific forces of its static positions (MB, m/s^2 or
in g) and the rate differences of its +/- rate pairs (MB). :func:`procedure_inputs` extracts them from a
:class:`~rimu.session.Session` or from any list of steps with ``rate_mb``, ``mat_ln_mb`` (e.g. the
``SegmentSpec`` lists of :mod:`rimu.sim`).

Eq. 19: for sensor i of sub-unit j, the least-squares covariances of the multi-position and rate tests are
``sigma^2 / N ((S^j)^T S^j)^-1`` (Eq. 19a, rows ``[C_j f_k, 1]``) and ``2 sigma^2 / N ((R^j)^T R^j)^-1``
(Eq. 19b, rows ``C_j (w+ - w-)``) with N samples per position or step. Because ``C_j`` is orthonormal, the
determinant and the eigenvalues of these matrices do not depend on the sub-unit: for the base model the
best procedure is the same for every geometry (what changes between geometries is how the covariance
splits into each sensor's scale factor and misalignment angles).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import IdentifiabilityError
from ..geometry import Geometry
from ..units import G0

__all__ = [
    "ProcedureInputs",
    "eq19",
    "fig3_curve",
    "greedy_d_optimal",
    "log_det_information",
    "plot_fig3",
    "predicted_std",
    "procedure_inputs",
    "turntable_candidates",
]


@dataclass
class ProcedureInputs:
    """Static specific forces (K, 3) and +/- pair rate differences (P, 3) in MB, SI."""

    forces: np.ndarray
    rate_diffs: np.ndarray
    n_static: int = 0
    n_pairs: int = 0


def procedure_inputs(steps: Iterable[Any], gravity: float = G0, known_only: bool = False) -> ProcedureInputs:
    """Inputs of a procedure (list of SegmentSpec-like steps, or a Session's segments).

    Static steps contribute ``C^T [0, 0, g]`` (or their ``specific_force_mb``); rate steps are paired +w/-w as
    in Cho & Park Eq. 11. With ``known_only`` only what the rig reports counts (no 'static_unknown' positions,
    no 'angle' rotations); by default the commanded inputs of every step count (to compare schemes).
    """
    forces, rates = [], []
    for s in steps:
        rate = np.asarray(getattr(s, "rate_mb", None) if getattr(s, "rate_mb", None) is not None else np.zeros(3),
                          dtype=float).reshape(-1, 3).mean(axis=0)
        kind = getattr(s, "kind", None) or getattr(s, "report", None)
        if np.any(rate) and not (known_only and kind == "angle"):
            rates.append(rate)
        elif not np.any(rate):
            f = getattr(s, "specific_force_mb", None)
            if callable(f):
                f = f(gravity)
            if f is None and getattr(s, "mat_ln_mb", None) is not None:
                f = np.asarray(s.mat_ln_mb).T @ np.array([0.0, 0.0, gravity])
            if f is not None and not (known_only and kind == "static_unknown"):
                forces.append(np.asarray(f, float).reshape(-1, 3).mean(axis=0))
    used: set[int] = set()
    diffs = []
    for a in range(len(rates)):
        if a in used:
            continue
        for b in range(a + 1, len(rates)):
            if b not in used and np.linalg.norm(rates[a] + rates[b]) <= 1e-9 * np.linalg.norm(rates[a]):
                diffs.append(rates[a] - rates[b])
                used |= {a, b}
                break
    F = np.array(forces).reshape(-1, 3)
    R = np.array(diffs).reshape(-1, 3)
    return ProcedureInputs(F, R, len(F), len(R))


def eq19(geometry: Geometry, inputs: ProcedureInputs, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Cho & Park 2005, Eq. 19a and 19b for sensor ``index``: ``((S^j)^T S^j)^-1`` (4 x 4) and
    ``((R^j)^T R^j)^-1`` (3 x 3). Raises IdentifiabilityError naming the parameters when singular."""
    C = geometry.subunit_of(index).mat_sb_mb
    S = np.column_stack([inputs.forces @ C.T, np.ones(len(inputs.forces))]) if len(inputs.forces) else np.zeros((0, 4))
    R = inputs.rate_diffs @ C.T
    out = []
    for M, what, bias in ((S, "static positions (Eq. 19a)", True), (R, "rate pairs (Eq. 19b)", False)):
        if M.shape[0] < M.shape[1] or np.linalg.matrix_rank(M, tol=1e-9 * max(np.abs(M).max(), 1e-300)) < M.shape[1]:
            from .cho_park import _named_rank_check
            from .model import SensorContext

            _named_rank_check(M, SensorContext("accel" if bias else "gyro", index, geometry), "design",
                              what, bias)
        out.append(np.linalg.inv(M.T @ M))
    return out[0], out[1]


def predicted_std(geometry: Geometry, inputs: ProcedureInputs, sigma_accel: float, sigma_gyro: float,
                  n_samples: int, n_static_gyro: int | None = None) -> dict[str, dict[str, float]]:
    """Predicted standard deviations (SI) of every parameter of a Cho & Park calibration (Eq. 19).

    Parameters
    ----------
    sigma_accel, sigma_gyro : float
        Per-sample white noise, SI (m/s^2, rad/s).
    n_samples : int
        Samples per position and per rate step.
    n_static_gyro : int, optional
        Static positions used for the gyro biases (Eq. 17); default: all static positions.

    Returns ``{instrument: {"x1.scale": relative std, "x1.mis_y": rad, "x1.bias": SI, ...}}``.
    """
    ns = inputs.n_static if n_static_gyro is None else n_static_gyro
    out: dict[str, dict[str, float]] = {"accel": {}, "gyro": {}}
    rows = geometry.nominal_rows()
    for i, name in enumerate(geometry.names):
        Sinv, Rinv = eq19(geometry, inputs, i)
        E, mis = geometry.off_axis_basis(i)
        r = rows[i]
        Ca = sigma_accel**2 / n_samples * Sinv
        Cg = 2.0 * sigma_gyro**2 / n_samples * Rinv
        for inst, Cm, cb in (("accel", Ca[:3, :3], Ca[3, 3]), ("gyro", Cg, sigma_gyro**2 / (n_samples * max(ns, 1)))):
            out[inst][f"{name}.scale"] = float(np.sqrt(r @ Cm @ r))
            for e, nm in zip(E, mis):
                out[inst][f"{name}.{nm}"] = float(np.sqrt(e @ Cm @ e))
            out[inst][f"{name}.bias"] = float(np.sqrt(cb))
    return out


def fig3_curve(geometry: Geometry, forces_g: np.ndarray, rate_diffs: np.ndarray, index: int = 0,
               start_static: int = 4, start_pairs: int = 3) -> dict[str, np.ndarray]:
    """Cho & Park 2005, Fig. 3: ``sqrt(diag(Eq. 19))`` against the number of sequences used (the first k rows
    of their Table 1 and of the pair differences of Table 2), for sensor ``index``. Forces in g and rates in
    units of w_rt as in their tables."""
    forces_g = np.asarray(forces_g, float)
    rate_diffs = np.asarray(rate_diffs, float)
    ks, ms, bs = [], [], []
    for k in range(start_static, len(forces_g) + 1):
        try:
            Sinv, _ = eq19(geometry, ProcedureInputs(forces_g[:k], rate_diffs, k, len(rate_diffs)), index)
        except IdentifiabilityError:
            continue
        ks.append(k)
        ms.append(np.sqrt(np.diag(Sinv)[:3]))
        bs.append(np.sqrt(Sinv[3, 3]))
    kr, mr = [], []
    for k in range(start_pairs, len(rate_diffs) + 1):
        try:
            _, Rinv = eq19(geometry, ProcedureInputs(forces_g, rate_diffs[:k], len(forces_g), k), index)
        except IdentifiabilityError:
            continue
        kr.append(k)
        mr.append(np.sqrt(np.diag(Rinv)))
    return {"static_k": np.array(ks), "static_mis": np.array(ms), "static_bias": np.array(bs),
            "rate_k": np.array(kr), "rate_mis": np.array(mr)}


def turntable_candidates(step_deg: float = 45.0) -> tuple[np.ndarray, np.ndarray]:
    """Candidate inputs of a two-axis turntable in Cho & Park's mounting (MB z along the table axis, tilt axis
    perpendicular to it): static 'up' directions on a grid of tilt and table angles (unit vectors, MB), and
    rotation axes: MB z (table axis) and every direction of the MB x-y plane (tilt axis at a table angle)."""
    ups = []
    for tilt in np.arange(0.0, 180.0 + 1e-9, step_deg):
        for az in (np.arange(0.0, 360.0, step_deg) if 0 < tilt < 180 else [0.0]):
            t, a = np.radians(tilt), np.radians(az)
            ups.append([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
    axes = [[0.0, 0.0, 1.0]] + [[np.cos(np.radians(a)), np.sin(np.radians(a)), 0.0]
                                for a in np.arange(0.0, 180.0, step_deg / 3.0)]
    U = np.array(ups)
    U[np.abs(U) < 1e-12] = 0.0
    A = np.array(axes)
    A[np.abs(A) < 1e-12] = 0.0
    return U, A


def log_det_information(geometry: Geometry, inputs: ProcedureInputs, which: str) -> float:
    """Sum over sensors of log det of the Eq. 19 information (``S^T S`` for ``which='static'``, ``R^T R`` for
    ``'rate'``); -inf when singular. The D-optimality criterion."""
    tot = 0.0
    for i in range(geometry.n):
        C = geometry.subunit_of(i).mat_sb_mb
        if which == "static":
            M = np.column_stack([inputs.forces @ C.T, np.ones(len(inputs.forces))])
        else:
            M = inputs.rate_diffs @ C.T
        sgn, ld = np.linalg.slogdet(M.T @ M) if len(M) else (0, -np.inf)
        if sgn <= 0:
            return -np.inf
        tot += ld
    return float(tot)


def greedy_d_optimal(geometry: Geometry, candidates: np.ndarray, n: int, which: str = "static",
                     ridge: float = 1e-6) -> list[int]:
    """Greedy D-optimal selection (with repetition) of ``n`` candidates: static 'up' directions (unit, MB;
    rows ``[C f, 1]``) or rotation axes (unit, MB; a +/- pair gives ``2 w``). Each step adds the candidate that
    most increases ``sum_i log det(info_i + ridge I)``."""
    cand = np.asarray(candidates, float)
    p = 4 if which == "static" else 3
    infos = [ridge * np.eye(p) for _ in range(geometry.n)]
    rows_all = []
    for i in range(geometry.n):
        C = geometry.subunit_of(i).mat_sb_mb
        rows_all.append(np.column_stack([cand @ C.T, np.ones(len(cand))]) if which == "static" else 2 * cand @ C.T)
    chosen: list[int] = []
    for _ in range(n):
        best, best_val = -1, -np.inf
        for k in range(len(cand)):
            val = 0.0
            for i in range(geometry.n):
                x = rows_all[i][k]
                # matrix determinant lemma: log det(I + x x^T) increment = log(1 + x^T I^-1 x)
                val += np.log1p(x @ np.linalg.solve(infos[i], x))
            if val > best_val + 1e-12:
                best, best_val = k, val
        chosen.append(best)
        for i in range(geometry.n):
            x = rows_all[i][best]
            infos[i] = infos[i] + np.outer(x, x)
    return chosen


def plot_fig3(curve: dict[str, np.ndarray], path: str | None = None, title: str = ""):
    """Plot :func:`fig3_curve` (Cho & Park 2005, Fig. 3). Returns the matplotlib Figure."""
    from ..plotting import pyplot

    plt = pyplot()

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for k, lab in enumerate("xyz"):
        ax[0].plot(curve["static_k"], curve["static_mis"][:, k], "o-", label=f"m_{lab}/SF")
        ax[1].plot(curve["rate_k"], curve["rate_mis"][:, k], "o-", label=f"m_{lab}/SF")
    ax[0].plot(curve["static_k"], curve["static_bias"], "s--", label="b/SF")
    ax[0].set_xlabel("number of static positions (Table 1)")
    ax[1].set_xlabel("number of +/- rate pairs (Table 2)")
    for a, t in zip(ax, ("multi-position test, Eq. 19a", "rate test, Eq. 19b")):
        a.set_ylabel("standard deviation (per unit noise)")
        a.set_title(t)
        a.grid(alpha=0.3)
        a.legend()
    fig.suptitle(title or "Cho & Park 2005, Fig. 3: standard deviation against the number of sequences")
    fig.tight_layout()
    if path:
        from ..atomic import atomic_path

        with atomic_path(path) as _tmp:  # whole or not at all
            fig.savefig(_tmp, dpi=110)
    return fig
