"""Use a DBC file as a rimu layout (cantools, extra ``dbc``).

    python examples/can_dbc_layout.py

Exports the shipped automotive layout (modelled on the Bosch MM7.10 CAN layout) as DBC text, reads it back with
Layout.from_dbc and a small role mapping, and decodes frames from the simulated device with both.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from rimu.epoch import EpochBlock
from rimu.io import CanDevice, CanReplaySource, Layout, load_layout


def main() -> None:
    shipped = load_layout("mm7_automotive")
    with tempfile.TemporaryDirectory() as d:
        dbc = Path(d) / "mm7.dbc"
        dbc.write_text(shipped.to_cantools().as_dbc_string())
        roles = {"YawRate": {"role": "sample", "instrument": "gyro", "index": 2},
                 "RollRate": {"role": "sample", "instrument": "gyro", "index": 0},
                 "PitchRate": {"role": "sample", "instrument": "gyro", "index": 1},
                 "AY": {"role": "sample", "instrument": "accel", "index": 1},
                 "AX": {"role": "sample", "instrument": "accel", "index": 0},
                 "AZ": {"role": "sample", "instrument": "accel", "index": 2},
                 "MM7_TX1_MSG_CNT_TX1": {"role": "counter"}, "MM7_TX2_MSG_CNT_TX2": {"role": "counter"},
                 "MM7_TX3_MSG_CNT_TX3": {"role": "counter"}}
        checks = {m.name: m.checksum for m in shipped.messages}   # a DBC does not say how its CRC is computed
        layout = Layout.from_dbc(dbc, roles, sample_rate_hz=100.0, checksums=checks)
        print(f"from DBC: {[m.name for m in layout.messages]}, instruments {layout.instruments}")
        t = np.arange(200) / 100.0
        block = EpochBlock(t, {"gyro": np.column_stack([np.sin(t), np.cos(t), 0 * t]) * 30,
                               "accel": np.column_stack([0 * t, 0 * t, 1 + 0 * t])})
        log = Path(d) / "mm7.asc"
        CanDevice(shipped).write_log(log, block)
        for lay in (shipped, layout):
            src = CanReplaySource(log, lay)
            got = src.read_block()
            print(f"{lay.name:16s} {len(got)} epochs, max |gyro - sent| = "
                  f"{np.abs(got.raw['gyro'] - block.raw['gyro']).max():.4f} deg/s (resolution 0.005); "
                  f"{src.accounting.summary()}")


if __name__ == "__main__":
    main()
