"""``rimu replay`` streaming against the in-memory replay: samples/s and peak RSS against the session's size.

    python benchmarks/replay_stream.py            # 250 000 and 1 000 000 samples, 3 repeats
    python benchmarks/replay_stream.py --quick    # 50 000 and 200 000 samples, 1 repeat

Each run is a fresh process (so its peak RSS is its own): ``stream`` is ``rimu replay FILE --calibration CAL -o DIR``
(two passes over the file in chunks, summary accumulated online); the reference, timed in the same run on the
same file, is the in-memory path rimu replay took before: ``load_session``, ``session_block``, one
``RedundancyManager.run`` per instrument over the whole block, ``segment_errors``. ``baseline`` is a process that
only imports rimu's command line (the RSS every run starts from). Both paths' summary figures are compared (they
must agree to 1e-9: the in-memory path subtracts two segment means of ~1 g, whose
rounding is ~1e-16 g, from errors of ~1e-5 g). Prints a table and one JSON line.
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
mode, data, cal, out = sys.argv[1:5]
import numpy as np
from rimu.cli import main
import rimu.cli.replay, rimu.fdi, rimu.experiments.campaign, rimu.experiments.faults, rimu.fusion.validation, rimu.session  # imports untimed
t0 = time.perf_counter()
if mode == "stream":
    assert main(["replay", data, "--calibration", cal, "-o", out, "-q"]) == 0
    summary = json.load(open(out + "/summary.json"))
elif mode == "memory":
    from rimu.calibration import Calibration
    from rimu.experiments.campaign import CampaignSpec, make_detector
    from rimu.experiments.validate import validate
    from rimu.session import load_session
    session = load_session(data)
    v = validate(session, Calibration.load(cal, geometries=session.geometries), p_fa=1e-3, confirm=3,
                 readmit_after=None, detector=lambda pipe: make_detector(CampaignSpec(), pipe.table.sigma))
    summary = {k: {"alarms": r.alarms, "segment_error_rms": r.errors.segment_error_rms,
                   "sample_error_rms": r.errors.sample_error_rms} for k, r in v.items()}
else:
    summary = {}
dt = time.perf_counter() - t0
# VmHWM: this process's own peak (ru_maxrss would carry the parent's peak over fork+exec)
hwm = next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:"))
print(json.dumps({"s": dt, "rss_mb": hwm / 1024, "summary": summary}))
"""


def child(mode: str, data: Path, cal: Path, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-c", CHILD, mode, str(data), str(cal), str(out)], capture_output=True,
                       text=True, env=env, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    sizes = (50_000, 200_000) if args.quick else (250_000, 1_000_000)
    repeat = 1 if args.quick else 3
    sys.path.insert(0, str(ROOT))
    from rimu.cli import main as rimu

    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        base = child("none", d, d, d)
        for n in sizes:
            data = d / f"s{n}.npz"
            # cho_park: 24 segments; --duration is s per segment at 100 Hz
            assert rimu(["simulate", "--duration", f"{n / 2400:g}", "-o", str(data), "-q"]) == 0
            if not (d / "cal.json").exists():
                assert rimu(["calibrate", str(data), "-o", str(d / "cal.json"), "-q"]) == 0
            runs = {"stream": [], "memory": []}
            for _ in range(repeat):  # interleaved: both paths see the same machine load
                for mode in runs:
                    runs[mode].append(child(mode, data, d / "cal.json", d / f"out{n}"))
            s, m = runs["stream"][0]["summary"], runs["memory"][0]["summary"]
            for k in m:
                for f in m[k]:
                    assert abs(s[k][f] - m[k][f]) <= 1e-9 * abs(m[k][f]), (k, f, s[k][f], m[k][f])
            t_s = statistics.median(r["s"] for r in runs["stream"])
            t_m = statistics.median(r["s"] for r in runs["memory"])
            rows.append({"samples": n, "file_mb": data.stat().st_size / 1e6,
                         "stream_samples_per_s": n / t_s, "memory_samples_per_s": n / t_m,
                         "speed_ratio": statistics.median(m_["s"] / s_["s"] for s_, m_ in zip(runs["stream"],
                                                                                             runs["memory"])),
                         "stream_rss_mb": max(r["rss_mb"] for r in runs["stream"]),
                         "memory_rss_mb": max(r["rss_mb"] for r in runs["memory"]), "summaries_equal": True})
    print("rimu replay: streaming (two passes in chunks of 20 000 samples) vs the whole session in memory")
    print(f"  fresh process per run, medians of {repeat}; baseline RSS (imports only) {base['rss_mb']:.0f} MB")
    print(f"{'samples':>9s} {'file MB':>8s} {'stream/s':>9s} {'memory/s':>9s} {'x speed':>7s} "
          f"{'stream RSS':>10s} {'memory RSS':>10s}")
    for r in rows:
        print(f"{r['samples']:9d} {r['file_mb']:8.1f} {r['stream_samples_per_s']:9.0f} {r['memory_samples_per_s']:9.0f}"
              f" {r['speed_ratio']:7.2f} {r['stream_rss_mb']:8.0f}MB {r['memory_rss_mb']:8.0f}MB")
    a, b = rows[0], rows[-1]
    growth = {"size_ratio": b["samples"] / a["samples"],
              "stream_rss_growth_mb": b["stream_rss_mb"] - a["stream_rss_mb"],
              "memory_rss_growth_mb": b["memory_rss_mb"] - a["memory_rss_mb"]}
    print(f"  {growth['size_ratio']:.0f}x the samples: streaming RSS +{growth['stream_rss_growth_mb']:.0f} MB, "
          f"in-memory RSS +{growth['memory_rss_growth_mb']:.0f} MB")
    print(json.dumps({"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]},
                      "baseline_rss_mb": base["rss_mb"], "rows": rows, "growth": growth}))


if __name__ == "__main__":
    main()
