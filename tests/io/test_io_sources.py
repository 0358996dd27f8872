"""The source interface: registry, iterator / callback / asyncio styles, recorded files, reconnect policy."""

from __future__ import annotations

import asyncio
import threading
import uuid

import can
import numpy as np
import pytest

from rimu.epoch import EpochBlock
from rimu.errors import SessionFormatError, TransportError
from rimu.io import SOURCES, open_source, register_source, source_class
from rimu.io.accounting import Accounting, AccountingError
from rimu.io.can import CanSource, ReconnectPolicy
from rimu.io.device import BlockSource, CanDevice
from rimu.io.recorded import CsvSource, NpzSource, write_csv


def test_registry_is_lazy_and_extensible():
    import subprocess
    import sys

    code = ("import sys, rimu.io; print(sorted(m for m in ('rimu.io.ulog', 'pyulog', 'serial', 'can', 'cantools', "
            "'rimu.io.can', 'rimu.io.serial', 'rimu.sim') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=str(__import__("pathlib").Path(__file__).resolve().parents[2]))
    assert out.stdout.strip() == "[]", out.stderr       # importing rimu.io loads no transport
    assert source_class("serial").__name__ == "SerialSource"
    with pytest.raises(TransportError, match="no source named"):
        open_source("carrier-pigeon")
    register_source("my-block", "rimu.io.device:BlockSource")
    try:
        src = open_source("my-block", block=EpochBlock(np.zeros(2), {"gyro": np.ones((2, 3))}))
        assert len(list(src)) == 2
    finally:
        del SOURCES["my-block"]


def test_callback_and_asyncio_styles(cone6_block):
    got = []
    n = BlockSource(cone6_block).run(lambda ep: got.append(ep.t) or len(got) < 10)
    assert n == 10 and got == list(cone6_block.t[:10])

    async def main():
        out = []
        async for ep in BlockSource(cone6_block).aepochs():
            out.append(ep.t)
        return out

    assert asyncio.run(main()) == list(cone6_block.t)


def test_accounting_identity_check():
    a = Accounting("frame", received=3, accepted=2)
    with pytest.raises(AccountingError):
        a.check()
    a.reject("checksum")
    a.check()
    assert a.as_dict()["rejected"] == {"checksum": 1}


def test_csv_roundtrip_and_malformed_rows(tmp_path, cone6_block):
    valid = {"gyro": np.ones((len(cone6_block), 6), bool), "accel": np.ones((len(cone6_block), 6), bool)}
    valid["gyro"][3, 1] = False
    raw = {k: np.where(valid[k], y, 0.0) for k, y in cone6_block.raw.items()}
    b = EpochBlock(cone6_block.t, raw, valid, cone6_block.temperature)
    p = write_csv(tmp_path / "rec.csv", b)
    with open(p, "a") as fh:
        fh.write("1.0,2.0,3.0\n")                      # too few cells
        fh.write("x" + ",1" * 13 + "\n")               # non-numeric time
    src = CsvSource(p)
    back = src.read_block()
    np.testing.assert_array_equal(back.t, b.t)
    for k in ("gyro", "accel"):
        np.testing.assert_array_equal(back.raw[k], b.raw[k])      # repr() round-trips floats exactly
        np.testing.assert_array_equal(back.valid[k], valid[k])
    assert src.accounting.rejected == {"malformed": 2} and src.accounting.accepted == len(b)
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x\n")
    with pytest.raises(SessionFormatError, match="line 1"):
        list(CsvSource(bad))


def test_npz_of_rimu_simulate(tmp_path):
    from rimu.cli import main

    out = tmp_path / "s.npz"
    assert main(["simulate", "--procedure", "cho_park_table1", "-o", str(out), "--sample-rate", "20"]) == 0
    src = NpzSource(out)
    block = src.read_block()
    z = np.load(out)
    np.testing.assert_array_equal(block.raw["gyro"], z["raw_gyro"])
    assert NpzSource.meta(out)["sample_rate_hz"] == 20.0


class _ScriptedBus:
    """A bus that returns its script item by item; an exception in the script is raised (a bus error)."""

    def __init__(self, script):
        self.script = list(script)

    def recv(self, timeout=None):
        if not self.script:
            return None
        item = self.script.pop(0)
        if isinstance(item, BaseException):
            raise item
        return item

    def shutdown(self):
        pass


def test_reconnect_after_bus_error(cone6_block):
    msgs = CanDevice("cone6_rimu").frames(cone6_block)[:50]
    buses = [_ScriptedBus(msgs[:25] + [can.CanOperationError("bus off")]), _ScriptedBus(msgs[25:])]
    opened = []

    def factory():
        opened.append(1)
        return buses[len(opened) - 1]

    src = CanSource("cone6_rimu", bus_factory=factory, idle_timeout=0.2,
                    reconnect=ReconnectPolicy(max_attempts=3, backoff_s=0.001))
    eps = list(src)
    assert len(eps) == 10 and len(opened) == 2
    assert src.accounting.events["bus_error"] == 1 and src.accounting.events["reconnect"] == 1
    src.accounting.check()


def test_reconnect_gives_up_with_transport_error():
    class Dead:
        def recv(self, timeout=None):
            raise can.CanOperationError("bus off")

        def shutdown(self):
            pass

    def factory():
        raise can.CanInterfaceNotImplementedError("no such interface")

    src = CanSource("cone6_rimu", bus=Dead(), bus_factory=factory,
                    reconnect=ReconnectPolicy(max_attempts=2, backoff_s=0.001))
    with pytest.raises(TransportError, match="could not be reopened after 2 attempts"):
        list(src)
    assert src.accounting.events["reconnect_failed"] == 2


def test_bus_off_error_frame_triggers_reconnect(cone6_block):
    channel = f"rimu-busoff-{uuid.uuid4().hex}"
    opened = []

    def factory():
        opened.append(1)
        return can.Bus(interface="virtual", channel=channel)

    src = CanSource("cone6_rimu", bus_factory=factory, idle_timeout=0.3,
                    reconnect=ReconnectPolicy(max_attempts=2, backoff_s=0.001))
    src.open()
    tx = can.Bus(interface="virtual", channel=channel)
    tx.send(can.Message(is_error_frame=True, arbitration_id=0x040, data=bytes(8)))    # CAN_ERR_BUSOFF
    list(src)
    tx.shutdown()
    src.close()
    assert src.accounting.rejected == {"error_frame": 1} and src.accounting.events["bus_off"] == 1
    assert src.accounting.events["reconnect"] == 1 and len(opened) == 2


def test_stop_event_ends_a_live_source(cone6_block):
    src = CanSource("cone6_rimu", interface="virtual", channel=f"rimu-stop-{uuid.uuid4().hex}")
    timer = threading.Timer(0.2, src.stop)
    timer.start()
    assert list(src) == []
    src.close()


def test_io_never_imports_sim():
    """Import rule: nothing in rimu/io imports rimu.sim (the simulated device takes a block from the caller)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "rimu" / "io"
    for f in root.glob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                mod = ("." * node.level) + (node.module or "")
                assert not mod.startswith("..sim") and not mod.startswith("rimu.sim"), (f.name, mod)
            elif isinstance(node, ast.Import):
                assert not any(a.name.startswith("rimu.sim") for a in node.names), f.name
