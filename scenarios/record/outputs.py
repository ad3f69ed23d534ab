"""A run's output files: both or neither, complete, from the same run, never half-written.

A run writes its recording and its report under hidden temporary names beside the final
ones (``.<name>.rrd.<pid>.partial``). ``OutputPair.commit`` then checks the recording
reads back whole (Rerun writes its footer last; a full disk or a killed writer leaves none),
flushes both files to the disk (``fsync``), moves the previous pair aside, puts the new pair in
place and syncs the directory; if any step fails, the previous pair is put back and the error
is raised. Without ``commit`` (an exception, an interrupt) the temporary files are removed.

One run at a time writes into a directory (``directory_lock``); the next run into it
removes the temporary files of runs whose process no longer exists.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = [
    "OutputError",
    "OutputPair",
    "directory_lock",
    "remove_stale_partials",
    "verify_rrd",
    "write_atomic",
]

LOCK_NAME = ".vnav-demo.lock"
_TEMP = re.compile(r"^\..+\.(\d+)\.(partial|old)$")
"""Hidden temporary files of a run: ``.<file>.<pid>.partial`` (new) or ``.old`` (previous)."""


class OutputError(OSError):
    """An output file could not be written, checked or put in place; the message says which."""


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Write one file whole or not at all: ``write(tmp)`` fills a hidden temporary file beside
    ``path``, which is flushed to the disk and then renamed over ``path``.

    Raises
    ------
    OutputError
        If any step fails; ``path`` is then as it was and the temporary file is gone.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        write(tmp)
        _fsync(tmp)
        os.replace(tmp, path)
        _fsync(path.parent)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OutputError):
            raise
        raise OutputError(exc.errno, f"{path.name}: {exc.strerror or exc}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def verify_rrd(path: Path) -> None:
    """Check that a Rerun recording is complete: it has its footer and every chunk decodes.

    Raises
    ------
    OutputError
        Naming the file and what is wrong with it.
    """
    from rerun.chunk import RrdReader  # Rerun only where a recording is checked

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            n_chunks = sum(1 for _ in RrdReader(str(path)).stream().to_chunks())
        except Exception as exc:  # Rerun reports a damaged file as RuntimeError
            raise OutputError(errno.EIO, f"{path.name} does not read back: {exc}") from None
    if any("no footer" in str(w.message) for w in caught) or n_chunks == 0:
        raise OutputError(errno.EIO, f"{path.name} is incomplete (no footer): disk full?")


class OutputPair:
    """The recording and the report of one run, committed together.

    Parameters
    ----------
    rrd_path, json_path : Path
        Final names; nothing changes there before ``commit``.
    """

    def __init__(self, rrd_path: Path, json_path: Path) -> None:
        self.finals = (Path(rrd_path), Path(json_path))
        pid = os.getpid()
        self.rrd_tmp, self.json_tmp = (p.with_name(f".{p.name}.{pid}.partial") for p in self.finals)

    def write_json(self, text: str) -> None:
        """Write the report's text to its temporary name and flush it to the disk."""
        try:
            with open(self.json_tmp, "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise OutputError(exc.errno, f"{self.finals[1].name}: {exc.strerror}") from None

    def commit(self) -> None:
        """Check the recording, then put both files in place together (see the module doc).

        Raises
        ------
        OutputError
            If the recording is incomplete or a file cannot be synced or moved; the previous
            pair (if any) is then as it was, and the temporary files are removed.
        """
        try:
            verify_rrd(self.rrd_tmp)
            _fsync(self.rrd_tmp)
            self._swap()
            _fsync(self.finals[0].parent)
        except OSError as exc:
            self.discard()
            if isinstance(exc, OutputError):
                raise
            raise OutputError(exc.errno, f"{exc.strerror}: {exc.filename}") from None

    def _swap(self) -> None:
        """Previous pair aside, new pair in, previous pair deleted; undone on failure."""
        pid = os.getpid()
        olds = [p.with_name(f".{p.name}.{pid}.old") for p in self.finals]
        moved: list[tuple[Path, Path]] = []
        placed: list[Path] = []
        try:
            for final, old in zip(self.finals, olds, strict=True):
                if final.exists():
                    os.replace(final, old)
                    moved.append((old, final))
            for tmp, final in zip((self.rrd_tmp, self.json_tmp), self.finals, strict=True):
                os.replace(tmp, final)
                placed.append(final)
        except OSError:
            for final in placed:
                final.unlink(missing_ok=True)
            for old, final in moved:
                os.replace(old, final)
            raise
        for old, _ in moved:
            old.unlink(missing_ok=True)

    def discard(self) -> None:
        """Remove the temporary files (the final names are untouched)."""
        for tmp in (self.rrd_tmp, self.json_tmp):
            tmp.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_partials(out_dir: Path) -> list[Path]:
    """Delete the temporary files of runs into ``out_dir`` whose process no longer exists.

    Returns
    -------
    list of Path
        What was removed.
    """
    removed = []
    for path in Path(out_dir).iterdir():
        match = _TEMP.match(path.name)
        if match and int(match.group(1)) != os.getpid() and not _alive(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


@contextlib.contextmanager
def directory_lock(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir``'s lock while writing into it; then clear dead runs' temporary files.

    Raises
    ------
    BlockingIOError
        If another run holds the lock (the caller says so and stops).
    """
    fd = os.open(Path(out_dir) / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        remove_stale_partials(Path(out_dir))
        yield
    finally:
        os.close(fd)  # releases the lock
