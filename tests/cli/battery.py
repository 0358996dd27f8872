"""The hostile-input battery's machinery (tests/cli/test_battery.py runs it; tests/cli/test_battery_planted.py shows
it fails on a planted defect of each class).

Everything is generated from the registries: the commands of :data:`rimu.cli.COMMANDS` (their options read from the
parser), the sources of :data:`rimu.io.registry.SOURCES` and the log formats of :data:`rimu.io.formats.FORMATS`.
What a registry cannot say is one table entry per command or source: a working invocation (:data:`BASE`) or a
small valid file (:data:`SOURCE_FILES`); a test fails until a new command or source has one.

Each ``check_*`` function raises ``AssertionError`` with what went wrong; the rules are the issue's: bad input ends
in exit status 2 with one line ``rimu CMD: error: ...`` that names the file or the option, never a traceback or
exit 3; afterwards the output folder holds nothing of the run and every input is byte for byte what it was.
"""

from __future__ import annotations

import argparse
import contextlib
import gzip
import hashlib
import io
import json
import math
import os
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from rimu.cli import build_parser, main
from rimu.cli._common import output_options

# ------------------------------------------------------------------ the commands
#: a working invocation of every registered command, with every output it can write ({in} the inputs folder,
#: {out} the output folder; inputs are files of :func:`make_inputs`)
BASE: dict[str, list[str]] = {
    "demo": ["--report", "{out}/rep", "--json", "{out}/d.json", "-o", "{out}/cal.json"],
    "simulate": ["--duration", "1", "-o", "{out}/s.npz", "--truth", "{out}/t.json"],
    "calibrate": ["{in}/s.npz", "-o", "{out}/c.json", "--report", "{out}/rep", "--json", "{out}/j.json"],
    "design": ["--report", "{out}/rep", "--json", "{out}/j.json"],
    "diagnose": ["{in}/s.npz", "--report", "{out}/rep", "--json", "{out}/j.json"],
    "monitor": ["--npz", "{in}/s.npz", "--calibration", "{in}/cal.json", "-o", "{out}/rec.csv", "--json",
                "{out}/j.json"],
    "replay": ["{in}/s.npz", "--calibration", "{in}/cal.json", "-o", "{out}/rep", "--json", "{out}/j.json",
               "--estimates", "{out}/e.csv"],
    "campaign": ["--workers", "0", "--repetitions", "1", "--sizes", "6", "--duration", "1", "--fault-start", "0.5",
                 "--json", "{out}/j.json", "--report", "{out}/rep"],
    "check": ["{in}/s.npz", "--calibration", "{in}/cal.json", "--report", "{out}/rep", "--json", "{out}/j.json"],
    "export-c": ["{in}/cal.json", "-o", "{out}/exp"],
    "detect": ["{in}/raw.csv", "-o", "{out}/det.npz", "--report", "{out}/rep", "--json", "{out}/j.json"],
    "array": ["{in}/arr.npz", "-o", "{out}/fit.json", "--report", "{out}/rep", "--json", "{out}/j.json"],
    "noise": ["{in}/s.npz", "--calibration", "{in}/cal.json", "-o", "{out}/noise.json", "--report", "{out}/rep",
              "--json", "{out}/j.json", "--write-calibration", "{out}/cn.json"],
    "import": ["{in}/px.csv", "-o", "{out}/rec.npz", "--json", "{out}/i.json"],
    "selfcal": ["{in}/s.npz", "--calibration", "{in}/cal.json", "-o", "{out}/cal2.json", "--json", "{out}/j.json",
                "--report", "{out}/rep", "--bias-rw", "1e-12"],
    "setup": ["{in}/px.csv", "-o", "{out}/cal.json", "--session", "{out}/unit.npz", "--json", "{out}/s.json"],
    "apply": ["{in}/px.csv", "--calibration", "{in}/px-cal.json", "-o", "{out}/ap.npz", "--json", "{out}/a.json"],
}


def subparsers() -> dict[str, argparse.ArgumentParser]:
    """Every registered command's parser, by its command-line name."""
    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def make_inputs(d: Path) -> None:
    """The valid input files of :data:`BASE`: a simulated session ``s.npz`` and its calibration ``cal.json``, a
    raw hand-held log ``raw.csv`` (counts), an array recording ``arr.npz`` (rad/s, m/s^2)."""
    from rimu.sim.array import random_array_truth, simulate_array
    from rimu.sim.handheld import handheld_run

    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", "--duration", "1", "-o", str(d / "s.npz"), "-q"]) == 0
        assert main(["calibrate", str(d / "s.npz"), "-o", str(d / "cal.json"), "-q"]) == 0
    run = handheld_run(n_poses=8, static_s=1.5, initial_still_s=2.0, seed=5)
    data = np.column_stack([np.arange(len(run.t)), run.raw["accel"], run.raw["gyro"]])
    with (d / "raw.csv").open("w") as fh:
        fh.write("Fs,100\nn,ax,ay,az,gx,gy,gz\n")
        np.savetxt(fh, data, fmt="%d", delimiter=",")
    from rimu.array import ArrayLayout

    lay = ArrayLayout.planar_grid(2, 2, pitch_m=0.012)
    rec = simulate_array(random_array_truth(lay, seed=6, centre_gyro_common_mode=True), duration_s=1.0, seed=6)
    np.savez(d / "arr.npz", t=rec.t, gyro=rec.gyro, accel=rec.accel, rotations=lay.rotations,
             positions_m=lay.positions_m)
    # a two-IMU autopilot log (the Pixhawk extraction's columns) and the calibration `rimu setup` makes of it
    rng = np.random.default_rng(0)
    t = np.arange(600) / 100.0
    w = np.column_stack([np.sin(2 * t), np.cos(3 * t), 0.5 * np.sin(t)])
    parts = [t]
    for _ in range(2):
        parts += [w + 0.01 * rng.standard_normal(w.shape), [0, 0, 9.81] + 0.05 * rng.standard_normal(w.shape),
                  np.full(len(t), 30.0)]
    cols = ["t_s"] + [f"imu{k}_{q}" for k in (0, 1) for q in ("gx", "gy", "gz", "ax", "ay", "az", "tempC")]
    np.savetxt(d / "px.csv", np.column_stack(parts), delimiter=",", header=",".join(cols), comments="", fmt="%.6f")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["setup", str(d / "px.csv"), "-o", str(d / "px-cal.json"), "-q"]) == 0


def argv(command: str, inp: Path, out: Path, base: list[str] | None = None) -> list[str]:
    return [command, *[a.format(**{"in": inp, "out": out}) for a in (BASE[command] if base is None else base)], "-q"]


def input_files(args: list[str], inp: Path) -> list[Path]:
    """The input files an invocation names."""
    return [Path(a) for a in args if a.startswith(str(inp)) and Path(a).is_file()]


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------ variants of a valid file
def _npz_with(path: Path, target: Path, change: Callable[[dict[str, np.ndarray]], None]) -> None:
    z = dict(np.load(path, allow_pickle=False))
    change(z)
    np.savez(target, **z)


def _nan_npz(z: dict[str, np.ndarray]) -> None:
    key = next(k for k in ("raw_gyro", "gyro") if k in z)
    y = np.array(z[key], dtype=float)
    y.reshape(len(y), -1)[len(y) // 2, 0] = np.nan
    z[key] = y


def _deg_npz(z: dict[str, np.ndarray]) -> None:
    if "gyro" in z:  # an array recording in rad/s: the values of deg/s under the rad/s label
        z["gyro"] = z["gyro"] * 180.0 / math.pi
    else:  # a session in counts: its sidecar declares the accelerometers' raw unit as g
        meta = json.loads(str(z["meta"]))
        z["meta"] = np.array(json.dumps(dict(meta, raw_unit={"accel": "g"})))


def _nan_text(text: str) -> str:
    lines = text.splitlines(keepends=True)
    k = len(lines) // 2
    cells = lines[k].split(",")
    cells[-1] = "nan\n"
    return "".join(lines[:k] + [",".join(cells)] + lines[k + 1:])


def _nan_json(text: str) -> str:
    doc = json.loads(text)

    def first(o: Any) -> bool:
        if isinstance(o, dict):
            return any(first(v) for v in o.values())
        if isinstance(o, list):
            for i, v in enumerate(o):
                if isinstance(v, float):
                    o[i] = math.nan
                    return True
                if first(v):
                    return True
        return False

    first(doc.get("instruments", doc))
    return json.dumps(doc)


#: class -> (file -> variant written to target; None where the class does not apply to the file's kind)
def variant(kind: str, src: Path, target: Path) -> bool:
    """Write the ``kind`` variant of ``src`` to ``target``; False where it does not apply."""
    data = src.read_bytes()
    if kind == "garbage":
        target.write_bytes(bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8)) + b"\x80\xff")
    elif kind == "truncated":
        target.write_bytes(data[: len(data) // 2])
    elif kind == "empty":
        target.write_bytes(b"")
    elif kind == "encoding":
        if src.suffix not in (".csv", ".json"):
            return False
        target.write_bytes(data.decode("utf-8").encode("utf-16"))
    elif kind == "nonfinite":
        if src.suffix not in (".npz", ".json", ".csv"):
            return False
        if src.suffix == ".npz":
            _npz_with(src, target, _nan_npz)
        elif src.suffix == ".json":
            target.write_text(_nan_json(data.decode()))
        else:
            target.write_text(_nan_text(data.decode()))
    elif kind == "units":
        if src.suffix != ".npz":
            return False
        _npz_with(src, target, _deg_npz)
    else:
        raise ValueError(kind)
    return True


FILE_CLASSES = ("garbage", "truncated", "empty", "encoding", "nonfinite", "units")
#: commands that do not read the unit label the "units" variant of a session changes (its values stay what they
#: were), with the reason
UNIT_LABEL_NOT_READ = {c: "streams the raw values through the calibration, whose raw unit applies; the values are "
                         "unchanged, so the result is right (a label contradicting the calibration's raw unit is not "
                         "yet flagged)" for c in ("monitor", "selfcal")}


# ------------------------------------------------------------------ running and the rules
def run(args: list[str], capsys: Any) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def no_traceback(code: int, out: str, err: str, args: list[str]) -> None:
    assert "Traceback" not in out + err and code != 3, (args, code, err[-2000:])


def one_error(err: str, command: str, args: list[str]) -> str:
    lines = [ln for ln in err.splitlines() if ": error:" in ln]
    assert len(lines) == 1, (args, err[-2000:])
    assert lines[0].startswith(f"rimu {command}: error:"), (args, err[-2000:])
    return lines[0]


def nothing_left(out: Path, before: dict[str, str], args: list[str]) -> None:
    left = sorted(str(p.relative_to(out)) for p in out.rglob("*") if str(p.relative_to(out)) not in before)
    assert not left, (args, "left behind", left)


def check_refused_or_ok(command: str, args: list[str], names: list[str], inp: Path, out: Path, capsys: Any,
                        ok: tuple[int, ...] = (0, 1), warn: str | None = None) -> int:
    """Exit 2 with one error line naming one of ``names`` and nothing left in ``out``, or an exit status in
    ``ok`` (with a warning line containing ``warn`` where given). Inputs never change, never a traceback."""
    before_in, before_out = digest(inp), digest(out)
    code, o, err = run(args, capsys)
    no_traceback(code, o, err, args)
    assert digest(inp) == before_in, (args, "an input changed")
    if code == 2:
        line = one_error(err, command, args)
        assert any(n in line for n in names), (args, names, line)
        nothing_left(out, before_out, args)
    else:
        assert code in ok, (args, code, err[-2000:])
        if warn is not None:
            assert any(warn in ln.lower() for ln in err.splitlines() if "warning" in ln), (args, err[-2000:])
    return code


def check_file_class(command: str, kind: str, src: Path, inp: Path, out: Path, capsys: Any) -> int | None:
    """``command`` with its input ``src`` replaced by the ``kind`` variant (None: not applicable)."""
    bad = inp / "bad" / f"{kind}-{src.name}"
    bad.parent.mkdir(exist_ok=True)
    if kind == "units" and src.name == "s.npz" and command in UNIT_LABEL_NOT_READ:
        return None
    if not variant(kind, src, bad):
        return None
    args = [bad.as_posix() if a == str(src) else a for a in argv(command, inp, out)]
    if kind == "garbage" or kind == "empty" or (kind == "truncated" and src.suffix == ".npz"):
        ok: tuple[int, ...] = ()  # must be refused
    else:  # truncated text may end on a whole line; NaN may be an invalid sample; units may be flagged
        ok = (0, 1)
    warn = "unit" if kind == "units" else None
    return check_refused_or_ok(command, args, [bad.name], inp, out, capsys, ok, warn)


def check_onto_input(command: str, inp: Path, out: Path, capsys: Any) -> int:
    """Every output option of ``command`` aimed at each of its inputs (the path itself, a symlink to it, a relative
    path to it) is refused before any work; returns the number of cases."""
    parser = subparsers()[command]
    base = argv(command, inp, out)
    ns = parser.parse_args(base[1:-1])
    files, dirs = output_options(ns)
    flags = {a.dest: a.option_strings[-1] for a in parser._actions if a.option_strings}
    n = 0
    for src in input_files(base, inp):
        link = out / f"link-{src.name}"
        with contextlib.suppress(FileExistsError):
            link.symlink_to(src)
        for dest in files + dirs:
            if dest not in flags:
                continue
            for target in (str(src), str(link), os.path.relpath(src)):
                args = _with_option(base, flags[dest], target, parser)
                before_in = digest(inp)
                code, o, err = run(args, capsys)
                no_traceback(code, o, err, args)
                line = one_error(err, command, args)
                assert code == 2 and (flags[dest] in line or "--output" in line), (args, line)
                assert digest(inp) == before_in, (args, "an input changed")
                n += 1
        link.unlink()
    return n


def _with_option(base: list[str], flag: str, value: str, parser: argparse.ArgumentParser) -> list[str]:
    short = {a.option_strings[-1]: a.option_strings for a in parser._actions if a.option_strings}
    names = set(short.get(flag, [flag]))
    out, skip = [], False
    for a in base:
        if skip:
            skip = False
            continue
        if a in names:
            skip = True
            continue
        out.append(a)
    return [*out[:-1], flag, value, out[-1]]


# ------------------------------------------------------------------ options
NUMERIC_TYPES = {float, int}
#: values a hostile user types into a numeric option
HOSTILE = ["nan", "inf", "-inf", "1e400", "-1e308", "0", "-1", "99999999999999999999", "1e-320", "",
           # and the edges of what the validators accept (rimu.cli._common): each must run or be refused by name
           "2147483647", "1e12", "-1e12", "1e-12", "1e-15", "0.5"]


def numeric_options(command: str) -> list[argparse.Action]:
    from rimu.cli import _common

    validators = {getattr(_common, n) for n in ("positive_float", "finite_float", "nonnegative_float", "probability",
                                                "positive_int", "nonnegative_int")}
    return [a for a in subparsers()[command]._actions
            if a.option_strings and (a.type in NUMERIC_TYPES or a.type in validators) and not a.choices]


def check_option_parsing(command: str, inp: Path, out: Path, capsys: Any) -> dict[str, list[str]]:
    """Every numeric option refuses non-finite values at once, naming itself; returns the hostile values each
    accepts (run by :func:`check_extreme_options`)."""
    parser = subparsers()[command]
    base = argv(command, inp, out)
    accepted: dict[str, list[str]] = {}
    for a in numeric_options(command):
        flag = a.option_strings[-1]
        for v in HOSTILE:
            try:
                with contextlib.redirect_stderr(io.StringIO()) as e:
                    parser.parse_args([*base[1:-1], flag, v])
            except SystemExit:
                line = e.getvalue().strip()
                assert len(line.splitlines()) == 1 and flag in line, (command, flag, v, line)
                continue
            value = float(v)
            assert math.isfinite(value), f"rimu {command} {flag} accepts the non-finite value {v!r}"
            accepted.setdefault(flag, []).append(v)
    return accepted


#: commands whose working run is long (s): their extreme options run up to the first write of an output, where
#: they are interrupted (what the options do before any output is written is what can crash or hang)
LONG_RUNS = {"demo": 9.0}


def check_extreme_options(command: str, accepted: dict[str, list[str]], inp: Path, out: Path, capsys: Any,
                          pick: Callable[[list[str]], str]) -> list[str]:
    """Run ``command`` with the picked accepted extreme value of every numeric option at once; an option the
    command refuses (exit 2, its name in the line) is dropped and the rest run again. Never a traceback, never
    exit 3, never a leftover. Returns the options refused at run time."""
    ok = (130,) if command in LONG_RUNS else (0, 1)
    parser = subparsers()[command]
    values = {flag: pick(v) for flag, v in accepted.items()}
    refused = []
    while True:
        args = argv(command, inp, out)
        for flag, v in values.items():
            args = _with_option(args, flag, v, parser)
        before = digest(out)
        with memory_limit(), (trap().armed(out, KeyboardInterrupt()) if command in LONG_RUNS
                              else contextlib.nullcontext()):
            code, o, err = run(args, capsys)
        no_traceback(code, o, err, args)
        if code != 2:
            assert code in ok, (args, code, err[-2000:])
            return refused
        line = one_error(err, command, args)
        named = [f for f in values if f in line]
        assert named, ("the refusal names no option", args, line)
        nothing_left(out, before, args)
        for f in named:
            del values[f]
        refused += named


@contextlib.contextmanager
def memory_limit(extra: int = 1 << 30) -> Iterator[None]:
    """At most ``extra`` bytes more address space while the block runs (an extreme option that asks for the
    memory of the machine fails with MemoryError instead of taking the machine down)."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with open("/proc/self/statm") as fh:
        used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (used + extra, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


# ------------------------------------------------------------------ interruptions and a full disk
class _Trap:
    """An audit hook that delivers ``exc`` just after the first file under ``folder`` is opened for writing: at the
    next audited event of the main thread (the next open, mkdir, chmod or rename), so that the first output
    exists, partly written, when the interruption comes."""

    def __init__(self) -> None:
        self.folder: str | None = None
        self.exc: BaseException | None = None
        self.fired: list[str] = []
        self.due = False

    def __call__(self, event: str, args: tuple) -> None:
        if self.folder is None or threading.current_thread() is not threading.main_thread():
            return
        if self.due:
            self.due, self.folder = False, None
            assert self.exc is not None
            raise self.exc
        if event != "open":
            return
        path, mode, flags = args
        if not isinstance(path, (str, bytes, os.PathLike)):
            return
        writing = any(c in mode for c in "wax+") if isinstance(mode, str) else bool(
            (flags or 0) & (os.O_WRONLY | os.O_RDWR | os.O_CREAT))
        p = os.path.abspath(os.fsdecode(path))
        if writing and p.startswith(self.folder):
            self.fired.append(p)
            self.due = True

    @contextlib.contextmanager
    def armed(self, folder: Path, exc: BaseException) -> Iterator[list[str]]:
        self.folder, self.exc, self.fired, self.due = str(folder.resolve()) + os.sep, exc, [], False
        try:
            yield self.fired
        finally:
            self.folder, self.due = None, False


_TRAP: _Trap | None = None


def trap() -> _Trap:
    global _TRAP
    if _TRAP is None:
        _TRAP = _Trap()
        sys.addaudithook(_TRAP)
    return _TRAP


#: commands for which Ctrl-C is the normal end (a live recording): the outputs are then written whole
CTRL_C_ENDS = {"monitor": "Ctrl-C ends a live recording; the epochs received so far are the recording"}


def whole(p: Path) -> None:
    """An output file that parses to its end."""
    if p.suffix == ".json":
        json.loads(p.read_text())
    elif p.suffix == ".csv":
        from rimu.io.recorded import CsvSource

        src = CsvSource(p)
        list(src)
        assert src.accounting.as_dict()["rejected_total"] == 0, (p, src.accounting.as_dict())


def check_ctrl_c(command: str, inp: Path, out: Path, capsys: Any) -> None:
    """KeyboardInterrupt just after the first output file is opened for writing: exit 130, the 'no partial output'
    line only when true, nothing of the run in ``out``, inputs unchanged (or, where Ctrl-C is the normal end, the
    outputs whole and no temporary left)."""
    args = argv(command, inp, out)
    before_in, before_out = digest(inp), digest(out)
    with trap().armed(out, KeyboardInterrupt()) as fired:
        code, o, err = run(args, capsys)
    assert fired, (args, "the command wrote nothing", code, err[-1000:])
    no_traceback(code, o, err, args)
    if command in CTRL_C_ENDS:
        assert code in (0, 1), (args, code, err[-2000:])
        files = [p for p in out.rglob("*") if p.is_file()]
        assert not [p for p in files if p.name.startswith(".")], (args, "temporaries left", files)
        for p in files:
            whole(p)
        return
    assert code == 130, (args, code, err[-2000:])
    assert err.strip().endswith(f"rimu {command}: interrupted; no partial output file was left behind"), err
    nothing_left(out, before_out, args)
    assert digest(inp) == before_in


def check_full_disk(command: str, inp: Path, out: Path, capsys: Any) -> None:
    """The output folder on a full disk: exit 2, one line naming the file and the cause, nothing left."""
    args = argv(command, inp, out)
    before_in, before_out = digest(inp), digest(out)
    code, o, err = run(args, capsys)
    no_traceback(code, o, err, args)
    line = one_error(err, command, args)
    assert code == 2 and "No space left on device" in line and str(out) in line, (args, line)
    nothing_left(out, before_out, args)
    assert digest(inp) == before_in


def fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last byte."""
    fd = os.open(folder / ".filler", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    try:
        for size in (1 << 16, 4096, 1):
            with contextlib.suppress(OSError):
                while os.write(fd, b"\0" * size):
                    pass
    finally:
        os.close(fd)


# ------------------------------------------------------------------ readers
def check_reader(open_and_read: Callable[[Path], Any], path: Path) -> str:
    """Reading ``path`` ends well or in a rimu error that names the file; returns "ok" or "refused"."""
    from rimu.errors import RimuError

    try:
        open_and_read(path)
    except RimuError as exc:
        assert path.name in str(exc), (path, str(exc))
        return "refused"
    except Exception as exc:
        raise AssertionError(f"{path.name}: {type(exc).__name__}: {exc} (not a rimu error)") from exc
    return "ok"


def gz_variants(src: Path, d: Path) -> dict[str, Path]:
    """Compressed-file variants: bad compression (not gzip), a truncated stream, garbage inside a good stream."""
    raw = src.read_bytes()
    good = gzip.compress(raw)
    out = {}
    for name, data in {"badgz": b"\x1f\x8b\x08 not really gzip" * 10, "truncgz": good[: len(good) // 2],
                       "garbagegz": gzip.compress(bytes(range(256)) * 8)}.items():
        p = d / f"{name}-{src.name}.gz"
        p.write_bytes(data)
        out[name] = p
    return out
