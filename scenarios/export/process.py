"""Exporters in a process of their own: the image formats' encoding kept off the run's
interpreter.

The EuRoC and MCAP exporters (``scenarios.export.base.Exporter``) encode every image
(deflate, zstd, the depth in millimetres) on threads of their own, but their Python (mcap's
writer, the messages' encoders, the copies into a chunk) holds the interpreter's lock a few
milliseconds a tick, and the run's thread waits for it each time it takes the lock back
(docs/SPEED.md, "Exports"). ``ExportProcess`` runs them in a child process instead, one for
every format that takes the images (``scenarios.export.Format.own_process``), at a lower
scheduling priority (``EXPORTER_NICE``). The run's thread only copies each tick's images into
a ring of shared memory and sends the tick's record down a pipe (``on_tick``); the child
copies the images out, frees the slot and hands the tick to its exporters, unchanged.

The protocol, one pickled message at a time each way (``_send``, ``_recv``):

====================  ==============================  ===================================
the command sends     the child answers               when
====================  ==============================  ===================================
``start``             ``started``                     the run starts (``start``)
``tick``              ``free`` (its slot, copied out) each camera tick (``on_tick``)
``finish``            ``finished`` with the results   the run is judged (``finish``)
``abort``             ``aborted``                     the run failed (``abort``)
====================  ==============================  ===================================

The child answers ``error`` (the exception) instead if anything fails, after aborting its
exporters (each removes its files); ``on_tick`` or ``finish`` raises it in the command, so
that a full disk is an ``OSError`` there as it would be in one process. Log records of the
child's ``logging`` are sent up (``log``) and logged by the command under the same names.

Faults:

- The command killed outright (SIGKILL): on Linux the kernel kills the child with it
  (``PR_SET_PDEATHSIG``); elsewhere the child reads the end of its commands' pipe, aborts its
  exporters and ends. It writes into the command's staging directories only, which a later
  run removes as the command's own (``scenarios.record.outputs``).
- The child killed or crashed: the command reads the end of its answers' pipe and raises
  ``ExportProcessError`` (an ``OSError``: the files cannot be written).
- Ctrl-C (SIGINT to the whole process group): the child ignores it; the command's clean-up
  aborts it.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import mmap
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from scenarios.export import base
from scenarios.export.base import ExportResult
from scenarios.run.observers import abort_all

if TYPE_CHECKING:
    from scenarios.run.records import RunResult, TickRecord
    from scenarios.scenario.spec import ScenarioSpec
    from sim.mesh import Scenery
    from vnav.camera import PinholeCamera

__all__ = ["SLOTS_MIN", "ExportProcess", "ExportProcessError", "HostedFormat", "ring_slots"]

logger = logging.getLogger(__name__)

SLOTS_MIN = 3
"""Ticks of images the ring holds at least, however large (``ring_slots``)."""
STOP_TIMEOUT_S = 60.0
"""How long ``abort`` waits for the child to remove its files before killing it."""
_ALIGN = 64
"""Each image's offset in a slot, bytes: a cache line."""
_DEPTH_ITEMSIZE_MAX = 8
"""A depth image's largest sample (float64), bytes: a slot holds any floating depth."""
_HEADER = struct.Struct("<Q")
"""A message's length, before its pickle."""


class ExportProcessError(OSError):
    """The export process ended before it was told to: its files cannot be written."""


@dataclass(frozen=True)
class HostedFormat:
    """One format the child writes.

    Attributes
    ----------
    name : str
        The format's name (``scenarios.export.FORMATS``).
    exporter : str
        ``module:Class`` of its exporter, imported in the child.
    staging : Path
        Its staging directory (exists, empty).
    """

    name: str
    exporter: str
    staging: Path


# -- messages ----------------------------------------------------------------------------


def _send(fd: int, message: tuple) -> None:
    """Write one message (a tuple, pickled) to the pipe ``fd``, whole.

    Raises
    ------
    BrokenPipeError
        If the other end is closed.
    """
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_HEADER.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view) :]


def _read_exactly(fd: int, n: int) -> bytes:
    """``n`` bytes from ``fd``; EOFError if it ends first."""
    parts, left = [], n
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            raise EOFError
        parts.append(chunk)
        left -= len(chunk)
    return b"".join(parts)


def _recv(fd: int) -> tuple:
    """Read one message from the pipe ``fd``; EOFError if it is closed."""
    (length,) = _HEADER.unpack(_read_exactly(fd, _HEADER.size))
    return pickle.loads(_read_exactly(fd, length))


def _picklable(exc: BaseException) -> BaseException:
    """``exc`` if it survives a pickle round trip, else a RuntimeError saying what it was."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")


# -- slots -------------------------------------------------------------------------------


def _aligned(n: int) -> int:
    return -(-n // _ALIGN) * _ALIGN


def _slot_bytes(camera: PinholeCamera) -> int:
    """A slot's size: the camera's (H, W, 3) uint8 image and an (H, W) depth of any float."""
    pixels = camera.width * camera.height
    return _aligned(3 * pixels) + _aligned(_DEPTH_ITEMSIZE_MAX * pixels)


def ring_slots(slot_bytes: int) -> int:
    """Ticks the ring holds: as many as ``scenarios.export.base.QUEUED_BYTES_MAX`` holds (the
    exporters' own bound on what they fall behind by), ``SLOTS_MIN`` at least."""
    return max(SLOTS_MIN, base.QUEUED_BYTES_MAX // slot_bytes)


def _layout(rgb: np.ndarray, depth: np.ndarray | None) -> tuple:
    """Where a tick's images are in a slot: ``((offset, shape, dtype), ...)``, rgb first."""
    meta = [(0, rgb.shape, rgb.dtype.str)]
    if depth is not None:
        meta.append((_aligned(rgb.nbytes), depth.shape, depth.dtype.str))
    return tuple(meta)


def _views(buffer: mmap.mmap, start: int, layout: tuple) -> list[np.ndarray]:
    """The arrays ``layout`` places in the slot that begins at ``start``."""
    return [
        np.ndarray(shape, dtype=np.dtype(dtype), buffer=buffer, offset=start + offset)
        for offset, shape, dtype in layout
    ]


def _slot_arrays(
    buffer: mmap.mmap, start: int, size: int, layout: tuple
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The slot at ``start`` as one uint8 array, and the arrays ``layout`` places in it, each
    a view of that one (which lives while any of them does)."""
    whole = np.ndarray((size,), dtype=np.uint8, buffer=buffer, offset=start)
    images = []
    for offset, shape, dtype in layout:
        dtype = np.dtype(dtype)
        n = int(np.prod(shape)) * dtype.itemsize
        images.append(whole[offset : offset + n].view(dtype).reshape(shape))
    return whole, images


# -- the command's side ------------------------------------------------------------------


class ExportProcess:
    """Exporters run in a child process (``scenarios.export.base.Exporter``'s calls, with
    ``finish`` returning every format's result).

    The child is started here, so that its imports overlap the scene's building; ``start``
    waits for it.

    Parameters
    ----------
    formats : sequence of HostedFormat
        In the order ``finish`` returns their results.

    Raises
    ------
    OSError
        If the process cannot be started.
    """

    name = "process"

    def __init__(self, formats: Sequence[HostedFormat]) -> None:
        self.formats = tuple(formats)
        self._ring: mmap.mmap | None = None  # made by start, sized by the camera
        self._ring_fd = _ring_file()
        commands_r, self._commands = os.pipe()
        self._answers, answers_w = os.pipe()
        try:
            self._process = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    __name__,
                    *(str(fd) for fd in (commands_r, answers_w, self._ring_fd)),
                    str(logging.getLogger().getEffectiveLevel()),
                    str(os.getpid()),
                ],
                pass_fds=(commands_r, answers_w, self._ring_fd),
                stdin=subprocess.DEVNULL,
            )
        except BaseException:
            for fd in (self._commands, self._answers, self._ring_fd):
                os.close(fd)
            raise
        finally:  # the child's ends: its own now
            os.close(commands_r)
            os.close(answers_w)
        self._slot_bytes = 0
        self._free: list[int] = []
        self._ticks = 0
        self._open = True

    @property
    def pid(self) -> int:
        """The child's process id."""
        return self._process.pid

    @property
    def exit_status(self) -> int | None:
        """The child's exit status (negative: the signal that ended it); None while it
        runs."""
        return self._process.poll()

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        """Size the ring for ``camera`` and start every format's exporter in the child.

        Raises
        ------
        OSError, ValueError
            What an exporter's ``start`` raised in the child (then aborted there).
        """
        self._slot_bytes = _slot_bytes(camera)
        slots = ring_slots(self._slot_bytes)
        os.ftruncate(self._ring_fd, slots * self._slot_bytes)
        self._ring = mmap.mmap(self._ring_fd, slots * self._slot_bytes)
        self._free = list(range(slots))[::-1]  # popped from the end: slot 0 first
        self._request(
            ("start", sys.path, self.formats, spec, seed, camera, scenery, self._slot_bytes, slots)
        )

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        """Copy the tick's images into a free slot (waiting for one if the child is behind)
        and send the tick.

        Raises
        ------
        ValueError
            If the images do not fit a slot (not the camera's size), or an exporter refused an
            earlier tick.
        OSError
            If writing an earlier tick failed (a full disk...), or the child ended.
        """
        if self._ring is None:
            raise ValueError("on_tick before start (or after finish or abort)")
        rgb = np.ascontiguousarray(rgb)
        depth = None if depth_m is None else np.ascontiguousarray(depth_m)
        layout = _layout(rgb, depth)
        used = layout[-1][0] + (rgb if depth is None else depth).nbytes
        if used > self._slot_bytes:
            raise ValueError(
                f"tick {record.tick}: images of {rgb.shape} and "
                f"{None if depth is None else depth.shape} do not fit the camera's slot"
            )
        self._take_answers(block=False)
        while not self._free:
            self._take_answers(block=True)
        slot = self._free.pop()
        for view, image in zip(
            _views(self._ring, slot * self._slot_bytes, layout), (rgb, depth), strict=False
        ):
            np.copyto(view, image)
        self._send(("tick", slot, record, layout))
        self._ticks += 1

    def finish(self, result: RunResult) -> tuple[ExportResult, ...]:
        """Finish every format's files in the child; their results, in ``formats`` order.

        Raises
        ------
        OSError
            If a file cannot be completed (a full disk...) or the child ended.
        """
        if self._ring is None:
            raise ValueError("finish before start (or after finish or abort)")
        # The child has every tick's record already: the result goes without them.
        answer = self._request(("finish", replace(result, ticks=[])))
        self._close(wait=True)
        return tuple(answer[1])

    def abort(self) -> None:
        """Tell the child to abort its exporters (each removes its files) and wait for it
        (``STOP_TIMEOUT_S`` at most, then it is killed); nothing if it has ended."""
        if not self._open:
            return
        try:
            self._send(("abort",), raising=False)
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while True:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self._answers], [], [], left)[0]:
                    logger.warning(
                        "the export process did not stop in %.0f s: killed", STOP_TIMEOUT_S
                    )
                    self._process.kill()
                    break
                try:
                    kind = self._answer()[0]
                except (EOFError, OSError):
                    break
                if kind in ("aborted", "error"):
                    break
        finally:
            self._close(wait=True)

    # -- the pipes ------------------------------------------------------------------------

    def _send(self, message: tuple, raising: bool = True) -> None:
        try:
            _send(self._commands, message)
        except BrokenPipeError:
            if raising:
                self._raise_ended()

    def _request(self, message: tuple) -> tuple:
        """Send ``message`` and wait for its answer (``started``, ``finished``)."""
        self._send(message)
        while True:
            answer = self._take_answers(block=True)
            if answer is not None:
                return answer

    def _take_answers(self, block: bool) -> tuple | None:
        """Read the answers waiting (one at least if ``block``): slots freed, log records;
        return the first other answer, or raise the child's error."""
        while block or select.select([self._answers], [], [], 0)[0]:
            try:
                answer = self._answer()
            except EOFError:
                self._raise_ended()
            kind = answer[0]
            if kind == "free":
                self._free.append(answer[1])
                block = False
            elif kind == "log":
                logging.getLogger(answer[1]).log(answer[2], "%s", answer[3])
            elif kind == "error":
                raise answer[1]
            else:
                return answer
        return None

    def _answer(self) -> tuple:
        return _recv(self._answers)

    def _raise_ended(self) -> None:
        """Raise the child's error if it sent one before its end (a command written after
        it failed finds its pipe closed), else ``ExportProcessError``."""
        error = None
        with contextlib.suppress(EOFError, OSError):
            while error is None:
                answer = self._answer()
                error = answer[1] if answer[0] == "error" else None
        if error is not None:
            raise error
        status = self._process.wait()
        how = f"killed by {signal.Signals(-status).name}" if status < 0 else f"exit status {status}"
        raise ExportProcessError(f"the export process ended unexpectedly ({how})")

    def _close(self, wait: bool) -> None:
        """Close the pipes and the ring, and wait for the child to end."""
        if not self._open:
            return
        self._open = False
        for fd in (self._commands, self._answers, self._ring_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._ring is not None:
            self._ring.close()
        self._ring = None
        if wait:
            try:
                self._process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()


def _ring_file() -> int:
    """A file for the ring, in memory, with no name: ``memfd_create`` where there is one,
    else an unlinked temporary file."""
    if hasattr(os, "memfd_create"):
        # Closed on exec like any other descriptor: pass_fds keeps it open for the child.
        return os.memfd_create("vnav-export-ring", os.MFD_CLOEXEC)
    import tempfile

    with tempfile.TemporaryFile() as f:
        return os.dup(f.fileno())


# -- the child's side --------------------------------------------------------------------


class _LogUp(logging.Handler):
    """Sends each log record to the command (``log``), whose logging handles it."""

    def __init__(self, child: _Child) -> None:
        super().__init__()
        self._child = child

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            self._child.answer(("log", record.name, record.levelno, record.getMessage()))


class _Child:
    """The child's loop: reads commands, runs the exporters, answers."""

    def __init__(self, commands: int, answers: int, ring_fd: int) -> None:
        import threading

        self._commands, self._answers, self._ring_fd = commands, answers, ring_fd
        # Answers come from the loop, from logging and from freed slots (any thread, even
        # one inside an answer when an array's last reference goes).
        self._lock = threading.RLock()
        self._ring: mmap.mmap | None = None
        self._slot_bytes = 0
        self._exporters: list[Any] = []
        self._ticks: list[TickRecord] = []

    def answer(self, message: tuple) -> None:
        with self._lock:
            _send(self._answers, message)

    def _free(self, slot: int) -> None:
        """Tell the command that ``slot`` may be written again (on whichever thread dropped
        its last array)."""
        with contextlib.suppress(OSError):
            self.answer(("free", slot))

    def run(self) -> int:
        """Serve commands until told to end or the command's end closes; the exit status."""
        try:
            while True:
                try:
                    message = _recv(self._commands)
                except EOFError:  # the command is gone: nothing of this run is kept
                    self._abort()
                    return 0
                if not self._handle(message):
                    return 0
        except BaseException as exc:
            logger.debug("export process failed", exc_info=True)
            with contextlib.suppress(BaseException):
                self._abort()
            with contextlib.suppress(OSError):
                self.answer(("error", _picklable(exc)))
            return 1

    def _handle(self, message: tuple) -> bool:
        """Carry out one command; False once the child should end."""
        kind = message[0]
        if kind == "tick":
            _, slot, record, layout = message
            # The exporters take the slot's memory as it is: the slot is freed when the last
            # of its arrays is gone (their queues written), not copied out.
            whole, images = _slot_arrays(
                self._ring, slot * self._slot_bytes, self._slot_bytes, layout
            )
            freed = weakref.finalize(whole, self._free, slot)
            freed.atexit = False
            del whole
            rgb, depth = images[0], images[1] if len(images) > 1 else None
            del images
            self._ticks.append(record)
            for exporter in self._exporters:
                exporter.on_tick(record, rgb, depth)
            return True
        if kind == "start":
            self._start(*message[1:])
            self.answer(("started",))
            return True
        if kind == "finish":
            result = replace(message[1], ticks=self._ticks)
            done = [exporter.finish(result) for exporter in self._exporters]
            self._exporters = []
            self.answer(("finished", done))
            return False
        if kind == "abort":
            self._abort()
            self.answer(("aborted",))
            return False
        raise ValueError(f"unknown command {kind!r}")

    def _start(self, path, formats, spec, seed, camera, scenery, slot_bytes, slots) -> None:
        sys.path[:] = path  # the command's: where its exporters' modules are found
        self._slot_bytes = slot_bytes
        self._ring = mmap.mmap(self._ring_fd, slots * slot_bytes)
        for f in formats:
            module, _, cls = f.exporter.partition(":")
            self._exporters.append(getattr(importlib.import_module(module), cls)(f.staging))
        for exporter in self._exporters:
            exporter.start(spec, seed, camera, scenery)

    def _abort(self) -> None:
        """Abort every exporter (each removes its files), even if one fails to."""
        exporters, self._exporters = self._exporters, []
        abort_all(exporters)


def _lower_priority() -> None:
    """The whole child ``EXPORTER_NICE`` nicer than the command (its threads with it).

    Not ``SCHED_IDLE``: a child that runs only on idle cores falls behind until the ring is
    full, and the run then waits for it (measured: slower than at nice +10)."""
    with contextlib.suppress(OSError):
        os.nice(base.EXPORTER_NICE)
    base.nice_threads(False)


def _die_with(parent_pid: int) -> bool:
    """Have the kernel kill this process when the command that started it dies (Linux's
    ``PR_SET_PDEATHSIG``); False if the command is gone already."""
    if sys.platform.startswith("linux"):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    return os.getppid() == parent_pid  # it may have died before the call


def main(argv: Sequence[str]) -> int:
    """The child: ``python -m scenarios.export.process COMMANDS ANSWERS RING LEVEL PARENT``
    (file descriptors, the command's logging level and process id)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the command stops it (module docstring)
    commands, answers, ring, level, parent_pid = (int(a) for a in argv)
    if not _die_with(parent_pid):
        return 0
    _lower_priority()
    child = _Child(commands, answers, ring)
    root = logging.getLogger()
    root.addHandler(_LogUp(child))
    root.setLevel(level)
    return child.run()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
