"""What every ``vnav-demo`` verb that writes files shares, written once: exit statuses, bad
input as one line, SIGTERM and SIGHUP ending a command as Ctrl-C does, and one command at a
time writing into an output directory (``scenarios.record.outputs.directory_lock``)."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from scenarios.commands.console import error
from scenarios.record import outputs

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_CHECK_FAILED",
    "EXIT_INCOMPLETE",
    "EXIT_PASSED",
    "InputError",
    "Signalled",
    "guarded",
    "prepare_out_dir",
    "signal_caught",
    "stop_on_signals",
]

EXIT_PASSED, EXIT_CHECK_FAILED, EXIT_BAD_INPUT, EXIT_INCOMPLETE = 0, 1, 2, 3

Prepared = TypeVar("Prepared")


class InputError(Exception):
    """Bad usage or bad input: one line for the user, exit status 2."""


class Signalled(BaseException):
    """SIGTERM or SIGHUP, raised in the main thread so that a command ends as on Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_caught: list[int] = []
"""Signals received during the command. The handler raises at once; if that exception lands
where Python swallows it (a ``__del__``, a weakref callback: "Exception ignored in ..."), the
next camera tick raises it again (``scenarios.commands.run.Progress``)."""


def _raise_signalled(signum: int, frame: object) -> None:
    _caught.append(signum)
    raise Signalled(signum)


def _raise_signalled_once(signum: int, frame: object) -> None:
    for s in (signal.SIGTERM, signal.SIGHUP):  # a second one would cut the clean-up short
        signal.signal(s, signal.SIG_IGN)
    _raise_signalled(signum, frame)


def signal_caught() -> int | None:
    """The first SIGTERM or SIGHUP received inside ``stop_on_signals``, or None.

    For code that must not take a swallowed ``Signalled`` for something else: re-raise it
    (``raise Signalled(signum)``) when this is not None.
    """
    return _caught[0] if _caught else None


@contextlib.contextmanager
def stop_on_signals(once: bool = False) -> Iterator[None]:
    """SIGTERM and SIGHUP raise ``Signalled`` in the main thread while inside, so that a
    command ends as on Ctrl-C (``KeyboardInterrupt``): cleaning up, keeping what is finished.
    ``once``: the first of them raises, later ones are ignored (a worker process, which its
    command stops with SIGTERM, whatever stopped the command: its clean-up runs whole)."""
    _caught.clear()
    handler = _raise_signalled_once if once else _raise_signalled
    previous = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _caught.clear()


def prepare_out_dir(out: str) -> Path:
    """Create ``out`` if needed and prove it can be written.

    Raises
    ------
    InputError
        If the directory cannot be made or written, saying why.
    """
    path = Path(out)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with outputs.temporary(path / "write-test") as probe:  # a name the next run clears
            probe.touch()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise InputError(f"output directory {out!r} cannot be written: {reason}") from None
    return path


def guarded(
    validate: Callable[[], tuple[Prepared, Path]],
    body: Callable[[Prepared, Path], int],
    *,
    kept: str,
    busy: str = "another vnav-demo command",
) -> int:
    """Run a command that writes into an output directory; return its exit status.

    ``validate()`` makes every check that can be made before anything is written and returns
    what the command needs with its output directory; an ``InputError`` there is one line and
    exit status 2. ``body(prepared, out_dir)`` then runs holding the directory's lock, with
    SIGTERM and SIGHUP raising ``Signalled``: a busy directory, an ``InputError`` found while
    running, or a signal end the command with one line (``kept`` says what stays on disk)
    and exit status 2, or 128 + the signal's number. A lock file that cannot be opened is one
    line and exit status 2; a dead run's work in the directory that cannot be ended
    (``scenarios.record.outputs.remove_stale_partials``) one line and exit status 3.
    """
    try:
        prepared, out_dir = validate()
    except InputError as exc:
        error(str(exc))
        return EXIT_BAD_INPUT
    try:
        with stop_on_signals(), contextlib.ExitStack() as stack:
            try:
                stack.enter_context(outputs.directory_lock(out_dir))
            except outputs.LockError as exc:  # its name taken by a directory...
                error(str(exc))
                return EXIT_BAD_INPUT
            except outputs.OutputError as exc:  # a dead run's commit could not be ended
                error(f"{exc}; nothing was written")
                return EXIT_INCOMPLETE
            return body(prepared, out_dir)
    except BlockingIOError:
        error(f"{busy} is writing into {out_dir}; wait for it to finish")
        return EXIT_BAD_INPUT
    except InputError as exc:
        error(str(exc))
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        error(f"interrupted; {kept}")
        return 128 + signal.SIGINT
    except Signalled as exc:
        error(f"stopped by {signal.Signals(exc.signum).name}; {kept}")
        return 128 + exc.signum
