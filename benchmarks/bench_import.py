"""Import of a long multi-IMU DataFlash log: ``rimu import`` against pymavlink reading the same file one message at
a time into Python objects, timed in the same run (interleaved rounds, median of per-round ratios).

    python benchmarks/bench_import.py                 # one hour at 1 kHz, 3 IMUs (10.8 M IMU records), 2 rounds
    python benchmarks/bench_import.py --minutes 5     # a shorter log

What each side includes. ``rimu``: the whole ``rimu import LOG -o REC.npz`` path in-process
(:func:`rimu.io.formats.iter_log` over the file in 4 MB blocks, every IMU record decoded to SI, plausibility
checked, written to the recording file in pieces). ``pymavlink``: the reading a specialist would write with the
library's documented entry and its fastest options: ``mavutil.mavlink_connection(path)`` (``DFReader_binary``: its
index pass, with the C indexer ``dfindexer`` when built) and ``recv_match(type="IMU")`` (skips to the next IMU
message by that index, the other messages are never parsed), each IMU message's time, gyro and accelerometer fields
appended to one Python list per column and instance; nothing written. (The other documented readings were timed
on a 20 s log of the same layout: ``recv_msg()`` over every message with a ``get_type()`` filter, and
``recv_match(type=..., strict=True)``, were within 3 % of it; ``mavlink_connection``'s options for DataFlash,
``zero_time_base`` and ``progress_callback``, do not change the read path, and ``DFReader_binary`` already
memory-maps the file: there is no further zero-copy mode.) The log (an ArduPilot layout: FMT, UNIT/MULT/FMTU, three
``IMU`` instances and an ``ATT`` message per millisecond, 14.4 M messages for the hour) is written uncompressed to
a temporary folder first; both sides read the same file. Wall time decides the ratio; each side's process CPU time
is recorded beside it (on 2 cores shared with other work, a round's wall time includes time slices given away).
Prints a table and one JSON line; also the peak traced memory (tracemalloc) of one rimu import.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
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
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    import numpy as np
    from pymavlink import mavutil

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
        # pymavlink's documented entry and its fastest reader options: mavlink_connection opens DFReader_binary
        # (with its C indexer, dfindexer, when built), recv_match(type=...) skips to the next IMU message by that
        # index (the ATT messages are never parsed); the fields go to one Python list per column and instance
        conn = mavutil.mavlink_connection(str(log))
        cols: dict[int, tuple[list[float], ...]] = {}
        while True:
            m = conn.recv_match(type="IMU")
            if m is None:
                break
            c = cols.get(m.I)
            if c is None:
                c = cols[m.I] = ([], [], [], [], [], [], [])
            c[0].append(m.TimeUS * 1e-6)
            c[1].append(m.GyrX)
            c[2].append(m.GyrY)
            c[3].append(m.GyrZ)
            c[4].append(m.AccX)
            c[5].append(m.AccY)
            c[6].append(m.AccZ)
        conn.close()
        counts.update({f"IMU{k}": len(v[0]) for k, v in sorted(cols.items())})

    run_rimu()  # warm-up: the command's modules imported before timing
    cpu: dict[str, list[float]] = {"rimu": [], "pymavlink": []}

    def cpu_timed(name: str, fn: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            c0 = time.process_time()
            fn()
            cpu[name].append(time.process_time() - c0)
        return run

    # wall time decides; the process's CPU time is kept beside it (the 2 shared cores lend time slices elsewhere)
    times = interleaved_times({"rimu": cpu_timed("rimu", run_rimu), "pymavlink": cpu_timed("pymavlink", run_pymavlink)},
                              args.rounds)
    ratio = round_ratio(times, "pymavlink", "rimu")
    with np.load(out) as z:
        got = {n_: int(z[f"{k}.t"].shape[0]) for k, n_ in enumerate(json.loads(str(z["rimu_recording"]))["imus"])}
    tracemalloc.start()
    for _ in iter_log(log):
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    shutil.rmtree(d)  # the log and the recording (1.4 GB for the hour)
    import pymavlink
    from pymavlink import dfindexer
    res = {"pymavlink": pymavlink.__version__, "pymavlink_c_indexer": bool(dfindexer.available),
           "rounds": args.rounds, "minutes": args.minutes, "rate_hz": args.rate, "imus": args.imus, "imu_records": n, "file_mb": size / 1e6,
           "rimu_s": times["rimu"], "pymavlink_s": times["pymavlink"],
           "rimu_cpu_s": cpu["rimu"], "pymavlink_cpu_s": cpu["pymavlink"],
           "median_cpu_ratio_pymavlink_over_rimu": round_ratio(cpu, "pymavlink", "rimu"),
           "median_ratio_pymavlink_over_rimu": ratio, "rimu_records_per_s": n / float(np.median(times["rimu"])),
           "pymavlink_records_per_s": n / float(np.median(times["pymavlink"])),
           "rimu_counts": got, "pymavlink_counts": counts, "reader_peak_traced_mb": peak / 1e6}
    print(f"DataFlash log: {args.minutes:g} min, {args.imus} IMUs at {args.rate:g} Hz, {n} IMU records, "
          f"{size / 1e6:.0f} MB")
    print(f"{'side':>10s} {'median s':>9s} {'records/s':>11s}")
    for k in ("rimu", "pymavlink"):
        med = float(np.median(times[k]))
        print(f"{k:>10s} {med:9.2f} {n / med:11.3g}")
    print(f"pymavlink {pymavlink.__version__}, C indexer {'on' if dfindexer.available else 'off'}; "
          f"every round's ratio: {[round(a / b, 1) for a, b in zip(times['pymavlink'], times['rimu'])]}")
    print(f"median of per-round ratios pymavlink/rimu: {ratio:.1f}x wall, "
          f"{round_ratio(cpu, 'pymavlink', 'rimu'):.1f}x CPU ({args.rounds} rounds, interleaved)")
    print(f"records: rimu {got}, pymavlink {counts}")
    print(f"peak traced memory of the streaming reader: {peak / 1e6:.1f} MB")
    print(json.dumps(res))
    return res


if __name__ == "__main__":
    main()
