"""``rimu replay`` streams: the figures of a replay in many chunks equal those of one pass over the session held in
memory (an independent reference built from the library's in-memory functions), the per-sample estimates it writes
are the RedundancyManager's, and its peak memory does not grow with the session's length."""

from __future__ import annotations

import csv
import json
import tracemalloc

import numpy as np
import pytest

import rimu.cli.replay as replay
from rimu.cli import main

INJECT = ["bias:gyro:y2:30:10sigma", "dropout:accel:z2:100:0:0.3", "bias:accel:x1:50:8sigma"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay-stream")
    assert main(["simulate", "--duration", "6", "--latitude", "45", "-o", str(d / "s.npz"), "-q"]) == 0
    assert main(["calibrate", str(d / "s.npz"), "-o", str(d / "cal.json"), "-q"]) == 0
    return d


def in_memory(data, cal_path, specs):  # type: ignore[no-untyped-def]
    """The reference: the whole session in memory, faults injected, effects compensated, one manager run per
    instrument, segment errors (rimu.experiments.validate, with the replay's detector and settings)."""
    from rimu.calibration import Calibration
    from rimu.experiments.campaign import CampaignSpec, make_detector
    from rimu.experiments.faults import parse_injection
    from rimu.experiments.validate import validate
    from rimu.session import load_session

    session = load_session(data)
    v = validate(session, Calibration.load(cal_path), p_fa=1e-3, confirm=3,
                 injections=[parse_injection(s) for s in specs], seed=0,
                 detector=lambda pipe: make_detector(CampaignSpec(), pipe.table.sigma))
    n = sum(s.n_samples for s in session.segments)
    return {k: (r.replay, {"alarms": r.alarms, "isolations": r.isolations, "final_state": r.final_state,
                           **r.errors.to_dict(), "samples": n}) for k, r in v.items()}


def test_a_replay_in_many_chunks_gives_the_in_memory_figures(files, tmp_path, monkeypatch, capsys):
    ref = in_memory(files / "s.npz", files / "cal.json", INJECT)
    monkeypatch.setattr(replay, "_CHUNK", 997)  # 14 400 samples: 15 chunks, boundaries inside segments
    argv = ["replay", str(files / "s.npz"), "--calibration", str(files / "cal.json"), "-o", str(tmp_path),
            "--json", str(tmp_path / "ev.json"), "--estimates", str(tmp_path / "est.csv")]
    for s in INJECT:
        argv += ["--inject", s]
    assert main(argv) == 0
    assert "holds the session in memory" not in capsys.readouterr().out
    got = json.loads((tmp_path / "summary.json").read_text())
    for k, (_, want) in ref.items():
        assert want["isolations"] >= 1 and want["alarms"] > 0 and want["segments_compared"] == 24
        for f in ("alarms", "isolations", "final_state", "samples", "segments_compared", "unit"):
            assert got[k][f] == want[f], (k, f)
        for f in ("segment_error_rms", "sample_error_rms"):
            assert got[k][f] == pytest.approx(want[f], rel=1e-12), (k, f)
    ev = json.loads((tmp_path / "ev.json").read_text())
    assert [e["t"] for e in ev["gyro"]["events"]] == [e.t for e in ref["gyro"][0].events]
    # the estimates: one row per sample, the manager's outputs
    with open(tmp_path / "est.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t", "gyro_x", "gyro_y", "gyro_z", "gyro_validity", "gyro_isolated",
                       "accel_x", "accel_y", "accel_z", "accel_validity", "accel_isolated"]
    body = rows[1:]
    r = ref["gyro"][0]
    assert len(body) == len(r.t) == 14400
    np.testing.assert_array_equal(np.array([float(x[0]) for x in body]), r.t)
    for c, k in ((1, "gyro"), (6, "accel")):
        rk = ref[k][0]
        np.testing.assert_array_equal(np.array([[float(v) for v in x[c:c + 3]] for x in body]), rk.x)
        np.testing.assert_array_equal(np.array([int(x[c + 3]) for x in body]), rk.validity)
        iso = [";".join(str(i) for i in np.flatnonzero(s >= 2)) for s in rk.sensor_state]
        assert [x[c + 4] for x in body] == iso
    # the same file as the exported C filter's format (rimu.export.estimates reads it back)
    from rimu.export.estimates import read_estimates

    back = read_estimates(tmp_path / "est.csv", {"gyro": 6, "accel": 6})
    for k in ("gyro", "accel"):
        np.testing.assert_array_equal(back.x[k], ref[k][0].x)
        np.testing.assert_array_equal(back.isolated[k], ref[k][0].sensor_state >= 2)
    y2 = ref["gyro"][0].names.index("y2")
    assert body[-1][5] == str(y2) and body[0][5] == ""   # y2 isolated at the end, nothing at the start


def test_a_fault_that_needs_its_whole_window_reads_the_file_as_one_chunk(files, tmp_path, monkeypatch, capsys):
    """scale (a median over its window): the same figures as in memory, with a note."""
    specs = ["scale:gyro:x1:40:20sigma"]
    ref = in_memory(files / "s.npz", files / "cal.json", specs)
    monkeypatch.setattr(replay, "_CHUNK", 997)
    assert main(["replay", str(files / "s.npz"), "--calibration", str(files / "cal.json"), "-o", str(tmp_path),
                 "--inject", specs[0]]) == 0
    assert "holds the session in memory" in capsys.readouterr().out
    got = json.loads((tmp_path / "summary.json").read_text())
    for k, (_, want) in ref.items():
        assert (got[k]["alarms"], got[k]["isolations"]) == (want["alarms"], want["isolations"])
        assert got[k]["segment_error_rms"] == pytest.approx(want["segment_error_rms"], rel=1e-12)


@pytest.mark.parametrize("case", ["dead", "rate", "units", "angle"])
def test_the_streamed_plausibility_checks_find_what_load_session_finds(files, tmp_path, case, capsys):
    """A dead gyro column, a wrong sample rate, accelerometers declared in g but in m/s^2, and a gyro declared in
    deg/s but in rad/s over angle segments: the streaming replay refuses each with load_session's message (from
    per-segment statistics: first values, minima, maxima, means, trapezoidal integrals, the exact median step)."""
    from rimu.errors import PlausibilityError
    from rimu.session import load_session, save_session

    z = dict(np.load(files / "s.npz"))
    meta = json.loads(str(z["meta"]))
    if case == "dead":
        z["raw_gyro"][:, 0] = 123.0
    elif case == "rate":
        meta["sample_rate_hz"] = 250.0
    elif case == "units":
        meta["raw_unit"] = {"accel": "g"}
    p = tmp_path / f"{case}.npz"
    if case == "angle":
        from rimu.sim import Simulator, cho_park_procedure

        run = Simulator(seed=2, sample_rate=50.0).run(cho_park_procedure(duration=2.0))
        sess = run.session
        for seg in sess.segments:
            seg.raw["gyro"] = run.truth["gyro"].compensate(seg.raw["gyro"])
            if seg.kind == "rate":
                seg.kind, seg.angle_mb = "angle", seg.table_rate() * seg.duration
        sess.raw_unit = {"gyro": "deg/s"}
        save_session(sess, p)
    else:
        np.savez(p, **dict(z, meta=np.array(json.dumps(meta))))
    with pytest.raises(PlausibilityError) as exc:
        load_session(p)
    assert main(["replay", str(p), "--calibration", str(files / "cal.json")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"rimu replay: error: {exc.value}"


def _peak(argv) -> int:  # type: ignore[no-untyped-def]
    tracemalloc.start()
    try:
        assert main(argv) == 0
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_peak_memory_does_not_grow_with_the_session(tmp_path, monkeypatch, capsys):
    """Two sessions, the second 4x longer (4 800 and 19 200 samples), replayed in chunks of 250 samples with the
    summary, events and estimates written: the peak of traced allocations stays within 1.3x, and below the size
    of the longer session's samples (an in-memory replay holds several times that)."""
    paths = {}
    for n, dur in (("short", "2"), ("long", "8")):
        paths[n] = tmp_path / f"{n}.npz"
        assert main(["simulate", "--duration", dur, "-o", str(paths[n]), "-q"]) == 0
    assert main(["calibrate", str(paths["short"]), "-o", str(tmp_path / "cal.json"), "-q"]) == 0
    monkeypatch.setattr(replay, "_CHUNK", 250)

    def argv(n):  # type: ignore[no-untyped-def]
        return ["replay", str(paths[n]), "--calibration", str(tmp_path / "cal.json"), "-q", "--p-fa", "1e-6",
                "-o", str(tmp_path / n), "--estimates", str(tmp_path / f"{n}.csv"), "--json", str(tmp_path / "ev.json")]

    assert main(argv("short")) == 0  # imports and one-time caches out of the way
    peaks = {n: _peak(argv(n)) for n in ("short", "long")}
    capsys.readouterr()
    assert sum(1 for _ in open(tmp_path / "long.csv")) == 19200 + 1
    raw_bytes = 19200 * 13 * 8  # t and twelve raw columns as float64
    assert peaks["long"] < 1.3 * peaks["short"], peaks
    assert peaks["long"] < raw_bytes, (peaks, raw_bytes)
