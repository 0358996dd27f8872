"""rimu.io benchmarks: CAN decoding vs cantools on the same frames (python-can messages, and candump log text),
serial decoding in MB/s, long fuzz runs.

    python benchmarks/io.py            # full sizes (about a minute)
    python benchmarks/io.py --quick    # smaller sizes

Prints a table and one JSON line. Reference timed in the same run: cantools ``Database.decode_message``, frame by
frame, on the very frames rimu decodes (the shipped layouts exported with ``Layout.to_cantools()``). Also timed:
the floor of any python-can Message path (a Python loop reading ``arbitration_id``, ``data`` and ``timestamp`` of
every message, nothing else), against which the Message figures are put ("floors").
"""

from __future__ import annotations

import os

os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # pinned in the script

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import median_time as timeit

from rimu.epoch import EpochBlock
from rimu.io import fuzz
from rimu.io.accounting import Accounting
from rimu.io.can import CanFrameProcessor, CanReplaySource, items_to_block
from rimu.io.device import CanDevice, SerialDevice
from rimu.io.layout import load_layout
from rimu.io.serial import CobsDecoder, SerialDecoder


def bench_can(layout, n_frames, repeat):
    K = len(load_layout(layout).messages)
    block, msgs, _exp, K = fuzz.layout_stream(layout, n_frames // K)
    N = len(msgs)
    db = load_layout(layout).to_cantools()
    proc = CanFrameProcessor(layout, Accounting())
    codec = proc.codec

    def rimu_decode():
        codec.decode_messages(msgs)

    def rimu_replay():          # frames -> EpochBlock (what CanReplaySource.read_block does after LogReader)
        p = CanFrameProcessor(layout, Accounting())
        items = []
        for i in range(0, N, 8192):
            items += p.process_items(msgs[i:i + 8192])
        items += p.flush()
        items_to_block(items, p.codec.other_names)

    def rimu_epochs():          # frames -> Epoch objects (iterating a replay source)
        p = CanFrameProcessor(layout, Accounting())
        for i in range(0, N, 8192):
            p.process(msgs[i:i + 8192])
        p.flush()

    sub = msgs[: min(N, 20000)]

    def rimu_per_frame():
        p = CanFrameProcessor(layout, Accounting())
        for m in sub:
            p.process([m])
        p.flush()

    def cantools_decode():
        dec = db.decode_message
        for m in msgs:
            dec(m.arbitration_id, m.data)

    def read_floor():           # the least any Message path does: read id, data and time of every Message
        for m in msgs:
            m.arbitration_id, m.data, m.timestamp  # noqa: B018

    # the same frames as a candump .log: rimu reads its text (rimu.io.canlog, no python-can message per frame)
    import can

    logdir = tempfile.TemporaryDirectory()
    log_path = Path(logdir.name) / "run.log"
    with can.Logger(str(log_path)) as lg:
        for m in msgs:
            lg.on_message_received(m)
    log_bytes = log_path.read_bytes()

    def rimu_log_decode():      # log text -> decoded signals (what cantools does from frames)
        from rimu.io.canlog import parse_candump

        for i in range(0, len(log_bytes), 1 << 21):
            j = log_bytes.rfind(b"\n", 0, i + (1 << 21)) + 1
            fr = parse_candump(log_bytes[i:j] if j > i else log_bytes[i:])
            codec.decode(fr.ids, fr.data, fr.dlc, fr.ext)

    def rimu_log_replay():      # log file -> EpochBlock (decode, checks, assembly), CanReplaySource.read_block
        CanReplaySource(log_path, layout).read_block()

    def logreader_cantools():   # the python-can route for a log file: can.LogReader + cantools
        dec = db.decode_message
        for m in can.LogReader(str(log_path)):
            dec(m.arbitration_id, m.data)

    # interleaved: each repeat times rimu and cantools back to back, so that both see the same machine load;
    # the ratios are medians of the per-repeat ratios
    rows = []
    for _ in range(repeat):
        rows.append((timeit(rimu_decode, 1), timeit(rimu_replay, 1), timeit(rimu_epochs, 1), timeit(cantools_decode, 1),
                     timeit(rimu_log_decode, 1), timeit(rimu_log_replay, 1), timeit(logreader_cantools, 1),
                     timeit(read_floor, 1)))
    t_dec, t_rep, t_eps, t_ct, t_ld, t_lr, t_lrc, t_floor = (statistics.median(c) for c in zip(*rows))
    r_floor = statistics.median(r[3] / r[7] for r in rows)          # the most any Message path could reach
    dec_floor = statistics.median(r[0] / r[7] for r in rows)        # rimu's Message decode in units of the floor
    r_dec = statistics.median(r[3] / r[0] for r in rows)
    r_rep = statistics.median(r[3] / r[1] for r in rows)
    r_eps = statistics.median(r[3] / r[2] for r in rows)
    r_log_dec = statistics.median(r[3] / r[4] for r in rows)
    r_log_rep = statistics.median(r[3] / r[5] for r in rows)
    r_log_e2e = statistics.median(r[6] / r[5] for r in rows)
    logdir.cleanup()
    t_pf = timeit(rimu_per_frame, 1)
    # a real log through can.LogReader (BLF) and the whole replay source
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "run.blf"
        CanDevice(layout).write_log(path, block)
        import can

        t_read = timeit(lambda: sum(1 for _ in can.LogReader(str(path))), 1)
        t_src = timeit(lambda: CanReplaySource(path, layout).read_block(), 1)
    return {"layout": layout, "frames": N,
            "rimu_log_decode_fps": N / t_ld, "rimu_log_replay_fps": N / t_lr, "logreader_cantools_fps": N / t_lrc,
            "ratio_log_decode": r_log_dec, "ratio_log_replay": r_log_rep, "ratio_log_vs_logreader_cantools": r_log_e2e,
            "rimu_decode_fps": N / t_dec, "rimu_replay_fps": N / t_rep, "rimu_epochs_fps": N / t_eps,
            "rimu_per_frame_fps": len(sub) / t_pf,
            "cantools_fps": N / t_ct, "ratio_decode": r_dec, "ratio_replay": r_rep,
            "read_floor_fps": N / t_floor, "ratio_read_floor": r_floor, "decode_over_read_floor": dec_floor,
            "replay_over_read_floor": statistics.median(r[1] / r[7] for r in rows),
            "ratio_epochs": r_eps, "ratio_per_frame": (len(sub) / t_pf) / (N / t_ct),
            "logreader_blf_fps": N / t_read, "replay_source_blf_fps": N / t_src}


def bench_serial(n_bytes, repeat):
    rng = np.random.default_rng(1)
    n = n_bytes // 74
    block = EpochBlock(np.arange(n) / 100.0, {"gyro": rng.normal(0, 100, (n, 6)), "accel": rng.normal(0, 1e4, (n, 6))},
                       temperature=np.full(n, 20.0))
    frames = SerialDevice().frames(block)
    clean = b"".join(frames)
    damaged, _ = fuzz.mutate_serial(frames, fuzz.draw_actions(rng, n, fuzz.SERIAL_ACTIONS), rng)

    def run(data, block=False, decoder=SerialDecoder):
        """Decode ``data`` in 64 KiB chunks, epoch by epoch or (``block``) into blocks."""
        def f():
            dec = decoder()
            feed, flush = (dec.feed_block, dec.flush_block) if block else (dec.feed, dec.flush)
            for i in range(0, len(data), 65536):
                feed(data[i:i + 65536])
            flush()
        return f

    t_block = timeit(run(clean, block=True), repeat)
    t_block_dam = timeit(run(damaged, block=True), repeat)
    t_clean = timeit(run(clean), repeat)
    t_dam = timeit(run(damaged), repeat)
    cobs = b"".join(SerialDevice(framing="cobs").frames(block))

    t_cobs = timeit(run(cobs, decoder=CobsDecoder), repeat)
    return {"bytes": len(clean), "frame_bytes": len(frames[0]), "clean_MBps": len(clean) / t_clean / 1e6,
            "clean_frames_per_s": n / t_clean, "damaged_MBps": len(damaged) / t_dam / 1e6,
            "cobs_MBps": len(cobs) / t_cobs / 1e6, "cobs_frames_per_s": n / t_cobs,
            "block_clean_MBps": len(clean) / t_block / 1e6, "block_damaged_MBps": len(damaged) / t_block_dam / 1e6,
            "block_over_epochs": t_clean / t_block}


def fuzz_can(layout, n_frames, seed=2024):
    K = len(load_layout(layout).messages)
    _block, msgs, exp, K = fuzz.layout_stream(layout, n_frames // K, seed=1)
    rng = np.random.default_rng(seed)
    bad, oracle = fuzz.mutate_can(msgs, K, fuzz.draw_actions(rng, len(msgs), fuzz.CAN_ACTIONS), rng)
    p = CanFrameProcessor(layout, Accounting())
    t0 = time.perf_counter()
    eps = fuzz.process_chunks(p, bad, 4096)
    dt = time.perf_counter() - t0
    rep = fuzz.check_can(eps, p.acc, oracle, exp, layout)
    return {"layout": layout, "mutated_frames_in": rep["frames"], "accepted": rep["accepted"],
            "rejected": dict(p.acc.rejected), "epochs": rep["epochs"], "intact_recovered": len(oracle.intact),
            "oracle_check": "pass", "s": dt}


def fuzz_serial(n_bytes, seed=99):
    n = n_bytes // 74
    block = fuzz.random_block(n, seed=3)
    rng = np.random.default_rng(seed)
    data, oracle = fuzz.mutate_serial(SerialDevice().frames(block), fuzz.draw_actions(rng, n, fuzz.SERIAL_ACTIONS), rng)
    cuts = np.unique(np.concatenate([[0, len(data)], rng.integers(0, len(data), len(data) // 500)])).tolist()
    dec = SerialDecoder()
    eps = fuzz.decode_pieces(dec, fuzz.pieces(data, cuts))
    rep = fuzz.check_serial(eps, dec.accounting, oracle, block)
    return {"mutated_bytes_in": rep["bytes"], "accepted_bytes": rep["accepted"],
            "rejected": dict(dec.accounting.rejected), "epochs": rep["epochs"], "intact_frames": len(oracle.intact),
            "oracle_check": "pass"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    n_frames = 50_000 if args.quick else 200_000
    repeat = 3 if args.quick else 5
    out = {"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}}
    out["can"] = [bench_can(L, n_frames, repeat) for L in ("cone6_rimu", "mm7_automotive")]
    out["serial"] = bench_serial(250_000 if args.quick else 1_000_000, repeat)
    out["fuzz_can"] = [fuzz_can(L, 20_000 if args.quick else 100_000) for L in ("cone6_rimu", "mm7_automotive")]
    out["fuzz_serial"] = fuzz_serial(200_000 if args.quick else 1_000_000)

    print("CAN decoding, frames/s (medians; the same python-can frames for rimu and cantools, timed back to back")
    print("  in each repeat; ratios are medians of the per-repeat ratios)")
    print("  decode: signals of every frame (numpy); replay: frames -> EpochBlock (decode, checks, assembly);")
    print("  epochs: frames -> Epoch objects; per-frame: live path, one frame per call; x = speed-up on cantools")
    print(f"{'layout':15s} {'frames':>7s} {'decode':>8s} {'replay':>8s} {'epochs':>8s} {'per-frm':>8s} "
          f"{'cantools':>8s} {'x dec':>6s} {'x repl':>6s} {'x eps':>6s} {'LogRdr':>7s} {'BLF src':>7s}")
    for r in out["can"]:
        print(f"{r['layout']:15s} {r['frames']:7d} {r['rimu_decode_fps']:8.0f} {r['rimu_replay_fps']:8.0f} "
              f"{r['rimu_epochs_fps']:8.0f} {r['rimu_per_frame_fps']:8.0f} {r['cantools_fps']:8.0f} "
              f"{r['ratio_decode']:6.1f} {r['ratio_replay']:6.1f} {r['ratio_epochs']:6.1f} "
              f"{r['logreader_blf_fps']:7.0f} {r['replay_source_blf_fps']:7.0f}")
    print("\nCAN logs (candump .log text read by rimu.io.canlog), frames/s; x = speed-up on cantools decoding the frames")
    print("  (already python-can messages in memory); log decode: text -> signals; log replay: file -> EpochBlock;")
    print("  LR+ct: the python-can route for the file (can.LogReader, then cantools per frame)")
    print(f"{'layout':15s} {'frames':>7s} {'log dec':>8s} {'log repl':>8s} {'cantools':>8s} {'LR+ct':>8s} "
          f"{'x dec':>6s} {'x repl':>6s} {'x LR+ct':>7s}")
    for r in out["can"]:
        print(f"{r['layout']:15s} {r['frames']:7d} {r['rimu_log_decode_fps']:8.0f} {r['rimu_log_replay_fps']:8.0f} "
              f"{r['cantools_fps']:8.0f} {r['logreader_cantools_fps']:8.0f} {r['ratio_log_decode']:6.1f} "
              f"{r['ratio_log_replay']:6.1f} {r['ratio_log_vs_logreader_cantools']:7.1f}")
    print("\nthe python-can Message path's floor: reading arbitration_id, data and timestamp of every Message (a Python")
    print("  loop, nothing else); x floor = what cantools would be over it; decode, replay = rimu's times in floors")
    print(f"{'layout':15s} {'floor':>8s} {'x floor':>7s} {'decode':>7s} {'replay':>7s}")
    for r in out["can"]:
        print(f"{r['layout']:15s} {r['read_floor_fps']:8.0f} {r['ratio_read_floor']:7.1f} "
              f"{r['decode_over_read_floor']:7.1f} {r['replay_over_read_floor']:7.1f}")
    s = out["serial"]
    print(f"\nserial decoding: {s['clean_MBps']:.1f} MB/s clean ({s['clean_frames_per_s']:.0f} frames/s of "
          f"{s['frame_bytes']} bytes), {s['damaged_MBps']:.1f} MB/s with ~20% of frames damaged; "
          f"COBS variant {s['cobs_MBps']:.1f} MB/s ({s['cobs_frames_per_s']:.0f} frames/s)")
    print(f"serial block decoding (feed_block, one EpochBlock per chunk, target >= 30 MB/s): "
          f"{s['block_clean_MBps']:.1f} MB/s clean ({s['block_over_epochs']:.1f}x the Epoch path), "
          f"{s['block_damaged_MBps']:.1f} MB/s damaged")
    print("\nfuzzing (exact oracle: intact frames recovered with exact values, counts per reason)")
    for r in out["fuzz_can"]:
        print(f"  CAN {r['layout']:15s} {r['mutated_frames_in']:7d} frames in, {r['accepted']} accepted, "
              f"rejected {r['rejected']}, {r['epochs']} epochs: {r['oracle_check']}")
    r = out["fuzz_serial"]
    print(f"  serial {r['mutated_bytes_in']} bytes in, {r['accepted_bytes']} accepted, rejected {r['rejected']}, "
          f"{r['epochs']} epochs: {r['oracle_check']}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
