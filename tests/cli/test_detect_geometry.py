"""``rimu detect --geometry`` (issue 32, item 5): a board of eight triads in one file is detected with its
geometry (a preset or ``triads:K``); without one the refusal names the option."""

from __future__ import annotations

import numpy as np

from rimu.cli import main
from rimu.geometry import preset
from rimu.session import load_session
from rimu.units import G0


def _board_csv(path, n_poses=8, fs=62.5, seed=0):
    rng = np.random.default_rng(seed)
    geo = preset("mimu4444")
    R = [su.mat_sb_mb for su in geo.subunits]
    acc, gyr = [], []
    for p in range(n_poses):
        u = rng.normal(size=3)
        g = G0 * u / np.linalg.norm(u)
        n = int(3 * fs)
        acc.append(np.column_stack([np.tile(R[j] @ g, (n, 1)) for j in range(8)]) + 0.03 * rng.normal(size=(n, 24)))
        gyr.append(0.003 * rng.normal(size=(n, 24)))
        if p < n_poses - 1:                                   # a 1 s turn to the next pose
            m = int(fs)
            w = rng.normal(size=3) * 2.0
            acc.append(np.column_stack([np.tile(R[j] @ g, (m, 1)) for j in range(8)]) + 3 * rng.normal(size=(m, 24)))
            gyr.append(np.column_stack([np.tile(R[j] @ w, (m, 1)) for j in range(8)]) + 0.003 * rng.normal(size=(m, 24)))
    A, W = np.vstack(acc), np.vstack(gyr)
    names = [f"a{j}{c}" for j in range(1, 9) for c in "xyz"] + [f"g{j}{c}" for j in range(1, 9) for c in "xyz"]
    with open(path, "w") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, np.hstack([A, W]), fmt="%.6f", delimiter=",")
    return names


def test_detect_a_board_of_eight_triads_with_its_geometry(tmp_path, capsys):
    raw = tmp_path / "board.csv"
    names = _board_csv(raw)
    cols = ["--accel", ",".join(names[:24]), "--gyro", ",".join(names[24:]), "--rate", "62.5"]
    assert main(["detect", str(raw), "-o", str(tmp_path / "x.npz"), *cols]) != 0
    assert "--geometry" in capsys.readouterr().err
    for geo, n in (("mimu4444", 24), ("triads:8", 24)):
        out = tmp_path / f"s_{geo.replace(':', '_')}.npz"
        assert main(["detect", str(raw), "-o", str(out), *cols, "--geometry", geo]) == 0, capsys.readouterr().err
        s = load_session(out)
        assert s.geometries["gyro"].n == n and len([g for g in s.segments if g.kind == "static_unknown"]) == 8
    assert main(["detect", str(raw), "-o", str(tmp_path / "y.npz"), *cols, "--geometry", "triads:3"]) != 0
    assert "24" in capsys.readouterr().err
