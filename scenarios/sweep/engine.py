"""Where a sweep's episodes run: in this process, or on Ray actors (local or a cluster).

Ray's pattern for simulation sweeps is one task per episode with the seed set inside it; here
each worker is a Ray *actor* holding an ``EpisodeRunner``, so that its OpenGL context and the
scenes it built survive from one episode to the next (an EGL context cannot be pickled or
carried across ``fork``: it is made inside the worker, on its first episode). Each actor asks
Ray for one CPU and runs with one rendering thread (Mesa's llvmpipe: ``LP_NUM_THREADS=1``) and
single-threaded BLAS and OpenCV, so N workers keep N cores busy instead of fighting over them.

Results come back in the order episodes finish; the episode, not the order, fixes the numbers.

A worker whose process dies (killed, out of memory, a crash in a native library) is restarted
by Ray (``max_restarts``: ``MAX_RESTARTS`` times) and the episodes lost with it run again, each
at most ``EPISODE_RETRIES`` more times and alone on its worker (so that an episode that kills
its worker every time takes no other with it); a worker Ray cannot restart is dropped and the
others run its episodes. An episode is a pure function of its grid point and seed, so one run
again gives the row it would have given. An episode that raises is not run again: the error is
its own, and costs that episode only.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from scenarios.sweep.episode import EpisodeRunner
from scenarios.sweep.plan import EstimatorSource
from scenarios.sweep.rows import Episode

__all__ = [
    "WORKER_ENV",
    "EngineError",
    "Failure",
    "RayEngine",
    "SerialEngine",
    "Task",
    "check_address",
    "default_workers",
    "join_cluster",
    "ray_missing",
    "usable_cpus",
]

logger = logging.getLogger(__name__)

WORKER_ENV = {
    "LP_NUM_THREADS": "1",  # Mesa llvmpipe's rasteriser threads (default: one per core)
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
}
"""The environment of every Ray worker: one thread each for rendering, BLAS and OpenCV."""

IN_FLIGHT_PER_WORKER = 2
"""Episodes queued on each actor: the next starts as soon as one ends."""

MAX_RESTARTS = 3
"""Times Ray restarts a worker whose process died (its ``max_restarts``); then it is dropped."""

EPISODE_RETRIES = 2
"""Times an episode lost with its worker's process runs again before it counts as one that
could not run (``--resume`` runs it again)."""

_QUIET: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
"""``ray.init``'s options: Ray's own logging and the workers' output kept off the terminal."""


class EngineError(Exception):
    """Ray could not be joined (a wrong ``--address``, a cluster not running): one line."""


@dataclass(frozen=True)
class Task:
    """One episode to run: the grid point's scenario file and the seed."""

    point: int
    seed: int
    scenario_toml: str


@dataclass(frozen=True)
class Failure:
    """An episode that could not run (an internal error, or its worker lost on every try):
    not a result; ``--resume`` runs it again."""

    point: int
    seed: int
    error: str


def usable_cpus() -> tuple[int, str]:
    """The CPUs this process may use, and where that number comes from (for messages): its
    CPU affinity where the system has one (a container or ``taskset`` may allow fewer than the
    machine has), else the machine's count."""
    process_cpu_count = getattr(os, "process_cpu_count", None)  # Python 3.13
    if process_cpu_count is not None and process_cpu_count():
        return process_cpu_count(), "os.process_cpu_count"
    try:
        return len(os.sched_getaffinity(0)), "os.sched_getaffinity"
    except AttributeError:  # not Linux
        return os.cpu_count() or 1, "os.cpu_count"


def default_workers() -> int:
    """The CPUs this process may use (``usable_cpus``)."""
    return usable_cpus()[0]


def ray_missing() -> str | None:
    """Why Ray cannot be used (not installed), or None."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed: pip install 'vnav-sim[sweep]'"
    return None


class SerialEngine:
    """Every episode in this process, one after another (``--workers 0``: for debugging);
    ``estimators``, the sweep's user estimators, run in each (``EpisodeRunner``)."""

    workers = 0
    startup_s = 0.0

    def __init__(self, estimators: Sequence[EstimatorSource] = ()) -> None:
        self._runner = EpisodeRunner(estimators)

    def run(self, tasks: Iterable[Task]) -> Iterator[Episode | Failure]:
        for task in tasks:
            try:
                episode = self._runner.run(task.scenario_toml, task.point, task.seed)
            except Exception as exc:  # an internal error: this episode, not the sweep
                logger.debug("episode failed", exc_info=True)
                yield Failure(task.point, task.seed, f"{type(exc).__name__}: {exc}")
            else:
                yield episode

    def close(self) -> None:
        self._runner.close()


class _Worker(EpisodeRunner):
    """An ``EpisodeRunner`` with OpenCV's threads as the environment says, and a ``ready``
    probe. It waits for each render (``render_ahead=False``): Ray gives it one CPU, and a
    worker rendering ahead keeps about two busy; with a worker per core that oversubscribes
    them (measured: 2 workers 0.60 episodes/s rendering ahead, 0.71 not,
    ``python -m benchmarks sweep``)."""

    def __init__(self, estimators: Sequence[EstimatorSource] = ()) -> None:
        threads = os.environ.get("OPENCV_FOR_THREADS_NUM")
        if threads:
            import cv2

            cv2.setNumThreads(int(threads))
        super().__init__(estimators, render_ahead=False)

    def ready(self) -> int:
        return os.getpid()


class RayEngine:
    """Episodes on ``workers`` Ray actors.

    Parameters
    ----------
    workers : int or None
        Actors to start; None: one per core of this machine, or per CPU of the cluster.
    address : str or None
        None starts a local Ray instance with ``workers`` CPUs (stopped by ``close``);
        ``"auto"`` or ``"ray://host:port"`` joins an existing cluster (``join_cluster``; a
        cluster this process has joined already is kept), whose nodes must have vnav-sim
        installed.
    env : dict, optional
        The workers' environment variables (default ``WORKER_ENV``; the benchmark compares).
    estimators : sequence of EstimatorSource, optional
        The sweep's user estimators: each worker imports them itself (``EpisodeRunner``),
        from their absolute paths (a cluster's nodes need the files at the same paths).

    Attributes
    ----------
    startup_s : float
        Seconds to start (or join) Ray and get every actor ready.

    Raises
    ------
    EngineError
        The cluster cannot be joined, or has fewer CPUs than ``workers``.
    """

    def __init__(
        self,
        workers: int | None,
        address: str | None = None,
        env: dict[str, str] | None = None,
        estimators: Sequence[EstimatorSource] = (),
    ) -> None:
        import ray

        self._ray = ray
        self._actors: list[Any] = []
        self._owns_ray = address is None
        self._unquiet = _quiet_lost_worker_messages()
        start = time.perf_counter()
        try:
            if address is None:
                self.workers = self._start_local(workers)
            else:
                self.workers = join_cluster(address, workers)
            env = WORKER_ENV if env is None else env
            # Ray restarts a worker whose process died; the engine, not Ray, runs the episodes
            # lost with it again (no max_task_retries), so that it can bound their tries, run
            # them alone, and give them to another worker when one cannot be restarted.
            actor = ray.remote(
                num_cpus=1,
                max_restarts=MAX_RESTARTS,
                max_task_retries=0,
                runtime_env={"env_vars": env},
            )(_Worker)
            self._actors = [actor.remote(tuple(estimators)) for _ in range(self.workers)]
            ray.get([a.ready.remote() for a in self._actors])
        except BaseException:
            self.close()
            raise
        self.startup_s = time.perf_counter() - start

    def _start_local(self, workers: int | None) -> int:
        """Start a local Ray instance; the number of workers to start."""
        workers = workers or default_workers()
        with _signals_kept():
            # "local": a new instance even where a cluster started by `ray start` is
            # running (which a bare ray.init() would join).
            self._ray.init(address="local", num_cpus=workers, include_dashboard=False, **_QUIET)
        return workers

    def run(self, tasks: Iterable[Task]) -> Iterator[Episode | Failure]:
        """Run ``tasks``, yielding each result as it comes (in the order episodes finish).

        An episode lost with its worker's process runs again (at most ``EPISODE_RETRIES``
        times, alone on a worker), then comes back as a ``Failure``; so do the episodes left
        once no worker can be restarted.
        """
        ray = self._ray
        queue = deque(_Attempt(task) for task in tasks)
        seats = [_Seat(actor) for actor in self._actors]
        pending: dict[Any, tuple[_Seat, _Attempt | None]] = {}  # None: a probe of the seat
        while queue or pending:
            _submit(queue, seats, pending)
            if not pending:  # no worker left to run them
                for attempt in queue:
                    lost = "every Ray worker was lost and could not be restarted"
                    yield Failure(attempt.task.point, attempt.task.seed, lost)
                return
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            seat, attempt = pending.pop(ref)
            if attempt is None:
                self._probed(ref, seat)
                continue
            seat.load -= attempt.weight
            task = attempt.task
            try:
                result: Episode | Failure = ray.get(ref)
            except ray.exceptions.RayActorError as exc:  # the worker's process died
                logger.debug("a worker was lost", exc_info=True)
                if seat.state == "up":  # the first of its episodes to say so: wait for Ray
                    seat.state = "restarting"  # to restart it before giving it more
                    pending[_probe_restarted(seat.actor)] = (seat, None)
                    logger.warning("a Ray worker's process died: its episodes run again")
                if attempt.lost < EPISODE_RETRIES:
                    queue.appendleft(_Attempt(task, attempt.lost + 1))
                    continue
                # Ray's own text is a paragraph on the OOM killer: the name says enough here
                why = f"lost its Ray worker {attempt.lost + 1} times ({type(exc).__name__})"
                result = Failure(task.point, task.seed, why)
            except ray.exceptions.RayError as exc:  # the episode raised: its own error
                result = Failure(task.point, task.seed, _one_line(exc))
            yield result

    def _probed(self, ref: Any, seat: _Seat) -> None:
        """A probe of a worker that lost its process has come back: running again, or gone
        (Ray's restarts used up, its node gone)."""
        try:
            self._ray.get(ref)
        except self._ray.exceptions.RayError:
            logger.debug("a worker could not be restarted", exc_info=True)
            logger.warning("a Ray worker could not be restarted: the others run its episodes")
            seat.state = "gone"
        else:
            seat.state = "up"

    def close(self) -> None:
        """Stop the actors (on a cluster) and leave Ray (stopping it if this engine started it:
        that stops the actors too)."""
        if not self._owns_ray:
            for a in self._actors:  # on a cluster they would outlive this command
                try:
                    self._ray.kill(a)
                except Exception:  # already gone (a cluster shutting down): nothing to stop
                    logger.debug("could not kill a worker", exc_info=True)
        self._actors = []
        self._ray.shutdown()
        self._unquiet()


@dataclass(frozen=True)
class _Attempt:
    """An episode to run, and the times it was lost with its worker's process."""

    task: Task
    lost: int = 0

    @property
    def weight(self) -> int:
        """The worker's slots it takes: all of them once it was lost (it runs alone, so that
        an episode that kills its worker every time takes no other episode with it)."""
        return IN_FLIGHT_PER_WORKER if self.lost else 1


@dataclass
class _Seat:
    """A worker as ``RayEngine.run`` schedules it: the slots its episodes take (at most
    ``IN_FLIGHT_PER_WORKER``), and its state: ``up``, ``restarting`` (its process died; a probe
    waits for Ray to restart it) or ``gone`` (not restarted: nothing more is given to it)."""

    actor: Any
    load: int = 0
    state: str = "up"


def _probe_restarted(actor: Any) -> Any:
    """A call that returns once Ray has restarted ``actor`` (an ``ActorDiedError`` if it
    cannot: its restarts used up). Tried again for as long as the actor is restarting (it
    says ``ActorUnavailableError`` meanwhile): ``max_task_retries=-1``, which Ray bounds by the
    actor's ``max_restarts``."""
    return actor.ready.options(max_task_retries=-1).remote()


def _submit(
    queue: deque[_Attempt], seats: list[_Seat], pending: dict[Any, tuple[_Seat, Any]]
) -> None:
    """Start the episodes at the head of ``queue`` on the least loaded workers with room for
    them, in order, until one does not fit (it waits for a worker to become free)."""
    while queue:
        attempt = queue[0]
        room = [
            s for s in seats if s.state == "up" and s.load + attempt.weight <= IN_FLIGHT_PER_WORKER
        ]
        if not room:
            return
        seat = min(room, key=lambda s: s.load)
        queue.popleft()
        task = attempt.task
        pending[seat.actor.run.remote(task.scenario_toml, task.point, task.seed)] = (seat, attempt)
        seat.load += attempt.weight


def join_cluster(address: str, workers: int | None) -> int:
    """Join the Ray cluster at ``address`` (``auto``, ``host:port`` or ``ray://host:port``),
    unless this process has joined it already; the number of workers to start there.

    Parameters
    ----------
    address : str
        Where the cluster is (``check_address``'s forms).
    workers : int or None
        Workers asked for; None: one per CPU of the cluster.

    Raises
    ------
    EngineError
        Nothing answers at ``address`` as a Ray cluster, Ray cannot join it, or it has fewer
        CPUs than ``workers`` (Ray is left again).
    """
    import ray

    if not ray.is_initialized():
        _probe(_resolve_auto() if address == "auto" else address, address)
        try:
            with _signals_kept():
                _init_retrying_client(ray, address, _QUIET)
        except ConnectionError as exc:
            raise EngineError(f"cannot join the Ray cluster at {address}: {exc}") from None
        except (ImportError, ValueError) as exc:  # Ray Client's packages missing
            raise EngineError(
                f"cannot join the Ray cluster at {address}: {_one_line(exc)} (pip install "
                "'vnav-sim[sweep]' installs ray[client])"
            ) from None
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if workers and workers > cpus:
        ray.shutdown()
        raise EngineError(
            f"the Ray cluster at {address} has {cpus} CPUs: {workers} workers (one CPU "
            "each) would wait for more; ask for fewer with --workers"
        )
    return workers or max(1, cpus)


_LOST_WORKER_MESSAGE = re.compile(
    r"A worker died or was killed while executing a task"
    r"|Task \S+ failed\. There are \S+ retries remaining"
)
"""What Ray's driver prints on stdout when a worker's process dies (a paragraph each, with
advice on the OOM killer), whatever ``log_to_driver`` says; the engine handles that and says
so in one line."""


def _quiet_lost_worker_messages() -> Callable[[], None]:
    """Send Ray's messages about a lost worker (``_LOST_WORKER_MESSAGE``) to this module's
    debug log instead of stdout, where the sweep's own output goes; Ray's other messages are
    printed as before. Returns what undoes it.

    Ray's driver prints the errors its raylets publish through the private
    ``ray._private.worker.print_to_stdstream``; where a Ray version has no such function,
    nothing is changed (the messages are printed).
    """
    try:
        from ray._private import worker as ray_worker
    except ImportError:
        return lambda: None
    printer = getattr(ray_worker, "print_to_stdstream", None)
    if printer is None:
        return lambda: None

    def print_others(data: dict[str, Any], *args: Any, **kwargs: Any) -> None:
        lines = data.get("lines") or []
        if data.get("pid") == "raylet" and all(_LOST_WORKER_MESSAGE.match(s) for s in lines):
            for line in lines:
                logger.debug("Ray: %s", line)
        else:
            printer(data, *args, **kwargs)

    ray_worker.print_to_stdstream = print_others

    def undo() -> None:
        ray_worker.print_to_stdstream = printer

    return undo


@contextlib.contextmanager
def _signals_kept() -> Iterator[None]:
    """Put this process's SIGINT, SIGTERM and SIGHUP handlers back after the block: Ray's core
    installs its own SIGTERM handler (it exits at once), where the command's stop a sweep
    cleanly, keeping what finished."""
    signums = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    handlers = {s: signal.getsignal(s) for s in signums}
    try:
        yield
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


CLIENT_ATTEMPTS = 2
"""Tries to join through Ray Client (``ray://``): its server forks a process per client, and
on a busy machine that process can die at start ("Starting Ray client server failed"); a
second try, a second later, gets a new one."""


def _init_retrying_client(ray: Any, address: str, options: dict[str, Any]) -> None:
    """``ray.init(address)``, tried again once where Ray Client's per-client server failed to
    start (``CLIENT_ATTEMPTS``); any other failure at once."""
    for attempt in range(CLIENT_ATTEMPTS):
        try:
            ray.init(address=address, **options)
            return
        except ConnectionError as exc:
            transient = address.startswith("ray://") and "client server failed" in str(exc)
            if not transient or attempt + 1 == CLIENT_ATTEMPTS:
                raise
            logger.info("Ray Client's server did not start; trying again: %s", exc)
            time.sleep(1.0)


PROBE_TIMEOUT_S = 5.0
# What a client sends first on an HTTP/2 connection (RFC 9113, section 3.4: the preface, then
# an empty SETTINGS frame). Both of Ray's addresses, the GCS (host:port) and the Ray Client
# server (ray://host:port), are gRPC servers, which answer with a SETTINGS frame of their own.
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_HTTP2_SETTINGS = 0x4  # frame type, the 4th byte of a frame header


def _resolve_auto() -> str:
    """Where ``--address auto`` leads: ``RAY_ADDRESS``, else the cluster last started on this
    machine by ``ray start`` (Ray's own lookup)."""
    from ray._private.services import canonicalize_bootstrap_address

    try:
        found = canonicalize_bootstrap_address("auto")
    except Exception:  # Ray's lookup raises ConnectionError and others where none is found
        found = None
    if not found:
        raise EngineError(
            "--address auto: no Ray cluster was started on this machine (`ray start --head`) "
            "and RAY_ADDRESS is not set"
        )
    return found


def check_address(address: str) -> None:
    """Raise ``EngineError`` unless ``address`` is ``auto``, ``host:port`` or
    ``ray://host:port`` (the form only: nothing is contacted)."""
    if address != "auto":
        _host_port(address, address)


def _host_port(address: str, given: str) -> tuple[str, int]:
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise EngineError(f"--address must be auto, host:port or ray://host:port, got {given!r}")
    return host.strip("[]"), int(port)


def _probe(address: str, given: str) -> None:
    """Fail at once, in one line, where no Ray cluster answers at ``address`` (``host:port`` or
    ``ray://host:port``; ``given`` is what the user wrote): Ray itself retries an unreachable
    cluster for minutes, and hangs on a port that answers but is not Ray's (the dashboard's).
    """
    host, port = _host_port(address, given)
    where = address if address == given else f"{address} ({given})"
    try:
        sock = socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S)
    except OSError as exc:  # refused, unreachable, no answer within the timeout
        reason = exc.strerror or type(exc).__name__
        raise EngineError(f"cannot reach the Ray cluster at {where}: {reason}") from None
    head = b""
    with sock:
        try:
            sock.sendall(_HTTP2_PREFACE)
            while len(head) < 9:
                part = sock.recv(9 - len(head))
                if not part:
                    break
                head += part
        except OSError:  # closed on us, or silent past the timeout: not a gRPC server
            pass
    if len(head) < 9 or head[3] != _HTTP2_SETTINGS:
        raise EngineError(
            f"{where} answers, but not as a Ray cluster (no gRPC): give the head node's GCS "
            "port (6379 by default) as host:port, or its client port (10001) as ray://host:port"
        )


def _one_line(exc: BaseException) -> str:
    """A Ray error's cause in one line (Ray wraps the worker's traceback in its message)."""
    cause = getattr(exc, "cause", None) or exc
    text = str(cause).strip().splitlines()
    return f"{type(cause).__name__}: {text[-1] if text else ''}"
