"""Property: every log reader either reads a log into finite samples on increasing time stamps, or ends in one of
rimu's errors whose message names the file and says what to do, printable (never binary text); through
``rimu import`` never a traceback. Mutations: truncation, garbage spliced in, bytes flipped, time stamps put out of
order, units that are not SI, one IMU stopping halfway. Derandomized, bounded examples."""

from __future__ import annotations

import functools
import gzip
import os
import struct
import tempfile
import uuid
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rimu.cli import main
from rimu.errors import RimuError
from rimu.io.formats import read_log
from rimu.io.formats._synth import write_dataflash
from tests.io.test_formats import _ulog_bytes, _ulog_combined_bytes

pytest.importorskip("pymavlink")

SETTINGS = settings(max_examples=int(os.environ.get("RIMU_FUZZ_EXAMPLES", "25")), deadline=None,
                    derandomize=not os.environ.get("RIMU_FUZZ_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])

MPU = "Fs,100\nLogging Type,1\nInitialization time,-1\nWaiting time,-1\nax,ay,az,gx,gy,gz\n" + "".join(
    f"{12 * k % 50},{-30 + k % 7},{16384 + k % 11},{k % 5},{-3 + k % 3},{2}\n" for k in range(300))
PIXHAWK = "t_s," + ",".join(f"imu{i}_{q}" for i in (0, 1) for q in ("gx", "gy", "gz", "ax", "ay", "az", "tempC")) + \
    "\n" + "".join(f"{0.012 * k:.3f}," + ",".join(["0.01", "-0.02", "0.0", "0.1", "0.2", "-9.8", "35"] * 2) + "\n"
                   for k in range(300))


@functools.lru_cache(maxsize=1)
def _valid() -> dict[str, tuple[str, bytes]]:
    d = Path(tempfile.mkdtemp(prefix="rimu-logfuzz-"))
    write_dataflash(d / "a.bin", 3, 200.0, 1.5)
    write_dataflash(d / "b.bin", 2, 100.0, 1.0, old_names=True)
    write_dataflash(d / "c.bin", 2, 100.0, 1.0, time_ms=True)
    write_dataflash(d / "m.bin", 2, 100.0, 1.0, gyro_mult="C")
    write_dataflash(d / "r.bin", 2, 100.0, 0.5, raw_rate_hz=400.0)
    out = {"dataflash": (".bin", (d / "a.bin").read_bytes()), "dataflash-old": (".bin", (d / "b.bin").read_bytes()),
           "dataflash-timems": (".bin", (d / "c.bin").read_bytes()),
           "dataflash-mult": (".bin", (d / "m.bin").read_bytes()),
           "dataflash-raw": (".bin", (d / "r.bin").read_bytes()),
           "ulog": (".ulg", _ulog_bytes(2, 120, 100.0)), "mpu6050": (".csv", MPU.encode()),
           "ulog-combined": (".ulg", _ulog_combined_bytes([10_000 + 4000 * k for k in range(300)])),
           "pixhawk": (".csv", PIXHAWK.encode()), "text": (".txt", b"t ax ay az\n" + b"".join(
               b"%g 0 0 1\n" % (k / 100) for k in range(100)))}
    try:  # a bare MCAP file (ROS 2 Imu messages, rosbags' writer; the .mcap without its metadata.yaml)
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        from tests.io.test_formats import _ros_msg

        store = get_typestore(Stores.ROS2_HUMBLE)
        with Writer(d / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
            c = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
            for k in range(200):
                w.write(c, int((5 + k / 100) * 1e9), store.serialize_cdr(_ros_msg(store, 5 + k / 100, 0.01),
                                                                         "sensor_msgs/msg/Imu"))
        out["mcap"] = (".mcap", (d / "bag" / "bag.mcap").read_bytes())
    except ImportError:
        pass
    return out


def _check(path: Path, capsys) -> None:
    """The property, through the library and through the command line."""
    try:
        rec = read_log(path, **({"accel_unit": "g"} if path.suffix == ".txt" else {}))
    except RimuError as exc:
        msg = str(exc)
        assert msg.isprintable(), msg
        assert path.name in msg, msg
    except ImportError:
        pytest.skip("a format library is missing")
    else:
        for u in rec.units:
            assert np.all(np.diff(u.t) > 0)
            assert np.all(np.isfinite(u.t))
    code = main(["import", str(path), "-o", str(path.with_suffix(".out.npz"))]
                + (["--accel-unit", "g"] if path.suffix == ".txt" else []))
    err = capsys.readouterr().err
    assert code in (0, 2), err
    assert "Traceback" not in err and "internal error" not in err, err
    assert err.isprintable() or all(ln.isprintable() for ln in err.splitlines()), err
    if code == 2:
        assert path.name in err and "error:" in err, err


def _write(tmp: Path, suffix: str, data: bytes, compress: bool) -> Path:
    p = tmp / f"f{uuid.uuid4().hex[:8]}{suffix}" if not compress else tmp / f"f{uuid.uuid4().hex[:8]}{suffix}.gz"
    p.write_bytes(gzip.compress(data) if compress else data)
    return p


@SETTINGS
@given(data=st.data())
def test_byte_mutations(tmp_path, capsys, data):
    kind = data.draw(st.sampled_from(sorted(_valid())))
    suffix, good = _valid()[kind]
    n = len(good)
    op = data.draw(st.sampled_from(["truncate", "garbage", "flip", "head", "empty"]))
    a = data.draw(st.integers(0, n))
    if op == "truncate":
        bad = good[:a]
    elif op == "garbage":
        bad = good[:a] + data.draw(st.binary(min_size=1, max_size=64)) + good[a:]
    elif op == "flip":
        k = data.draw(st.integers(1, 16))
        arr = bytearray(good)
        for j in data.draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=k)):
            arr[j] ^= data.draw(st.integers(1, 255))
        bad = bytes(arr)
    elif op == "head":
        bad = data.draw(st.binary(min_size=1, max_size=32)) + good[a:]
    else:
        bad = b""
    _check(_write(tmp_path, suffix, bad, data.draw(st.booleans())), capsys)


@SETTINGS
@given(data=st.data())
def test_time_out_of_order_and_one_imu_stopping(tmp_path, capsys, data):
    """DataFlash records re-stamped out of order, or one IMU's records cut from some point on."""
    _, good = _valid()["dataflash"]
    arr = bytearray(good)
    starts = [i for i in range(len(arr) - 2) if arr[i] == 0xA3 and arr[i + 1] == 0x95 and arr[i + 2] == 64]
    op = data.draw(st.sampled_from(["restamp", "stop"]))
    if op == "restamp":
        for i in data.draw(st.lists(st.sampled_from(starts), min_size=1, max_size=20)):
            arr[i + 3:i + 11] = struct.pack("<Q", data.draw(st.integers(0, 2_000_000)))
        p = _write(tmp_path, ".bin", bytes(arr), False)
        rec = read_log(p)
        assert sum(sum(r.values()) for r in rec.meta["rejected"].values()) >= 0
        _check(p, capsys)
    else:
        stop_at = data.draw(st.integers(0, len(starts) - 1))
        imu = data.draw(st.integers(0, 2))
        keep = bytearray()
        last = 0
        for i in starts[stop_at:]:
            if arr[i + 11] == imu:  # the instance byte after TimeUS
                keep += arr[last:i]
                last = i + 54
        keep += arr[last:]
        p = _write(tmp_path, ".bin", bytes(keep), False)
        rec = read_log(p)
        counts = {u.name: len(u) for u in rec.units}
        assert all(v == 300 for k, v in counts.items() if k != f"imu{imu}")
        _check(p, capsys)


def test_wrong_units_refused_at_the_door(tmp_path, capsys):
    """Gyros logged in deg/s under a rad/s declaration, accelerometers in g under m/s^2: refused, the unit named."""
    def deg(t, i):
        g = np.tile([30.0, -20.0, 10.0], (len(t), 1)) * (1 + np.sin(t))[:, None] * 60  # deg/s values
        return g, np.tile([0.0, 0.0, 9.80665], (len(t), 1))

    def in_g(t, i):
        return np.zeros((len(t), 3)), np.tile([0.0, 0.0, 1.0], (len(t), 1))

    for name, sig, unit in (("deg.bin", deg, "deg/s"), ("g.bin", in_g, "g")):
        write_dataflash(tmp_path / name, 2, 100.0, 3.0, sig, units=False)
        assert main(["import", str(tmp_path / name), "-o", str(tmp_path / "x.npz")]) == 2
        err = capsys.readouterr().err
        assert name in err and unit in err and "Traceback" not in err, err
        assert not (tmp_path / "x.npz").exists()
