"""Where a sweep's episodes run: in this process, or on Ray actors (local or a cluster).

Ray's pattern for simulation sweeps is one task per episode with the seed set inside it; here
each worker is a Ray *actor* holding an ``EpisodeRunner``, so that its OpenGL context and the
scenes it built survive from one episode to the next (an EGL context cannot be pickled or
carried across ``fork``: it is made inside the worker, on its first episode). Each actor asks
Ray for one CPU and runs with one rendering thread (Mesa's llvmpipe: ``LP_NUM_THREADS=1``) and
single-threaded BLAS and OpenCV, so N workers keep N cores busy instead of fighting over them.

Results come back in the order episodes finish; the episode, not the order, fixes the numbers.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from scenarios.sweep.episode import EpisodeRunner
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
    "ray_missing",
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
    """An episode that could not run (an internal error or a lost worker): not a result;
    ``--resume`` runs it again."""

    point: int
    seed: int
    error: str


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def ray_missing() -> str | None:
    """Why Ray cannot be used (not installed), or None."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed: pip install 'vnav-sim[sweep]'"
    return None


class SerialEngine:
    """Every episode in this process, one after another (``--workers 0``: for debugging)."""

    workers = 0
    startup_s = 0.0

    def __init__(self) -> None:
        self._runner = EpisodeRunner()

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
    probe."""

    def __init__(self) -> None:
        threads = os.environ.get("OPENCV_FOR_THREADS_NUM")
        if threads:
            import cv2

            cv2.setNumThreads(int(threads))
        super().__init__()

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
        ``"auto"`` or ``"ray://host:port"`` joins an existing cluster, whose nodes must have
        vnav-sim installed.
    env : dict, optional
        The workers' environment variables (default ``WORKER_ENV``; the benchmark compares).

    Attributes
    ----------
    startup_s : float
        Seconds to start (or join) Ray and get every actor ready.
    """

    def __init__(
        self, workers: int | None, address: str | None = None, env: dict[str, str] | None = None
    ) -> None:
        if address is not None:
            _probe(_resolve_auto() if address == "auto" else address, address)
        import ray

        self._ray = ray
        self._actors: list[Any] = []
        self._owns_ray = address is None
        start = time.perf_counter()
        try:
            self.workers = self._connect(workers, address)
            # No restarts or retries: a lost worker's episodes come back as failures, which
            # the command reports and --resume runs again.
            env = WORKER_ENV if env is None else env
            actor = ray.remote(num_cpus=1, runtime_env={"env_vars": env})(_Worker)
            self._actors = [actor.remote() for _ in range(self.workers)]
            ray.get([a.ready.remote() for a in self._actors])
        except BaseException:
            self.close()
            raise
        self.startup_s = time.perf_counter() - start

    def _connect(self, workers: int | None, address: str | None) -> int:
        """Start or join Ray; the number of workers to start."""
        ray = self._ray
        quiet: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
        # Ray's core installs its own SIGTERM handler (it exits at once); the command's own
        # handlers stop a sweep cleanly, keeping what finished, so they are put back.
        handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        try:
            if address is None:
                # "local": a new instance even where a cluster started by `ray start` is
                # running (which a bare ray.init() would join).
                workers = workers or default_workers()
                ray.init(address="local", num_cpus=workers, include_dashboard=False, **quiet)
                return workers
            try:
                _init_retrying_client(ray, address, quiet)
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
        finally:
            for signum, handler in handlers.items():
                signal.signal(signum, handler)

    def run(self, tasks: Iterable[Task]) -> Iterator[Episode | Failure]:
        """Run ``tasks``, yielding each result as it comes (in the order episodes finish)."""
        ray = self._ray
        queue = deque(tasks)
        free = [a for a in self._actors for _ in range(IN_FLIGHT_PER_WORKER)]
        pending: dict[Any, tuple[Task, Any]] = {}
        while queue or pending:
            while queue and free:
                task, actor = queue.popleft(), free.pop(0)
                ref = actor.run.remote(task.scenario_toml, task.point, task.seed)
                pending[ref] = (task, actor)
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                task, actor = pending.pop(ref)
                free.append(actor)
                try:
                    yield ray.get(ref)
                except ray.exceptions.RayError as exc:
                    yield Failure(task.point, task.seed, _one_line(exc))

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
