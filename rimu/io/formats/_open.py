"""One opener for every recorded log: ``.xz``, ``.gz``, ``.bz2`` and ``.zst`` are decompressed on the fly, by
content (magic bytes) as well as by name, so a reader never sees a compressed byte.

>>> import gzip, tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "log.csv.gz"
>>> with gzip.open(p, "wt") as fh:
...     _ = fh.write("t,x\\n0,1\\n")
>>> plain_name(p), head(p, 4)
('log.csv', b't,x\\n')
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import os
import shutil
import tempfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from ...errors import SessionFormatError, TransportError

__all__ = ["COMPRESSIONS", "compression", "head", "is_text", "local_file", "open_binary", "open_text", "plain_name"]

#: suffix -> magic bytes of the compressed stream
COMPRESSIONS: dict[str, bytes] = {".xz": b"\xfd7zXZ\x00", ".gz": b"\x1f\x8b", ".bz2": b"BZh", ".zst": b"\x28\xb5\x2f\xfd"}


def compression(path: str | os.PathLike[str]) -> str | None:
    """The compression of a file (``.xz``, ``.gz``, ``.bz2``, ``.zst``) from its first bytes, else None."""
    p = Path(path)
    if p.is_dir():
        return None
    try:
        with open(p, "rb") as fh:
            magic = fh.read(6)
    except FileNotFoundError:
        raise TransportError(f"no file at {p}; check the path") from None
    for suffix, m in COMPRESSIONS.items():
        if magic.startswith(m):
            return suffix
    return None


def plain_name(path: str | os.PathLike[str]) -> str:
    """The file name without its compression suffix (``flight.bin.xz`` -> ``flight.bin``)."""
    name = Path(path).name
    for suffix in COMPRESSIONS:
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return name


def open_binary(path: str | os.PathLike[str]) -> IO[bytes]:
    """Open a file for reading bytes, decompressing it on the fly (streaming: constant memory).

    Raises
    ------
    TransportError
        No such file.
    SessionFormatError
        A ``.zst`` file and no ``zstandard`` module (``pip install 'rimu[logs]'``).
    """
    p = Path(path)
    kind = compression(p)
    if kind is None:
        return open(p, "rb")
    if kind == ".xz":
        return lzma.open(p, "rb")  # type: ignore[return-value]
    if kind == ".gz":
        return gzip.open(p, "rb")  # type: ignore[return-value]
    if kind == ".bz2":
        return bz2.open(p, "rb")  # type: ignore[return-value]
    try:
        import zstandard
    except ImportError:
        raise SessionFormatError(f"{p} is zstd-compressed: reading it needs zstandard (pip install 'rimu[logs]'), "
                                 "or decompress it first (unzstd)") from None
    return io.BufferedReader(_ZstdStream(zstandard.ZstdDecompressor().stream_reader(open(p, "rb"), closefd=True),
                                         zstandard.ZstdError), 1 << 20)


class _ZstdStream(io.RawIOBase):
    """zstandard's stream reader with its errors as ``OSError`` (errno None), as the other codecs' damaged-stream
    errors are caught: a damaged or fake ``.zst`` ends in the readers' one-line error, not a ZstdError traceback."""

    def __init__(self, reader: Any, error: type[Exception]) -> None:
        self._r, self._error = reader, error

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        try:
            data = self._r.read(len(b))
        except self._error as exc:
            raise OSError(f"zstd: {exc}") from None
        b[:len(data)] = data
        return len(data)

    def close(self) -> None:
        self._r.close()
        super().close()


def open_text(path: str | os.PathLike[str]) -> io.TextIOBase:
    """Open a text file (UTF-8), decompressing it on the fly."""
    return io.TextIOWrapper(open_binary(path), encoding="utf-8", newline="")  # type: ignore[arg-type]


def head(path: str | os.PathLike[str], n: int = 4096) -> bytes:
    """The first ``n`` decompressed bytes of a file (``b""`` for a folder)."""
    p = Path(path)
    if p.is_dir():
        return b""
    with open_binary(p) as fh:
        out = b""
        while len(out) < n:
            try:
                chunk = fh.read(n - len(out))
            except (OSError, EOFError, lzma.LZMAError):  # a truncated compressed file: what was read is the head
                break
            if not chunk:
                break
            out += chunk
        return out


def is_text(data: bytes) -> bool:
    """Does ``data`` look like text (UTF-8, no NUL bytes, few control characters)?"""
    if b"\x00" in data:
        return False
    try:
        s = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(data) - 4:  # not just a multi-byte character cut at the end of the head
            return False
        s = data[: exc.start].decode("utf-8")
    bad = sum(1 for c in s if ord(c) < 32 and c not in "\r\n\t")
    return bad <= len(s) // 100


@contextmanager
def local_file(path: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """A plain (decompressed) file of the content of ``path`` for libraries that need a file name: ``path``
    itself if it is not compressed, else a temporary copy decompressed in blocks (removed afterwards)."""
    p = Path(path)
    if compression(p) is None:
        yield p
        return
    fd, tmp = tempfile.mkstemp(suffix=suffix or Path(plain_name(p)).suffix, prefix="rimu-")
    try:
        with os.fdopen(fd, "wb") as out, open_binary(p) as src:
            try:
                shutil.copyfileobj(src, out, 1 << 20)
            except (EOFError, lzma.LZMAError, OSError, ValueError, zlib.error) as exc:
                if isinstance(exc, OSError) and not isinstance(exc, (gzip.BadGzipFile, EOFError)) \
                        and exc.errno is not None:
                    raise
                raise SessionFormatError(f"{p}: the compressed stream is damaged or truncated ({type(exc).__name__});"
                                         " re-copy the file or decompress what is left by hand") from None
        yield Path(tmp)
    finally:
        os.unlink(tmp)
