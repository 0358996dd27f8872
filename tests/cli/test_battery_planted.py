"""The battery can fail: for each class of tests/cli/test_battery.py, a defect of that class is planted (the
guard or check that prevents it is taken away, or a reader made to crash on it) and the battery's check of that
class must raise ``AssertionError``; with the defect removed the same check passes."""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from . import battery as B


def _fails(check, *args) -> None:
    with pytest.raises(AssertionError):
        check(*args)


def _raw_load(path, what="array file"):  # the loader without its guard: numpy's own exceptions escape
    z = np.load(path, allow_pickle=False)
    return {k: z[k] for k in z.files} if hasattr(z, "files") else z


@pytest.mark.parametrize("kind", ["garbage", "truncated", "empty"])
def test_planted_unguarded_npz_loader(kind, inp, out, capsys, monkeypatch):
    B.check_file_class("array", kind, inp / "arr.npz", inp, out, capsys)  # passes as shipped
    monkeypatch.setattr("rimu.io.guard.load_array", _raw_load)
    _fails(B.check_file_class, "array", kind, inp / "arr.npz", inp, out, capsys)


def test_planted_crash_on_nan(inp, out, capsys, monkeypatch):
    import rimu.array as array

    real = array.array_report

    def crashes_on_nan(layout, t, gyro, *a, **k):
        if not np.all(np.isfinite(gyro)):
            return int(float("nan"))  # ValueError: cannot convert float NaN to integer
        return real(layout, t, gyro, *a, **k)

    B.check_file_class("array", "nonfinite", inp / "arr.npz", inp, out, capsys)
    monkeypatch.setattr(array, "array_report", crashes_on_nan)
    monkeypatch.setattr("rimu.array.ArrayLayout", array.ArrayLayout)
    monkeypatch.setattr("rimu.array.report.array_report", crashes_on_nan, raising=False)
    _fails(B.check_file_class, "array", "nonfinite", inp / "arr.npz", inp, out, capsys)


def test_planted_missing_unit_check(inp, out, capsys, monkeypatch):
    B.check_file_class("array", "units", inp / "arr.npz", inp, out, capsys)
    monkeypatch.setattr("rimu.array.guards.check_units", lambda *a, **k: [])
    monkeypatch.setattr("rimu.cli.array._check_options", lambda *a: None)
    _fails(B.check_file_class, "array", "units", inp / "arr.npz", inp, out, capsys)


def test_planted_unvalidated_option(inp, out, capsys, monkeypatch):
    B.check_option_parsing("detect", inp, out, capsys)
    monkeypatch.setattr("rimu.cli.detect.nonnegative_float", float)  # --margin as it was: nan accepted
    _fails(B.check_option_parsing, "detect", inp, out, capsys)


def test_planted_extreme_value_crash(inp, out, capsys, monkeypatch):
    accepted = B.check_option_parsing("export-c", inp, out, capsys)
    B.check_extreme_options("export-c", accepted, inp, out, capsys, pick=lambda v: max(v, key=float))
    import rimu.export.c_fdi as c_fdi

    real = c_fdi.FdiSettings.__post_init__ if hasattr(c_fdi.FdiSettings, "__post_init__") else None

    def overflow(self):
        if real is not None:
            real(self)
        if self.confirm > 10**6:
            raise OverflowError("int too large to convert to C int")

    monkeypatch.setattr(c_fdi.FdiSettings, "__post_init__", overflow)
    _fails(B.check_extreme_options, "export-c", accepted, inp, out, capsys, lambda v: max(v, key=float))


def test_planted_missing_input_protection(inp, out, capsys, monkeypatch):
    monkeypatch.chdir(inp)
    B.check_onto_input("detect", inp, out, capsys)
    work = out / "work"
    work.mkdir()
    shutil.copy(inp / "raw.csv", work / "raw.csv")
    monkeypatch.setattr("rimu.cli._common._inputs", lambda *a, **k: [])
    _fails(B.check_onto_input, "detect", work, out, capsys)


@contextlib.contextmanager
def _no_undo(monkeypatch):
    import rimu.atomic as atomic

    monkeypatch.setattr(atomic, "_remove", lambda paths: [])
    yield


def test_planted_ctrl_c_leftovers(inp, out, capsys, monkeypatch):
    B.check_ctrl_c("array", inp, out, capsys)
    with _no_undo(monkeypatch):
        _fails(B.check_ctrl_c, "array", inp, out, capsys)


def test_planted_reader_exceptions(tmp_path, monkeypatch):
    """A reader whose decoding errors escape: the encoding and compression classes of the reader battery fail."""
    from rimu.io.registry import open_source

    from .test_battery import MULTI_MAPPING, _multi

    src = _multi(tmp_path)
    bad = tmp_path / "utf16.csv"
    assert B.variant("encoding", src, bad)

    def read(p: Path):
        return list(open_source("multi-imu-csv", mapping=MULTI_MAPPING, path=p))

    assert B.check_reader(read, bad) == "refused"
    gz = B.gz_variants(src, tmp_path)["badgz"]
    assert B.check_reader(read, gz) == "refused"
    monkeypatch.setattr("rimu.io.multiimu.reading", lambda *a, **k: contextlib.nullcontext())
    _fails(B.check_reader, read, bad)
    _fails(B.check_reader, read, gz)


def test_planted_log_format_escaping_errors(tmp_path, monkeypatch):
    """A log format registered the day it is added is covered: one that lets UnicodeDecodeError escape fails."""
    import sys
    import types

    from rimu.io import formats

    from .test_battery import check_log_format

    mod = types.ModuleType("planted_format")
    mod.NAME, mod.EXTRA = "planted", None
    mod.sniff = lambda name, head: False
    mod.read = lambda path, **kw: Path(path).read_text(encoding="utf-8")
    monkeypatch.setitem(sys.modules, "planted_format", mod)
    monkeypatch.setitem(formats.FORMATS, "planted", "planted_format")
    _fails(check_log_format, "planted", tmp_path)


def test_planted_full_disk_message(inp, small_disk_or_skip, capsys, monkeypatch):
    out = small_disk_or_skip
    B.check_full_disk("simulate", inp, out, capsys)
    monkeypatch.setattr("rimu.atomic.OutputGroup.folders", lambda self: [])
    _fails(B.check_full_disk, "simulate", inp, out, capsys)


@pytest.fixture
def small_disk_or_skip(tmp_path):
    import subprocess

    d = tmp_path / "tmpfs"
    d.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(d)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {res.stderr.decode().strip()}")
    (d / "out").mkdir()
    B.fill(d)
    yield d / "out"
    subprocess.run(["umount", str(d)], capture_output=True)
