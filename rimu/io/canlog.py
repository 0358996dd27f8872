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
import re
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

__all__ = ["LogFrames", "parse_candump", "iter_candump", "NATIVE_LOG_SUFFIXES", "CAN_ERR_FLAG"]

#: SocketCAN: the identifier of an error frame carries this flag (linux/can.h)
CAN_ERR_FLAG = 0x20000000
#: log formats read natively (others go through python-can's LogReader)
NATIVE_LOG_SUFFIXES = (".log",)

KIND_DATA, KIND_ERROR, KIND_REMOTE = 0, 1, 2



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
    #: lines of text read (frames, malformed and blank lines)
    n_lines: int = 0

    def __len__(self) -> int:
        return len(self.ts)

    def take(self, sel: np.ndarray) -> LogFrames:
        return LogFrames(self.ts[sel], self.ids[sel], self.ext[sel], self.dlc[sel], self.data[sel], self.kind[sel],
                         self.line[sel], [])


def _empty() -> LogFrames:
    return LogFrames(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0, np.int64),
                     np.zeros((0, 8), np.uint8), np.zeros(0, np.int8), np.zeros(0, np.int64))


_SHAPE = re.compile(rb"\((\d+)\.(\d+)\) ([^ ]+) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#([0-9A-Fa-f]*)( [RTrt])?")


def _shape(line: bytes) -> tuple | None:
    """Where the fields of a regular candump line sit: (length, separator offsets and bytes, digit offsets and
    sizes), or None for a line the vectorised pass does not take."""
    m = _SHAPE.fullmatch(line)
    if m is None:
        return None
    n_int, n_frac, n_data = len(m[1]), len(m[2]), len(m[5])
    if n_int + n_frac > 15 or n_data % 2 or n_data > 16 or not all(33 <= c < 127 for c in m[3]):
        return None   # (a channel of printable characters: python-can splits a line at any white space)
    seps = [(0, 40), (m.end(1), 46), (m.end(2), 41), (m.end(2) + 1, 32), (m.end(3), 32), (m.end(4), 35)]
    if m[6]:
        seps.append((m.start(6), 32))
    return (len(line), seps, list(range(m.start(3), m.end(3))), m.start(1), n_int, n_frac, m.start(4), len(m[4]),
            m.start(5), n_data, m.start(6) + 1 if m[6] else -1)


def _hex_tables() -> tuple[np.ndarray, np.ndarray]:
    """Two ASCII characters read as one little-endian uint16 -> their hexadecimal byte (0-255), and one character
    -> its hex digit; 256 where a character is not a hex digit."""
    hexv = np.full(256, 256, np.int32)
    for c in b"0123456789":
        hexv[c] = c - 48
    for c in b"abcdef":
        hexv[c] = hexv[c - 32] = c - 87
    lo, hi = np.meshgrid(np.arange(256), np.arange(256), indexing="xy")   # uint16 = lo | hi << 8: lo first
    hx = np.where((hexv[lo] < 16) & (hexv[hi] < 16), hexv[lo] * 16 + hexv[hi], 256)
    return hx.reshape(-1).astype(np.uint16), hexv.astype(np.uint16)


_HEX2, _HEX1 = _hex_tables()


class _Lines:
    """n lines of one length as strided views: rows ``origin + k * stride`` of the contiguous uint8 ``base``
    (the text itself when the lines are evenly spaced, else a copy of them with 8 spare bytes a row)."""

    def __init__(self, base: np.ndarray, origin: int, stride: int, n: int) -> None:
        self.base, self.origin, self.stride, self.n = base, origin, stride, n

    def col(self, off: int) -> np.ndarray:
        return np.ndarray((self.n,), np.uint8, self.base, self.origin + off, (self.stride,))

    def col16(self, off: int) -> np.ndarray:
        return np.ndarray((self.n,), "<u2", self.base, self.origin + off, (self.stride,))

    def word(self, off: int) -> np.ndarray:
        """(n,) uint64: characters off .. off + 7 of every line, the first in the lowest byte (unaligned view)."""
        return np.ndarray((self.n,), "<u8", self.base, self.origin + off, (self.stride,))


def _bytes_of(c: int) -> np.uint64:
    return np.uint64(c * 0x0101010101010101)


_HIGH, _ZEROS = _bytes_of(0x80), _bytes_of(0x30)
_M16, _M32, _M64 = np.uint64(0x00FF00FF00FF00FF), np.uint64(0x0000FFFF0000FFFF), np.uint64(0xFFFFFFFF)


def _fill_mask(k: int) -> np.uint64:
    """The bytes k..7 of a word (where a field of k characters has none)."""
    return np.uint64(((1 << 64) - 1) ^ ((1 << (8 * k)) - 1))


def _digits_word(lines: _Lines, off: int, k: int) -> np.ndarray:
    """The k (1..8) digits at column ``off`` of every line in one word, in bytes 8-k..7 with '0' below them (the
    leading zeros of the number). Loads never reach before a line or beyond the end of the text: a field of
    fewer than 8 characters is read from its end backwards when it sits after column 8, else forwards (a
    timestamp, followed by at least 8 characters)."""
    if k == 8:
        return lines.word(off) | np.uint64(0)        # a contiguous copy
    low = _ZEROS & ~_fill_mask(8 - k)                # '0' in bytes 0..7-k
    if off + k >= 8:
        return (lines.word(off + k - 8) & _fill_mask(8 - k)) | low    # the field in the high bytes
    return (lines.word(off) << np.uint64(8 * (8 - k))) | low          # the field in the low bytes, shifted up


def _decimal8(w: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """The number written by the 8 ASCII decimal digits of every word of ``w`` (the first in the lowest byte: the
    most significant), in a few word-wide operations done in place (``w`` is overwritten and returned); ``bad``
    |= some byte is no digit."""
    u = np.uint64
    # a byte c < 0x80 is a digit when c + 0x50 carries into bit 7 (c >= 0x30) and c + 0x46 does not (c <= 0x39);
    # a byte >= 0x80 is caught by w & _HIGH (its carry may spoil the test of the next byte: the line is bad anyway)
    t1 = w + _bytes_of(0x46)
    t2 = w + _bytes_of(0x50)
    np.invert(t2, out=t2)
    t1 |= t2
    t1 |= w
    t1 &= _HIGH
    bad |= t1 != 0
    w -= _ZEROS                                      # digit values, one per byte
    for shift, mul, mask in ((8, 10, _M16), (16, 100, _M32), (32, 10000, _M64)):
        np.right_shift(w, u(shift), out=t1)          # pairs of bytes, then of 16-bit and 32-bit lanes
        w *= u(mul)
        w += t1
        w &= mask
    return w


def _hex_word(src: np.ndarray, bad: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The 4 bytes written by the 8 ASCII hexadecimal digits of every word of ``src`` (upper or lower case; the
    first two characters give byte 0) as the low 32 bits of a uint64 (byte 0 lowest), in word-wide operations
    done in place; ``bad`` |= some character is no hex digit."""
    u = np.uint64
    w = np.bitwise_or(src, u(0), out=out)           # a contiguous copy of the (strided) characters
    t1 = w + _bytes_of(0x50)                         # bit 7 of each byte: c >= '0'
    t2 = w + _bytes_of(0x46)                         # bit 7: c > '9'
    np.invert(t2, out=t2)
    t1 &= t2                                         # a decimal digit
    np.bitwise_or(w, _bytes_of(0x20), out=t2)        # lower case
    t3 = t2 + _bytes_of(0x1F)                        # >= 'a'
    t2 += _bytes_of(0x19)                            # > 'f'
    np.invert(t2, out=t2)
    t3 &= t2
    t1 |= t3                                         # a hex digit (bytes below 0x80)
    t1 &= _HIGH
    t1 ^= _HIGH
    np.bitwise_and(w, _HIGH, out=t2)
    t1 |= t2
    bad |= t1 != 0
    np.right_shift(w, u(6), out=t1)                  # 1 for letters
    t1 &= _bytes_of(1)
    t1 *= u(9)
    w &= _bytes_of(0x0F)
    w += t1                                          # nibbles
    np.left_shift(w, u(4), out=t1)
    w >>= u(8)
    w |= t1
    w &= _M16                                        # a byte per 16-bit lane
    np.right_shift(w, u(8), out=t1)
    w |= t1
    w &= _M32
    np.right_shift(w, u(16), out=t1)
    w |= t1
    w &= _M64
    return w


def _decimal(lines: _Lines, off: int, n: int, bad: np.ndarray) -> np.ndarray:
    """The unsigned number written in ``n`` (1..16) decimal digits at column ``off`` of every line; int64."""
    if n <= 8:
        return _decimal8(_digits_word(lines, off, n), bad).view(np.int64)
    hi = _decimal8(_digits_word(lines, off, n - 8), bad)
    hi *= np.uint64(10 ** 8)
    hi += _decimal8(lines.word(off + n - 8) | np.uint64(0), bad)
    return hi.view(np.int64)


def _hex_number(lines: _Lines, off: int, n: int, bad: np.ndarray) -> np.ndarray:
    """The unsigned number written in ``n`` hexadecimal digits at column ``off`` of every line, two digits per table
    look-up on a uint16 view; int64. (On these short fields a look-up beats word-wide arithmetic in numpy.)"""
    v = np.zeros(lines.n, np.int64)
    if n % 2:
        d = np.take(_HEX1, lines.col(off))
        bad |= d > 255
        v += d
        off, n = off + 1, n - 1
    for j in range(n // 2):
        d = np.take(_HEX2, lines.col16(off + 2 * j))
        bad |= d > 255
        v <<= 8
        v |= d
    return v


def _shaped(buf: np.ndarray, starts: np.ndarray, shape: tuple) -> tuple[np.ndarray, tuple]:
    """The lines (starts of candidate lines of the shape's length) that have the shape, and their fields, each
    converted for all lines at once: timestamps eight digits at a time as one 64-bit word (word-wide arithmetic),
    hexadecimal fields two digits at a time by table look-up, channel and separators compared eight characters
    at a time with the first line's."""
    L = shape[0]
    n = len(starts)
    step = int(starts[1] - starts[0]) if n > 1 else L
    if (n > 1 and step > L and int(starts[-1] - starts[0]) == step * (n - 1)
            and (n < 3 or (np.diff(starts) == step).all())):
        lines = _Lines(buf, int(starts[0]), step, n)        # evenly spaced (a run of one shape): views, no copy
    else:
        copy = np.zeros((n, L + 8), np.uint8)
        copy[:, :L] = np.lib.stride_tricks.sliding_window_view(buf, L)[starts]
        lines = _Lines(copy.reshape(-1), 0, L + 8, n)
    return _fields(lines, shape)


def _fields(lines: _Lines, shape: tuple, cr: bool = False) -> tuple[np.ndarray, tuple]:
    """:func:`_shaped` of lines already located (``cr``: each must be followed by a carriage return)."""
    L, seps, _chan, o_int, n_int, n_frac, o_id, n_id, o_data, n_data, o_flag = shape
    n = lines.n
    ok = lines.col(seps[0][0]) == seps[0][1]
    if cr:
        ok &= lines.col(L) == 13
    close = o_int + n_int + 1 + n_frac              # ") channel " up to the identifier
    for p in sorted({*range(close, o_id - 8, 8), o_id - 8}):
        # eight characters at a time: the channel and separators as in the first line (checked by _shape);
        # loads end before the identifier's end (never beyond the text)
        lo, hi = max(p, close), min(p + 8, o_id)
        mask = np.uint64(((1 << (8 * (hi - lo))) - 1) << (8 * (lo - p)))
        w = lines.word(p) & mask
        ok &= w == w[0]
    for off, byte in seps[1:]:   # column by column: a reduction along a short axis is slow in numpy
        if not close <= off < o_id:
            ok &= lines.col(off) == byte
    if o_flag >= 0:
        f = lines.col(o_flag) | 32
        ok &= (f == ord("r")) | (f == ord("t"))
    bad = np.zeros(n, bool)
    whole = _decimal(lines, o_int, n_int, bad)
    frac = _decimal(lines, o_int + n_int + 1, n_frac, bad)
    can_id = _hex_number(lines, o_id, n_id, bad)
    nb = n_data // 2
    data = np.zeros((n, 8), np.uint8)
    if nb == 8:          # eight data bytes (most frames): sixteen digits as two words
        words = data.view("<u8").reshape(n)
        _hex_word(lines.word(o_data), bad, words)
        high = _hex_word(lines.word(o_data + 8), bad)
        high <<= np.uint64(32)
        words |= high
    else:
        for j in range(nb):
            d = np.take(_HEX2, lines.col16(o_data + 2 * j))
            bad |= d > 255
            data[:, j] = d
    ok &= ~bad
    ts = (whole * 10 ** n_frac + frac) / 10.0 ** n_frac   # an exact numerator below 1e15, one rounded division
    if not ok.all():
        ts, can_id, data = ts[ok], can_id[ok], data[ok]
    return ok, (ts, can_id, n_id > 3, nb, data)


def _line_starts(buf: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int, int]]] | None:
    """Where the lines of ``buf`` (ending with a newline) start, found as runs of lines of one length: the
    newline ending each line of a run sits at a fixed stride, checked with one strided comparison. None when the
    text has too many runs (lines of many lengths): then every byte has to be searched. A run may hide a line
    break inside one of its lines; every character of a line the vectorised pass takes is checked (none is a
    line break), and :func:`parse_candump` looks for one in the other lines. Also the runs: (first line, lines,
    stride)."""
    size = len(buf)
    parts = []
    runs = []
    pos = 0
    while pos < size:
        if len(parts) >= 32:
            return None
        head = np.flatnonzero(buf[pos:pos + 512] == 10)
        if not len(head):
            return None
        S = int(head[0]) + 1                          # the first line's length with its newline
        m = (size - pos) // S
        eq = buf[pos + S - 1: pos + m * S: S] == 10
        k = m if eq.all() else int(np.argmin(eq))
        runs.append((sum(len(p) for p in parts), k, S))
        parts.append(np.arange(pos, pos + k * S, S, dtype=np.int64))
        pos += k * S
    return (np.concatenate(parts) if len(parts) > 1 else parts[0]), runs


def parse_candump(text: bytes | memoryview, first_line: int = 1, runs: bool = True) -> LogFrames:
    """The frames of candump ``-L`` text (whole lines; see the module docstring). ``first_line`` numbers the
    first line of ``text``.

    The lines are grouped by shape (length and the places of their separators: a log has a handful, as the
    timestamp gains digits and messages differ in length); a group's digits sit at fixed offsets and are
    converted field by field for all its lines at once. The lines themselves are found as runs of equally long
    lines (``runs``, one strided comparison per run) where the text allows, else by a search of every byte."""
    if not text:
        return _empty()
    if bytes(text[-1:]) != b"\n":
        text = bytes(text) + b"\n"
    buf = np.frombuffer(text, dtype=np.uint8)
    found = _line_starts(buf) if runs else None
    groups: list[tuple[np.ndarray, tuple]] = []
    every_line_taken = False
    if found is not None:      # long runs of equally long lines: each its own group if its first line has a shape
        starts, run_list = found
        every_line_taken = True
        for i0, k, S in run_list:
            p0 = int(starts[i0])
            L = S - 1 - int(S > 1 and buf[p0 + S - 2] == 13)       # without a carriage return
            shape = _shape(bytes(text[p0:p0 + L])) if k >= 64 and L > 0 else None
            if shape is None:
                every_line_taken = False
                continue
            ok, fields = _fields(_Lines(buf, p0, S, k), shape, cr=L == S - 2)
            if ok.all():
                groups.append((np.arange(i0, i0 + k), fields))
            else:
                groups.append((i0 + np.flatnonzero(ok), fields))
                every_line_taken = False
    if found is None:
        nl = np.flatnonzero(buf == 10)
        starts = np.empty(len(nl), np.int64)
        starts[0] = 0
        starts[1:] = nl[:-1] + 1
        ends = nl.astype(np.int64)
    elif not every_line_taken:
        ends = np.empty(len(starts), np.int64)
        ends[:-1] = starts[1:] - 1
        ends[-1] = len(buf) - 1
    if every_line_taken:
        rem = np.zeros(0, np.int64)
    else:
        cr = np.flatnonzero(buf[np.maximum(ends - 1, 0)] == 13)
        if len(cr):
            ends[cr[ends[cr] > starts[cr]]] -= 1
        length = ends - starts
        keep = length > 0                            # empty lines are not frames
        for rows, _ in groups:
            keep[rows] = False
        rem = np.flatnonzero(keep)
    slow: list[int] = []
    rounds = 0
    while len(rem) and rounds < 64:
        rounds += 1
        i0 = int(rem[0])
        shape = _shape(bytes(text[starts[i0]:ends[i0]]))
        if shape is None:
            slow.append(i0)
            rem = rem[1:]
            continue
        cand = np.flatnonzero(length[rem] == shape[0])
        ok, fields = _shaped(buf, starts[rem[cand]], shape)
        groups.append((rem[cand[ok]], fields))
        keep = np.ones(len(rem), bool)
        keep[cand[ok]] = False
        rem = rem[keep]
    slow += rem.tolist()
    bad: list[tuple[int, str]] = []
    slow_rows: list[int] = []
    got: list[tuple] = []
    for i in sorted(slow):
        raw = bytes(text[starts[i]:ends[i]])
        if runs and b"\n" in raw:     # a run hid a line break inside this line: find the lines byte by byte
            return parse_candump(text, first_line, runs=False)
        line = raw.decode("utf-8", "replace")
        if not line.strip():
            continue                                  # whitespace only: not a frame
        f = _parse_line(line)
        if f is None:
            bad.append((first_line + i, line))
        else:
            slow_rows.append(i)
            got.append(f)
    if len(groups) == 1 and not got:     # one shape (most chunks of a long log): its arrays as they are
        rows, (ts, cid, ext, dlc, data) = groups[0]
        if ext:                          # (3 hex digits never reach the error flag)
            kind = np.where(cid & CAN_ERR_FLAG, KIND_ERROR, KIND_DATA).astype(np.int8)
            cid = cid & 0x1FFFFFFF
        else:
            kind = np.zeros(len(rows), np.int8)
        return LogFrames(ts, cid, np.full(len(rows), ext), np.full(len(rows), dlc, np.int64), data, kind,
                         rows + first_line, bad, len(starts))
    # every frame in line order: each group scattered to its rows' places among the frames
    n_fast = sum(len(g[0]) for g in groups)
    n = n_fast + len(got)
    out = LogFrames(np.empty(n), np.empty(n, np.int64), np.empty(n, bool), np.empty(n, np.int64),
                    np.empty((n, 8), np.uint8), np.empty(n, np.int8), np.empty(n, np.int64), bad)
    groups.sort(key=lambda g: int(g[0][0]) if len(g[0]) else -1)
    if not got and all(len(r) == 0 or int(r[-1]) - int(r[0]) + 1 == len(r) for r, _ in groups):
        # each group a run of consecutive lines (the usual log: the timestamp gains a digit now and then)
        where, a = [], 0
        for rows, f in groups:
            where.append((slice(a, a + len(rows)), f))
            out.line[a:a + len(rows)] = rows
            a += len(rows)
    else:
        is_frame = np.zeros(len(starts), bool)
        for rows, _ in groups:
            is_frame[rows] = True
        is_frame[slow_rows] = True
        pos = np.cumsum(is_frame) - 1
        where = [(pos[rows], f) for rows, f in groups]
        out.line[pos[is_frame]] = np.flatnonzero(is_frame)
        if got:
            at_slow = pos[slow_rows]
    for at, (ts, cid, ext, dlc, data) in where:
        out.ts[at] = ts
        out.ids[at] = cid
        out.ext[at] = ext
        out.dlc[at] = dlc
        out.data[at] = data
    out.kind[:] = np.where((out.ids & CAN_ERR_FLAG) != 0, KIND_ERROR, KIND_DATA)
    if got:
        at = at_slow
        t, cid, ext, dlc, payload, kind = zip(*got)
        out.ts[at], out.ids[at], out.ext[at], out.dlc[at], out.kind[at] = t, cid, ext, dlc, kind
        d = np.zeros((len(got), 8), np.uint8)
        for r, pl in enumerate(payload):
            d[r, :len(pl)] = np.frombuffer(pl, np.uint8)
        out.data[at] = d
    out.ids &= 0x1FFFFFFF
    out.line += first_line
    out.n_lines = len(starts)
    return out


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
    """The frames of a candump log file, a chunk of whole lines at a time (constant memory: one buffer, read
    into and reused; the part line at its end moved to its start for the next chunk; a line longer than the
    buffer grows it). The frames of a chunk own their arrays (nothing refers to the buffer)."""
    line = 1
    buf = bytearray(max(int(chunk_bytes), 1))
    filled = 0
    with open(path, "rb", buffering=0) as fh:
        while True:
            if filled == len(buf):                    # no line break in the whole buffer: a longer one
                buf = buf + bytes(len(buf))
            with memoryview(buf) as view:
                n = fh.readinto(view[filled:])
            if not n:
                break
            end = filled + n
            cut = buf.rfind(b"\n", 0, end) + 1
            if cut == 0:
                filled = end
                continue
            with memoryview(buf) as view:
                fr = parse_candump(view[:cut], line)  # the lines without a copy of them
            line += fr.n_lines
            yield fr
            buf[:end - cut] = buf[cut:end]            # the part line, to the start
            filled = end - cut
    if filled:
        yield parse_candump(bytes(buf[:filled]), line)
