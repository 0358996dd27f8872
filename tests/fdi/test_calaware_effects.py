"""Calibration-aware thresholds with fitted effects (issue 11): the covariance of every fitted effect reaches the
parity covariance, so the false-alarm rate stays at design after the effects are added."""

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.calibration.model import RuntimeInputs
from rimu.errors import MissingInputError
from rimu.experiments.campaign import clopper_pearson
from rimu.fdi import CalibrationAwareGlt, CalibrationCovariance, RedundancyManager, glt_threshold, stated_covariance
from rimu.fusion import EffectCompensation, InstrumentPipeline
from rimu.geometry import cone6
from rimu.sim import cho_park_table3
from rimu.units import ARW_DSQH_TO_RSQS, DEG_TO_RAD, DH_TO_RS, G0, PPM, white_noise_sigma

P_FA = 1e-3
K2_SIGMA = 5.0 * PPM / DEG_TO_RAD          # 5 ppm/(deg/s): a short nonlinearity test
GS_SIGMA = 30.0 * DH_TO_RS / G0            # 30 (deg/h)/g


@pytest.fixture(scope="module")
def setting():
    """Cho & Park Table 3 gyros with sf_quadratic and g_sensitivity fitted, stated 1-sigma covariance of every
    parameter (0.01 deg, 50 ppm, 5 ppm/(deg/s), 30 (deg/h)/g) and a correlation between each sensor's bias and
    its g-sensitivity x (as a joint fit gives)."""
    g = cone6()
    sig = white_noise_sigma(0.5 * ARW_DSQH_TO_RSQS, 100.0)
    base = cho_park_table3()["gyro"]
    est = stated_covariance(InstrumentCalibration("gyro", g, base.scale, base.misalignment, base.bias,
                                                  np.full(6, sig)), 0.01 * DEG_TO_RAD, 50e-6, 2 * DH_TO_RS)
    k2 = np.array([1.0, -0.5, 2.0, 0.3, -1.2, 0.8]) * PPM / DEG_TO_RAD
    gs = np.array([[40.0, -25.0, 30.0 + i] for i in range(6)]) * DH_TO_RS / G0
    effects = {"sf_quadratic": {f"{nm}.k2": float(k2[i]) for i, nm in enumerate(g.names)},
               "g_sensitivity": {f"{nm}.gsens_{a}": float(gs[i, j]) for i, nm in enumerate(g.names)
                                 for j, a in enumerate("xyz")}}
    names = list(est.param_names)
    var = list(np.diag(est.covariance))
    for nm in g.names:
        names += [f"{nm}.k2", f"{nm}.gsens_x", f"{nm}.gsens_y", f"{nm}.gsens_z"]
        var += [K2_SIGMA**2] + [GS_SIGMA**2] * 3
    cov = np.diag(var)
    for nm in g.names:  # correlation -0.6 between bias and gsens_x
        a, b = names.index(f"{nm}.bias"), names.index(f"{nm}.gsens_x")
        cov[a, b] = cov[b, a] = -0.6 * np.sqrt(cov[a, a] * cov[b, b])
    full = InstrumentCalibration("gyro", g, est.scale, est.misalignment, est.bias, est.noise_sigma, cov, names, effects)
    return g, sig, full, k2, gs


def _drawn_axis(g, est, d, i):
    """Sensor i's unit misalignment row with the drawn off-axis parameter errors ``d`` added, per draw."""
    nm, names = g.names[i], est.param_names
    E, off = g.off_axis_basis(i)
    m = (est.misalignment[i] + d[:, [names.index(f"{nm}.{off[0]}")]] * E[0]
         + d[:, [names.index(f"{nm}.{off[1]}")]] * E[1])
    return m / np.linalg.norm(m, axis=1)[:, None]


def _truth(g, est, k2, gs, sig, rng, N, f):
    """Raw outputs of true units drawn from the stated covariance, one draw per sample, at 200 deg/s."""
    names = est.param_names
    d = rng.multivariate_normal(np.zeros(len(names)), est.covariance, N)
    u = rng.standard_normal((N, 3))
    u *= 200 * DEG_TO_RAD / np.linalg.norm(u, axis=1)[:, None]
    s = u @ g.H.T
    Y = np.empty((N, 6))
    for i, nm in enumerate(g.names):
        m = _drawn_axis(g, est, d, i)
        k2_true = k2[i] + d[:, names.index(f"{nm}.k2")]
        gs_true = gs[i] + d[:, [names.index(f"{nm}.gsens_{a}") for a in "xyz"]]
        z = (np.einsum("nj,nj->n", m @ g.subunit_of(i).mat_sb_mb, u) + est.bias[i] + d[:, names.index(f"{nm}.bias")]
             + k2_true * s[:, i] ** 2 + np.einsum("nj,nj->n", gs_true, f) + sig * rng.standard_normal(N))
        Y[:, i] = z / (est.scale[i] + d[:, names.index(f"{nm}.scale")])
    return Y, u


def test_false_alarms_at_design_with_fitted_effects(setting):
    g, sig, est, k2, gs = setting
    rng = np.random.default_rng(21)
    N = 20_000
    f = np.broadcast_to(np.array([0.0, 3.0, 9.3]), (N, 3))  # a tilted, static specific force
    Y, _ = _truth(g, est, k2, gs, sig, rng, N, f)
    # the gyros' g-sensitivity needs the accelerometers: the specific force is fed as the unit pipeline does
    ip, comp = InstrumentPipeline(est), EffectCompensation(est)
    ctx = RuntimeInputs(t=np.zeros(N), specific_force=np.asarray(f))
    res = ip.process(comp.raw(Y, ctx))
    Vz = ip.table.Vz[0]
    with_effects = CalibrationCovariance(est)
    assert with_effects.effects is not None and not with_effects.ignored
    s, thr, _ = CalibrationAwareGlt(with_effects, P_FA).block(res.parity, Vz, 3, U=res.x, inputs=ctx)
    # the same calibration with the effects' covariance dropped: thresholds as before this issue
    keep = [k for k, nm in enumerate(est.param_names) if nm.split(".")[1] in ("scale", "bias") or "mis_" in nm]
    base_only = InstrumentCalibration("gyro", g, est.scale, est.misalignment, est.bias, est.noise_sigma,
                                      est.covariance[np.ix_(keep, keep)], [est.param_names[k] for k in keep])
    s0, _, _ = CalibrationAwareGlt(CalibrationCovariance(base_only), P_FA).block(res.parity, Vz, 3, U=res.x)
    k = int((s > thr).sum())
    lo, hi = clopper_pearson(k, N)
    assert lo <= P_FA <= hi, (k / N, lo, hi)                 # at design with every effect's covariance
    assert np.mean(s0 > thr) > 20 * P_FA                   # without it: far above design (measured ~0.05)
    assert glt_threshold(P_FA, 3) == thr


def test_effect_covariance_matches_monte_carlo_and_needs_its_inputs(setting):
    """C(u) against the sample covariance of the parity over calibration draws at one fixed input."""
    g, sig, est, k2, gs = setting
    rng = np.random.default_rng(22)
    N = 30_000
    f = np.array([2.0, -1.0, 9.5])
    names = est.param_names
    d = rng.multivariate_normal(np.zeros(len(names)), est.covariance, N)
    u = np.array([1.0, -2.0, 2.0]) / 3 * 200 * DEG_TO_RAD
    Y = np.empty((N, 6))
    for i, nm in enumerate(g.names):
        m = _drawn_axis(g, est, d, i)
        z = ((m @ g.subunit_of(i).mat_sb_mb) @ u + est.bias[i] + d[:, names.index(f"{nm}.bias")]
             + (k2[i] + d[:, names.index(f"{nm}.k2")]) * (g.H[i] @ u) ** 2
             + (gs[i] + d[:, [names.index(f"{nm}.gsens_{a}") for a in "xyz"]]) @ f + sig * rng.standard_normal(N))
        Y[:, i] = z / (est.scale[i] + d[:, names.index(f"{nm}.scale")])
    ip, comp = InstrumentPipeline(est), EffectCompensation(est)
    ctx = RuntimeInputs(t=np.zeros(N), specific_force=np.broadcast_to(f, (N, 3)))
    P = ip.process(comp.raw(Y, ctx)).parity
    model = CalibrationCovariance(est)
    C = model.covariance(ip.table.Vz[0], u, inputs=RuntimeInputs(t=np.zeros(1), specific_force=f[None]))
    np.testing.assert_allclose(np.cov(P.T), C, atol=0.05 * np.abs(C).max())
    assert np.abs(C - np.eye(3)).max() > 1.0   # the effects matter here (so the check above can fail)
    with pytest.raises(MissingInputError, match="set_context"):
        model.covariance(ip.table.Vz[0], u)


def test_manager_step_uses_the_context(setting):
    g, sig, est, k2, gs = setting
    rng = np.random.default_rng(23)
    f = np.array([0.0, 3.0, 9.3])
    Y, _ = _truth(g, est, k2, gs, sig, rng, 200, np.broadcast_to(f, (200, 3)))
    ip, comp = InstrumentPipeline(est), EffectCompensation(est)
    ctx = RuntimeInputs(t=np.zeros(200), specific_force=np.broadcast_to(f, (200, 3)))
    Yc = comp.raw(Y, ctx)
    det = CalibrationAwareGlt(CalibrationCovariance(est), P_FA)
    det.set_context(RuntimeInputs(t=np.zeros(1), specific_force=f[None]))
    res = RedundancyManager(ip, det, confirm=3).run(Yc)
    blk = InstrumentPipeline(est).process(Yc)
    s, _, _ = CalibrationAwareGlt(CalibrationCovariance(est), P_FA).block(blk.parity, ip.table.Vz[0], 3, U=blk.x,
                                                                          inputs=ctx)
    np.testing.assert_allclose(res.statistic, s, rtol=1e-8)
