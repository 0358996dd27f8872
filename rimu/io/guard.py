"""Reader failures as rimu errors: every reader of a file goes through :func:`reading` (text, compressed text) or
:func:`load_array` (``.npy``/``.npz``), so that garbage, a truncated file, a wrong encoding or a damaged
compression ends in one :class:`~rimu.errors.SessionFormatError` naming the file, the line where it can be known,
and what to do, never in ``UnicodeDecodeError``, ``EOFError``, ``BadGzipFile`` or numpy's advice to load
"unsafely using allow_pickle".

>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "log.csv"
>>> _ = p.write_bytes(b"t,x\\n0,1\\n1,\\x80\\n")
>>> try:
...     with reading(p):
...         _ = p.read_text(encoding="utf-8")
... except SessionFormatError as exc:
...     print(str(exc).replace(str(p.parent), "DIR"))
DIR/log.csv: line 3 (byte 10) is not UTF-8 text (invalid start byte); save the file as UTF-8 (or plain ASCII) text
"""

from __future__ import annotations

import bz2
import contextlib
import csv
import gzip
import lzma
import os
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..errors import RimuError, SessionFormatError

__all__ = ["reading", "load_array", "COMPRESSED"]

NEWLINE = b"\n"

#: suffix -> opener of the compressed text files every text reader accepts
COMPRESSED = {".xz": lzma.open, ".gz": gzip.open, ".bz2": bz2.open}


def _bytes(path: Path, limit: int = 1 << 26) -> bytes | None:
    """The (decompressed) bytes of ``path``, at most ``limit``; None if they cannot be read."""
    opener = COMPRESSED.get(path.suffix.lower(), open)
    try:
        with opener(path, "rb") as fh:  # type: ignore[operator]
            return bytes(fh.read(limit))
    except Exception:
        return None


def _line_of(path: Path, exc: UnicodeDecodeError) -> str:
    data = _bytes(path)
    if data is not None:
        try:
            data.decode(exc.encoding or "utf-8")
        except UnicodeDecodeError as e:
            return f"line {data.count(NEWLINE, 0, e.start) + 1} (byte {e.start})"
    return "the file"


@contextlib.contextmanager
def reading(path: str | os.PathLike[str], what: str = "text",
            parse_errors: tuple[type[Exception], ...] = ()) -> Iterator[None]:
    """Turn the failures of reading ``path`` inside the block into one :class:`SessionFormatError` naming it.

    A missing file (``FileNotFoundError``, with its name) and rimu's own errors pass unchanged; ``parse_errors``
    are the exceptions a third-party parser raises on a malformed file (python-can's log readers:
    ``ValueError``, ``IndexError``).
    """
    p = Path(path)
    try:
        yield
    except RimuError:
        raise
    except UnicodeError as exc:
        if isinstance(exc, UnicodeDecodeError):
            raise SessionFormatError(f"{p}: {_line_of(p, exc)} is not UTF-8 {what} ({exc.reason}); save the file "
                                     "as UTF-8 (or plain ASCII) text") from None
        raise SessionFormatError(f"{p}: not UTF-8 {what} ({exc}); save the file as UTF-8 text") from None
    except (EOFError, zlib.error, lzma.LZMAError, gzip.BadGzipFile, zipfile.BadZipFile) as exc:
        raise SessionFormatError(f"{p}: the file ends early or its compression is damaged ({type(exc).__name__}: "
                                 f"{exc}); the copy may be incomplete: copy or export it again") from None
    except OSError as exc:
        if exc.filename is not None or isinstance(exc, (FileNotFoundError, PermissionError, IsADirectoryError)):
            raise
        raise SessionFormatError(f"{p}: cannot be read as {what} ({exc}); the file may be damaged or not "
                                 "what its name says: copy or export it again") from None
    except csv.Error as exc:
        raise SessionFormatError(f"{p}: not CSV text ({exc}); check that this is the right file") from None
    except parse_errors as exc:
        raise SessionFormatError(f"{p}: not a readable {what} ({type(exc).__name__}: {exc}); check that this is "
                                 "the right file and that it is complete") from None


def load_array(path: str | os.PathLike[str], what: str = "array file") -> Any:
    """``numpy.load(path)`` without pickles: an ``ndarray`` (``.npy``) or a loaded ``NpzFile`` (``.npz``, read
    into a dict), or :class:`SessionFormatError` naming the file and what to do.

    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "empty.npz"
    >>> _ = p.write_bytes(b"")
    >>> load_array(p)
    Traceback (most recent call last):
    ...
    rimu.errors.SessionFormatError: .../empty.npz: empty file; write the array file with numpy.save or numpy.savez
    """
    import tokenize

    import numpy as np

    p = Path(path)
    if p.is_file() and p.stat().st_size == 0:
        raise SessionFormatError(f"{p}: empty file; write the {what} with numpy.save or numpy.savez")
    try:
        z = np.load(p, allow_pickle=False)
        if hasattr(z, "files"):
            with z:
                return {k: z[k] for k in z.files}
        return z
    except (FileNotFoundError, PermissionError, IsADirectoryError):
        raise
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            with open(p, "rb") as fh:
                head = fh.read(2)
            if head[:1] == b"\x80":  # a pickle (protocol 2 and later)
                raise SessionFormatError(f"{p}: holds pickled Python objects, which rimu never loads; save plain "
                                         "numeric arrays with numpy.save or numpy.savez") from None
            raise SessionFormatError(f"{p}: not an NPZ or NPY file (numpy's files start with 'PK' or "
                                     f"'\\x93NUMPY', this one with {head!r}); write the {what} with numpy.save or "
                                     "numpy.savez") from None
        raise SessionFormatError(f"{p}: not a readable {what} ({exc}); write it with numpy.save or numpy.savez")\
            from None
    except (OSError, EOFError, KeyError, SyntaxError, tokenize.TokenError, zipfile.BadZipFile, zlib.error) as exc:
        raise SessionFormatError(f"{p}: not a readable {what} ({type(exc).__name__}: {exc}); it may be truncated "
                                 "or not written by numpy.save / numpy.savez") from None
