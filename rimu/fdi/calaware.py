"""Calibration-aware thresholds: the calibration's own uncertainty propagated to the parity covariance.

With calibration errors ``d_theta`` (true minus estimated: relative scale, misalignment, bias), the
compensated output of sensor i (Cho & Park 2005, Eq. 1 and 20) is, to first order::

    z_i = a_i . u + e_i + v_i,   e_i = -(dSF_i / SF_i) (a_i . u + b_i) + dm_i . (E_i C_j u) + db_i

so the normalised parity ``p = Vz z`` carries ``Vz D(u) d_theta`` with D(u) linear in the true input u
(E_i: the off-axis basis of sensor i, C_j its sub-unit's ``mat_sb_mb``; de Oliveira et al. 2012, Eq. 11 with
the bias and misalignment terms of Eq. 5 and 13). A misalignment or scale error makes the parity vector
follow the angular rate or specific force, and a fixed threshold alarms in manoeuvres. Over the
calibration's stated covariance Sigma the parity covariance is::

    C(u) = I + Vz D(u) Sigma D(u)^T Vz^T

and the calibration-aware GLT tests ``p^T C(u)^-1 p`` against ``chi2(dof)``, with u the current estimate.
Isolation uses the same metric: ``argmax_j (v_j^T C^-1 p)^2 / (v_j^T C^-1 v_j)``. For a bias b on sensor j
the test's noncentrality is ``b^2 v_j^T C^-1 v_j``, which is what detection costs.

``D(u) = sum_c u~_c D_c`` with ``u~ = (u_x, u_y, u_z, 1)``, so per active set the blocks
``Q_cd = Vz D_c Sigma D_d^T Vz^T`` are computed once and ``C(u) = I + sum_cd u~_c u~_d Q_cd`` costs a few
hundred multiplications per sample.

Further effects (nonlinearity, g-sensitivity, temperature, drift, ...) enter the same way: the compensation
subtracts ``phi_e . theta_e`` (:meth:`rimu.calibration.model.Effect.runtime_columns`), so an error in theta
leaves ``phi_e(inputs) . d_theta`` in the output and adds the columns ``phi`` to D. Their covariance, and its
correlation with scale, misalignment and bias, comes from the calibration's ``covariance`` over every fitted
parameter (:class:`EffectCovariance`). Effects of the sensor's own input use the current estimate u; effects
of other inputs (temperature, time, specific force, angular rate) use what :meth:`CalibrationAwareGlt.set_context`
was last given (or the ``inputs`` of :meth:`CalibrationAwareGlt.block`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..calibration.model import RuntimeInputs, SensorContext, effect, unit_axes
from ..calibration.result import InstrumentCalibration
from ..errors import MissingInputError, ParameterNameError
from .glt import glt_threshold

__all__ = ["CalibrationAwareGlt", "CalibrationCovariance", "EffectCovariance", "stated_covariance"]


def stated_covariance(cal: InstrumentCalibration, misalignment_rad: float, scale_rel: float,
                      bias: float = 0.0) -> InstrumentCalibration:
    """A copy of ``cal`` with a stated diagonal covariance (1 sigma): misalignment angle (rad), relative
    scale error and bias (SI), in the parameter naming of :mod:`rimu.calibration.result`.

    Use it until an estimator fills the covariance (e.g. 0.05 deg and 300 ppm).

    >>> from rimu.geometry import cone6
    >>> c = stated_covariance(InstrumentCalibration.nominal("gyro", cone6(), 0.01), 1e-3, 3e-4)
    >>> c.param_names[:4], round(c.std()["x1.scale"] / 0.01, 6)
    (['x1.scale', 'x1.mis_y', 'x1.mis_z', 'x1.bias'], 0.0003)
    """
    g = cal.geometry
    names, var = [], []
    for i, nm in enumerate(g.names):
        _, off = g.off_axis_basis(i)
        names += [f"{nm}.scale", f"{nm}.{off[0]}", f"{nm}.{off[1]}", f"{nm}.bias"]
        var += [(scale_rel * cal.scale[i]) ** 2, misalignment_rad**2, misalignment_rad**2, bias**2]
    # everything else (effects, range limits, noise model) is kept: only the covariance is stated
    return dataclasses.replace(cal, scale=cal.scale.copy(), misalignment=cal.misalignment.copy(),
                               bias=cal.bias.copy(),
                               noise_sigma=None if cal.noise_sigma is None else cal.noise_sigma.copy(),
                               covariance=np.diag(var), param_names=names, effects=dict(cal.effects))


class CalibrationCovariance:
    """Parity covariance ``C(u)`` from a calibration's covariance (see the module docstring).

    Parameters
    ----------
    calibration : InstrumentCalibration
        With ``covariance`` and ``param_names``. Parameters other than scale, misalignment and bias (further
        effects) do not enter; they are listed in :attr:`ignored`.
    """

    def __init__(self, calibration: InstrumentCalibration) -> None:
        cal = calibration
        if cal.covariance is None or not cal.param_names:
            raise ParameterNameError(
                "this calibration has no covariance; calibration-aware thresholds need one. "
                "Use rimu.fdi.stated_covariance(cal, misalignment_rad, scale_rel) to state it")
        g = cal.geometry
        n = g.n
        index = {nm: i for i, nm in enumerate(g.names)}
        A = cal.axes_mb()
        p = len(cal.param_names)
        D = np.zeros((4, n, p))  # D_c: c = x, y, z, const
        self.ignored: list[str] = []
        for k, full in enumerate(cal.param_names):
            sname, _, par = full.partition(".")
            i = index.get(sname)
            if i is None:
                self.ignored.append(full)
                continue
            if par == "scale":  # a scale error scales the whole output, bias included
                D[:3, i, k] = -A[i] / cal.scale[i]
                D[3, i, k] = -cal.bias[i] / cal.scale[i]
            elif par == "bias":
                D[3, i, k] = 1.0
            elif par.startswith("mis_"):
                E, off = g.off_axis_basis(i)
                if par not in off:
                    self.ignored.append(full)
                    continue
                C = g.subunit_of(i).mat_sb_mb
                D[:3, i, k] = E[off.index(par)] @ C
            elif not any(full in prm for prm in cal.effects.values()):
                self.ignored.append(full)
        self.D = D
        self.Sigma = np.asarray(cal.covariance, dtype=float)
        self._cache: dict[int, np.ndarray] = {}
        #: the fitted further effects' part of the parity covariance (None without such parameters)
        self.effects = EffectCovariance.from_calibration(cal, self.D, self.Sigma)

    def blocks(self, Vz: np.ndarray, key: int | None = None) -> np.ndarray:
        """``Q_cd`` (4, 4, r, r) for the parity rows Vz (cached under ``key``, e.g. the table entry)."""
        if key is not None and key in self._cache:
            return self._cache[key]
        L = np.einsum("rn,cnp->crp", Vz, self.D)
        Q = np.einsum("crp,pq,dsq->cdrs", L, self.Sigma, L)
        if key is not None:
            self._cache[key] = Q
        return Q

    def covariance(self, Vz: np.ndarray, u: np.ndarray, key: int | None = None, inputs: Any = None) -> np.ndarray:
        """``C(u)`` (r, r) for one input u (3,), or (N, r, r) for inputs (N, 3); ``inputs`` (a
        :class:`~rimu.calibration.model.RuntimeInputs`) for effects of other inputs than u."""
        Q = self.blocks(Vz, key)
        u = np.asarray(u, dtype=float)
        ut = np.concatenate([u, np.ones(u.shape[:-1] + (1,))], axis=-1)
        r = Q.shape[-1]
        if ut.ndim == 1:
            C = np.eye(r) + np.einsum("c,d,cdrs->rs", ut, ut, Q)
        else:
            C = np.eye(r)[None] + np.einsum("nc,nd,cdrs->nrs", ut, ut, Q)
        if self.effects is not None:
            C = C + self.effects.extra(Vz, u, inputs)
        return C


class CalibrationAwareGlt:
    """GLT against the parity covariance ``C(u)`` that the calibration's uncertainty implies at the input u.

    The manager passes the current estimate through :meth:`set_input` before each :meth:`update`.

    Parameters
    ----------
    model : CalibrationCovariance
    p_fa : float
    """

    name = "glt_calaware"
    window = 1
    uses_input = True

    def __init__(self, model: CalibrationCovariance, p_fa: float = 1e-3) -> None:
        self.model = model
        self.p_fa = p_fa
        self._u = np.zeros(3)
        self._dof = 0
        self._context: Any = None

    def configure(self, Vz: np.ndarray, dof: int) -> None:
        self._dof = int(dof)
        self._V = np.asarray(Vz)[:dof]
        self._Q = self.model.blocks(self._V) if dof else None
        self._thr = glt_threshold(self.p_fa, dof) if dof else float("inf")
        self._Cinv_p = np.zeros(dof)

    def set_input(self, u: np.ndarray) -> None:
        self._u = u

    def set_context(self, inputs: Any) -> None:
        """The epoch's other inputs (a one-sample :class:`~rimu.calibration.model.RuntimeInputs`: time,
        temperature, specific force, angular rate) for the effects that need them."""
        self._context = inputs

    def update(self, parity: np.ndarray) -> tuple[float, float]:
        d = self._dof
        if d < 1:
            return 0.0, float("inf")
        u = self._u
        ut = np.array([u[0], u[1], u[2], 1.0])
        C = np.einsum("c,d,cdrs->rs", ut, ut, self._Q)
        C.flat[:: d + 1] += 1.0
        if self.model.effects is not None:
            C += self.model.effects.extra(self._V, np.asarray(u, dtype=float), self._context)
        p = parity[:d]
        self._C = C
        self._Cinv_p = np.linalg.solve(C, p)
        return float(p @ self._Cinv_p), self._thr

    def isolate(self, parity: np.ndarray) -> tuple[int, np.ndarray]:
        V = self._V
        if self._dof < 2:
            return -1, np.zeros(V.shape[1])
        CiV = np.linalg.solve(self._C, V)
        den = np.einsum("ij,ij->j", V, CiV)
        ok = den > 1e-12
        ratios = np.zeros(V.shape[1])
        ratios[ok] = (self._Cinv_p @ V[:, ok]) ** 2 / den[ok]
        return int(np.argmax(ratios)), ratios

    def block(self, P: np.ndarray, Vz: np.ndarray, dof: int, U: np.ndarray | None = None, inputs: Any = None
              ) -> tuple[np.ndarray, float, np.ndarray]:
        """Vectorised over N samples with inputs U (N, 3) (the estimates x of the pipeline), and the other
        inputs of the samples (``RuntimeInputs``) where fitted effects need them."""
        if U is None:
            raise ValueError("the calibration-aware test needs the input of every sample (U)")
        V = Vz[:dof]
        C = self.model.covariance(V, U, inputs=inputs)
        p = P[:, :dof]
        Cip = np.linalg.solve(C, p[..., None])[..., 0]
        stat = np.einsum("ij,ij->i", p, Cip)
        iso = np.full(len(p), -1)
        if dof >= 2:
            CiV = np.linalg.solve(C, np.broadcast_to(V, C.shape[:1] + V.shape))
            den = np.einsum("rj,nrj->nj", V, CiV)
            R = (Cip @ V) ** 2 / np.where(den > 1e-12, den, np.inf)
            iso = np.argmax(R, axis=1)
        return stat, glt_threshold(self.p_fa, dof), iso


class EffectCovariance:
    """The part of the parity covariance that the fitted further effects add (see the module docstring).

    With L(u) = Vz D(u) over every parameter of the calibration's covariance, D's base columns
    ``sum_c u~_c D_c`` and the effect columns ``phi_ik(inputs)`` at sensor i::

        C(u) - C_base(u) = L_b Sigma_be L_e^T + L_e Sigma_eb L_b^T + L_e Sigma_ee L_e^T

    Built by :meth:`from_calibration` (None when the covariance holds no effect parameter).
    """

    def __init__(self, cal: InstrumentCalibration, D: np.ndarray, Sigma: np.ndarray,
                 columns: list[tuple[int, int, str, int]]) -> None:
        g = cal.geometry
        A = unit_axes(cal.axes_mb())  # effects along an axis act on the calibrated one
        self.ctxs = [SensorContext(cal.instrument, i, g, axes=A) for i in range(g.n)]
        self.H = A
        self.D = D
        self.index = np.array([k for k, _, _, _ in columns])
        self.sensor = np.array([i for _, i, _, _ in columns])
        self.Sigma_ee = Sigma[np.ix_(self.index, self.index)]
        self.Sigma_be = Sigma[:, self.index]
        self.groups: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for name in dict.fromkeys(e for _, _, e, _ in columns):
            pos = np.array([m for m, c in enumerate(columns) if c[2] == name])
            self.groups[name] = (pos, self.sensor[pos], np.array([columns[m][3] for m in pos]))
        self.effects = {name: effect(name) for name in self.groups}
        self.needs = sorted({x for e in self.effects.values() for x in e.runtime_needs if x not in ("axis_input", "input")})

    @classmethod
    def from_calibration(cls, cal: InstrumentCalibration, D: np.ndarray, Sigma: np.ndarray
                         ) -> EffectCovariance | None:
        g = cal.geometry
        index = {nm: i for i, nm in enumerate(g.names)}
        cols = []
        for k, full in enumerate(cal.param_names):
            sname, _, par = full.partition(".")
            for name, prm in cal.effects.items():
                if full in prm and sname in index:
                    i = index[sname]
                    specs = effect(name).physical_parameters(SensorContext(cal.instrument, i, g))
                    col = [p.name for p in specs].index(par)
                    cols.append((k, i, name, col))
        return cls(cal, D, Sigma, cols) if cols else None

    def columns(self, u: np.ndarray, inputs: RuntimeInputs | None) -> np.ndarray:
        """phi of every effect parameter (N, p_e) at inputs u (N, 3) and the other inputs."""
        N = u.shape[0]
        if inputs is None:
            if self.needs:
                raise MissingInputError(
                    f"the calibration's covariance holds effects that need {self.needs}; give them with "
                    "CalibrationAwareGlt.set_context(RuntimeInputs(...)) or block(..., inputs=...)",
                    ", ".join(self.groups), self.needs[0])
            inputs = RuntimeInputs(t=np.zeros(N))
        inp = RuntimeInputs(np.broadcast_to(np.asarray(inputs.t, dtype=float), (N,)), u @ self.H.T,
                            None if inputs.temperature is None else np.broadcast_to(inputs.temperature, (N,)),
                            None if inputs.specific_force is None else np.broadcast_to(inputs.specific_force, (N, 3)),
                            None if inputs.angular_rate is None else np.broadcast_to(inputs.angular_rate, (N, 3)), u)
        out = np.zeros((N, len(self.index)))
        for name, (pos, sens, col) in self.groups.items():
            out[:, pos] = self.effects[name].runtime_columns(inp, self.ctxs)[:, sens, col]
        return out

    def extra(self, Vz: np.ndarray, u: np.ndarray, inputs: RuntimeInputs | None) -> np.ndarray:
        """``C(u) - C_base(u)``, (r, r) for u (3,) or (N, r, r) for u (N, 3)."""
        one = u.ndim == 1
        U = u[None] if one else u
        ut = np.concatenate([U, np.ones((U.shape[0], 1))], axis=1)
        Lb = np.einsum("nc,rm,cmp->nrp", ut, Vz, self.D)                       # (N, r, p)
        Le = Vz[:, self.sensor][None] * self.columns(U, inputs)[:, None, :]   # (N, r, p_e)
        cross = np.einsum("nrp,pe,nse->nrs", Lb, self.Sigma_be, Le)
        out = cross + np.swapaxes(cross, 1, 2) + np.einsum("nre,ef,nsf->nrs", Le, self.Sigma_ee, Le)
        return out[0] if one else out
