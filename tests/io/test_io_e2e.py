"""End to end on python-can's virtual bus: simulated cone6 stream with a gyro fault at t = 10 s -> CAN frames ->
CanSource -> the unit's runtime (rimu.fdi.Runtime: GLT detection, the set test, confirmation, isolation)."""

from __future__ import annotations

import uuid

import can
import numpy as np
from scipy.stats import ncx2

from rimu.epoch import EpochBlock
from rimu.fdi import FdiSettings, Runtime, glt_snapshot
from rimu.fusion import Pipeline
from rimu.io import CanDevice, CanSource
from rimu.sim import Simulator, rotation

T_FAULT = 10.0
FAULTY = 4          # gyro y2
CONFIRM = 5
P_FA = 1e-3


def _step_fault(sim, truth):
    def fault(block: EpochBlock) -> EpochBlock:
        raw = {k: y.copy() for k, y in block.raw.items()}
        size = 10.0 * sim.noise_sigma("gyro")                        # 10 sigma, SI
        raw["gyro"][block.t >= T_FAULT, FAULTY] += size / truth["gyro"].scale[FAULTY]   # in raw counts
        return EpochBlock(block.t, raw, dict(block.valid), block.temperature, dict(block.meta))
    return fault


def test_virtual_can_fault_detected_and_isolated():
    sim = Simulator(seed=3)
    run = sim.run([rotation("manoeuvre", [0.0, np.radians(30.0), 0.0], duration=20.0)])
    truth = run.truth
    dev = CanDevice("cone6_rimu", fault=_step_fault(sim, truth))
    expected = dev.expected(run.block)
    channel = f"rimu-e2e-{uuid.uuid4().hex}"
    rx = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    tx = can.Bus(interface="virtual", channel=channel)
    # sent as fast as possible: frame times are wall-clock, so the epoch time window is widened to 1 s lest a
    # scheduler stall of the sending thread look like a late frame (the counter window still closes epochs)
    src = CanSource("cone6_rimu", bus=rx, idle_timeout=10.0, timeout=1.0)   # ends at N epochs
    sender = dev.start(tx, run.block)                               # as fast as possible, in a thread
    pipe = Pipeline(truth)
    rt = Runtime(pipe, FdiSettings(p_fa=P_FA, confirm=CONFIRM))   # the runtime of rimu monitor and rimu replay
    events, epochs = [], []
    try:
        for ep in src:
            epochs.append(ep)
            rt.step(ep)
            if len(epochs) == len(run.block):
                break
    finally:
        sender.join(5)
        src.close()
        tx.shutdown()

    # every epoch arrived, in order, with the simulated values to the layout's resolution
    N = len(run.block)
    assert len(epochs) == N
    acc = src.accounting
    acc.check()
    assert acc.received == acc.accepted == 5 * N and acc.rejected_total == 0
    Y = np.array([e.raw["gyro"] for e in epochs])
    A = np.array([e.raw["accel"] for e in epochs])
    t = np.array([e.t for e in epochs])
    assert np.array_equal(Y, expected["gyro"]) and np.array_equal(A, expected["accel"])
    faulted = dev.fault(run.block)
    assert np.abs(Y - faulted.raw["gyro"]).max() <= (1 / 32) / 2 + 1e-12        # gyro resolution 1/32 count
    assert np.abs(A - faulted.raw["accel"]).max() <= 1.0 / 2 + 1e-12            # accel resolution 1 count
    assert np.abs(t - run.block.t).max() <= 5e-6                               # time resolution 10 us

    # the fault: one isolation, the right sensor, with the delay the test's power predicts
    ip = pipe["gyro"]
    full = ip.table.lookup(ip.table.full_code)
    b = 10.0 * sim.noise_sigma("gyro")
    lam = float(np.sum((b * ip.table.Vz[full][:, FAULTY]) ** 2))               # non-centrality of p^T p
    thr = glt_snapshot(np.zeros(3), ip.table.Vz[full], 3, P_FA).threshold
    p_detect = ncx2.sf(thr, 3, lam)
    assert p_detect > 0.999       # so CONFIRM detections in a row happen with probability > 0.995
    events = [(k, pipe[k].calibration.geometry.index(e.sensor), e.t) for k, e in rt.events if e.kind == "isolated"]
    assert [(k, i) for k, i, _ in events] == [("gyro", FAULTY)]
    delay = events[0][2] - T_FAULT
    dt = 1.0 / sim.sample_rate
    # no faster than CONFIRM alarms, and within 0.1 s (the set test names y2 once the episode's evidence is
    # consistent); the same sample as the runtime on the received epochs as a block (rimu replay's path)
    assert (CONFIRM - 1) * dt - 1e-9 <= delay < 0.1
    ref = Runtime(Pipeline(truth), FdiSettings(p_fa=P_FA, confirm=CONFIRM)).run(
        EpochBlock(t, {"gyro": Y, "accel": A}))
    assert [(e.sensor, e.t) for e in ref["gyro"].events if e.kind == "isolated"] == [("y2", events[0][2])]
    assert rt.managers["gyro"].isolated.tolist() == [False] * 4 + [True, False]
