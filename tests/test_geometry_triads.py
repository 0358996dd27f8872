"""Units of k triads: rotations, positions (lever arms), serialisation, fingerprints."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.errors import GeometryError
from rimu.fdi import isolability
from rimu.fusion.projection import ProjectionTable
from rimu.geometry import Geometry, cone6, preset, tetrad4, triads
from rimu.session.model import rotation_matrix

# fingerprints computed by rimu before sub-unit positions existed (main at a6968b9): must not change
OLD_FINGERPRINTS = {"cone6": "e591d796927ee6a3", "tetrad4": "88978cbe81394202", "triads2": "2f66967eda39925e"}


def test_fingerprint_unchanged_for_units_without_positions():
    assert cone6().fingerprint() == OLD_FINGERPRINTS["cone6"]
    assert tetrad4().fingerprint() == OLD_FINGERPRINTS["tetrad4"]
    assert triads(2).fingerprint() == OLD_FINGERPRINTS["triads2"]
    # a position is part of the identity of the unit
    assert triads(2, positions_mb_m=[[0, 0, 0], [0.1, 0, 0]]).fingerprint() != OLD_FINGERPRINTS["triads2"]


def test_rotations_positions_round_trip():
    rng = np.random.default_rng(3)
    rots = [rotation_matrix(rng.normal(size=3)) for _ in range(4)]
    pos = [[0.0, 0.0, 0.0], [0.0095, 0.0, 0.0], None, [0.0, -0.02, 0.001]]
    g = triads(rots, pos, names=["a", "b", "c", "d"])
    assert g.n == 12 and g.redundancy == 9
    assert np.allclose(g.H[3:6], rots[1])                    # rows = triad axes in MB
    assert np.allclose(g.nominal_rows(), np.vstack([np.eye(3)] * 4), atol=1e-12)
    assert g.names[3:6] == ("b_x", "b_y", "b_z")
    P = g.positions_mb_m()
    assert np.allclose(P[3:6], [0.0095, 0, 0]) and np.isnan(P[6:9]).all()
    d = json.loads(json.dumps(g.to_dict()))
    g2 = Geometry.from_dict(d)
    assert g2 == g and g2.fingerprint() == g.fingerprint()
    assert np.allclose(g2.subunits[1].position_mb_m, [0.0095, 0, 0])
    assert g2.subunits[2].position_mb_m is None
    assert "position_mb_m" not in d["subunits"][2]
    assert preset("triads", rotations=3).n == 9


def test_two_parallel_triads_detect_but_do_not_isolate():
    g = triads(2)
    rep = isolability(ProjectionTable(g.H), g.names)
    assert rep.full.detect_one and not rep.full.isolate_one
    g3 = triads(3)
    assert isolability(ProjectionTable(g3.H), g3.names).full.isolate_one


@pytest.mark.parametrize("kwargs, words", [
    ({"rotations": 0}, "at least one"),
    ({"rotations": [np.eye(3), np.eye(2)]}, "3 x 3"),
    ({"rotations": [np.eye(3), 2 * np.eye(3)]}, "orthonormal"),
    ({"rotations": 2, "positions_mb_m": [[0, 0, 0]]}, "1 positions for 2"),
    ({"rotations": 2, "positions_mb_m": [[0, 0, 0], [0, np.nan, 0]]}, "finite"),
    ({"rotations": 2, "positions_mb_m": [[0, 0, 0], [0, 0]]}, "3 finite numbers"),
    ({"rotations": 2, "names": ["a"]}, "one name per triad"),
])
def test_bad_triads_are_refused(kwargs, words):
    with pytest.raises(GeometryError, match=words):
        triads(**kwargs)
