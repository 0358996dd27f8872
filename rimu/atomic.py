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

A command run is one :class:`OutputGroup`: inside it every atomic write is held back (its temporary stays in the
target folder) until the group commits, so a command's outputs appear together or not at all. On an exception, a
refusal or Ctrl-C, :meth:`OutputGroup.abort` removes every temporary, every planned output file this run created
(also one a third-party writer wrote directly) and every folder it created, and says what it could not undo:

>>> with output_group([d / "x.json"]) as run:
...     _ = write_text(d / "x.json", "{}")
...     (d / "x.json").exists()       # held back until the group commits
False
>>> (d / "x.json").exists()
True
>>> try:
...     with output_group([d / "y.json", d / "z.md"], [d / "rep"]) as run:
...         _ = write_text(d / "y.json", "{}")
...         _ = (d / "z.md").write_text("half")     # a direct write: removed too
...         (d / "rep").mkdir()
...         raise KeyboardInterrupt
... except KeyboardInterrupt:
...     run.left_behind
[]
>>> sorted(p.name for p in d.iterdir())
['a.txt', 'b.txt', 'c.txt', 'x.json']
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import secrets
import shutil
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

__all__ = ["OutputGroup", "output_group", "current_group", "flush_outputs", "atomic_files", "atomic_path", "atomic_open", "write_text", "write_bytes", "AtomicFiles", "file_mode"]


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
        """Move the temporaries over their final names (inside an active :class:`OutputGroup`: when it
        commits)."""
        group = _GROUP.get()
        if group is not None:
            group._hold(self._pairs)
            self._pairs = []
            return
        _move(self._pairs)
        self._pairs.clear()

    def abort(self) -> None:
        _remove(p for p, _ in self._pairs)
        self._pairs.clear()


def _move(pairs: Iterable[tuple[Path, Path]]) -> None:
    mode = file_mode()
    for tmp, final in pairs:
        if tmp.exists():
            os.chmod(tmp, mode)
            os.replace(tmp, final)


def _remove(paths: Iterable[Path]) -> list[Path]:
    """Remove files (folders with their content); the ones that could not be removed."""
    left = []
    for p in paths:
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.exists() or p.is_symlink():
                p.unlink()
        except OSError:
            left.append(p)
    return left


def _state(p: Path) -> tuple[int, int, int] | None:
    try:
        st = p.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _listing(d: Path) -> set[Path]:
    return set(d.rglob("*")) if d.is_dir() else set()


_GROUP: contextvars.ContextVar[OutputGroup | None] = contextvars.ContextVar("rimu_output_group", default=None)


def current_group() -> OutputGroup | None:
    """The :class:`OutputGroup` of the command being run, if any."""
    return _GROUP.get()


class OutputGroup:
    """Every output of one run: atomic writes are held back until :meth:`commit`; :meth:`abort` undoes the run.

    Parameters
    ----------
    files : paths
        The output files the run plans to write (``-o``, ``--json``, sidecars, ...): one that did not exist before
        and exists at the abort is removed, whoever wrote it.
    dirs : paths
        The output folders (``--report``): a folder the run created is removed with its content; in a folder that
        existed, the entries the run added are removed.
    """

    def __init__(self, files: Iterable[str | os.PathLike[str]] = (), dirs: Iterable[str | os.PathLike[str]] = ()
                 ) -> None:
        self._held: list[tuple[Path, Path]] = []
        self._flushed: list[tuple[Path, Path | None]] = []
        self._files = {Path(f): _state(Path(f)) for f in files}
        self._dirs = {Path(d): (Path(d).is_dir(), _listing(Path(d))) for d in dirs}
        self._token: contextvars.Token | None = None
        self._started = time.time_ns() - 2_000_000_000  # (file system clocks are coarse)
        #: after :meth:`abort`: outputs that could not be removed, or existing files the run changed
        self.left_behind: list[Path] = []
        self.done = False

    def _hold(self, pairs: list[tuple[Path, Path]]) -> None:
        self._held.extend(pairs)

    def activate(self) -> OutputGroup:
        """Make this the group atomic writes of this context go to."""
        self._token = _GROUP.set(self)
        return self

    def _deactivate(self) -> None:
        if self._token is not None:
            _GROUP.reset(self._token)
            self._token = None

    def flush(self) -> None:
        """Move the held outputs into place now (a later step reads them: a build, a reload). An existing file
        they replace is kept aside until the group ends, so that :meth:`abort` can still put it back."""
        mode = file_mode()
        for tmp, final in self._held:
            if not tmp.exists():
                continue
            backup = None
            if final.exists():
                backup = final.parent / f".{final.name}.{secrets.token_hex(4)}.tmpbak"
                os.replace(final, backup)
            os.chmod(tmp, mode)
            os.replace(tmp, final)
            self._flushed.append((final, backup))
        self._held.clear()

    def commit(self) -> None:
        """Every held output appears under its name."""
        self._deactivate()
        if not self.done:
            self.flush()
            _remove(b for _, b in self._flushed if b is not None)
            self._flushed.clear()
            self.done = True

    def abort(self) -> list[Path]:
        """Undo the run: remove temporaries, new planned files, created folders and new entries of planned
        folders. Returns (and keeps in :attr:`left_behind`) what could not be undone."""
        self._deactivate()
        if self.done:
            return self.left_behind
        self.done = True
        left = _remove(t for t, _ in self._held)
        self._held.clear()
        for final, backup in reversed(self._flushed):  # outputs already in place: the previous file back
            try:
                if backup is not None:
                    os.replace(backup, final)
                else:
                    left += _remove([final])
            except OSError:
                left.append(final)
        self._flushed.clear()
        for f, before in self._files.items():
            now = _state(f)
            if before is None and now is not None:
                left += _remove([f])
            elif before is not None and now != before:
                left.append(f)  # an existing file the run replaced: cannot be restored
        for d, (existed, entries) in self._dirs.items():
            if not existed:
                left += _remove([d])
            else:
                new = sorted(_listing(d) - entries, key=lambda p: len(p.parts))
                top = [p for p in new if p.parent not in new]
                left += _remove(top)
        # temporaries of writers that were still open (their names carry the atomic pattern; made during this run)
        for folder in {f.parent for f in self._files} | {d for d in self._dirs if d.is_dir()}:
            with contextlib.suppress(OSError):
                left += _remove(p for p in folder.glob(".*.tmp*")
                                if _is_temporary(p) and p.stat().st_mtime_ns >= self._started)
        self.left_behind = left
        return left

    def folders(self) -> list[Path]:
        """The folders the run writes into (of the planned files and folders)."""
        return sorted({f.parent for f in self._files} | set(self._dirs))

    def __enter__(self) -> OutputGroup:
        return self.activate()

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is None:
            self.commit()
        else:
            self.abort()


def _is_temporary(p: Path) -> bool:
    parts = p.name.split(".")
    return p.name.startswith(".") and len(parts) >= 4 and any(x.startswith("tmp") for x in parts[2:]) and \
        any(len(x) == 8 and all(c in "0123456789abcdef" for c in x) for x in parts)


def flush_outputs() -> None:
    """Move the outputs held back so far into place (a command that reads one of its outputs back calls this
    first); outside a group, nothing to do."""
    group = _GROUP.get()
    if group is not None:
        group.flush()


def output_group(files: Iterable[str | os.PathLike[str]] = (), dirs: Iterable[str | os.PathLike[str]] = ()
                 ) -> OutputGroup:
    """An :class:`OutputGroup` as a context manager: commits on success, aborts on any exception."""
    return OutputGroup(files, dirs)



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
