"""Session files: CSV + JSON sidecar and NPZ round trips; readers name what is missing or malformed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rimu.errors import SessionFormatError
from rimu.session import load_session, save_session
from rimu.sim import Simulator, cho_park_procedure


@pytest.fixture(scope="module")
def session():
    return Simulator(seed=5).run(cho_park_procedure(duration=1.0)).session


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip(tmp_path, session, suffix):
    p = save_session(session, tmp_path / f"s{suffix}")
    back = load_session(p)
    assert back.sample_rate == session.sample_rate and back.latitude == pytest.approx(session.latitude)
    assert [s.label for s in back] == [s.label for s in session]
    for a, b in zip(session, back):
        assert a.kind == b.kind
        for k in ("gyro", "accel"):
            assert np.array_equal(a.raw[k], b.raw[k])
        for attr in ("specific_force_mb", "rate_mb", "mat_ln_mb"):
            va, vb = getattr(a, attr), getattr(b, attr)
            assert (va is None) == (vb is None)
            if va is not None:
                assert np.allclose(va, vb)
    assert back.geometries["gyro"] == session.geometries["gyro"]


def _with_cell(lines, row, col, value):
    """The CSV text of ``lines`` with cell (row, col) replaced by ``value``."""
    bad = lines[:]
    cols = bad[row].split(",")
    cols[col] = value
    bad[row] = ",".join(cols)
    return "\n".join(bad) + "\n"


def test_csv_errors_name_row_and_column(tmp_path, session):
    p = save_session(session, tmp_path / "s.csv")
    lines = p.read_text().splitlines()
    p.write_text(_with_cell(lines, 5, 4, "abc"))
    with pytest.raises(SessionFormatError, match=r"row 6, column 'gyro_z1'"):
        load_session(p)
    hdr = lines[0].replace("accel_y2,", "")
    p.write_text("\n".join([hdr] + [",".join(r.split(",")[:13] + r.split(",")[14:]) for r in lines[1:]]) + "\n")
    with pytest.raises(SessionFormatError, match="accel_y2"):
        load_session(p)
    p.write_text(_with_cell(lines, 3, 1, "P99"))
    with pytest.raises(SessionFormatError, match=r"row 4, column 'segment'"):
        load_session(p)
    p.write_text("\n".join(lines) + "\n")
    side = json.loads(p.with_suffix(".json").read_text())
    del side["segments"][3]["specific_force_mb_m_s2"]
    del side["segments"][3]["mat_ln_mb"]
    p.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(SessionFormatError, match="P4"):
        load_session(p)
    p.with_suffix(".json").unlink()
    with pytest.raises(SessionFormatError, match="sidecar"):
        load_session(p)


def test_sidecar_accepts_human_units(tmp_path):
    """A hand-written sidecar with degrees and g."""
    t = np.arange(200) / 100.0
    rows = ["t,segment,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"]
    for i, tt in enumerate(t):
        lab = "up" if i < 100 else "spin"
        rows.append(f"{tt},{lab},0.1,0.2,{10.0 if lab == 'spin' else 0.3},0,0,1")
    (tmp_path / "hand.csv").write_text("\n".join(rows) + "\n")
    side = {"format": "rimu.session", "version": 1, "data": "hand.csv", "sample_rate_hz": 100, "latitude_deg": 48.1,
            "raw_unit": "count", "geometries": {"gyro": "triad3", "accel": "triad3"},
            "segments": [{"label": "up", "kind": "static", "specific_force_mb_g": [0, 0, 1]},
                         {"label": "spin", "kind": "rate", "rate_mb_deg_s": [0, 0, 10]}]}
    (tmp_path / "hand.json").write_text(json.dumps(side))
    s = load_session(tmp_path / "hand.json")
    assert np.allclose(s.segment("up").specific_force_mb, [0, 0, 9.80665])
    assert np.allclose(s.segment("spin").rate_mb, [0, 0, np.radians(10)])
    side["version"] = 7
    (tmp_path / "hand.json").write_text(json.dumps(side))
    with pytest.raises(SessionFormatError, match="version"):
        load_session(tmp_path / "hand.json")


def test_npz_errors(tmp_path, session):
    p = save_session(session, tmp_path / "s.npz")
    z = dict(np.load(p))
    z["raw_gyro"] = z["raw_gyro"][:, :5]
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(SessionFormatError, match="raw_gyro has shape"):
        load_session(tmp_path / "bad.npz")
    z = dict(np.load(p))
    del z["meta"]
    np.savez(tmp_path / "bad2.npz", **z)
    with pytest.raises(SessionFormatError, match="meta"):
        load_session(tmp_path / "bad2.npz")


def test_round_trip_property(tmp_path_factory):
    """Any session of static segments with plain labels survives CSV and NPZ exactly (hypothesis)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from rimu.geometry import triad3
    from rimu.session import Segment, Session

    label = st.text("abcdefghijklmnopqrstuvwxyzABC0123456789_-", min_size=1, max_size=8)

    @settings(max_examples=15, deadline=None)
    @given(st.lists(label, min_size=1, max_size=4, unique=True), st.integers(1, 30), st.integers(0, 2**31 - 1))
    def check(labels, n, seed):
        rng = np.random.default_rng(seed)
        segs, t0 = [], 0.0
        for lab in labels:
            t = t0 + np.arange(n) * 0.01
            t0 = t[-1] + 0.01
            f = rng.standard_normal(3)
            segs.append(Segment(lab, "static", t, {"gyro": rng.standard_normal((n, 3)) * 1e3,
                                                  "accel": rng.standard_normal((n, 3))}, specific_force_mb=f))
        s = Session(segs, {"gyro": triad3(), "accel": triad3()}, 100.0, None)
        d = tmp_path_factory.mktemp("rt")
        for suffix in (".csv", ".npz"):
            back = load_session(save_session(s, d / f"s{suffix}"))
            for a, b in zip(s, back):
                assert a.label == b.label
                assert np.array_equal(a.t, b.t) and np.array_equal(a.raw["gyro"], b.raw["gyro"])
                assert np.allclose(a.specific_force_mb, b.specific_force_mb, rtol=1e-15, atol=0)

    check()


def test_session_from_sidecar_rebuilds_the_session(session):
    """The public sidecar API (what ``rimu replay`` builds its reduced session with): a session's own sidecar
    and its samples give back the same session; a segment without samples is named."""
    from rimu.session import session_from_sidecar, session_sidecar, sidecar_geometries

    side = json.loads(json.dumps(session_sidecar(session)))  # as read back from the JSON file
    assert sidecar_geometries(side)["gyro"] == session.geometries["gyro"]
    t = np.concatenate([s.t for s in session])
    idx = np.concatenate([np.full(len(s.t), i) for i, s in enumerate(session)])
    raw = {k: np.vstack([s.raw[k] for s in session]) for k in session.geometries}
    back = session_from_sidecar(side, t, idx, raw)
    assert [s.label for s in back] == [s.label for s in session]
    for a, b in zip(session, back):
        assert a.kind == b.kind and np.array_equal(a.t, b.t)
        for k in ("gyro", "accel"):
            assert np.array_equal(a.raw[k], b.raw[k])
        for attr in ("specific_force_mb", "rate_mb"):
            va, vb = getattr(a, attr), getattr(b, attr)
            assert (va is None) == (vb is None) and (va is None or np.allclose(va, vb))
    assert back.sample_rate == session.sample_rate and back.gravity == pytest.approx(session.gravity)
    with pytest.raises(SessionFormatError, match=repr(session.segments[1].label)):
        session_from_sidecar(side, t, np.where(idx == 1, 0, idx), raw, src="x.json")
