"""Record a simulated unit to a python-can log, damage it, and replay it through rimu as one block.

    python examples/can_replay_log.py [out-folder]

Writes ``run.blf`` (cone6_rimu layout), drops one frame and duplicates another, replays it with
CanReplaySource.read_block (vectorised decoding and assembly), runs the block through the pipeline and prints
the accounting: every frame is accounted for, the sample that lost a frame has those three sensors invalid.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import can
import numpy as np

from rimu.fusion import Pipeline
from rimu.io import CanDevice, CanReplaySource
from rimu.sim import Simulator, rotation


def main(folder: Path) -> None:
    run = Simulator(seed=1).run([rotation("spin", [0.0, 0.0, np.radians(45.0)], duration=10.0)])
    frames = CanDevice("cone6_rimu").frames(run.block)
    frames = frames[:502] + frames[503:3000] + [frames[2999]] + frames[3000:]   # one lost, one repeated
    path = folder / "run.blf"
    with can.Logger(str(path)) as log:
        for m in frames:
            log.on_message_received(m)
    src = CanReplaySource(path, "cone6_rimu")
    block = src.read_block()
    res = Pipeline(run.truth).process(block)
    bad = np.flatnonzero(~block.valid["gyro"].all(axis=1))
    print(f"{len(block)} epochs from {path.name}; {src.accounting.summary()}")
    print(f"epochs with an invalid gyro: {bad.tolist()} (sensors {np.flatnonzero(~block.valid['gyro'][bad[0]]).tolist()})")
    err = res["gyro"].x - run.truth_inputs["gyro"]
    print(f"gyro estimate error rms: {np.degrees(err.std(axis=0)).round(4).tolist()} deg/s")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as d:
            main(Path(d))
