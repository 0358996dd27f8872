"""Import of a long multi-IMU DataFlash log: ``rimu import`` against pymavlink reading the same file one message at
a time into Python objects, timed in the same run (interleaved rounds, median of per-round ratios).

    python benchmarks/bench_import.py                 # one hour at 1 kHz, 3 IMUs (10.8 M IMU records), 3 rounds
    python benchmarks/bench_import.py --minutes 5     # a shorter log

What each side includes. ``rimu``: the whole ``rimu import LOG -o REC.npz`` path in-process
(:func:`rimu.io.formats.iter_log` over the file in 4 MB blocks, every IMU record decoded to SI, plausibility
checked, written to the recording file in pieces). ``pymavlink``: ``DFReader_binary(path)`` (its index pass) and
``recv_msg()`` over every message, the IMU messages' time, gyro and accelerometer fields appended to Python lists
(what a script built on the library does), nothing written. The log (an ArduPilot layout: FMT, UNIT/FMTU, three
``IMU`` instances and an ``ATT`` message per millisecond, 14.4 M messages for the hour) is written uncompressed to
a temporary folder first; both sides read the same file. Prints a table and one JSON line; also the peak
traced memory (tracemalloc) of one rimu import.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _timing import interleaved_times, round_ratio  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--imus", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    import numpy as np
    import pymavlink.DFReader as DF

    from rimu.cli import main as rimu
    from rimu.io.formats import iter_log
    from rimu.io.formats._synth import write_dataflash

    d = Path(tempfile.mkdtemp(prefix="rimu-bench-import-"))
    log = d / "flight.bin"
    n = write_dataflash(log, args.imus, args.rate, 60.0 * args.minutes, block=100_000)
    size = log.stat().st_size
    out = d / "rec.npz"

    def run_rimu() -> None:
        assert rimu(["import", str(log), "-o", str(out), "-q"]) == 0

    counts: dict[str, int] = {}

    def run_pymavlink() -> None:
        r = DF.DFReader_binary(str(log))
        rows: dict[tuple[str, int], list[list[float]]] = {}
        while True:
            m = r.recv_msg()
            if m is None:
                break
            if m.get_type() == "IMU":
                rows.setdefault(("IMU", m.I), []).append([m.TimeUS * 1e-6, m.GyrX, m.GyrY, m.GyrZ, m.AccX, m.AccY,
                                                         m.AccZ])
        counts.update({f"{k[0]}{k[1]}": len(v) for k, v in rows.items()})

    run_rimu()  # warm-up: the command's modules imported before timing
    times = interleaved_times({"rimu": run_rimu, "pymavlink": run_pymavlink}, args.rounds)
    ratio = round_ratio(times, "pymavlink", "rimu")
    z = np.load(out)
    got = {n_: int(z[f"{k}.t"].shape[0]) for k, n_ in enumerate(json.loads(str(z["rimu_recording"]))["imus"])}
    tracemalloc.start()
    for _ in iter_log(log):
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    os.unlink(log)
    res = {"minutes": args.minutes, "rate_hz": args.rate, "imus": args.imus, "imu_records": n, "file_mb": size / 1e6,
           "rimu_s": sorted(times["rimu"]), "pymavlink_s": sorted(times["pymavlink"]),
           "median_ratio_pymavlink_over_rimu": ratio, "rimu_records_per_s": n / float(np.median(times["rimu"])),
           "pymavlink_records_per_s": n / float(np.median(times["pymavlink"])),
           "rimu_counts": got, "pymavlink_counts": counts, "reader_peak_traced_mb": peak / 1e6}
    print(f"DataFlash log: {args.minutes:g} min, {args.imus} IMUs at {args.rate:g} Hz, {n} IMU records, "
          f"{size / 1e6:.0f} MB")
    print(f"{'side':>10s} {'median s':>9s} {'records/s':>11s}")
    for k in ("rimu", "pymavlink"):
        med = float(np.median(times[k]))
        print(f"{k:>10s} {med:9.2f} {n / med:11.3g}")
    print(f"median of per-round ratios pymavlink/rimu: {ratio:.1f}x ({args.rounds} rounds, interleaved)")
    print(f"records: rimu {got}, pymavlink {counts}")
    print(f"peak traced memory of the streaming reader: {peak / 1e6:.1f} MB")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
