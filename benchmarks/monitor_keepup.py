"""Does the whole ``rimu monitor`` keep up with a serial line at 921600 baud? End to end, on a pseudo-terminal.

    python benchmarks/monitor_keepup.py             # 3 rounds
    python3 dev.py bench monitor_keepup             # the same, recorded in benchmarks/results

A simulated cone6 unit (gyros and accelerometers, Cho & Park's procedure, calibrated by rimu.calibration.ChoPark)
is framed as its serial device sends it (rimu.io.device.SerialDevice, 74 bytes an epoch). A writer thread pushes the
stream into the master side of a pseudo-terminal as fast as the terminal takes it; ``rimu monitor --serial SLAVE
--calibration CAL --estimates FILE`` runs in this process (rimu.cli.main) and reads, decodes, compensates, projects,
tests parity, isolates and writes the estimates file of every epoch: all of the monitor's work. The figure is the
bytes of the stream divided by the time from the first byte written to the monitor's end less its idle timeout
(it stops after 0.5 s without data), against the line rate of 921600 baud 8N1 (92160 bytes/s), per round, median
[min, max] over rounds, after one untimed warm-up run. Every epoch sent must reach the estimates file; the epochs
missing per round are reported. The reference is the line itself: a ratio of 1 means the monitor just keeps up.
"""

from __future__ import annotations

import json
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

for _k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_k, "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rimu.calibration import ChoPark  # noqa: E402
from rimu.cli import main as rimu_main  # noqa: E402
from rimu.io.device import SerialDevice  # noqa: E402
from rimu.sim import Simulator, cho_park_procedure  # noqa: E402

BAUD = 921600
LINE_RATE = BAUD / 10.0
IDLE = 0.5


def one_round(stream: bytes, cal: Path, est: Path, n: int, transport: str) -> float:
    t_first: list[float] = []
    if transport == "pty":
        master, slave = os.openpty()
        port = os.ttyname(slave)
        tty.setraw(slave)

        def send() -> None:
            time.sleep(0.3)  # the monitor opens the port first (its idle timeout is 0.5 s)
            t_first.append(time.perf_counter())
            view = memoryview(stream)
            while view:
                k = os.write(master, view[:4096])
                view = view[k:]

        def close() -> None:
            os.close(master)
            os.close(slave)
    else:                                       # socket:// to a local TCP server (loopback only)
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        server.settimeout(30)
        port = f"socket://127.0.0.1:{server.getsockname()[1]}"

        def send() -> None:
            conn, _ = server.accept()
            with conn:
                time.sleep(0.1)
                t_first.append(time.perf_counter())
                conn.sendall(stream)
                time.sleep(2 * IDLE + 1)       # keep the link open: the monitor ends on its idle timeout

        def close() -> None:
            server.close()

    th = threading.Thread(target=send, daemon=True)
    th.start()
    try:
        code = rimu_main(["-q", "monitor", "--serial", port, "--baud", str(BAUD), "--calibration", str(cal),
                          "--estimates", str(est), "--idle-timeout", str(IDLE)])
        t_end = time.perf_counter() - IDLE
    finally:
        th.join(5)
        close()
    rows = sum(1 for _ in est.open()) - 1
    if code != 0:
        raise SystemExit(f"rimu monitor exited with {code}")
    return len(stream) / (t_end - t_first[0]), rows


def main() -> None:
    run = Simulator(seed=1).run(cho_park_procedure(duration=20.0))
    tmp = Path(tempfile.mkdtemp(prefix="rimu-keepup-"))
    cal = tmp / "cal.json"
    ChoPark().fit(run.session).to_calibration().save(cal)
    frames = SerialDevice().frames(run.block)
    stream = b"".join(frames)
    n = len(frames)
    one_round(stream[: 74 * 2000], cal, tmp / "warm.csv", 2000, "pty")   # warm-up: imports, kernels, caches
    out = {}
    for transport in ("pty", "socket"):
        got = [one_round(stream, cal, tmp / f"est{r}.csv", n, transport) for r in range(3)]
        ratios = [g[0] / LINE_RATE for g in got]
        lost = [n - g[1] for g in got]
        out[transport] = {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios),
                          "epochs_missing_per_round": lost}
        if any(lost):  # every epoch sent must reach the estimates file: a loss is reported, never hidden
            print(f"  {transport}: epochs missing from the estimates file per round: {lost} of {n}")
        print(f"rimu monitor --serial ({transport}) end to end, cone6 gyro+accel, {n} epochs, {len(stream)} bytes "
              f"({len(stream) / n:.0f} B/epoch): {out[transport]['median']:.1f}x the {BAUD}-baud line rate "
              f"[{min(ratios):.1f}, {max(ratios):.1f}] (monitor: read, decode, runtime with FDI, estimates file; "
              "reference: the line)")
    print(json.dumps({"baud": BAUD, "line_rate_bytes_s": LINE_RATE, "epochs": n, "bytes": len(stream),
                      "ratio_to_line_rate": out}))


if __name__ == "__main__":
    main()
