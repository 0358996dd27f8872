"""The runtime pipeline: Cho & Park Eq. 20/21 against simulated truth, step vs block, bad input."""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.errors import ShapeError
from rimu.fusion import InstrumentPipeline, Pipeline, ProjectionTable, cho_park_eq20, mask_bits
from rimu.geometry import cone6, dodecahedron6, tetrad4
from rimu.sim import Simulator, cho_park_procedure, cho_park_table3, rotation
from rimu.units import DS_TO_RS


@pytest.fixture(scope="module")
def cho_park_run():
    """Cho & Park Table 1 + Table 2 with the Table 3 coefficients as truth (30 s per step, 100 Hz)."""
    return Simulator(seed=21).run(cho_park_procedure(duration=30.0))


@pytest.mark.parametrize("instrument", ["gyro", "accel"])
def test_compensation_with_true_coefficients_is_unbiased_and_honest(cho_park_run, instrument):
    run = cho_park_run
    out = Pipeline(run.truth).process(run.block)[instrument]
    err = out.x - run.truth_inputs[instrument]
    P = out.covariance()
    sd = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    N = len(err)
    # zero mean within 3 sigma / sqrt(N), per MB axis, over the whole run and per segment
    assert np.all(np.abs(err.mean(axis=0)) < 3 * sd[0] / math.sqrt(N))
    for s in np.unique(run.segment_index):
        e = err[run.segment_index == s]
        assert np.all(np.abs(e.mean(axis=0)) < 4 * sd[0] / math.sqrt(len(e)))
    # the noise level the covariance predicts
    rms = np.sqrt(np.mean((err / sd) ** 2, axis=0))
    assert np.all((0.9 < rms) & (rms < 1.1)), rms
    # normalised parity: unit covariance
    par = out.parity
    assert np.allclose(par.mean(axis=0), 0, atol=4 / math.sqrt(N))
    assert np.allclose(np.cov(par.T), np.eye(3), atol=0.03)


def test_projection_table_is_eq21_row_removal():
    cal = cho_park_table3()["gyro"]
    A = cal.axes_mb()
    tab = ProjectionTable(A, 0.01)
    assert len(tab) == 1  # only the full set is computed up front; the others when they occur
    for k in range(4):
        for excl in combinations(range(6), k):
            act = np.ones(6, bool)
            act[list(excl)] = False
            e = tab.entry_for(act)
            Ar = A.copy()
            Ar[~act] = 0.0  # Cho & Park Eq. 21: the row of H (here M H) set to zero
            G_eq21 = np.linalg.pinv(Ar)
            assert np.allclose(tab.G[e], G_eq21, atol=1e-12)
            assert np.allclose(tab.G[e][:, act] @ A[act], np.eye(3), atol=1e-12)
            d = tab.dof[e]
            assert d == act.sum() - 3
            assert np.allclose(tab.Vz[e][:d] @ A, 0, atol=1e-9)
            assert np.allclose(tab.Vz[e][:d] @ tab.Vz[e][:d].T * 0.01**2, np.eye(d), atol=1e-12)
            assert np.all(tab.Vz[e][:, ~act] == 0) and np.all(tab.G[e][:, ~act] == 0)
    assert len(tab) == tab.computed == sum(math.comb(6, k) for k in range(4))  # each set computed once


def test_cho_park_fault_scenario_std_grows_as_predicted():
    """Cho & Park Fig. 6 / Table 5: gyro y2 fails at 15 s, accelerometer x1 at 20 s; isolate by Eq. 21."""
    sim = Simulator(seed=4)
    run = sim.run([rotation("M", [0, 30 * DS_TO_RS, 0], duration=60.0)])
    t = run.block.t
    pipe = Pipeline(run.truth)
    Y = {k: run.block.raw[k].copy() for k in ("gyro", "accel")}
    g = cone6()
    faults = {"gyro": (g.index("y2"), 15.0), "accel": (g.index("x1"), 20.0)}
    for k, (i, tf) in faults.items():
        Y[k][t >= tf, i] += 1e4  # a gross fault; its detection is the FDI module's business, here we isolate at tf
    for k, (i, tf) in faults.items():
        before = pipe[k].process(Y[k][t < tf])
        keep = np.ones(6, bool)
        keep[i] = False
        after = pipe[k].process(Y[k][t >= tf], active=keep)
        e_b = before.x - run.truth_inputs[k][t < tf]
        e_a = after.x - run.truth_inputs[k][t >= tf]
        sd_a = np.sqrt(np.diagonal(after.covariance()[0]))
        assert np.all(np.abs(e_a.mean(axis=0)) < 3 * sd_a / math.sqrt(len(e_a)))  # unbiased after isolation
        tab = pipe[k].table
        P_full = tab.P[tab.lookup(tab.full_code)]
        P_red = tab.P[tab.lookup(tab.full_code & ~(1 << i))]
        # (H_r^T H_r)^-1 of Eq. 21, with H_r the unit-noise calibrated axes less row i
        Hr = np.delete(run.truth[k].axes_mb(), i, axis=0)
        assert np.allclose(P_red / run.truth[k].noise_sigma[0] ** 2, np.linalg.inv(Hr.T @ Hr), rtol=1e-10)
        predicted = np.sqrt(np.diag(P_red) / np.diag(P_full))
        measured = e_a.std(axis=0) / e_b.std(axis=0)
        assert np.all(np.abs(measured / predicted - 1) < 0.10), (k, measured, predicted)
        assert np.all(np.isfinite(after.x))


def test_step_and_block_are_identical():
    sim = Simulator(seed=9)
    run = sim.run(cho_park_procedure(duration=1.0))
    cal = run.truth["gyro"]
    Y = run.block.raw["gyro"].copy()
    rng = np.random.default_rng(0)
    Y[rng.integers(0, len(Y), 40), rng.integers(0, 6, 40)] = np.nan
    Y[100, :4] = np.inf  # unobservable sample
    Y[200, 2] = -np.inf
    a, b = InstrumentPipeline(cal), InstrumentPipeline(cal)
    keep = np.array([1, 1, 1, 1, 1, 0], bool)
    blk = b.process(Y, active=keep)
    xs, ps = np.empty((len(Y), 3)), np.empty((len(Y), 3))
    for n, y in enumerate(Y):
        r = a.step(y, active=keep)
        xs[n], ps[n] = r.x, r.parity
        assert r.observable == blk.observable[n] and r.dof == blk.dof[n]
        assert np.array_equal(r.active, blk.active[n]) and np.array_equal(r.invalid, blk.invalid[n])
        assert np.array_equal(np.isinf(np.diag(r.P)), np.isinf(np.diag(blk.covariance()[n])))
    assert np.array_equal(np.isnan(xs), np.isnan(blk.x)) and np.isnan(xs[100]).all()
    assert np.nanmax(np.abs(xs - blk.x)) < 1e-12 * max(1.0, np.nanmax(np.abs(blk.x)))
    assert np.abs(ps - blk.parity).max() < 1e-9
    assert np.array_equal(a.invalid_count, b.invalid_count)
    assert a.invalid_count.sum() == np.isnan(Y).sum() + np.isinf(Y).sum()


def test_non_finite_never_reaches_an_output():
    cal = InstrumentCalibration.nominal("gyro", cone6(), scale=0.01, bias=0.2, noise_sigma=0.001)
    p = InstrumentPipeline(cal)
    u = np.array([0.1, -0.2, 0.3])
    y = cal.raw_output(u)
    y1 = y.copy()
    y1[2] = np.nan
    r = p.step(y1)
    assert r.observable and r.dof == 2 and r.invalid[2] and np.allclose(r.x, u)
    y2 = np.full(6, np.nan)
    y2[0] = y[0]
    r = p.step(y2)
    assert not r.observable and np.all(np.isnan(r.x)) and np.all(np.isinf(np.diag(r.P)))  # no estimate: NaN
    r = p.step(y)
    assert r.observable and not r.invalid.any() and np.allclose(r.x, u) and r.dof == 3
    assert p.invalid_count.tolist() == [0, 1, 2, 1, 1, 1]
    blk = p.process(np.vstack([y, y2, y1]))
    assert not np.isnan(blk.parity).any()
    assert blk.observable.tolist() == [True, False, True]
    assert np.isnan(blk.x).any(axis=1).tolist() == [False, True, False]  # no estimate is NaN, never a number
    with pytest.raises(ShapeError):
        p.step(np.ones(5) * np.nan)
    with pytest.raises(ShapeError):
        p.process(np.ones((3, 5)))
    for bad in (-1, 64, np.ones(5, bool)):
        with pytest.raises(ShapeError):
            p.step(y, active=bad)


def test_valid_mask_from_a_source_is_honoured():
    cal = InstrumentCalibration.nominal("accel", dodecahedron6(), scale=1e-3, bias=0.0, noise_sigma=0.01)
    p = InstrumentPipeline(cal)
    u = np.array([0.0, 0.0, 9.8])
    y = cal.raw_output(u)
    y_bad = y.copy()
    y_bad[3] = 0.0  # a missing frame: the source sends 0.0 and valid False
    valid = np.ones(6, bool)
    valid[3] = False
    r = p.step(y_bad, valid)
    assert np.allclose(r.x, u) and r.invalid[3] and r.dof == 2
    assert p.process(y_bad[None], valid[None]).x == pytest.approx(u[None])


def test_eq20_literal_agrees_and_isolation_is_exact_only_by_row_removal():
    cal = cho_park_table3()["gyro"]
    u = np.array([0.4, -0.3, 0.5])
    y = cal.raw_output(u)
    assert np.allclose(cho_park_eq20(cal, y), u, atol=1e-12)  # both left inverses of M H
    p = InstrumentPipeline(cal, sigma=0.01)
    assert np.allclose(p.step(y).x, u, atol=1e-12)
    # Eq. 21 applied literally (y and b of the sensor zeroed, its H row zeroed) inside Eq. 20 leaks M^-1 mixing
    z = cal.compensate(y)
    z[4] = 0.0  # Eq. 21: y and b of the failed sensor set to zero ...
    Hr = cal.geometry.H.copy()
    Hr[4] = 0.0  # ... and its row of H
    x_eq20 = np.linalg.pinv(Hr) @ _minv(cal) @ z
    leak = np.abs(x_eq20 - u).max()
    assert 1e-4 < leak < 0.05  # of the order of the misalignment times the input
    assert np.allclose(p.step(y, active=np.arange(6) != 4).x, u, atol=1e-12)  # row removal on the calibrated axes is exact


def _minv(cal):
    g = cal.geometry
    M = np.zeros((6, 6))
    for su in g.subunits:
        idx = list(su.members)
        M[np.ix_(idx, idx)] = cal.misalignment[idx] @ g.nominal_rows()[idx].T
    return np.linalg.inv(M)


def test_tetrad_pipeline_parity_matches_de_oliveira_eq24():
    cal = InstrumentCalibration.nominal("gyro", tetrad4(), scale=1.0, noise_sigma=1.0)
    p = InstrumentPipeline(cal)
    tab = p.table
    e = tab.lookup(tab.full_code)
    assert np.allclose(tab.Vz[e][0], [-0.408250, -0.40825, -0.408250, 0.70711], atol=1e-5)
    assert mask_bits(np.ones(4, bool)) == tab.full_code
