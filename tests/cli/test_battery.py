"""The hostile-input battery: every registered command, source and log format against the classes of issue 31
(garbage, truncated, empty, wrong encoding, bad compression, wrong units, non-finite values, extreme options, an
output onto an input, Ctrl-C at the first write, a full disk), generated from the registries (tests/cli/battery.py).

A command or reader added to a registry is covered the day it is added: the coverage tests fail until it has a
working invocation (``battery.BASE``) or a small valid file (``SOURCE_FILES``). tests/cli/test_battery_planted.py
shows that each class fails on a planted defect.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rimu.io.formats import FORMATS, format_module
from rimu.io.registry import SOURCES, open_source

from . import battery as B

COMMANDS = sorted(B.subparsers())


def test_every_registered_command_has_a_working_invocation():
    from rimu.cli import COMMANDS as MODULES

    assert len(COMMANDS) == len(MODULES)
    missing = sorted(set(COMMANDS) - set(B.BASE))
    assert not missing, f"add a working invocation with every output to tests/cli/battery.BASE for {missing}"


# ------------------------------------------------------------------ input files: every class, every input
# (fixtures inp: the valid inputs, out: an empty output folder: tests/cli/conftest.py)
def _file_cases() -> list[tuple[str, str, str]]:
    cases = []
    for c in COMMANDS:
        names = [a.split("/")[-1] for a in B.BASE[c] if a.startswith("{in}/")]
        for name in names:
            for kind in B.FILE_CLASSES:
                cases.append((c, name, kind))
    return cases


@pytest.mark.parametrize("command,name,kind", _file_cases(), ids=["-".join(c) for c in _file_cases()])
def test_hostile_input_file(command, name, kind, inp, out, capsys):
    B.check_file_class(command, kind, inp / name, inp, out, capsys)


# ------------------------------------------------------------------ outputs aimed at inputs
@pytest.mark.parametrize("command", COMMANDS)
def test_no_output_overwrites_an_input(command, inp, out, capsys, monkeypatch):
    monkeypatch.chdir(inp)  # the relative spelling of each input
    n = B.check_onto_input(command, inp, out, capsys)
    has_inputs = any(a.startswith("{in}/") for a in B.BASE[command])
    assert n or not has_inputs


# ------------------------------------------------------------------ options
@pytest.mark.parametrize("command", COMMANDS)
def test_extreme_options(command, inp, out, capsys):
    """Non-finite values are refused while parsing, naming the option; the accepted extremes (the largest and the
    smallest each option takes) run all at once to a clean end or a refusal naming the option."""
    accepted = B.check_option_parsing(command, inp, out, capsys)
    big = B.check_extreme_options(command, accepted, inp, out, capsys, pick=lambda v: max(v, key=float))
    for flag in big:
        assert flag in accepted
    small = {f: [x for x in v if 0 < abs(float(x)) < 1e-300] for f, v in accepted.items()}
    small = {f: v for f, v in small.items() if v}
    if small:  # (the validators refuse subnormal values at parse time today)
        B.check_extreme_options(command, small, inp, out, capsys, pick=lambda v: v[0])


def test_export_c_compiles_at_the_extremes_it_accepts(inp, out, capsys):
    """export-c: the C written for the largest accepted value of every option, in float and in double, compiles
    (or the value is refused, naming the option)."""
    if not shutil.which("cc"):
        pytest.skip("no C compiler")
    accepted = B.check_option_parsing("export-c", inp, out, capsys)
    parser = B.subparsers()["export-c"]
    for real in ("float", "double"):
        target = out / real
        args = B.argv("export-c", inp, out)
        args = B._with_option(args, "--output", str(target), parser)
        args = B._with_option(args, "--real", real, parser)
        for flag, v in accepted.items():
            args = B._with_option(args, flag, max(v, key=float), parser)
        code, _, err = B.run(args, capsys)
        if code == 2:
            line = B.one_error(err, "export-c", args)
            assert any(f in line for f in accepted), line
            continue
        assert code == 0, err
        res = subprocess.run(["cc", "-std=c99", "-Wall", "-Werror=overflow", "-c", "rimu_unit.c", "-o", "u.o"],
                             cwd=target, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr[-2000:]


# ------------------------------------------------------------------ Ctrl-C and a full disk
@pytest.mark.parametrize("command", COMMANDS)
def test_ctrl_c_at_the_first_write(command, inp, out, capsys):
    B.check_ctrl_c(command, inp, out, capsys)


@pytest.fixture(scope="module")
def small_disk(tmp_path_factory):
    d = tmp_path_factory.mktemp("tmpfs")
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(d)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {res.stderr.decode().strip()}")
    yield d
    subprocess.run(["umount", str(d)], capture_output=True)


@pytest.mark.parametrize("command", COMMANDS)
def test_full_disk(command, inp, small_disk, capsys):
    out = small_disk / "out"
    shutil.rmtree(out, ignore_errors=True)
    (small_disk / ".filler").unlink(missing_ok=True)
    out.mkdir()
    B.fill(small_disk)
    try:
        B.check_full_disk(command, inp, out, capsys)
    finally:
        (small_disk / ".filler").unlink(missing_ok=True)
        shutil.rmtree(out, ignore_errors=True)


# ------------------------------------------------------------------ readers: every registered source and format
def _block():
    from rimu.io.fuzz import random_block

    return random_block(40)


def _csv(d: Path) -> Path:
    from rimu.io.recorded import write_csv

    return write_csv(d / "rec.csv", _block())


def _serial(d: Path) -> Path:
    from rimu.io.device import SerialDevice

    (d / "cap.bin").write_bytes(SerialDevice().stream(_block()))
    return d / "cap.bin"


def _can(d: Path) -> Path:
    import can

    from rimu.io.fuzz import layout_stream

    _b, msgs, _e, _k = layout_stream("cone6_rimu", 20)
    with can.Logger(str(d / "bus.asc")) as lg:
        for m in msgs:
            lg(m)
    return d / "bus.asc"


def _npz(d: Path) -> Path:
    from rimu.cli import main

    assert main(["simulate", "--duration", "1", "-o", str(d / "s.npz"), "-q"]) == 0
    return d / "s.npz"


def _triads(n: int = 300, k: int = 2, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    w = np.column_stack([np.sin(2 * t), np.cos(3 * t), 0.5 * np.sin(t)])
    cols = [t]
    for _ in range(k):
        cols += [w + 0.01 * rng.standard_normal(w.shape), [0, 0, 9.81] + 0.05 * rng.standard_normal(w.shape)]
    return np.column_stack(cols)


def _multi(d: Path) -> Path:
    data = _triads()
    head = "t," + ",".join(f"g{j}x,g{j}y,g{j}z,a{j}x,a{j}y,a{j}z" for j in range(2))
    np.savetxt(d / "multi.csv", data, delimiter=",", header=head, comments="", fmt="%.6f")
    return d / "multi.csv"


MULTI_MAPPING = {"time": "t", "imus": [{"name": f"imu{j}", "gyro": [f"g{j}{a}" for a in "xyz"],
                                        "accel": [f"a{j}{a}" for a in "xyz"]} for j in range(2)]}


def _pixhawk(d: Path) -> Path:
    data = _triads()
    temps = np.full((len(data), 2), 30.0)
    full = np.column_stack([data[:, :7], temps[:, 0], data[:, 7:], temps[:, 1]])
    cols = ["t_s"] + [f"imu0_{q}{a}" for q in "ga" for a in "xyz"] + ["imu0_tempC"] + \
        [f"imu1_{q}{a}" for q in "ga" for a in "xyz"] + ["imu1_tempC"]
    np.savetxt(d / "px.csv", full, delimiter=",", header=",".join(cols), comments="", fmt="%.6f")
    return d / "px.csv"


def _xsens(d: Path) -> Path:
    run = d / "run"
    run.mkdir()
    data = _triads(k=1)
    for k in (1, 2):
        full = np.column_stack([data[:, 0], np.zeros((len(data), 3)), data[:, 4:7], np.degrees(data[:, 1:4])])
        np.savetxt(run / f"IMU_{k}.csv", full, delimiter=",", comments="", fmt="%.6f",
                   header="time,Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z")
    return run / "IMU_2.csv"


def _mpu(d: Path) -> Path:
    rng = np.random.default_rng(0)
    counts = np.column_stack([rng.integers(-50, 50, (300, 2)), 16384 + rng.integers(-50, 50, 300),
                              rng.integers(-200, 200, (300, 3))])
    with (d / "mpu.csv").open("w") as fh:
        fh.write("Fs,100\nLogging Type,raw\nax,ay,az,gx,gy,gz\n")
        np.savetxt(fh, counts, fmt="%d", delimiter=",")
    return d / "mpu.csv"


def _mimu4444(d: Path) -> Path:
    from rimu.io.formats import mimu4444 as m

    rng = np.random.default_rng(0)
    counts = np.zeros((200, 8, 6), dtype=int)
    counts[:, :, 2] = 2048                                   # 1 g on every triad's z
    counts += rng.integers(-20, 20, counts.shape)
    (d / "board.bin").write_bytes(m.ACK + b"".join(m.encode_packet(k, k * 1_024_000, counts[k]) for k in range(200)))
    return d / "board.bin"


def _read(name: str) -> Callable[[Path], Any]:
    return lambda p: list(open_source(name, **_arg(name, p)))


def _arg(name: str, p: Path) -> dict[str, Any]:
    if name == "multi-imu-csv":
        return {"mapping": MULTI_MAPPING, "path": p}
    if name == "xsens-dot":
        return {"folder": p.parent}
    if name == "can-replay":
        return {"path": p, "layout": "cone6_rimu"}
    return {"path": p}


#: every file source: (writer of a small valid file, does garbage have to be refused (a text format) or may it be
#: read as nothing (a byte stream whose damaged frames are counted), compressed variants apply)
SOURCE_FILES: dict[str, tuple[Callable[[Path], Path] | None, bool, bool]] = {
    "csv": (_csv, True, False),
    "npz": (_npz, True, False),
    "serial-replay": (_serial, False, False),
    "can-replay": (_can, False, False),
    "ulog": (None, True, False),
    "multi-imu-csv": (_multi, True, True),
    "pixhawk-dual": (_pixhawk, True, True),
    "xsens-dot": (_xsens, True, True),
    "mpu6050-csv": (_mpu, True, True),
    "mimu4444-file": (_mimu4444, False, False),
}
#: live sources: a device or an object, no file (the serial transports are tested in tests/io/test_io_serial.py)
LIVE = {"can": "a CAN bus", "serial": "a serial port or pyserial URL", "block": "an EpochBlock in memory",
        "mimu4444": "the board's serial port (its file twin, mimu4444-file, is in SOURCE_FILES)"}


def test_every_registered_source_is_in_the_battery():
    missing = sorted(set(SOURCES) - set(SOURCE_FILES) - set(LIVE))
    assert not missing, f"add a small valid file for {missing} to SOURCE_FILES in tests/cli/test_battery.py"


@pytest.mark.parametrize("name", sorted(SOURCE_FILES))
def test_reader_hostile_files(name, tmp_path):
    make, strict, compressed = SOURCE_FILES[name]
    read = _read(name)
    d = tmp_path / "valid"
    d.mkdir()
    if make is None:  # no writer of this format here: garbage and emptiness only
        src = tmp_path / "x.ulg"
        src.write_bytes(b"ULog\x01\x12\x35\x01" + bytes(200))
        kinds = ["garbage", "empty", "truncated"]
    else:
        src = make(d)
        assert B.check_reader(read, src) == "ok"
        kinds = ["garbage", "truncated", "empty", "encoding", "nonfinite"]
    results = {}
    for kind in kinds:
        target = src.parent / f"{kind}-{src.name}" if name != "xsens-dot" else src
        keep = src.read_bytes()
        if not B.variant(kind, src if name != "xsens-dot" else _copy(src, tmp_path), target):
            continue
        try:
            results[kind] = B.check_reader(read, target)
        finally:
            if name == "xsens-dot":
                src.write_bytes(keep)
    if strict:
        assert results.get("garbage") == "refused" and results.get("empty") == "refused", results
    if compressed:
        for kind, p in B.gz_variants(src, tmp_path).items():
            if name == "xsens-dot":
                q = src.parent / ("IMU_2.csv.gz")
                shutil.copy(p, q)
                src.unlink()
                try:
                    assert B.check_reader(read, q) == "refused", kind
                finally:
                    q.unlink()
                    src.write_bytes(keep)
            else:
                assert B.check_reader(read, p) == "refused", kind


def _copy(src: Path, tmp: Path) -> Path:
    c = tmp / f"copy-{src.name}"
    shutil.copy(src, c)
    return c


def test_multi_imu_units_are_checked_per_imu(tmp_path):
    """One IMU of a multi-IMU file in deg/s declared rad/s, or in g declared m/s^2: refused, naming the IMU."""
    from rimu.errors import PlausibilityError
    from rimu.io.multiimu import read_multi_imu_csv

    src = _multi(tmp_path)
    data = np.loadtxt(src, delimiter=",", skiprows=1)
    head = src.read_text().splitlines()[0]
    for col, factor, word in ((slice(7, 10), 180 / np.pi, "deg/s"), (slice(10, 13), 1 / 9.80665, "g")):
        bad = data.copy()
        bad[:, col] *= factor
        p = tmp_path / f"bad-{word.replace('/', '')}.csv"
        np.savetxt(p, bad, delimiter=",", header=head, comments="", fmt="%.6f")
        with pytest.raises(PlausibilityError, match="imu1") as ei:
            read_multi_imu_csv(MULTI_MAPPING, p)
        assert word in str(ei.value) and p.name in str(ei.value)
    assert read_multi_imu_csv(MULTI_MAPPING, src).names == ["imu0", "imu1"]


def test_log_formats_hostile_files(tmp_path):
    """Every registered log format (none may be registered yet: the loop covers each one the day it is)."""
    for name in sorted(FORMATS):
        check_log_format(name, tmp_path / name)


def check_log_format(name: str, tmp_path: Path) -> None:
    tmp_path.mkdir(parents=True, exist_ok=True)
    mod = format_module(name)
    for kind, data in {"garbage": bytes(range(256)) * 16, "empty": b"", "encoding": "t,x\n1,2\n".encode("utf-16")
                       }.items():
        p = tmp_path / f"{kind}.log"
        p.write_bytes(data)
        assert mod.sniff(p.name, data[:512]) in (True, False)
        assert B.check_reader(mod.read, p) == "refused", kind
    for kind, p in B.gz_variants(tmp_path / "empty.log", tmp_path).items():
        assert B.check_reader(mod.read, p) == "refused", kind


def test_the_battery_json_counts(inp):
    """The fixture is what the base invocations need (a guard against a silently empty battery)."""
    assert {p.name for p in inp.iterdir()} >= {"s.npz", "cal.json", "raw.csv", "arr.npz"}
    assert len(_file_cases()) >= len(COMMANDS) * 4
    assert json.loads((inp / "cal.json").read_text())
    assert os.path.getsize(inp / "s.npz") > 1000


# ------------------------------------------------------------------ the issue's own examples, one by one
ISSUE_CASES = [
    (["noise", "{in}/s.npz", "--calibration", "{in}/cal.json", "-o", "{out}/n.json", "--terms", ""], "--terms"),
    (["noise", "{in}/s.npz", "-o", "{out}/n.json", "--write-calibration", "{out}/c.json"], "--write-calibration"),
    (["detect", "{in}/raw.csv", "-o", "{out}/d.npz", "--margin", "nan"], "--margin"),
    (["detect", "{in}/raw.csv", "-o", "{out}/d.npz", "--margin", "5"], "--margin"),
    (["detect", "{in}/raw.csv", "-o", "{out}/d.npz", "--gravity", "1e9"], "--gravity"),
    (["detect", "{in}/raw.csv", "-o", "{out}/d.npz", "--gyro", "ax,ay,az"], "serve as more than one"),
    (["export-c", "{in}/cal.json", "-o", "{out}/x", "--confirm", "99999999999999999999"], "--confirm"),
    (["array", "{in}/arr.npz", "--motion-threshold-deg-s", "1e9"], "--motion-threshold-deg-s"),
    (["array", "{in}/arr.npz", "--lowpass-hz", "1e6"], "--lowpass-hz"),
    # issue 27: a log of counts with a calibration of counts is read as counts; one of another unit is refused
    (["noise", "{in}/raw.csv", "--calibration", "{in}/cal.json", "-o", "{out}/n.json"], "calibrate this unit"),
    (["noise", "{in}/raw.csv", "--calibration", "{in}/nope.json", "-o", "{out}/n.json"], "nope.json"),
    (["calibrate", "{in}/s.npz", "-o", "{out}/c.json", "--report", "{out}/rep", "--reference", "{in}/raw.csv"],
     "raw.csv"),
    (["replay", "{in}/s.npz", "--calibration", "{in}/cal.json", "--report", "{in}/s.npz"], "--report"),
]


@pytest.mark.parametrize("args,word", ISSUE_CASES, ids=[" ".join(c[0][:1] + c[0][-2:]) for c in ISSUE_CASES])
def test_the_issue_examples_are_refused_by_name(args, word, inp, out, capsys):
    argv = [a.format(**{"in": inp, "out": out}) for a in args]
    code, o, err = B.run(argv, capsys)
    B.no_traceback(code, o, err, argv)
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert code == 2 and len(lines) == 1 and word in lines[0], err
    assert not list(out.iterdir()), "the refusal left output behind"


def test_monitor_json_beside_a_csv_recording_is_not_a_sidecar(inp, out, capsys):
    args = ["monitor", "--npz", f"{inp}/s.npz", "--calibration", f"{inp}/cal.json", "-o", f"{out}/rec.csv",
            "--json", f"{out}/rec.json", "-q"]
    code, _, err = B.run(args, capsys)
    assert code == 0, err
    assert json.loads((out / "rec.json").read_text())["epochs"] > 0
    B.whole(out / "rec.csv")


def test_xsens_dot_reads_a_relative_folder(tmp_path, monkeypatch):
    from rimu.io.xsens_dot import read_xsens_dot_run

    _xsens(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert read_xsens_dot_run("run").names == ["imu1", "imu2"]


def test_export_c_float_refuses_a_coefficient_beyond_the_float_range(inp, out, capsys):
    from rimu.calibration import Calibration

    cal = Calibration.load(inp / "cal.json")
    k = cal.instruments[0]
    cal[k].bias = cal[k].bias + 1e39
    cal.save(out / "big.json")
    code, _, err = B.run(["export-c", str(out / "big.json"), "-o", str(out / "c"), "--real", "float"], capsys)
    assert code == 2 and "C float" in err and not (out / "c").exists()
    code, _, err = B.run(["export-c", str(out / "big.json"), "-o", str(out / "d")], capsys)
    assert code == 0, err
