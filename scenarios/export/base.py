"""What every exporter is: a ``TickObserver`` that writes one data format into a staging
directory, and what it reports.

An exporter (``Exporter``) is made with its staging directory, a hidden temporary name in
the output directory (``scenarios.record.outputs.staging_dir``). The run feeds it as it feeds
the recording (``scenarios.run.runner.FanOut``): ``start``, ``on_tick`` per camera tick,
then ``finish`` once the run is judged, or ``abort`` if anything fails. Every file it writes
is flushed to the disk (``write_flushed``, or a ``Flusher`` for the many files of a run)
before ``finish`` returns, so that the commit flushes only the directories. ``finish``
returns an ``ExportResult``: the final names it staged (files or directories, named as they
will be in the output directory) and those it did not write this time (with the reason in
``note``). ``scenarios.pipeline`` commits them with the recording and the report, all or none
(``scenarios.record.outputs.OutputPair.add``).

What several exporters write of the same image is made once: the depth in millimetres
(``tick_depth_mm``), which the EuRoC PNGs and the bag's depth images both hold, made on the
exporters' threads, not the run's.

The exporters' threads (``exporter_threads``) run at a lower scheduling priority than the run's
own: on a machine whose cores the run already keeps busy (its thread, the renderer's), they
take the time the run leaves idle instead of delaying its next tick, and catch up while it
waits; their queue (``queue_bound``) is deep enough to hold what they fall behind by, and
bounded in bytes. A run (``scenarios.pipeline``) runs the formats that encode every image in
an export process instead (``scenarios.export.process``), itself that much nicer, where the
exporters' Python does not hold the run's interpreter's lock; there the threads run at the
process's priority (``nice_threads``).
"""

from __future__ import annotations

import logging
import os
import sys
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from scenarios.run.records import RunResult, TickRecord
from vnav.camera import PinholeCamera

if TYPE_CHECKING:  # annotations only: importing sim.mesh loads MuJoCo before sim.gl
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery

__all__ = [
    "DEPTH_MM_MAX",
    "DEPTH_SCALE",
    "EXPORTER_NICE",
    "QUEUED_BYTES_MAX",
    "ExportResult",
    "Exporter",
    "Flusher",
    "TickDepthMm",
    "depth_mm",
    "exporter_threads",
    "listed_files",
    "queue_bound",
    "stamp_ns",
    "tick_depth_mm",
    "write_flushed",
]

logger = logging.getLogger(__name__)

DEPTH_SCALE = 1000.0
"""The exported 16-bit depth's value per metre (millimetres)."""
DEPTH_MM_MAX = int(np.iinfo(np.uint16).max)
"""The farthest depth 16 bits hold, millimetres (65.535 m)."""
EXPORTER_NICE = 10
"""How much nicer than the run's thread an exporter's thread is (Linux ``nice``, per thread):
the kernel's weight of such a thread is about a tenth of the run's, so that the run's thread
and the renderer's get a core first when they want one. The cost: an exporter's thread
descheduled while it holds the GIL keeps the run's thread waiting; they hold it little (their
work is deflate, zstd and numpy, which release it)."""
QUEUED_BYTES_MAX = 64 * 2**20
"""The images an exporter keeps waiting for its thread at most, bytes (``queue_bound``)."""
QUEUED_TICKS_MIN = 2
"""Ticks an exporter keeps waiting at least, whatever their size."""
QUEUED_TICKS_MAX = 64
"""Ticks an exporter keeps waiting at most, however small (each costs some time to write
whatever its size, which ``finish`` waits for)."""


def _priority(tid: int) -> int | None:
    """A thread's nice value (Linux, where ``getpriority`` of a thread id is that thread's;
    elsewhere a thread id is not a process id): None where it cannot be read."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return os.getpriority(os.PRIO_PROCESS, tid)
    except OSError:
        return None


def _set_priority(nice: int) -> None:
    """Set the calling thread's nice value to ``nice`` (a ``ThreadPoolExecutor``
    initializer; Linux only). A failure leaves it as it is: the speed depends on it, not the
    output."""
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:
        logger.debug("exporter thread %d keeps its priority: %s", tid, exc)


_threads_nicer = True


def nice_threads(enabled: bool) -> None:
    """Whether ``exporter_threads`` makes its threads nicer than the thread that makes the
    pool: not in a process that is itself nicer (``scenarios.export.process``)."""
    global _threads_nicer
    _threads_nicer = enabled


def exporter_threads(workers: int, name: str) -> ThreadPoolExecutor:
    """A pool of ``workers`` threads named ``name``, each ``EXPORTER_NICE`` nicer than the
    thread that makes the pool (the run's), whichever thread starts them (a pool starts its
    threads on its first calls, from the thread that calls; a thread inherits its parent's
    priority); at the process's priority after ``nice_threads(False)``."""
    base = _priority(threading.get_native_id()) if _threads_nicer else None
    if base is None:
        return ThreadPoolExecutor(max_workers=workers, thread_name_prefix=name)
    return ThreadPoolExecutor(
        max_workers=workers,
        thread_name_prefix=name,
        initializer=_set_priority,
        initargs=(min(19, base + EXPORTER_NICE),),  # 19: Linux's nicest
    )


def queue_bound(*images: np.ndarray | None) -> int:
    """Ticks an exporter may keep waiting for its thread, each holding ``images`` (the
    arrays queued with a tick): as many as ``QUEUED_BYTES_MAX`` holds (31 ticks of a 640x480
    colour image and its float32 depth, which the two exporters share), between
    ``QUEUED_TICKS_MIN`` and ``QUEUED_TICKS_MAX``. Beyond, the run's thread waits."""
    tick_bytes = sum(a.nbytes for a in images if a is not None)
    fits = QUEUED_BYTES_MAX // max(tick_bytes, 1)
    return min(QUEUED_TICKS_MAX, max(QUEUED_TICKS_MIN, fits))


@dataclass(frozen=True)
class ExportResult:
    """What one exporter staged.

    Attributes
    ----------
    format : str
        The format's name (``scenarios.export.FORMATS``).
    written : tuple of str
        Final names (in the output directory) of the files or directories staged, each under
        the same name in the staging directory.
    not_written : tuple of str
        Final names of the format that this run has nothing for: the commit removes a
        previous run's file there, so that none is left beside the new set.
    note : str or None
        One sentence: why something was not written, or what the files leave out.
    figures : dict
        More for the report (``tum``: the PnP trajectory's error statistics).
    """

    format: str
    written: tuple[str, ...]
    not_written: tuple[str, ...] = ()
    note: str | None = None
    figures: dict[str, Any] = field(default_factory=dict)


class Exporter(Protocol):
    """A data format written from a run (``scenarios.export.FORMATS``); made with its
    staging directory, which exists and is empty."""

    name: str

    def start(
        self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery
    ) -> None: ...

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None: ...

    def finish(self, result: RunResult) -> ExportResult: ...

    def abort(self) -> None: ...


def write_flushed(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file at ``path`` and flush it to the disk (``fsync``).

    Raises
    ------
    OSError
        If it cannot be written (a full disk...).
    """
    with open(path, "xb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


class Flusher:
    """Flushes files to the disk (``fsync``) on threads of its own, several at a time.

    One ``fsync`` waits for the disk's journal (about 5 ms on this project's machines);
    several waiting at once share a commit. An exporter writing two files a tick hands each
    to ``submit`` once written, and calls ``wait`` before its ``finish`` returns.

    Parameters
    ----------
    threads : int
        ``fsync`` calls waiting at once at most.

    Notes
    -----
    ``submit``, ``raise_done``, ``wait`` and ``shutdown`` are called from one thread at a
    time (the exporter's writer, then its ``finish``).
    """

    def __init__(self, threads: int = 4) -> None:
        self._pool = exporter_threads(threads, "vnav-fsync")
        self._pending: list[Future] = []

    def submit(self, path: Path) -> None:
        """Flush the file ``path`` (already written and closed) to the disk.

        Raises
        ------
        OSError
            An earlier file's flush failed (a full disk...): raised as soon as it is known.
        """
        self.raise_done()
        self._pending.append(self._pool.submit(_fsync_path, Path(path)))

    def raise_done(self) -> None:
        """Raise the error of a flush that failed, if one has; forget those that succeeded."""
        done = [f for f in self._pending if f.done()]
        if done:
            self._pending = [f for f in self._pending if not f.done()]
            for f in done:
                f.result()

    def wait(self) -> None:
        """Return once every file submitted is on the disk.

        Raises
        ------
        OSError
            If one could not be flushed.
        """
        pending, self._pending = self._pending, []
        for f in pending:
            f.result()

    def shutdown(self) -> None:
        """Stop the threads (after the flushes under way); nothing more is flushed."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pending = []


def _fsync_path(path: Path) -> None:
    # A read-only descriptor flushes the file's data as well: fsync acts on the file, and a
    # write-back error not yet reported to anyone is reported to it.
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def depth_mm(depth_m: np.ndarray, far_m: float) -> np.ndarray:
    """Planar depth in metres -> uint16 millimetres, rounded (half to even); 0 where there is
    no return (not finite, not positive, at or beyond ``far_m``: the sky) or beyond 65.535 m.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W)
    far_m : float
        The renderer's far plane (the sky reads it).

    Returns
    -------
    ndarray, shape (H, W), uint16
    """
    depth_m = np.asarray(depth_m)
    # In float64, where a float32 depth times 1000 is exact (float32 would round some 0.5 mm
    # off), in one pass with no float64 copy of the depth first.
    mm = np.multiply(depth_m, DEPTH_SCALE, dtype=np.float64)
    np.rint(mm, out=mm)
    # NaN compares false: no return. A depth that rounds to 0 mm is written 0 either way.
    valid = depth_m < far_m
    valid &= mm > 0.0
    valid &= mm <= DEPTH_MM_MAX
    out = np.zeros(depth_m.shape, dtype=np.uint16)
    np.copyto(out, mm, casting="unsafe", where=valid)
    return out


class TickDepthMm:
    """A tick's depth in millimetres (``depth_mm``), made by the first thread that asks for it
    (an exporter's writer, off the run's thread) and shared by every exporter of the tick.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W)
        Not modified until ``get`` has been called (the renderer makes a new one each tick).
    far_m : float
    """

    def __init__(self, depth_m: np.ndarray, far_m: float) -> None:
        self._depth_m: np.ndarray | None = depth_m
        self.far_m = far_m
        self._mm: np.ndarray | None = None
        self._lock = threading.Lock()

    def get(self) -> np.ndarray:
        """The (H, W) uint16 millimetres, read-only (the exporters share them)."""
        with self._lock:
            if self._mm is None:
                mm = depth_mm(self._depth_m, self.far_m)
                mm.flags.writeable = False
                self._mm, self._depth_m = mm, None
            return self._mm


_tick_depth_lock = threading.Lock()
_tick_depth_last: tuple[TickRecord, np.ndarray, TickDepthMm] | None = None


def tick_depth_mm(record: TickRecord, depth_m: np.ndarray, far_m: float) -> TickDepthMm:
    """The ``TickDepthMm`` of a tick, one for every exporter given that tick: the last call's is
    returned again for the same ``record`` and ``depth_m`` (the same objects, as
    ``scenarios.run.runner.FanOut`` hands each observer) and ``far_m``. Nothing is computed
    here: the first ``get`` computes."""
    global _tick_depth_last
    with _tick_depth_lock:
        last = _tick_depth_last
        if last is not None and last[0] is record and last[1] is depth_m and last[2].far_m == far_m:
            return last[2]
        shared = TickDepthMm(depth_m, far_m)
        # The record and the depth are held (not their ids): neither id is reused meanwhile.
        _tick_depth_last = (record, depth_m, shared)
        return shared


def stamp_ns(record: TickRecord) -> int:
    """The image's exposure stamp on the camera clock, integer nanoseconds (the simulated
    time for a tick with no stamps)."""
    t_s = record.t_s if record.timing is None else record.timing.stamp_cam_s
    return round(t_s * 1e9)


def listed_files(staging: Path, names: tuple[str, ...]) -> list[dict[str, Any]]:
    """Every file under the staged ``names`` (files or directories): ``{"path", "bytes"}``,
    the path relative to the output directory with ``/`` separators, sorted."""
    out = []
    for name in names:
        top = Path(staging) / name
        if not top.is_dir():
            out.append({"path": name, "bytes": top.stat().st_size})
            continue
        for root, dirs, files in os.walk(top):
            dirs.sort()
            for f in sorted(files):
                path = Path(root, f)
                rel = path.relative_to(staging).as_posix()
                out.append({"path": rel, "bytes": path.stat().st_size})
    return out
