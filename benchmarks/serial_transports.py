"""Live serial transports against their line rate: does ``rimu monitor --serial`` keep up?

    python benchmarks/serial_transports.py            # 500 kB per round, 5 rounds
    python benchmarks/serial_transports.py --quick    # 200 kB, 3 rounds
    python3 dev.py bench serial_transports            # the same, recorded in benchmarks/results

For each pyserial transport rimu's live source reads (``loop://``, ``socket://`` to a local TCP server, a
pseudo-terminal as a local port), a sender writes rimu-framed epochs (SerialDevice, the simulated device) as fast
as it can; :class:`rimu.io.serial.SerialSource` reads and decodes them into epochs, as ``rimu monitor`` does. The
figure is the decoded throughput, bytes of the stream per second from the first to the last epoch, against the
reference: the line rate of the default settings (921600 baud, 8N1: 92160 bytes/s). Both read strategies are timed
in the same rounds, interleaved: the block reads of ``rimu.io.serial.read_available`` and the previous one (read
``max(in_waiting, 1)`` bytes per call; ``in_waiting`` of ``socket://`` is 0 or 1). Each side includes the
transport, the read calls and the frame decoding (CRC, values), not the pipeline or FDI. Medians over rounds of
the per-round ratio to the line rate. ``loop://`` is pyserial's in-process loopback for tests, not a line: its
writer puts every byte into a queue of at most 4096 bytes one by one, so its figure is that writer's pace (both
strategies alike), not the reader's. The reader's capacity is measured: the sender runs ahead, so the figure
is how fast the bytes are taken and decoded, which must be at least what the line delivers. Prints a table and one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import serial

from rimu.io import fuzz
from rimu.io.device import SerialDevice
from rimu.io.serial import SerialSource

BAUD = 921600
LINE_RATE = BAUD / 10  # bytes/s, 8N1


class _PreviousSource(SerialSource):
    """The read before issue 31: ``max(in_waiting, 1)`` bytes per call."""

    def _epochs(self):  # type: ignore[no-untyped-def]
        self._open()
        last = time.monotonic()
        while not self.stop_event.is_set():
            data = self.ser.read(min(max(self.ser.in_waiting, 1), self.read_size))
            if data:
                last = time.monotonic()
                yield from self.decoder.feed(data)
            elif time.monotonic() - last > self.idle_timeout:
                break
        yield from self.decoder.flush()


def _consume(src: SerialSource, n_expected: int) -> tuple[int, float]:
    n, t0 = 0, None
    for _ep in src:
        if t0 is None:
            t0 = time.perf_counter()
        n += 1
        if n == n_expected:
            break
    return n, time.perf_counter() - (t0 or time.perf_counter())


def run_loop(stream: bytes, n: int, cls: type) -> tuple[int, float]:
    port = serial.serial_for_url("loop://", timeout=0.05)
    src = cls(serial_port=port, idle_timeout=0.5)
    th = threading.Thread(target=lambda: [port.write(stream[i:i + 4096]) for i in range(0, len(stream), 4096)])
    th.start()
    try:
        return _consume(src, n)
    finally:
        th.join()
        src.close()


def run_socket(stream: bytes, n: int, cls: type) -> tuple[int, float]:
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    host, port = server.getsockname()

    def send() -> None:
        conn, _ = server.accept()
        time.sleep(0.2)  # pyserial's socket:// open discards what has arrived (reset_input_buffer)
        conn.sendall(stream)
        time.sleep(1.0)
        conn.close()

    th = threading.Thread(target=send, daemon=True)
    th.start()
    src = cls(port=f"socket://{host}:{port}", baudrate=BAUD, idle_timeout=0.5)
    try:
        return _consume(src, n)
    finally:
        src.close()
        server.close()


def run_pty(stream: bytes, n: int, cls: type) -> tuple[int, float]:
    master, slave = os.openpty()
    name = os.ttyname(slave)
    import tty

    tty.setraw(slave)

    def send() -> None:
        view = memoryview(stream)
        while view:
            k = os.write(master, view[:4096])
            view = view[k:]

    src = cls(port=name, baudrate=BAUD, idle_timeout=0.5)
    src._open()
    th = threading.Thread(target=send, daemon=True)
    th.start()
    try:
        return _consume(src, n)
    finally:
        src.close()
        th.join(5)
        os.close(master)
        os.close(slave)


TRANSPORTS = {"loop://": run_loop, "socket://": run_socket, "pty": run_pty}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--rounds", type=int, default=None)
    a = ap.parse_args()
    size = 200_000 if a.quick else 500_000
    rounds = a.rounds or (3 if a.quick else 5)
    frames = SerialDevice().frames(fuzz.random_block(4000))
    per = len(b"".join(frames)) / len(frames)
    n = int(size / per)
    stream = b"".join((frames * (n // len(frames) + 1))[:n])
    rows = {}
    for name, fn in TRANSPORTS.items():
        ratios: dict[str, list[float]] = {"block": [], "previous": []}
        for _ in range(rounds):
            for side, cls in (("block", SerialSource), ("previous", _PreviousSource)):  # interleaved
                got, dt = fn(stream, n, cls)
                rate = len(stream) * got / n / dt if dt > 0 else float("inf")
                ratios[side].append(rate / LINE_RATE)
        rows[name] = {side: statistics.median(v) for side, v in ratios.items()}
    print(f"decoded serial stream against the line rate of {BAUD} baud ({LINE_RATE:.0f} bytes/s), {len(stream)} bytes "
          f"per round, median of {rounds} rounds")
    print(f"{'transport':<12}{'block reads':>14}{'previous reads':>17}")
    for name, r in rows.items():
        print(f"{name:<12}{r['block']:>13.2f}x{r['previous']:>16.2f}x")
    doc = {"baud": BAUD, "line_rate_bytes_s": LINE_RATE, "bytes_per_round": len(stream), "rounds": rounds,
           "ratio_to_line_rate": rows}
    print(json.dumps(doc))


if __name__ == "__main__":
    main()
