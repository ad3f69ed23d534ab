"""A run's output files: all or none, complete, from the same run, never half-written, at
whatever instant the run is stopped (SIGKILL included).

Every file is first written under a hidden temporary name beside its final one, made by
``temp_path`` alone: ``.vnav-demo.<pid>.<name>.partial`` for the new file, ``.old`` for the
previous one while a set is swapped and ``.journal`` for the swap's journal. Apart from a
new file it put in place itself (a swap undone), these are the only files this program
removes: a user's file never has such a name, whatever its suffix. A final name may be a
directory (an export such as ``NAME.euroc/``): it is written, moved and removed whole under
the same temporary names, and only ever deleted at one of them.

``write_atomic`` writes one file: the temporary file is flushed to the disk (``fsync``) and
renamed over the final name. ``OutputPair.commit`` puts a recording, its report and the run's
exports (``OutputPair.add``) in place together, as a database commits with a journal: it
checks the recording reads back whole (Rerun writes its footer last; a full disk or a killed
writer leaves none), flushes every file, writes and flushes a journal naming the set and its
new files, moves the previous files aside, puts the new set in place, deletes the previous
files and then the journal. A final name with no new file this time (an export that wrote
nothing there) loses its previous file with the swap, so that no file of an older run is left
beside the new set. If a step fails, the previous set is put back and the error is raised;
without ``commit`` (an exception, an interrupt) the temporary files are removed.

One run at a time writes into a directory (``directory_lock``). Under the lock, the next run
first finishes the work of runs whose process no longer exists (``remove_stale_partials``): a
journal left by a killed commit is rolled forward if the new set is there whole (every new
file or directory, its size as the journal names it), else rolled back to the previous set;
then the dead runs' temporary files are removed. Whatever instant a run was killed at, the
directory then holds the previous set or the new one, whole, and none of the dead run's
temporary files.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
import shutil
import signal
import stat
import threading
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
    "signals_held",
    "staging_dir",
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


@contextlib.contextmanager
def staging_dir(final: Path) -> Iterator[Path]:
    """A new empty directory at this process's temporary name for ``final``
    (``temp_path``), removed with what it holds when the block ends.

    Raises
    ------
    OutputError
        If it cannot be made.
    """
    tmp = temp_path(final)
    _in_progress.add(tmp)
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise _output_error(exc) from None
        yield tmp
    finally:
        try:
            _remove(tmp)
        finally:
            _in_progress.discard(tmp)


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP received inside the block take effect at its end.

    For two steps that must not be parted: a file put in place and the record in memory of
    what it holds (a sweep's journal entry and its episode). A command's handlers raise an
    exception in the main thread at the next bytecode (``scenarios.commands.common``), which
    can land between the two. Blocking the signals (``pthread_sigmask``) would not do: any
    other thread of the process (Ray's, Rerun's) takes the signal instead and Python runs the
    handler in the main thread all the same. So each is caught here and, once the block is
    done and the previous handlers are back, sent again (``signal.raise_signal``) to them.
    Outside the main thread (where handlers cannot be set) the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.getsignal(s) for s in _HELD_SIGNALS}
    for s in _HELD_SIGNALS:
        signal.signal(s, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(caught):  # each once, in the order they came
            signal.raise_signal(signum)


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
    """A file's size in bytes; for a directory, the bytes of every file in it plus the number
    of its entries, at any depth (each deletion lowers it, so a directory cut short while it
    was removed never has its whole size); None if there is nothing."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    if not stat.S_ISDIR(st.st_mode):
        return st.st_size
    total = 0
    for root, dirs, files in os.walk(path):
        total += len(dirs) + len(files)
        total += sum(os.lstat(os.path.join(root, f)).st_size for f in files)
    return total


def _size_of(path: Path) -> int:
    """``_size`` of a file that must be there (FileNotFoundError if it is not)."""
    size = _size(path)
    if size is None:
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(path))
    return size


def _exists(path: Path) -> bool:
    return os.path.lexists(path)


def _remove(path: Path) -> bool:
    """Remove a file or a directory tree; True if something was there."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    if stat.S_ISDIR(st.st_mode):
        shutil.rmtree(path)
        return True
    return _unlink(path)


def _fsync_tree(path: Path, files: bool = True) -> None:
    """Flush a file, or every file (unless ``files`` is false: flushed already) and directory
    of a tree, directories after their files."""
    if not Path(path).is_dir():
        if files:
            _fsync(path)
        return
    for root, _, names in os.walk(path, topdown=False):
        if files:
            for f in names:
                _fsync(Path(root, f))
        _fsync(Path(root))


class _Swap:
    """The journalled swap of a set of files (a recording, its report, the run's exports) in
    one directory.

    ``finals`` are the final names, ``news`` the new files or directories (``.partial``;
    None where the set has no new file: the previous one is then removed), ``olds`` where
    the previous files wait while the new ones are put in place (``.old``), ``journal`` the
    file naming them, all named by ``temp_path`` with the writer's process id. The journal's
    first line holds the final names, the new files' sizes (``_size``; null for no new file)
    and which final names held a previous file; a second line ``back`` marks a swap being
    undone.

    Every state the swap passes through is told by which names exist: a new file leaves its
    temporary name only by its rename to the final name (or, a directory being undone, back
    from it), and a previous file its ``.old`` name only by its rename back or, once every new
    file is in place, by its deletion. A directory is deleted only at a temporary name.
    """

    def __init__(self, finals: Sequence[Path], pid: int, has_new: Sequence[bool] | None = None):
        self.finals = tuple(Path(p) for p in finals)
        has_new = [True] * len(self.finals) if has_new is None else list(has_new)
        self.news = tuple(
            temp_path(p, "partial", pid) if new else None
            for p, new in zip(self.finals, has_new, strict=True)
        )
        self.olds = tuple(temp_path(p, "old", pid) for p in self.finals)
        self.journal = temp_path(self.finals[-1], "journal", pid)
        self.directory = self.finals[-1].parent

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every temporary name of the swap."""
        return (*(p for p in self.news if p is not None), *self.olds, self.journal)

    # ------------------------------------------------------------------ the commit, in order

    def begin(self) -> None:
        """Write the journal and flush it (and its name) to the disk: from here, whatever
        instant the process dies at, ``recover`` ends the swap one way or the other."""
        entry = {
            "files": [p.name for p in self.finals],
            "sizes": [None if p is None else _size_of(p) for p in self.news],
            "previous": [_exists(p) for p in self.finals],
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
            if _exists(final):
                os.replace(final, old)
        for new, final in zip(self.news, self.finals, strict=True):
            if new is not None:
                os.replace(new, final)
        _fsync(self.directory)

    def end(self) -> list[Path]:
        """Delete the previous files, then the journal: the swap is over. Return what was
        deleted."""
        removed = [old for old in self.olds if _remove(old)]
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
            if new is None:  # nothing new went there: the previous file back, if moved
                if _exists(old):
                    os.replace(old, final)
                continue
            if _exists(old):
                if os.path.isdir(old) and _exists(final):
                    # A directory cannot be renamed over: the new one back to its temporary
                    # name (removed below) first.
                    os.replace(final, new)
                os.replace(old, final)  # over the new file, if it was put there
            elif not previous and not _exists(new) and _size(final) == size:
                if os.path.isdir(final):
                    os.replace(final, new)  # removed below, at its temporary name
                else:
                    final.unlink()  # the new file, where there was none before
                    removed.append(final)
        _fsync(self.directory)  # the previous files back before the new ones go
        removed += [new for new in self.news if new is not None and _remove(new)]
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
            and all(
                (v is None) if new is None else (type(v) is int and v >= 0)
                for v, new in zip(sizes, self.news, strict=True)
            )
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
            entry = json.loads(journal.read_text(encoding="utf-8").partition("\n")[0])
            files, sizes = entry["files"], entry["sizes"]
        except (OSError, ValueError, TypeError, KeyError):
            return None
        if not (
            match
            and isinstance(files, list)
            and files
            and isinstance(sizes, list)
            and len(sizes) == len(files)
            and all(
                isinstance(f, str) and f == Path(f).name and f not in ("", ".", "..") for f in files
            )
        ):
            return None
        swap = cls(
            [journal.parent / f for f in files], int(match.group(1)), [v is not None for v in sizes]
        )
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
            new is None or (_size(new) if _exists(new) else _size(final)) == size
            for new, final, size in zip(self.news, self.finals, entry["sizes"], strict=True)
        )
        if whole and not entry["back"]:
            logger.info("%s: finishing the commit of a run that died", self.journal)
            for new, final, old in zip(self.news, self.finals, self.olds, strict=True):
                if new is None or _exists(new):
                    # Not moved yet: what the final name holds is the previous file, aside.
                    if _exists(final):
                        os.replace(final, old)
                    if new is not None:
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
    """The recording and the report of one run, and its exports, committed together.

    Parameters
    ----------
    rrd_path, json_path : Path
        Final names; nothing changes there before ``commit``.
    """

    def __init__(self, rrd_path: Path, json_path: Path) -> None:
        self.finals = (Path(rrd_path), Path(json_path))
        self._others: list[tuple[Path, bool]] = []  # (final name, has a new file)
        self._flushed: set[Path] = set()  # new files whose writer flushed their files
        self._swap = _Swap(self.finals, os.getpid())
        self.rrd_tmp, self.json_tmp = self._swap.news
        self._pending = False  # a journal left for the next run to recover
        _in_progress.update(self._swap.paths)

    def add(self, final: Path, staged: Path | None, flushed: bool = False) -> None:
        """Commit one more final name with the pair: ``staged``, a whole file or directory in
        the same directory (an export's), is moved to its temporary name now; None means
        there is no new file there this time and the commit removes the previous one.
        ``flushed``: every file of ``staged`` is on the disk already (``fsync``); the commit
        then flushes only its directories.

        Raises
        ------
        ValueError
            If ``final`` is already in the set or lies in another directory.
        OutputError
            If ``staged`` cannot be moved.
        """
        final = Path(final)
        if final.parent != self.finals[0].parent or final in self.finals:
            raise ValueError(f"{final}: not a new name beside {self.finals[0].name}")
        if any(final == f for f, _ in self._others):
            raise ValueError(f"{final}: already in the set")
        self._others.append((final, staged is not None))
        names = (*(f for f, _ in self._others), *self.finals)
        has_new = (*(n for _, n in self._others), True, True)
        self._swap = _Swap(names, os.getpid(), has_new)
        _in_progress.update(self._swap.paths)
        if staged is not None:
            if flushed:
                self._flushed.add(temp_path(final))
            try:
                os.replace(staged, temp_path(final))
            except OSError as exc:
                raise _output_error(exc) from None

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
        """Check the recording, then put every file in place together (see the module doc).

        Raises
        ------
        OutputError
            If the recording is incomplete or a file cannot be synced or moved; the previous
            set (if any) is then as it was, and the temporary files are removed. Should
            putting it back fail too, the journal stays and the next run into the directory
            ends the commit (``remove_stale_partials``); the message says so.
        """
        swap = self._swap
        try:
            verify_rrd(self.rrd_tmp)
            _fsync(self.rrd_tmp)
            for new in swap.news[:-2]:
                if new is not None:
                    _fsync_tree(new, files=new not in self._flushed)
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
            # An error or an interrupt (SIGTERM, Ctrl-C) mid-swap: the previous set back.
            try:
                swap.roll_back()
            except BaseException:
                self._pending = True  # the next run recovers it; nothing more is touched
                if isinstance(exc, OSError):
                    raise OutputError(
                        exc.errno,
                        f"{_output_error(exc)}; the next run into {swap.directory} puts the "
                        "previous files back",
                    ) from None
                raise
            self.discard()
            if isinstance(exc, OSError):
                raise _output_error(exc) from None
            raise
        try:
            swap.end()  # the new set is in place: what is left is clearing up
        except BaseException as exc:
            self._pending = True  # the next run removes the previous set
            if isinstance(exc, OSError):
                raise OutputError(
                    exc.errno,
                    f"{_output_error(exc)}; the new files are in place, the next run into "
                    f"{swap.directory} removes the previous ones",
                ) from None
            raise
        _in_progress.difference_update(swap.paths)

    def discard(self) -> None:
        """Remove the temporary files (the final names are untouched); nothing while a
        commit's journal is left for the next run to recover."""
        if self._pending:
            return
        for tmp in self._swap.news:
            if tmp is not None:
                _remove(tmp)
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
    files and directories (an export's staging directory, a new export directory). Only
    names made by ``temp_path`` are touched (and the final names of an undone swap). A
    ``.old`` file with no journal beside it is left alone (a swap deletes its journal last),
    as are the files of a run whose journal is not one this program wrote.

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
            and _remove(path)
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
