"""Atomic file writes: every file rimu writes appears whole or not at all.

Each output is written to a temporary file in the same folder and moved over its final name with
:func:`os.replace` once complete, so an interrupted run (Ctrl-C, a crash, a full disk) never leaves a half-written
session, calibration or report behind, and never damages the file it was going to replace. The new file gets the
normal mode of a new file (``0o666`` less the umask), not the ``0o600`` of :func:`tempfile.mkstemp`.

>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> write_text(d / "a.txt", "hello").name
'a.txt'
>>> (d / "a.txt").read_text()
'hello'
>>> with atomic_files() as tx:          # several files replaced together at the end
...     _ = tx.path(d / "b.txt").write_text("b")
...     _ = tx.path(d / "c.txt").write_text("c")
>>> sorted(p.name for p in d.iterdir())
['a.txt', 'b.txt', 'c.txt']
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO

__all__ = ["atomic_files", "atomic_path", "atomic_open", "write_text", "write_bytes", "AtomicFiles", "file_mode"]


def file_mode() -> int:
    """The mode a new file gets in this process: ``0o666`` less the umask."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


class AtomicFiles:
    """Temporary paths for a group of outputs, moved over their final names together by :meth:`commit`.

    Use through :func:`atomic_files`; on any exception (including ``KeyboardInterrupt``) every temporary file is
    removed and no final file is touched.
    """

    def __init__(self) -> None:
        self._pairs: list[tuple[Path, Path]] = []

    def path(self, final: str | os.PathLike[str]) -> Path:
        """A temporary path beside ``final`` with the same suffix (numpy and matplotlib pick the format from
        it)."""
        final = Path(final)
        tmp = final.parent / f".{final.name}.{secrets.token_hex(4)}.tmp{final.suffix}"
        self._pairs.append((tmp, final))
        return tmp

    def commit(self) -> None:
        mode = file_mode()
        for tmp, final in self._pairs:
            if tmp.exists():
                os.chmod(tmp, mode)
                os.replace(tmp, final)
        self._pairs.clear()

    def abort(self) -> None:
        for tmp, _ in self._pairs:
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._pairs.clear()


@contextlib.contextmanager
def atomic_files() -> Iterator[AtomicFiles]:
    """A group of atomic outputs: ``with atomic_files() as tx: write to tx.path(final) ...``."""
    tx = AtomicFiles()
    try:
        yield tx
    except BaseException:
        tx.abort()
        raise
    tx.commit()


@contextlib.contextmanager
def atomic_path(final: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path to write ``final`` through (for writers that take a path: ``np.savez``,
    ``fig.savefig``)."""
    with atomic_files() as tx:
        yield tx.path(final)


@contextlib.contextmanager
def atomic_open(final: str | os.PathLike[str], mode: str = "w", encoding: str | None = "utf-8",
                newline: str | None = None) -> Iterator[IO]:
    """``open`` for writing, atomically: the file appears under its name only when the block ends without an
    exception."""
    if "b" in mode:
        encoding = None
    with atomic_path(final) as tmp, open(tmp, mode, encoding=encoding, newline=newline) as fh:
        yield fh


def write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """``Path.write_text``, atomically. Returns the final path."""
    with atomic_open(path, "w", encoding=encoding) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """``Path.write_bytes``, atomically. Returns the final path."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return Path(path)
