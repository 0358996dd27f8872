"""Sensor geometries against the papers, and the parity-space invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.errors import GeometryError, RankDeficientError
from rimu.geometry import PRESETS, Geometry, SubUnit, cone, cone6, dodecahedron6, preset, tetrad4, triad3

S2, S3, S6 = math.sqrt(2), math.sqrt(3), math.sqrt(6)

# Cho & Park 2005, Eq. 18, typed from the paper
EQ18 = np.array([
    [S2 / S3, 0, -1 / S3],
    [-1 / S6, -1 / S2, -1 / S3],
    [-1 / S6, 1 / S2, -1 / S3],
    [-S2 / S3, 0, -1 / S3],
    [1 / S6, 1 / S2, -1 / S3],
    [1 / S6, -1 / S2, -1 / S3],
])
# de Oliveira et al. 2012, Eq. 1
EQ1 = np.array([
    [1 / S3, 0, S6 / 3],
    [1 / S3, S2 / 2, -S6 / 6],
    [1 / S3, -S2 / 2, -S6 / 6],
    [1, 0, 0],
])


def test_cone6_is_cho_park_eq18():
    g = cone6()
    assert np.allclose(g.H, EQ18, atol=1e-15)
    sb1, sb2 = g.subunits
    for su in (sb1, sb2):
        assert np.allclose(su.mat_sb_mb @ su.mat_sb_mb.T, np.eye(3), atol=1e-15)
        assert su.proper  # both sub-IMUs are right-handed triads
    # SB2 is SB1 turned 180 deg about z_m
    assert np.allclose(sb2.mat_sb_mb, sb1.mat_sb_mb @ np.diag([-1, -1, 1]), atol=1e-15)
    # every axis at the cone half-angle 54.7356 deg from -z_m
    assert np.allclose(np.degrees(np.arccos(-g.H[:, 2])), 54.7356, atol=1e-4)
    assert np.allclose(g.nominal_rows(), np.vstack([np.eye(3), np.eye(3)]), atol=1e-15)


def test_tetrad4_is_de_oliveira_eq1_and_parity_eq24():
    g = tetrad4()
    assert np.allclose(g.H, EQ1, atol=1e-15)
    assert math.degrees(math.acos(g.H[0, 0])) == pytest.approx(54.736, abs=1e-3)
    V = g.parity_matrix()
    eq24 = np.array([-0.408250, -0.40825, -0.408250, 0.70711])
    assert V.shape == (1, 4)
    assert np.allclose(V[0], eq24, atol=1e-5)


def test_dodecahedron_and_triad():
    g = dodecahedron6()
    cosines = np.abs(g.H @ g.H.T)[np.triu_indices(6, 1)]
    assert np.allclose(cosines, 1 / math.sqrt(5), atol=1e-12)  # all pairs at 63.435 deg
    assert np.allclose(g.H.T @ g.H, 2 * np.eye(3), atol=1e-12)
    assert np.array_equal(triad3().H, np.eye(3))
    assert triad3().parity_matrix().shape == (0, 3)


def test_cone_general_and_registry():
    g = cone(8, math.radians(40))
    assert g.n == 8
    s = math.sin(math.radians(40)) ** 2
    assert np.allclose(g.H.T @ g.H, np.diag([4 * s, 4 * s, 8 * (1 - s)]), atol=1e-12)
    assert set(PRESETS) >= {"cone6", "tetrad4", "triad3", "dodecahedron6", "cone"}
    with pytest.raises(GeometryError, match="unknown geometry"):
        preset("hexagon")


def _check_parity(g: Geometry) -> None:
    H = g.H
    V = g.parity_matrix()
    assert V.shape == (g.n - 3, g.n)
    assert np.allclose(V @ H, 0, atol=1e-12)
    assert np.allclose(V @ V.T, np.eye(g.n - 3), atol=1e-12)
    # the reference projector through the normal equations loses ~eps cond(H)^2 (a near-coplanar random H)
    cond = np.linalg.cond(H)
    assert np.allclose(V.T @ V, np.eye(g.n) - H @ np.linalg.solve(H.T @ H, H.T), atol=1e-12 + 1e-15 * cond**2)


@pytest.mark.parametrize("name", ["cone6", "tetrad4", "triad3", "dodecahedron6", "cone"])
def test_parity_invariants_presets(name):
    _check_parity(preset(name))


@st.composite
def geometries(draw):
    n = draw(st.integers(3, 9))
    vals = draw(st.lists(st.floats(-1, 1, allow_nan=False), min_size=3 * n, max_size=3 * n))
    H = np.array(vals).reshape(n, 3)
    norms = np.linalg.norm(H, axis=1)
    short = norms < 0.2
    if np.any(short):  # replace only the short rows (adding to every row could cancel one, e.g. (-1, 0, 0))
        H[short] = np.eye(3)[np.arange(n)[short] % 3]
        norms = np.linalg.norm(H, axis=1)
    H = H / norms[:, None]
    s = np.linalg.svd(H, compute_uv=False)
    if s[-1] < 1e-3 * s[0]:
        H[:3] = np.eye(3)
    return Geometry(H)


@settings(max_examples=150, deadline=None)
@given(geometries())
def test_parity_invariants_random(g):
    _check_parity(g)


def test_validation_errors_say_what_is_wrong():
    with pytest.raises(GeometryError, match="non-finite"):
        Geometry([[1, 0, 0], [0, 1, 0], [0, 0, np.nan]])
    with pytest.raises(GeometryError, match=r"row 1 has norm 1\.1"):
        Geometry([[1, 0, 0], [0, 1.1, 0], [0, 0, 1]])
    with pytest.raises(GeometryError, match=r"shape \(n, 3\)"):
        Geometry(np.eye(4))
    with pytest.raises(RankDeficientError) as exc:
        Geometry([[1, 0, 0], [0, 1, 0], [math.sqrt(0.5), math.sqrt(0.5), 0], [-1, 0, 0]])
    assert exc.value.unobservable and np.allclose(np.abs(exc.value.unobservable[0]), [0, 0, 1])
    assert "span only 2" in str(exc.value)
    with pytest.raises(RankDeficientError):
        cone(5, math.pi / 2)  # all axes in the xy plane: z unobservable
    with pytest.raises(GeometryError, match="3 sensor names given for 4 rows"):
        Geometry(EQ1, names=["a", "b", "c"])
    with pytest.raises(GeometryError, match="unique"):
        Geometry(EQ1, names=["a", "b", "c", "a"])
    with pytest.raises(GeometryError, match="no sub-unit"):
        Geometry(EQ1, subunits=[SubUnit("T", EQ1[:3], (0, 1, 2))])
    with pytest.raises(GeometryError, match="not orthonormal"):
        Geometry(EQ1, subunits=[SubUnit("T", 2 * np.eye(3), (0, 1, 2, 3))])


def test_fingerprint_and_round_trip():
    g = cone6()
    g2 = Geometry.from_dict(g.to_dict())
    assert g2 == g and g2.fingerprint() == g.fingerprint()
    assert g.fingerprint() != tetrad4().fingerprint()
    assert g.fingerprint() != Geometry(g.H, names=["a", "b", "c", "d", "e", "f"]).fingerprint()
    assert g.index("y2") == 4
