"""``vnav-demo run`` with several scenarios on several worker processes (``--jobs N``).

Each worker has its own ``SceneCache`` and OpenGL context, kept for every scenario it runs
(an OpenGL context, EGL's included, cannot be shared across processes, nor safely inherited
by a fork). The workers are forked by multiprocessing's fork server, a fresh process that
has made no OpenGL context nor Rerun recording and imports a run's modules once for them
(``PRELOAD``); where there is none, each is a fresh Python (``spawn``). A worker takes the
command's working directory and environment (``MUJOCO_GL`` is read when MuJoCo is imported,
``sim.gl``: the fork server's, the command's too) and runs a scenario exactly as the serial
command does (``scenarios.commands.run.worker_session``): each scenario's files are written and
committed by the worker that ran it, under that worker's temporary names
(``scenarios.record.outputs``), while the command holds the directory's lock. It reports
the CPU seconds it spent, which the command adds to its own (the fork server's imports,
about 1.5 s, are not counted).

The costliest scenario starts first (``start_order``), the others in order. What the user
sees is the serial command's: the command prints each scenario's summary and
error lines in the scenarios' order, whichever finishes first (a worker sends them back as
text), one progress bar on a terminal (the earliest scenario still running), and the exit
status of every scenario the same way. Signals:

- The command's SIGTERM, SIGHUP or Ctrl-C stop every worker (SIGTERM): each removes its
  unfinished files, as the serial command does, before the command ends with 128 + N. The
  summaries of scenarios that finished (and were committed) after one still running are
  printed first, in order, as the serial command prints each one it finished.
  Workers ignore SIGINT (a terminal's Ctrl-C reaches the whole process group: the command
  stops them itself) and any signal after the first (their clean-up runs whole).
- A worker stopped by SIGTERM or SIGHUP from outside stops the command as if it had
  received the signal; a worker killed outright (SIGKILL, the out-of-memory killer) leaves
  its scenario incomplete (exit status 3) and the others run on.
- A command killed outright (SIGKILL) takes its workers with it: each watches a pipe
  only the command holds open and stops as on SIGTERM when it closes, so that no worker
  commits a file once its command is gone (and its directory's lock with it). Files a worker
  could not remove are the next run's to remove (``remove_stale_partials``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import multiprocessing
import os
import resource
import signal
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from scenarios.commands.common import (
    EXIT_INCOMPLETE,
    Signalled,
    signal_caught,
    stop_on_signals,
)
from scenarios.scenario.spec import ScenarioSpec

__all__ = ["cost", "default_jobs", "run_parallel", "start_order"]

logger = logging.getLogger(__name__)

STOP_TIMEOUT_S = 60.0
"""How long the command waits for a stopped worker to clean up before killing it."""

Messages = list[tuple[str, str]]
"""A scenario's printed texts, in order: ``("out", summary)`` or ``("err", error line)``."""

RunOne = Callable[
    [ScenarioSpec, Path, Callable[[str, str], None], Callable[[int, int], None]],
    tuple[int, Path | None],
]
"""A worker's ``run(spec, out_dir, emit, progress)``: a scenario's exit status and
recording (``scenarios.commands.run.run_one``)."""


def usable_cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_jobs(n_scenarios: int) -> int:
    """Worker processes for ``n_scenarios`` when ``--jobs`` is not given: two where there
    are two cores and two scenarios, else one (the serial command)."""
    return max(1, min(2, usable_cores(), n_scenarios))


@dataclass
class _Worker:
    """One worker process, its pipes and the scenario it runs (an index, or None)."""

    process: Any
    tasks: Connection
    results: Connection
    lifeline: Connection
    index: int | None = None
    gone: bool = False


@dataclass
class _Bar:
    """The command's progress bar: the earliest scenario still running, one line on
    stderr (``scenarios.commands.run.Progress``)."""

    specs: list[ScenarioSpec]
    draw: Callable[[str], Callable[[int, int], None]] | None
    ticks: dict[int, tuple[int, int]] = field(default_factory=dict)
    shown: bool = False

    def update(self, index: int, done: int, total: int, running: set[int]) -> None:
        self.ticks[index] = (done, total)
        first = min(running, default=None)
        if self.draw is None or first is None or first not in self.ticks:
            return
        done, total = self.ticks[first]
        self.draw(self.specs[first].name)(done, total)
        self.shown = done != total

    def clear(self) -> None:
        """Clear a bar left on the line before the command prints there."""
        if self.shown:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()
            self.shown = False


def _worker_options(args: argparse.Namespace) -> dict[str, Any]:
    """What each worker's ``session`` is given: the command's options, its directory and its
    environment (picklable)."""
    return {
        "seed": args.seed,
        "quiet": args.quiet,
        "exports": tuple(getattr(args, "exports", ())),
        "estimator": list(getattr(args, "estimator", None) or []),
        "estimator_timeout_s": getattr(args, "estimator_timeout_s", None),
        "progress": not args.quiet and sys.stderr.isatty(),
        # A fork server outlives its first command in a process that runs several (tests):
        # its workers take this command's directory and environment, not the server's.
        "cwd": os.getcwd(),
        "environ": dict(os.environ),
    }


def run_parallel(
    specs: list[ScenarioSpec],
    args: argparse.Namespace,
    out_dir: Path,
    jobs: int,
    *,
    session: Callable[[dict[str, Any]], contextlib.AbstractContextManager[RunOne]],
    emit: Callable[[str, str], None],
    progress_bar: Callable[[str], Callable[[int, int], None]],
) -> tuple[list[tuple[int, Path | None]], float]:
    """Run ``specs`` on ``jobs`` worker processes; return each scenario's exit status and
    recording (None when nothing was written), in ``specs``' order, and the CPU seconds
    (user and system) the workers spent.

    Each worker enters ``session(options)`` once (a module-level function, which the worker
    imports: ``scenarios.commands.run.worker_session``), ``options`` the command's (seed,
    exports, ``--estimator``...), and runs each scenario it is given with the function it
    yields, ``run(spec, out_dir, emit, progress)`` -> (exit status, recording). Each
    scenario's texts are passed to ``emit(stream, text)`` in ``specs``' order, as soon as it
    and every scenario before it have finished. On a terminal (and without ``--quiet``)
    ``progress_bar(name)(done, total)`` draws the bar of the earliest scenario running.

    Raises
    ------
    Signalled, KeyboardInterrupt
        When the command or a worker is stopped by a signal; every worker has ended then.
    """
    ctx = _context()
    options = _worker_options(args)
    bar = _Bar(specs, progress_bar if options["progress"] else None)
    pending = start_order(specs)
    done: dict[int, tuple[int, Path | None, Messages]] = {}
    printed = 0
    workers: list[_Worker] = []
    cpu_s = [0.0]
    try:
        cannot_start = _start_workers(
            workers, min(jobs, len(specs)), ctx, session, options, out_dir
        )
        for worker in workers:
            _assign(worker, pending, specs)
        while printed < len(specs):
            live = [w for w in workers if not w.gone]
            if not live:  # every worker died: nothing left to run the rest
                _left_incomplete(specs, pending, done, cannot_start)
            else:
                ready = wait([w.results for w in live] + [w.process.sentinel for w in live])
                for worker in live:
                    if worker.results in ready or worker.process.sentinel in ready:
                        _receive(worker, specs, pending, done, bar, workers, cpu_s)
            while printed in done:
                messages = done[printed][2]
                bar.clear()
                for stream, text in messages:
                    emit(stream, text)
                printed += 1
        for worker in workers:
            if not worker.gone:
                with contextlib.suppress(OSError):
                    worker.tasks.send(None)
        for worker in workers:
            _receive(worker, specs, pending, done, bar, workers, cpu_s, until_gone=True)
    except BaseException:
        bar.clear()
        _stop(workers)
        # Scenarios that finished after one still running were written and committed (their
        # news perhaps still in a pipe): say so, as the serial command says each scenario it
        # finished before a signal.
        _finished_before_stop(workers, done)
        _say_unprinted(done, printed, emit)
        raise
    finally:
        for worker in workers:
            for end in (worker.tasks, worker.results, worker.lifeline):
                end.close()
    return [(done[i][0], done[i][1]) for i in range(len(specs))], cpu_s[0]


def _start_workers(
    workers: list[_Worker], n: int, ctx, session, options: dict[str, Any], out_dir: Path
) -> str:
    """Start up to ``n`` workers into ``workers``; what to say of a scenario none could run
    (why the last one could not start, if one could not)."""
    for _ in range(n):
        try:
            workers.append(_start(ctx, session, options, out_dir))
        except OSError as exc:  # no process left to make, no fork server...
            return f"could not start: {exc}"
    return "could not run it"


def _left_incomplete(
    specs: list[ScenarioSpec],
    pending: list[int],
    done: dict[int, tuple[int, Path | None, Messages]],
    cannot_start: str,
) -> None:
    """Every scenario still ``pending`` ended incomplete: no worker is left to run it."""
    for index in pending:
        line = f"{specs[index].name}: could not complete: its worker {cannot_start}"
        done[index] = (EXIT_INCOMPLETE, None, [("err", line)])
    pending.clear()


def cost(spec: ScenarioSpec) -> int:
    """A rough cost of running ``spec``: its camera ticks, twice where the mount is
    calibrated (the run's images are estimated again with the recovered mount)."""
    return spec.n_ticks * (2 if spec.checks_calibration else 1)


def start_order(specs: list[ScenarioSpec]) -> list[int]:
    """The order scenarios start in: the costliest first (``cost``), then the others in
    order. Started last, the longest would end the command alone on one core (the
    calibration built-in is a third of ``run --all``); the others, in order, still print as
    they finish."""
    first = max(range(len(specs)), key=lambda i: cost(specs[i]))
    return [first, *(i for i in range(len(specs)) if i != first)]


PRELOAD = (
    "scenarios.commands.run",
    "scenarios.record.recording",
    "matplotlib.figure",
    "matplotlib.backends.backend_agg",
    "PIL.PngImagePlugin",
    "pyarrow",
    "pandas",
)
"""What the fork server imports once for every worker it forks (what a run imports: about
1.5 s of CPU). Nothing here makes an OpenGL context or a Rerun recording."""


def _context():
    """multiprocessing's ``forkserver`` (a fresh process, which has made no OpenGL context
    nor Rerun recording, imports ``PRELOAD`` once and forks each worker from itself), or
    ``spawn`` where there is none."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOAD))
    return ctx


def _start(ctx, session, options: dict[str, Any], out_dir: Path) -> _Worker:
    task_r, task_w = ctx.Pipe(duplex=False)
    result_r, result_w = ctx.Pipe(duplex=False)
    life_r, life_w = ctx.Pipe(duplex=False)  # never written: closed when the command ends
    process = ctx.Process(
        target=_serve,
        args=(task_r, result_w, life_r, session, options, out_dir),
        name="vnav-demo-run",
        daemon=True,  # ended by multiprocessing if the command leaves without stopping it
    )
    process.start()
    for end in (task_r, result_w, life_r):  # the worker's: its death reads as EOF here
        end.close()
    return _Worker(process, task_w, result_r, life_w)


def _assign(worker: _Worker, pending: list[int], specs: list[ScenarioSpec]) -> None:
    """Give ``worker`` the next scenario, or tell it to end."""
    worker.index = pending.pop(0) if pending else None
    try:
        worker.tasks.send(None if worker.index is None else (worker.index, specs[worker.index]))
    except OSError:  # it has died: its sentinel says so next
        if worker.index is not None:
            pending.insert(0, worker.index)
        worker.index = None


def _receive(
    worker: _Worker,
    specs: list[ScenarioSpec],
    pending: list[int],
    done: dict[int, tuple[int, Path | None, Messages]],
    bar: _Bar,
    workers: list[_Worker],
    cpu_s: list[float],
    until_gone: bool = False,
) -> None:
    """Read every message ``worker`` has sent (``until_gone``: until it ends); note its
    death; add the CPU seconds it says it spent to ``cpu_s[0]``."""
    while True:
        try:
            if not until_gone and not worker.results.poll():
                break
            message = worker.results.recv()
        except (EOFError, OSError):
            break
        kind = message[0]
        if kind == "cpu":
            cpu_s[0] += message[1]
        elif kind == "ticks":
            running = {w.index for w in workers if w.index is not None and not w.gone}
            bar.update(message[1], message[2], message[3], running)
        elif kind == "done":
            _, index, status, rrd, messages = message
            done[index] = (status, rrd, messages)
            _assign(worker, pending, specs)
        elif kind == "signalled":  # stopped from outside: the command stops as if it had been
            raise Signalled(message[1])
        elif kind == "broken":  # it could not start (no OpenGL context...): run nothing more
            if worker.index is not None:
                done[worker.index] = (
                    EXIT_INCOMPLETE,
                    None,
                    [("err", f"{specs[worker.index].name}: could not complete: {message[1]}")],
                )
                worker.index = None
    if not until_gone and worker.process.is_alive():
        return
    worker.process.join()
    worker.gone = True
    if worker.index is not None:  # killed while running a scenario
        done[worker.index] = (
            EXIT_INCOMPLETE,
            None,
            [("err", _lost(specs[worker.index], worker.process.exitcode))],
        )
        worker.index = None


def _lost(spec: ScenarioSpec, exitcode: int) -> str:
    """The error line of a scenario whose worker ended without finishing it."""
    if exitcode is not None and exitcode < 0:
        how = f"was killed by {signal.Signals(-exitcode).name}"
    else:
        how = f"ended with status {exitcode}"
    return f"{spec.name}: could not complete: its worker process {how}"


def _finished_before_stop(
    workers: list[_Worker], done: dict[int, tuple[int, Path | None, Messages]]
) -> None:
    """Read the scenarios that stopped workers finished but the command had not yet heard
    of into ``done``; nothing else of what they sent."""
    for worker in workers:
        with contextlib.suppress(EOFError, OSError):
            while worker.results.poll():
                message = worker.results.recv()
                if message[0] == "done":
                    _, index, status, rrd, messages = message
                    done[index] = (status, rrd, messages)


def _say_unprinted(
    done: dict[int, tuple[int, Path | None, Messages]],
    printed: int,
    emit: Callable[[str, str], None],
) -> None:
    """Emit the texts of every finished scenario from ``printed`` on, in order."""
    for index in sorted(i for i in done if i >= printed):
        for stream, text in done[index][2]:
            emit(stream, text)


def _stop(workers: list[_Worker]) -> None:
    """Stop every worker (SIGTERM) and wait for each to clean up; kill one that does not
    within ``STOP_TIMEOUT_S``."""
    for worker in workers:
        if worker.process.is_alive():
            worker.process.terminate()
    for worker in workers:
        worker.process.join(STOP_TIMEOUT_S)
        if worker.process.is_alive():
            logger.warning("worker %d did not stop; killing it", worker.process.pid)
            worker.process.kill()
            worker.process.join()


# ------------------------------------------------------------------------ in the worker


def _watch(lifeline: Connection) -> None:
    """Stop this worker as on SIGTERM once the command's end of ``lifeline`` closes: the
    command ended without stopping it (killed outright)."""

    def wait_for_the_end() -> None:
        with contextlib.suppress(EOFError, OSError):
            lifeline.recv()  # nothing is ever sent: this returns when the command is gone
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=wait_for_the_end, name="vnav-demo-lifeline", daemon=True).start()


class _Ticks:
    """A worker's ``progress``: stops the run on a signal whose exception was swallowed, and
    sends the bar's steps to the command."""

    def __init__(self, results: Connection, index: int, send: bool) -> None:
        self.results, self.index, self.send = results, index, send
        self.step = -1

    def __call__(self, done: int, total: int) -> None:
        if (signum := signal_caught()) is not None:
            raise Signalled(signum)
        step = 30 * done // total  # the bar's width (run.Progress): one message a step
        if self.send and (step != self.step or done == total):
            self.step = step
            self.results.send(("ticks", self.index, done, total))


def _serve(
    tasks: Connection,
    results: Connection,
    lifeline: Connection,
    session: Callable[[dict[str, Any]], contextlib.AbstractContextManager[RunOne]],
    options: dict[str, Any],
    out_dir: Path,
) -> None:
    """A worker's main: run each scenario the command sends until it sends None."""
    # Ctrl-C reaches the whole process group; the command stops its workers itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.chdir(options["cwd"])
    os.environ.clear()
    os.environ.update(options["environ"])
    try:
        with stop_on_signals(once=True):
            _watch(lifeline)
            _run_tasks(tasks, results, session, options, out_dir)
    except Signalled as exc:
        with contextlib.suppress(OSError):
            results.send(("signalled", exc.signum))
        sys.exit(128 + exc.signum)
    except (EOFError, BrokenPipeError):  # the command has gone
        sys.exit(EXIT_INCOMPLETE)


def _run_tasks(
    tasks: Connection,
    results: Connection,
    session: Callable[[dict[str, Any]], contextlib.AbstractContextManager[RunOne]],
    options: dict[str, Any],
    out_dir: Path,
) -> None:
    stack = contextlib.ExitStack()
    try:
        run = stack.enter_context(session(options))
    except Exception as exc:  # the command has checked the functions: not expected
        logger.debug("worker set-up failed", exc_info=True)
        results.send(("broken", f"its worker could not start: {type(exc).__name__}: {exc}"))
        sys.exit(EXIT_INCOMPLETE)
    with stack:
        while (task := tasks.recv()) is not None:
            index, spec = task
            messages: Messages = []
            status, rrd = run(
                spec,
                out_dir,
                lambda stream, text, said=messages: said.append((stream, text)),
                _Ticks(results, index, bool(options["progress"])),
            )
            results.send(("done", index, status, rrd, messages))
    # This process's, since its fork, and its export processes'.
    usage = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    results.send(("cpu", sum(u.ru_utime + u.ru_stime for u in usage)))
