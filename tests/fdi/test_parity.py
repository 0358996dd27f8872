"""Parity space of every active set and the isolability report, against closed-form theory."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.fdi import isolability, wrong_isolation_bounds
from rimu.fdi.parity import column_correlations, pairwise_wrong_isolation
from rimu.fusion import ProjectionTable
from rimu.geometry import cone, cone6, dodecahedron6, tetrad4


def test_tetrad_detects_but_cannot_isolate():
    g = tetrad4()
    r = isolability(ProjectionTable(g.H), g.names, "tetrad4")
    assert r.full.dof == 1 and r.full.detect_one
    assert not r.full.isolate_one and r.faults_isolable == 0
    assert "isolation impossible" in r.summary()


def test_five_sensors_isolate_one_then_detect_only():
    g = cone(5, math.radians(54.7))
    r = isolability(ProjectionTable(g.H), g.names, "cone5")
    assert r.full.isolate_one and r.faults_isolable == 1
    assert all(not s.isolate_one and s.detect_one for s in r.after_one.values())


@pytest.mark.parametrize("make", [cone6, dodecahedron6])
def test_six_sensors_detect_two_isolate_one_twice(make):
    g = make()
    r = isolability(ProjectionTable(g.H), g.names, g.name)
    assert r.full.detect_two and r.full.isolate_one and r.faults_isolable == 2


def test_correlations_are_minus_h_dot_h_for_cone6_and_dodecahedron():
    # H^T H = 2 I for both, so V^T V = I - H H^T / 2, |v_j|^2 = 1/2 and rho_jk = -h_j . h_k
    for g in (cone6(), dodecahedron6()):
        rho = column_correlations(g.parity_matrix())
        off = ~np.eye(6, dtype=bool)
        np.testing.assert_allclose(rho[off], -(g.H @ g.H.T)[off], atol=1e-12)
    assert np.isclose(np.abs(column_correlations(dodecahedron6().parity_matrix())[0, 1:]), 1 / math.sqrt(5)).all()


@settings(max_examples=25, deadline=None)
@given(n=st.integers(4, 8), seed=st.integers(0, 10_000))
def test_parity_rows_of_every_exclusion_set(n, seed):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, 3))
    A /= np.linalg.norm(A, axis=1)[:, None]
    sig = rng.uniform(0.5, 2.0, n)
    tab = ProjectionTable(A, sig)
    for e in [0] + [tab.lookup(tab.full_code & ~(1 << i)) for i in range(n)]:
        d = int(tab.dof[e])
        V = tab.Vz[e, :d]
        act = ((int(tab.codes[e]) >> np.arange(n)) & 1).astype(bool)
        # normalised parity of a noise-free input is zero, and white noise gives unit covariance
        np.testing.assert_allclose(V @ A, 0.0, atol=1e-10)
        np.testing.assert_allclose((V * sig**2) @ V.T, np.eye(d), atol=1e-10)
        assert np.all(V[:, ~act] == 0.0)


def test_pairwise_wrong_isolation_matches_monte_carlo():
    rng = np.random.default_rng(3)
    for m, rho in ((3.0, 0.6), (5.0, 0.667), (2.0, -0.3)):
        N = 200_000
        Xj = m + rng.standard_normal(N)
        Xk = rho * (Xj - m) + math.sqrt(1 - rho**2) * rng.standard_normal(N) + m * rho
        mc = np.mean(np.abs(Xk) > np.abs(Xj))
        th = float(pairwise_wrong_isolation(m, rho))
        assert abs(mc - th) < 4 * math.sqrt(th * (1 - th) / N) + 1e-6


def test_wrong_isolation_bounds_at_10_sigma():
    lo6, hi6 = wrong_isolation_bounds(cone6().parity_matrix(), 0, 10.0)
    lod, hid = wrong_isolation_bounds(dodecahedron6().parity_matrix(), 0, 10.0)
    assert 0 < lo6 <= hi6 < 0.01       # the cone6 target: below 1 %
    assert 0 < lod <= hid < 0.002      # dodecahedron: below 0.2 %
