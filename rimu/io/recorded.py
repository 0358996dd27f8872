"""Recorded epochs: rimu's CSV recording format and the NPZ files of ``rimu simulate``.

CSV (written by :class:`CsvRecorder`, e.g. ``rimu monitor --record``)::

    # rimu epochs v1
    t,temperature,gyro[0],...,gyro[n-1],accel[0],...,accel[m-1]
    0.000000000,25.0,499.125,...

An empty cell is an invalid sensor (or, for temperature, none sent). Rows are counted: a malformed row (wrong
number of cells, non-numeric or non-finite value) is rejected with reason ``malformed`` and skipped, never
guessed at.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..epoch import INSTRUMENTS, Epoch, EpochBlock
from ..errors import SessionFormatError, TransportError
from .base import Source
from .guard import reading

__all__ = ["CsvRecorder", "CsvSource", "NpzSource", "write_csv"]

CSV_MAGIC = "# rimu epochs v1"


class CsvRecorder:
    """Appends epochs to a CSV file as they come (call :meth:`close`, or use as a context manager).

    The rows go to a temporary file beside ``path`` that :meth:`close` moves over ``path`` (rimu.atomic): the
    recording appears whole; an exception inside the ``with`` block discards it (:meth:`abort`).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from ..atomic import AtomicFiles

        self.path = Path(path)
        self._tx = AtomicFiles()
        self._fh: TextIO = open(self._tx.path(self.path), "w", newline="", encoding="utf-8")
        self._w = csv.writer(self._fh)
        self._sizes: dict[str, int] | None = None
        self.rows = 0

    def write(self, ep: Epoch) -> None:
        if self._sizes is None:
            self._sizes = {k: len(ep.raw[k]) for k in INSTRUMENTS if k in ep.raw}
            self._fh.write(CSV_MAGIC + "\n")
            self._w.writerow(["t", "temperature"] + [f"{k}[{i}]" for k, n in self._sizes.items() for i in range(n)])
        row = [repr(float(ep.t)), "" if ep.temperature is None else repr(float(ep.temperature))]
        for k in self._sizes:
            v = ep.valid_mask(k)
            row += [repr(float(y)) if ok else "" for y, ok in zip(ep.raw[k], v)]
        self._w.writerow(row)
        self.rows += 1

    def close(self) -> None:
        """Finish the recording: the file appears under its name (no epoch written: no file, an empty file is
        not a recording)."""
        if self.rows == 0:
            self.abort()
            return
        if not self._fh.closed:
            self._fh.close()
            self._tx.commit()

    def abort(self) -> None:
        """Discard the recording (the temporary file is removed, ``path`` is untouched)."""
        if not self._fh.closed:
            self._fh.close()
        self._tx.abort()

    def __enter__(self) -> CsvRecorder:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_csv(path: str | os.PathLike[str], block: EpochBlock) -> Path:
    """Write a block in the CSV format (round-trips exactly through :class:`CsvSource`)."""
    with CsvRecorder(path) as rec:
        for ep in block.epochs():
            rec.write(ep)
    return Path(path)


class _FileSource(Source):
    """A source reading one file, which must exist."""

    what = "file"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__()
        self.path = Path(path)
        if not self.path.exists():
            raise TransportError(f"no {self.what} at {self.path}")


class CsvSource(_FileSource):
    """Epochs from a CSV recording (see the module docstring)."""

    unit = "row"
    what = "CSV recording"

    def _epochs(self) -> Iterator[Epoch]:
        acc = self.accounting
        with reading(self.path, "CSV text"), open(self.path, newline="", encoding="utf-8") as fh:
            first = fh.readline().strip()
            if first != CSV_MAGIC:
                raise SessionFormatError(f"{self.path}: line 1 must be {CSV_MAGIC!r}, got {first[:40]!r}")
            rd = csv.reader(fh)
            try:
                header = next(rd)
            except StopIteration:
                raise SessionFormatError(f"{self.path}: no header line") from None
            if header[:2] != ["t", "temperature"]:
                raise SessionFormatError(f"{self.path}: line 2 must start with t,temperature")
            cols: dict[str, list[int]] = {}
            for j, name in enumerate(header[2:], start=2):
                inst = name.split("[")[0]
                if inst not in INSTRUMENTS:
                    raise SessionFormatError(f"{self.path}: line 2, column {j + 1}: unknown instrument {name!r}")
                cols.setdefault(inst, []).append(j)
            for lineno, row in enumerate(rd, start=3):
                if self.stop_event.is_set():
                    break
                acc.received += 1
                ep = self._row(row, len(header), cols)
                if ep is None:
                    acc.reject("malformed", 1, ",".join(row).encode(), None, line=lineno)
                    continue
                yield self._accepted(ep, "row", lineno)

    @staticmethod
    def _row(row: list[str], width: int, cols: dict[str, list[int]]) -> Epoch | None:
        if len(row) != width:
            return None
        try:
            t = float(row[0])
            temp = float(row[1]) if row[1] != "" else None
            raw, valid = {}, {}
            for k, js in cols.items():
                v = np.array([row[j] != "" for j in js])
                y = np.array([float(row[j]) if row[j] != "" else 0.0 for j in js])
                raw[k], valid[k] = y, v
        except ValueError:
            return None
        if not math.isfinite(t) or (temp is not None and not math.isfinite(temp)):
            return None
        for k, y in raw.items():  # a NaN or infinite cell is an invalid sample, as an empty one (and as in NPZ)
            nf = ~np.isfinite(y)
            if nf.any():
                y[nf] = 0.0
                valid[k] = valid[k] & ~nf
        return Epoch(t, raw, valid, temp)


class NpzSource(_FileSource):
    """Epochs from an NPZ file with ``t`` and ``raw_<instrument>`` arrays (``rimu simulate`` writes these);
    optional ``valid_<instrument>`` and ``temperature``."""

    unit = "epoch"
    what = "NPZ file"

    def _epochs(self) -> Iterator[Epoch]:
        import tokenize
        import zipfile
        import zlib

        try:
            z = np.load(self.path, allow_pickle=False)
            if not hasattr(z, "files"):
                raise ValueError("a single .npy array, not an .npz archive")
            with z:
                if "t" not in z:
                    raise SessionFormatError(f"{self.path}: no 't' array")
                raw = {k: z[f"raw_{k}"] for k in INSTRUMENTS if f"raw_{k}" in z}
                if not raw:
                    raise SessionFormatError(f"{self.path}: no raw_gyro / raw_accel arrays")
                valid = {k: z[f"valid_{k}"] for k in raw if f"valid_{k}" in z}
                temp = z["temperature"] if "temperature" in z else None
                block = EpochBlock(z["t"], raw, valid, temp)
        except (OSError, ValueError, EOFError, KeyError, SyntaxError, tokenize.TokenError, zipfile.BadZipFile,
            zlib.error) as exc:
        # (numpy parses each member's header with ast: a damaged header is a SyntaxError)
            if isinstance(exc, SessionFormatError):
                raise
            raise SessionFormatError(f"{self.path}: not a readable NPZ recording ({exc or type(exc).__name__}); it "
                                     "may be truncated") from exc
        acc = self.accounting
        for k, ep in enumerate(block.epochs()):
            if self.stop_event.is_set():
                break
            acc.received += 1
            bad = not math.isfinite(ep.t)
            for inst, y in ep.raw.items():  # non-finite raw values: that sensor invalid, value 0.0
                nf = ~np.isfinite(y)
                if nf.any():
                    v = ep.valid_mask(inst) & ~nf
                    y[nf] = 0.0
                    ep.valid[inst] = v
                    acc.event("nonfinite_values", int(nf.sum()))
            if bad:
                acc.reject("malformed", 1, None)
                continue
            yield self._accepted(ep, "index", k)

    @staticmethod
    def meta(path: str | os.PathLike[str]) -> dict[str, Any]:
        """The JSON metadata ``rimu simulate`` stores (empty dict if none)."""
        import json

        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z["meta"])) if "meta" in z else {}
