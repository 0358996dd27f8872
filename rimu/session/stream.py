"""Reading a session file in chunks: constant memory, whatever its length.

:func:`iter_blocks` yields the samples of a session file (rimu's CSV with its JSON sidecar, or NPZ) as
:class:`~rimu.epoch.EpochBlock` chunks of at most ``chunk`` samples, with the segment of every sample in
``meta["segment"]`` (indices into ``meta["labels"]``). Nothing but one chunk and the sidecar is held: a replay of
1e8 samples runs in the memory of one chunk. The CSV is parsed row by row; an NPZ member is decompressed as a
stream (``zipfile``) and its ``.npy`` header read with :mod:`numpy.lib.format`, so a compressed archive is never
expanded in memory either. Malformed content raises :class:`~rimu.errors.SessionFormatError` naming the file,
row (or array) and column, as :func:`rimu.session.load_session` does.

>>> import tempfile, pathlib
>>> from rimu.sim import Simulator, cho_park_procedure
>>> from rimu.session import save_session
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> p = save_session(Simulator(seed=1).run(cho_park_procedure(duration=1.0)).session, d / "s.npz")
>>> [len(b) for b in iter_blocks(p, chunk=1000)]
[1000, 1000, 400]
"""

from __future__ import annotations

import csv
import json
import math
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..epoch import EpochBlock
from ..errors import SessionFormatError
from .native import _check_sidecar, _columns, _read_sidecar, npz_layout, read_header, sidecar_geometries

__all__ = ["iter_blocks"]


def iter_blocks(path: str | Path, chunk: int = 65536, invalid: bool = False) -> Iterator[EpochBlock]:
    """The samples of a session file as blocks of at most ``chunk`` samples (see the module docstring).

    Parameters
    ----------
    path : str or Path
        ``.csv`` (with its ``.json`` sidecar beside it), the ``.json`` sidecar, or ``.npz``.
    chunk : int
        Samples per block (>= 1).
    invalid : bool
        False (calibration): a raw value that is not a finite number is refused. True (the runtime: ``rimu
        replay``, as ``rimu monitor`` and the live sources): an empty, NaN or infinite raw cell, or a False in an
        NPZ's ``valid_<instrument>`` array, is an invalid sample of that sensor (``valid`` False, value NaN).

    Yields
    ------
    EpochBlock
        ``raw`` per instrument (raw units), ``temperature`` (degC) when the file has it, ``meta`` with
        ``segment`` (N,) indices, ``labels`` (the sidecar's segment labels), ``sample_rate_hz`` and the
        sidecar itself under ``sidecar``.
    """
    if int(chunk) < 1:
        raise SessionFormatError(f"chunk must be at least 1 sample, got {chunk}")
    path = Path(path)
    if not path.exists():
        raise SessionFormatError(f"{path} does not exist")
    if path.suffix == ".npz":
        yield from _iter_npz(path, int(chunk), invalid)
        return
    if path.suffix == ".json":
        side = _read_sidecar(path)
        if "data" not in side:
            raise SessionFormatError(f"{path}: the sidecar has no 'data' key naming its CSV file")
        yield from _iter_csv(path.parent / side["data"], side, path, int(chunk), invalid)
        return
    if path.suffix == ".csv":
        sp = path.with_suffix(".json")
        if not sp.exists():
            raise SessionFormatError(f"{path}: its sidecar {sp.name} is missing (geometry, sample rate, segments)")
        yield from _iter_csv(path, _read_sidecar(sp), sp, int(chunk), invalid)
        return
    raise SessionFormatError(f"{path}: unknown session file type {path.suffix!r}; use .csv/.json or .npz")


def _meta(side: dict, seg: np.ndarray) -> dict:
    return {"segment": seg, "labels": [str(d["label"]) for d in side["segments"]],
            "sample_rate_hz": float(side["sample_rate_hz"]), "sidecar": side}


def _iter_csv(path: Path, side: dict, src: Path, chunk: int, invalid: bool = False) -> Iterator[EpochBlock]:
    _check_sidecar(side, str(src))
    geoms = sidecar_geometries(side, str(src))
    need = ["t", "segment"] + _columns(geoms)
    if not path.exists():
        raise SessionFormatError(f"{src}: its data file {path} does not exist")
    labels = {str(d["label"]): k for k, d in enumerate(side["segments"])}
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = read_header(reader, path, need)
        has_temp = "temperature" in header
        num_cols = [c for c in need if c != "segment"] + (["temperature"] if has_temp else [])
        ci = [header.index(c) for c in num_cols]
        si = header.index("segment")
        nh = len(header)
        row = 1
        last_t, last_seg = -math.inf, -1
        rows: list[list[str]] = []
        for line in reader:
            row += 1
            if len(line) != nh:
                raise SessionFormatError(f"{path}: row {row} has {len(line)} fields, the header has {nh}")
            rows.append(line)
            if len(rows) == chunk:
                blk = _csv_block(rows, row - len(rows) + 1, path, ci, si, num_cols, labels, geoms, has_temp, side,
                                 invalid)
                last_t, last_seg = _check_time(blk, last_t, last_seg, row - len(rows) + 1, path, side)
                yield blk
                rows = []
        if rows:
            blk = _csv_block(rows, row - len(rows) + 1, path, ci, si, num_cols, labels, geoms, has_temp, side,
                             invalid)
            _check_time(blk, last_t, last_seg, row - len(rows) + 1, path, side)
            yield blk
        elif row == 1:
            raise SessionFormatError(f"{path}: no data rows")


def _csv_block(rows, first_row, path, ci, si, num_cols, labels, geoms, has_temp, side,  # type: ignore[no-untyped-def]
               invalid=False) -> EpochBlock:
    seg = np.empty(len(rows), dtype=np.int64)
    for r, line in enumerate(rows):
        k = labels.get(line[si].strip())
        if k is None:
            raise SessionFormatError(f"{path}: row {first_row + r}, column 'segment': label {line[si].strip()!r} is "
                                     f"not a segment of the sidecar ({sorted(labels)})")
        seg[r] = k
    raw_cols = set(_columns(geoms)) if invalid else set()
    try:
        vals = np.array([[line[c] for c in ci] for line in rows], dtype=float)
    except ValueError:
        vals = None
    if invalid and vals is None:  # empty raw cells: invalid samples (NaN)
        try:
            vals = np.array([[(line[c] if line[c].strip() or name not in raw_cols else "nan")
                              for name, c in zip(num_cols, ci)] for line in rows], dtype=float)
        except ValueError:
            vals = None
    if vals is None or not np.all(np.isfinite(vals)):
        for r, line in enumerate(rows):
            for name, c in zip(num_cols, ci):
                if name in raw_cols and (not line[c].strip() or line[c].strip().lower() in ("nan", "inf", "-inf")):
                    continue  # an invalid sample of that sensor
                try:
                    v = float(line[c])
                except ValueError:
                    raise SessionFormatError(f"{path}: row {first_row + r}, column {name!r}: {line[c]!r} is not a "
                                             "number") from None
                if not math.isfinite(v):
                    raise SessionFormatError(f"{path}: row {first_row + r}, column {name!r} is not finite ({v})")
    raw, c0 = {}, 1
    for k in ("gyro", "accel"):
        if k in geoms:
            raw[k] = vals[:, c0:c0 + geoms[k].n]
            c0 += geoms[k].n
    valid = {k: np.isfinite(y) for k, y in raw.items()} if invalid else {}
    if invalid:
        for k, y in raw.items():
            y[~valid[k]] = np.nan
    return EpochBlock(vals[:, 0], raw, valid, temperature=vals[:, c0] if has_temp else None, meta=_meta(side, seg))


def _check_time(blk: EpochBlock, last_t: float, last_seg: int, first_row: int, path: Path,
                side: dict) -> tuple[float, int]:
    """Time must increase within a segment, across chunk boundaries too."""
    t = np.concatenate([[last_t], blk.t])
    s = np.concatenate([[last_seg], blk.meta["segment"]])
    bad = np.flatnonzero((np.diff(t) <= 0) & (np.diff(s) == 0))
    if bad.size:
        raise SessionFormatError(f"{path}: row {first_row + bad[0]}, column 't': time does not increase within "
                                 f"segment {side['segments'][s[bad[0] + 1]]['label']!r}")
    return float(blk.t[-1]), int(blk.meta["segment"][-1])


class _NpyStream:
    """One member of an NPZ archive read as a stream of rows (no full decompression in memory)."""

    def __init__(self, zf: zipfile.ZipFile, name: str, path: Path) -> None:
        self.name = name
        self.fh = zf.open(name)
        try:
            version = np.lib.format.read_magic(self.fh)
            reader = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                      else np.lib.format.read_array_header_2_0)
            self.shape, fortran, self.dtype = reader(self.fh)
        except ValueError as exc:
            raise SessionFormatError(f"{path}: array {name!r} is not a readable .npy member ({exc})") from exc
        if fortran and len(self.shape) > 1:
            raise SessionFormatError(f"{path}: array {name!r} is stored in Fortran order; save it C-ordered "
                                     "(np.ascontiguousarray) to stream it")
        if self.dtype.hasobject:
            raise SessionFormatError(f"{path}: array {name!r} holds Python objects; rimu reads numbers only")
        self.row_items = int(np.prod(self.shape[1:])) if len(self.shape) > 1 else 1

    def read(self, rows: int) -> np.ndarray:
        nbytes = rows * self.row_items * self.dtype.itemsize
        data = self.fh.read(nbytes)
        if len(data) != nbytes:
            raise SessionFormatError(f"array {self.name!r} ends early: the archive is truncated")
        return np.frombuffer(data, dtype=self.dtype).reshape((rows, *self.shape[1:]))

    def close(self) -> None:
        self.fh.close()


def _iter_npz(path: Path, chunk: int, invalid: bool = False) -> Iterator[EpochBlock]:
    try:
        zf = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as exc:
        raise SessionFormatError(f"{path}: not a readable NPZ file ({exc})") from exc
    with zf:
        names = {n[:-4] for n in zf.namelist() if n.endswith(".npy")}
        if "meta" not in names:
            raise SessionFormatError(f"{path}: no 'meta' entry (the JSON sidecar); arrays present: {sorted(names)}")
        try:
            with zf.open("meta.npy") as fh:
                side = json.loads(str(np.lib.format.read_array(fh, allow_pickle=False)))
        except (ValueError, json.JSONDecodeError) as exc:
            raise SessionFormatError(f"{path}: 'meta' is not valid JSON ({exc})") from exc
        geoms, need = npz_layout(side, sorted(names), path)
        keys = need + (["temperature"] if "temperature" in names else [])
        if invalid:
            keys += [f"valid_{k}" for k in geoms if f"valid_{k}" in names]
        streams = {k: _NpyStream(zf, f"{k}.npy", path) for k in keys}
        try:
            N = streams["t"].shape[0]
            for k, g in geoms.items():
                if streams[f"raw_{k}"].shape != (N, g.n):
                    raise SessionFormatError(f"{path}: raw_{k} has shape {streams[f'raw_{k}'].shape}, expected "
                                             f"({N}, {g.n}) (columns {list(g.names)})")
            for k in ("segment", "temperature"):
                if k in streams and streams[k].shape != (N,):
                    raise SessionFormatError(f"{path}: '{k}' has shape {streams[k].shape}, expected ({N},)")
            nseg = len(side["segments"])
            last_t, last_seg = -math.inf, -1
            for a in range(0, N, chunk):
                m = min(chunk, N - a)
                t = streams["t"].read(m).astype(float)
                seg = streams["segment"].read(m).astype(np.int64)
                if seg.size and (seg.min() < 0 or seg.max() >= nseg):
                    raise SessionFormatError(f"{path}: 'segment' must hold indices into the {nseg} segments of meta "
                                             f"(rows {a}..{a + m - 1})")
                raw, valid = {}, {}
                for k, g in geoms.items():
                    y = streams[f"raw_{k}"].read(m).astype(float)
                    if invalid:  # non-finite values and the valid_<instrument> flags: invalid samples
                        v = np.isfinite(y)
                        if f"valid_{k}" in streams:
                            v &= streams[f"valid_{k}"].read(m).astype(bool).reshape(y.shape)
                        y[~v] = np.nan
                        raw[k], valid[k] = y, v
                        continue
                    if not np.all(np.isfinite(y)):
                        r, c = np.argwhere(~np.isfinite(y))[0]
                        raise SessionFormatError(f"{path}: raw_{k} row {a + r}, column {g.names[c]!r} is not finite")
                    raw[k] = y
                temp = streams["temperature"].read(m).astype(float) if "temperature" in streams else None
                blk = EpochBlock(t, raw, valid, temperature=temp, meta=_meta(side, seg))
                last_t, last_seg = _check_time(blk, last_t, last_seg, a, path, side)
                yield blk
        finally:
            for s in streams.values():
                s.close()
