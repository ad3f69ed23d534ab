"""A run's output files: both or neither, complete, from the same run, never half-written, at
whatever instant the run is stopped (SIGKILL included).

Every file is first written under a hidden temporary name beside its final one, made by
``temp_path`` alone: ``.vnav-demo.<pid>.<name>.partial`` for the new file, ``.old`` for the
previous one while a pair is swapped and ``.journal`` for the swap's journal. Apart from a
new file it put in place itself (a swap undone), these are the only files this program
removes: a user's file never has such a name, whatever its suffix.

``write_atomic`` writes one file: the temporary file is flushed to the disk (``fsync``) and
renamed over the final name. ``OutputPair.commit`` puts a recording and its report in place
together, as a database commits with a journal: it checks the recording reads back whole
(Rerun writes its footer last; a full disk or a killed writer leaves none), flushes both files,
writes and flushes a journal naming the pair and its new files, moves the previous pair aside,
puts the new pair in place, deletes the previous pair and then the journal. If a step fails,
the previous pair is put back and the error is raised; without ``commit`` (an exception, an
interrupt) the temporary files are removed.

One run at a time writes into a directory (``directory_lock``). Under the lock, the next run
first finishes the work of runs whose process no longer exists (``remove_stale_partials``): a
journal left by a killed commit is rolled forward if the new pair is there whole (both files,
as the journal names them), else rolled back to the previous pair; then the dead runs'
temporary files are removed. Whatever instant a run was killed at, the directory then holds the
previous pair or the new one, whole, and none of the dead run's temporary files.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

__all__ = [
    "LOCK_NAME",
    "TEMP_PREFIX",
    "LockError",
    "OutputError",
    "OutputPair",
    "directory_lock",
    "remove_stale_partials",
    "temp_path",
    "temporary",
    "verify_rrd",
    "write_atomic",
]

logger = logging.getLogger(__name__)

LOCK_NAME = ".vnav-demo.lock"
TEMP_PREFIX = ".vnav-demo."
"""Every temporary name this program makes starts so (``temp_path``)."""
_KINDS = ("partial", "old", "journal")
_TEMP = re.compile(r"^\.vnav-demo\.(\d+)\.(.+)\.(partial|old|journal)$")
"""``temp_path``'s names: the process id, the final file's name and the kind."""

_in_progress: set[Path] = set()
"""This process's temporary files still in use. A file named with this process's id but not
here was left by an earlier process with the same id (in a container, every command may get
the same one)."""


class OutputError(OSError):
    """An output file could not be written, checked or put in place; the message says which."""


class LockError(OutputError):
    """A directory's lock file cannot be opened (its name is taken by a directory...); the
    message (``str``) names it and says why."""


def temp_path(final: Path, kind: str = "partial", pid: int | None = None) -> Path:
    """The hidden temporary name of ``final`` beside it: ``.vnav-demo.<pid>.<name>.<kind>``.

    Parameters
    ----------
    final : Path
        The file's final name.
    kind : {"partial", "old", "journal"}
        The new file being written, the previous one moved aside, or a commit's journal.
    pid : int, optional
        The writing process's id (default: this process's).

    Raises
    ------
    ValueError
        If ``kind`` is none of these.
    """
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    final = Path(final)
    return final.with_name(
        f"{TEMP_PREFIX}{os.getpid() if pid is None else pid}.{final.name}.{kind}"
    )


@contextlib.contextmanager
def temporary(final: Path) -> Iterator[Path]:
    """This process's temporary name for ``final`` (``temp_path``), removed when the block
    ends if it is still there (renamed into place, it is not)."""
    tmp = temp_path(final)
    _in_progress.add(tmp)
    try:
        yield tmp
    finally:
        try:
            tmp.unlink(missing_ok=True)
        finally:
            _in_progress.discard(tmp)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Write one file whole or not at all: ``write(tmp)`` fills a hidden temporary file beside
    ``path`` (``temp_path``), which is flushed to the disk and then renamed over ``path``.

    Raises
    ------
    OutputError
        If any step fails; ``path`` is then as it was and the temporary file is gone.
    """
    path = Path(path)
    try:
        with temporary(path) as tmp:
            write(tmp)
            _fsync(tmp)
            os.replace(tmp, path)
            _fsync(path.parent)
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(exc.errno, f"{path.name}: {exc.strerror or exc}") from None


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


def _size(path: Path) -> int | None:
    """The file's size in bytes, or None if there is no file."""
    try:
        return os.stat(path).st_size
    except FileNotFoundError:
        return None


class _Swap:
    """The journalled swap of a group of files (a recording and its report) in one directory.

    ``finals`` are the final names, ``news`` the new files (``.partial``), ``olds`` where the
    previous files wait while the new ones are put in place (``.old``), ``journal`` the file
    naming them, all named by ``temp_path`` with the writer's process id. The journal's first
    line holds the final names, the new files' sizes and which final names held a previous
    file; a second line ``back`` marks a swap being undone.

    Every state the swap passes through is told by which names exist: a new file leaves its
    temporary name only by its rename to the final name, and a previous file its ``.old``
    name only by its rename back or, once every new file is in place, by its deletion.
    """

    def __init__(self, finals: Sequence[Path], pid: int) -> None:
        self.finals = tuple(Path(p) for p in finals)
        self.news = tuple(temp_path(p, "partial", pid) for p in self.finals)
        self.olds = tuple(temp_path(p, "old", pid) for p in self.finals)
        self.journal = temp_path(self.finals[-1], "journal", pid)
        self.directory = self.finals[-1].parent

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every temporary name of the swap."""
        return (*self.news, *self.olds, self.journal)

    # ------------------------------------------------------------------ the commit, in order

    def begin(self) -> None:
        """Write the journal and flush it (and its name) to the disk: from here, whatever
        instant the process dies at, ``recover`` ends the swap one way or the other."""
        entry = {
            "files": [p.name for p in self.finals],
            "sizes": [os.stat(p).st_size for p in self.news],
            "previous": [p.exists() for p in self.finals],
        }
        self._write_journal(json.dumps(entry) + "\n", os.O_CREAT | os.O_TRUNC)

    def _write_journal(self, text: str, flags: int) -> None:
        fd = os.open(self.journal, os.O_WRONLY | flags, 0o644)
        try:
            os.write(fd, text.encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        _fsync(self.directory)

    def put_in_place(self) -> None:
        """Previous files aside, new files in (each an atomic rename), flushed."""
        for final, old in zip(self.finals, self.olds, strict=True):
            if final.exists():
                os.replace(final, old)
        for new, final in zip(self.news, self.finals, strict=True):
            os.replace(new, final)
        _fsync(self.directory)

    def end(self) -> list[Path]:
        """Delete the previous files, then the journal: the swap is over. Return what was
        deleted."""
        removed = [old for old in self.olds if _unlink(old)]
        _fsync(self.directory)  # the previous files gone before the journal that names them
        if _unlink(self.journal):
            removed.append(self.journal)
        return removed

    def roll_back(self) -> list[Path]:
        """Put the previous files back and remove the new ones (at their temporary or final
        names), then the journal. Return what was removed."""
        entry = self._entry()
        if entry is None:
            raise OutputError(errno.EIO, f"{self.journal} cannot be read back")
        if not entry["back"]:  # from here a recovery goes on backwards, never forwards
            self._write_journal("back\n", os.O_APPEND)
        removed = []
        for final, old, new, size, previous in zip(
            self.finals, self.olds, self.news, entry["sizes"], entry["previous"], strict=True
        ):
            if old.exists():
                os.replace(old, final)  # over the new file, if it was put there
            elif not previous and not new.exists() and _size(final) == size:
                final.unlink()  # the new file, where there was none before
                removed.append(final)
        _fsync(self.directory)  # the previous files back before the new ones go
        removed += [new for new in self.news if _unlink(new)]
        _fsync(self.directory)
        if _unlink(self.journal):
            removed.append(self.journal)
        return removed

    # ------------------------------------------------------------- after the writer has died

    def _entry(self) -> dict | None:
        """The journal's content if it is one this program wrote whole, else None."""
        try:
            first, _, rest = self.journal.read_text(encoding="utf-8").partition("\n")
            entry = json.loads(first)
        except (OSError, ValueError):
            return None
        if not isinstance(entry, dict) or entry.get("files") != [p.name for p in self.finals]:
            return None
        n = len(self.finals)
        sizes, previous = entry.get("sizes"), entry.get("previous")
        if not (
            isinstance(sizes, list)
            and isinstance(previous, list)
            and len(sizes) == len(previous) == n
            and all(type(v) is int and v >= 0 for v in sizes)
            and all(type(v) is bool for v in previous)
        ):
            return None
        return {"sizes": sizes, "previous": previous, "back": rest.startswith("b")}

    @classmethod
    def from_journal(cls, journal: Path) -> _Swap | None:
        """The swap a journal names, or None if it is not a whole journal of this program's
        (it is written whole before any file is moved: one cut short names no move)."""
        match = _TEMP.match(journal.name)
        try:
            files = json.loads(journal.read_text(encoding="utf-8").partition("\n")[0])["files"]
        except (OSError, ValueError, TypeError, KeyError):
            return None
        if not (
            match
            and isinstance(files, list)
            and files
            and all(
                isinstance(f, str) and f == Path(f).name and f not in ("", ".", "..") for f in files
            )
        ):
            return None
        swap = cls([journal.parent / f for f in files], int(match.group(1)))
        if swap.journal != journal or swap._entry() is None:
            return None
        return swap

    def recover(self) -> list[Path]:
        """End a swap whose writer died: forward if it was not being undone and every new
        file is there whole (its size as the journal says, at its temporary name or, moved,
        at its final one), else back to the previous files. Each step can itself be cut short
        and recovered again. Return what was removed."""
        entry = self._entry()
        if entry is None:
            raise OutputError(errno.EIO, f"{self.journal} cannot be read back")
        whole = all(
            _size(new) == size if new.exists() else _size(final) == size
            for new, final, size in zip(self.news, self.finals, entry["sizes"], strict=True)
        )
        if whole and not entry["back"]:
            logger.info("%s: finishing the commit of a run that died", self.journal)
            for new, final in zip(self.news, self.finals, strict=True):
                if new.exists():
                    os.replace(new, final)
            _fsync(self.directory)
            return self.end()
        logger.info("%s: undoing the commit of a run that died", self.journal)
        return self.roll_back()


def _unlink(path: Path) -> bool:
    """Remove ``path``; True if it was there."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        return False
    return True


class OutputPair:
    """The recording and the report of one run, committed together.

    Parameters
    ----------
    rrd_path, json_path : Path
        Final names; nothing changes there before ``commit``.
    """

    def __init__(self, rrd_path: Path, json_path: Path) -> None:
        self.finals = (Path(rrd_path), Path(json_path))
        self._swap = _Swap(self.finals, os.getpid())
        self.rrd_tmp, self.json_tmp = self._swap.news
        self._pending = False  # a journal left for the next run to recover
        _in_progress.update(self._swap.paths)

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
            pair (if any) is then as it was, and the temporary files are removed. Should
            putting it back fail too, the journal stays and the next run into the directory
            ends the commit (``remove_stale_partials``); the message says so.
        """
        swap = self._swap
        try:
            verify_rrd(self.rrd_tmp)
            _fsync(self.rrd_tmp)
            swap.begin()
        except OSError as exc:
            with contextlib.suppress(OSError):
                _unlink(swap.journal)
            self.discard()
            raise _output_error(exc) from None
        except BaseException:
            with contextlib.suppress(OSError):
                _unlink(swap.journal)
            self.discard()
            raise
        try:
            swap.put_in_place()
        except BaseException as exc:
            # An error or an interrupt (SIGTERM, Ctrl-C) mid-swap: the previous pair back.
            try:
                swap.roll_back()
            except BaseException:
                self._pending = True  # the next run recovers it; nothing more is touched
                if isinstance(exc, OSError):
                    raise OutputError(
                        exc.errno,
                        f"{_output_error(exc)}; the next run into {swap.directory} puts the "
                        "previous pair back",
                    ) from None
                raise
            self.discard()
            if isinstance(exc, OSError):
                raise _output_error(exc) from None
            raise
        try:
            swap.end()  # the new pair is in place: what is left is clearing up
        except BaseException as exc:
            self._pending = True  # the next run removes the previous pair
            if isinstance(exc, OSError):
                raise OutputError(
                    exc.errno,
                    f"{_output_error(exc)}; the new pair is in place, the next run into "
                    f"{swap.directory} removes the previous one",
                ) from None
            raise
        _in_progress.difference_update(swap.paths)

    def discard(self) -> None:
        """Remove the temporary files (the final names are untouched); nothing while a
        commit's journal is left for the next run to recover."""
        if self._pending:
            return
        for tmp in (self.rrd_tmp, self.json_tmp):
            tmp.unlink(missing_ok=True)
        _in_progress.difference_update(self._swap.paths)


def _output_error(exc: OSError) -> OutputError:
    if isinstance(exc, OutputError):
        return exc
    where = f": {Path(exc.filename).name}" if exc.filename else ""
    return OutputError(exc.errno, f"{exc.strerror or exc}{where}")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _stale(path: Path) -> bool:
    """A temporary name of this program's whose writer is gone (``temp_path``)."""
    match = _TEMP.match(path.name)
    if match is None:
        return False
    pid = int(match.group(1))
    return not _alive(pid) or (pid == os.getpid() and path not in _in_progress)


def remove_stale_partials(out_dir: Path) -> list[Path]:
    """End the work of runs into ``out_dir`` whose process no longer exists: finish or roll
    back their interrupted commits (``OutputPair``'s journals), then delete their temporary
    files. Only names made by ``temp_path`` are touched (and the final names of an undone
    swap). A ``.old`` file with no journal beside it is left alone (a swap deletes its
    journal last), as are the files of a run whose journal is not one this program wrote.

    Returns
    -------
    list of Path
        What was removed.

    Raises
    ------
    OSError
        If a file cannot be moved or removed; what is left is recovered by the next call.
    """
    out_dir = Path(out_dir)
    removed, unknown = [], set()
    for journal in sorted(out_dir.glob(f"{TEMP_PREFIX}*.journal")):
        if not _stale(journal):
            continue
        swap = _Swap.from_journal(journal)
        pid = _TEMP.match(journal.name).group(1)
        if swap is not None:
            removed += swap.recover()
        elif not list(out_dir.glob(f"{TEMP_PREFIX}{pid}.*.old")):
            # Cut short while it was written: no file was moved yet.
            removed += [journal] if _unlink(journal) else []
        else:  # not written by this program: its run's files are left as they are
            logger.warning("%s: not a journal this program wrote; left alone", journal)
            unknown.add(pid)
    for path in sorted(out_dir.iterdir()):
        match = _TEMP.match(path.name)
        if (
            match
            and match.group(3) == "partial"
            and match.group(1) not in unknown
            and _stale(path)
            and _unlink(path)
        ):
            removed.append(path)
    return removed


@contextlib.contextmanager
def directory_lock(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir``'s lock while writing into it, after ending the work of dead runs in it
    (``remove_stale_partials``).

    Raises
    ------
    BlockingIOError
        If another run holds the lock (the caller says so and stops).
    LockError
        If the lock file cannot be opened (its name is a directory...).
    OutputError
        If a dead run's commit cannot be ended; nothing should then be written there.
    """
    lock = Path(out_dir) / LOCK_NAME
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        reason = (
            "is a directory" if exc.errno == errno.EISDIR else f"cannot be opened ({exc.strerror})"
        )
        raise LockError(
            f"{lock} {reason}: vnav-demo locks the output directory with a file of that name; "
            "remove or rename it"
        ) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        try:
            remove_stale_partials(Path(out_dir))
        except OSError as exc:
            raise OutputError(
                exc.errno, f"cannot end a dead run's work in {out_dir}: {_output_error(exc)}"
            ) from None
        yield
    finally:
        os.close(fd)  # releases the lock
