"""Recorded CAN logs read straight from their text into arrays: candump ``-L`` logs (``.log``) in numpy.

``(1600000000.123456) can0 101#0011223344556677[ R|T]``: the lines of a chunk are cut, their fields located
and their hexadecimal and decimal digits converted with array operations, no python-can ``Message`` per frame
(whose creation and attribute access cost more than the decoding). A line the vectorised pass does not take
(a remote frame, CAN FD, irregular spacing, a timestamp beyond 15 significant digits) is read by a per-line
parser that follows python-can's ``CanutilsLogReader``; a line neither takes is *malformed*: it is counted as
a received frame rejected for ``malformed_line`` (its text and line number go to the side log), never dropped
silently. Blank lines are not frames.

Timestamps are correctly rounded (``float`` of the decimal text: an integer of at most 15 digits divided by a
power of ten), identifiers of 3 hex digits are standard and longer ones extended (python-can's rule), and an
identifier with SocketCAN's error flag (``CAN_ERR_FLAG``, 0x20000000) is an error frame whose error class bits
are kept (so a bus-off error frame is recognised as one).

>>> fr = parse_candump(b"(0.010000) can0 101#0102030405060708 R\\n(0.020000) can0 1F334455#\\n\\nnot a frame\\n")
>>> fr.ids.tolist(), fr.ext.tolist(), fr.dlc.tolist(), fr.ts.tolist()
([257, 523453525], [False, True], [8, 0], [0.01, 0.02])
>>> fr.malformed
[(4, 'not a frame')]
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

__all__ = ["LogFrames", "parse_candump", "iter_candump", "NATIVE_LOG_SUFFIXES", "CAN_ERR_FLAG"]

#: SocketCAN: the identifier of an error frame carries this flag (linux/can.h)
CAN_ERR_FLAG = 0x20000000
#: log formats read natively (others go through python-can's LogReader)
NATIVE_LOG_SUFFIXES = (".log",)

KIND_DATA, KIND_ERROR, KIND_REMOTE = 0, 1, 2

_HEX = np.full(256, 16, dtype=np.int64)
for _c in b"0123456789":
    _HEX[_c] = _c - 48
for _c in b"abcdef":
    _HEX[_c] = _c - 87
    _HEX[_c - 32] = _c - 87
_DEC = np.full(256, 10, dtype=np.int64)
for _c in b"0123456789":
    _DEC[_c] = _c - 48
_POW16 = 16 ** np.arange(8, dtype=np.int64)
_POW10 = 10 ** np.arange(16, dtype=np.int64)


@dataclass
class LogFrames:
    """Frames of a log as arrays (N frames in log order) and the malformed lines.

    Attributes
    ----------
    ts : (N,) float, s
    ids : (N,) int64
        Arbitration identifier (29 bits; for error frames the error class bits).
    ext : (N,) bool
    dlc : (N,) int64
        Data bytes of the frame (a remote frame: its requested length).
    data : (N, 8) uint8
        Data bytes, zero-padded.
    kind : (N,) int8
        0 data frame, 1 error frame, 2 remote frame.
    line : (N,) int64
        1-based line number of each frame in the file.
    malformed : list of (line number, text)
    """

    ts: np.ndarray
    ids: np.ndarray
    ext: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    kind: np.ndarray
    line: np.ndarray
    malformed: list[tuple[int, str]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.ts)

    def take(self, sel: np.ndarray) -> LogFrames:
        return LogFrames(self.ts[sel], self.ids[sel], self.ext[sel], self.dlc[sel], self.data[sel], self.kind[sel],
                         self.line[sel], [])


def _empty() -> LogFrames:
    return LogFrames(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0, np.int64),
                     np.zeros((0, 8), np.uint8), np.zeros(0, np.int8), np.zeros(0, np.int64))


def _first_at_or_after(pos: np.ndarray, at: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Per line, the first position in the sorted ``pos`` at or after ``at`` and before ``end``; -1 if none."""
    i = np.searchsorted(pos, at)
    p = np.append(pos, np.iinfo(np.int64).max)[i]
    return np.where(p < end, p, -1)


def _gather(buf: np.ndarray, start: np.ndarray, n: np.ndarray, width: int, table: np.ndarray,
            reverse: bool) -> tuple[np.ndarray, np.ndarray]:
    """Digits of the fields [start, start + n) of every line (n <= width), via ``table``; (values (N, width) with
    0 beyond each field, and whether every digit of the field is valid). ``reverse``: column j is the j-th digit
    from the field's end (least significant first)."""
    j = np.arange(width)
    used = j[None, :] < n[:, None]
    idx = (start + n - 1)[:, None] - j[None, :] if reverse else start[:, None] + j[None, :]
    idx = np.clip(idx, 0, len(buf) - 1)
    d = table[buf[idx]]
    bad = (d >= (16 if table is _HEX else 10)) & used
    return np.where(used, d, 0), ~bad.any(axis=1)


def parse_candump(text: bytes, first_line: int = 1) -> LogFrames:
    """The frames of candump ``-L`` text (whole lines; see the module docstring). ``first_line`` numbers the
    first line of ``text``."""
    if not text:
        return _empty()
    if not text.endswith(b"\n"):
        text += b"\n"
    buf = np.frombuffer(text, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate([[0], nl[:-1] + 1]).astype(np.int64)
    ends = nl.astype(np.int64)
    cr = (ends > starts) & (buf[np.maximum(ends - 1, 0)] == 13)
    ends = ends - cr
    lineno = first_line + np.arange(len(starts))
    # fields of a regular line: "(" ts ")" " " channel " " id "#" data [" " R|T]
    rp = _first_at_or_after(np.flatnonzero(buf == 41), starts, ends)              # ')'
    sp = np.flatnonzero(buf == 32)
    sp1 = np.where(rp >= 0, rp + 1, -1)
    ok = (buf[starts] == 40) & (rp >= 0) & (buf[np.clip(sp1, 0, len(buf) - 1)] == 32) & (sp1 < ends)
    sp2 = _first_at_or_after(sp, sp1 + 1, ends)                                    # after the channel
    ok &= (sp2 > sp1 + 1)
    hs = _first_at_or_after(np.flatnonzero(buf == 35), sp2 + 1, ends)              # '#'
    ok &= hs >= 0
    sp3 = _first_at_or_after(sp, hs + 1, ends)                                      # before R/T
    dend = np.where(sp3 >= 0, sp3, ends)
    tail = np.where(sp3 >= 0, ends - sp3, 0)
    flag = buf[np.clip(sp3 + 1, 0, len(buf) - 1)] | 32
    ok &= (tail == 0) | ((tail == 2) & ((flag == ord("r")) | (flag == ord("t"))))
    # timestamp: integer . fraction, both decimal, at most 15 digits together (exact as a float numerator)
    dot = _first_at_or_after(np.flatnonzero(buf == 46), starts + 1, rp)
    ok &= dot > starts + 1
    n_int = dot - starts - 1
    n_frac = rp - dot - 1
    ok &= (n_int + n_frac <= 15) & (n_frac >= 1)
    n_id = hs - sp2 - 1
    n_data = dend - hs - 1
    ok &= ((n_id == 3) | (n_id == 8)) & (n_data % 2 == 0) & (n_data <= 16)
    n_int, n_frac, n_id, n_data = (np.where(ok, v, 0) for v in (n_int, n_frac, n_id, n_data))
    di, good = _gather(buf, starts + 1, n_int, 15, _DEC, True)
    ok &= good
    df, good = _gather(buf, dot + 1, n_frac, 15, _DEC, False)
    ok &= good
    hi, good = _gather(buf, sp2 + 1, n_id, 8, _HEX, True)
    ok &= good
    hd, good = _gather(buf, hs + 1, n_data, 16, _HEX, False)
    ok &= good
    blank = ends - starts == 0
    if not blank.all():  # whitespace-only lines are blank too
        ws = (buf == 32) | (buf == 9) | (buf == 13) | (buf == 10)
        cs = np.concatenate([[0], np.cumsum(~ws)])
        blank = cs[ends] - cs[starts] == 0
    ok &= ~blank
    fr = ok.nonzero()[0]
    ints = (di[fr] * _POW10[:15]).sum(axis=1)
    fracs = (df[fr] * _POW10[:15][::-1]).sum(axis=1) // _POW10[15 - n_frac[fr]]
    scale = _POW10[n_frac[fr]]
    ts = (ints * scale + fracs) / scale.astype(float)
    can_id = (hi[fr] * _POW16).sum(axis=1)
    data = (hd[fr, 0::2] * 16 + hd[fr, 1::2]).astype(np.uint8)
    err = (can_id & CAN_ERR_FLAG) != 0
    fast = LogFrames(ts, can_id & 0x1FFFFFFF, n_id[fr] > 3, n_data[fr] // 2, data,
                     np.where(err, KIND_ERROR, KIND_DATA).astype(np.int8), lineno[fr])
    rest = np.flatnonzero(~ok & ~blank)
    if not len(rest):
        return fast
    # irregular lines: one by one, python-can's rules
    slow: list[tuple] = []
    bad: list[tuple[int, str]] = []
    for i in rest.tolist():
        line = text[starts[i]:ends[i]].decode("utf-8", "replace")
        f = _parse_line(line)
        if f is None:
            bad.append((int(lineno[i]), line))
        else:
            slow.append((int(lineno[i]), *f))
    if slow:
        ln, t, cid, ext, dlc, payload, kind = zip(*slow)
        d = np.zeros((len(slow), 8), np.uint8)
        for r, p in enumerate(payload):
            d[r, :len(p)] = np.frombuffer(p, np.uint8)
        more = LogFrames(np.array(t, float), np.array(cid, np.int64), np.array(ext, bool), np.array(dlc, np.int64),
                         d, np.array(kind, np.int8), np.array(ln, np.int64))
        order = np.argsort(np.concatenate([fast.line, more.line]), kind="stable")
        fast = LogFrames(*(np.concatenate([getattr(fast, f), getattr(more, f)])[order]
                           for f in ("ts", "ids", "ext", "dlc", "data", "kind", "line")))
    fast.malformed = bad
    return fast


def _parse_line(line: str) -> tuple | None:
    """(t, id, extended, dlc, data bytes, kind) of one candump line as python-can's CanutilsLogReader reads it
    (classic CAN; CAN FD frames are taken with their first 8 bytes only if they have at most 8), or None."""
    temp = line.strip()
    try:
        parts = temp.split()
        if len(parts) == 4 and parts[3].lower() in ("r", "t"):
            parts = parts[:3]
        if len(parts) != 3 or not (parts[0].startswith("(") and parts[0].endswith(")")):
            return None
        t = float(parts[0][1:-1])
        if t != t or t in (float("inf"), float("-inf")):
            return None
        can_id_s, data = parts[2].split("#", 1)
        if not can_id_s or len(can_id_s) > 8:
            return None
        can_id = int(can_id_s, 16)
        ext = len(can_id_s) > 3
        if data.startswith("#"):  # CAN FD: flags digit, then data
            data = data[2:]
        if data[:1] in ("R", "r"):
            dlc = int(data[1:]) if len(data) > 1 else 0
            if not 0 <= dlc <= 8:
                return None
            return t, can_id & 0x1FFFFFFF, ext, dlc, b"", KIND_REMOTE
        payload = bytes.fromhex(data)
        if len(data) % 2 or len(payload) > 8:
            return None
    except ValueError:
        return None
    kind = KIND_ERROR if can_id & CAN_ERR_FLAG else KIND_DATA
    return t, can_id & 0x1FFFFFFF, ext, len(payload), payload, kind


def iter_candump(path: str | os.PathLike[str], chunk_bytes: int = 1 << 22) -> Iterator[LogFrames]:
    """The frames of a candump log file, a chunk of whole lines at a time (constant memory)."""
    line = 1
    rest = b""
    with open(path, "rb") as fh:
        while True:
            block = fh.read(chunk_bytes)
            if not block:
                break
            block = rest + block
            cut = block.rfind(b"\n") + 1
            if cut == 0:
                rest = block
                continue
            body, rest = block[:cut], block[cut:]
            yield parse_candump(body, line)
            line += body.count(b"\n")
    if rest:
        yield parse_candump(rest, line)
