"""Choose MuJoCo's OpenGL backend before MuJoCo is imported, and fail clearly when none works.

MuJoCo reads ``MUJOCO_GL`` once, when ``mujoco`` is first imported; left unset on a machine with
no display it tries GLFW and fails with the bare "OpenGL platform library has not been loaded".
Every module of ``sim`` imports MuJoCo through this one::

    from sim.gl import mujoco

If ``MUJOCO_GL`` is unset and there is no display (``DISPLAY`` / ``WAYLAND_DISPLAY``), the first
of EGL and OSMesa whose system library loads is chosen. Physics never needs OpenGL, so nothing
here raises at import (with no platform library at all ``MUJOCO_GL=disable`` is set);
``create_gl_context`` raises one clear ``GLBackendError`` when a rendering context cannot
be made.

Every OpenGL call of the process runs on one thread of its own (``on_gl_thread``,
``submit_gl``): a context is current on one thread at a time, and a render drawn there
overlaps the physics and the estimation of the caller's thread (``sim.render.Renderer.
render_async``): the software rasteriser's threads and the caller's then keep both cores busy.

MuJoCo's own warnings (e.g. "Nan, Inf or huge value in QVEL") are routed to the ``mujoco``
logger instead of stderr and a ``MUJOCO_LOG.TXT`` file in the working directory.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

logger = logging.getLogger(__name__)

HEADLESS_BACKENDS: tuple[str, ...] = ("egl", "osmesa")
"""Headless backends in the order they are tried."""

_LIBRARIES: dict[str, tuple[str, ...]] = {
    "egl": ("EGL", "libEGL.so.1"),
    "osmesa": ("OSMesa", "libOSMesa.so.8", "libOSMesa.so.6"),
}

_INSTALL_HINT = (
    "Install an OpenGL platform library, e.g. on Debian/Ubuntu "
    "`apt-get install libegl1 libgl1-mesa-dri` (EGL, preferred) or "
    "`apt-get install libosmesa6` (OSMesa), or run with a display. "
    "You can also set MUJOCO_GL=egl|osmesa|glfw explicitly before starting Python."
)


class GLBackendError(RuntimeError):
    """No OpenGL platform could create a MuJoCo rendering context."""


def _library_loads(backend: str) -> bool:
    """Whether the system library of ``backend`` can be loaded with ctypes."""
    for name in _LIBRARIES[backend]:
        path = ctypes.util.find_library(name) if not name.startswith("lib") else name
        if not path:
            continue
        try:
            ctypes.CDLL(path)
        except OSError:
            continue
        return True
    return False


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def select_backend() -> tuple[str, tuple[str, ...]]:
    """Set ``MUJOCO_GL`` if it is unset and there is no display.

    Returns
    -------
    backend : str
        The value of ``MUJOCO_GL`` now in force (``""`` means MuJoCo's default, GLFW).
    tried : tuple of str
        The headless backends that were probed, in order (empty if none was probed).
    """
    current = os.environ.get("MUJOCO_GL")
    if current is not None:
        return current, ()
    if _has_display():
        return "", ()
    tried: list[str] = []
    for backend in HEADLESS_BACKENDS:
        tried.append(backend)
        if _library_loads(backend):
            if "mujoco" in sys.modules:
                logger.warning(
                    "mujoco was imported before sim.gl; MUJOCO_GL=%s may not take effect", backend
                )
            os.environ["MUJOCO_GL"] = backend
            logger.debug("MUJOCO_GL unset and no display: chose %s", backend)
            return backend, tuple(tried)
    # Nothing loads: disable MuJoCo's GL so that importing it (for physics) still works and does
    # not try GLFW; create_gl_context() reports the failure with the list of what was tried.
    os.environ["MUJOCO_GL"] = "disable"
    logger.debug("no OpenGL platform library found (tried %s): rendering disabled", tried)
    return "disable", tuple(tried)


BACKEND, TRIED = select_backend()

import mujoco  # noqa: E402  (must follow select_backend: MuJoCo reads MUJOCO_GL on import)

_mujoco_logger = logging.getLogger("mujoco")


def _log_mujoco_warning(message: str) -> None:
    """Route MuJoCo's warnings to logging (instead of stderr and MUJOCO_LOG.TXT in the cwd)."""
    _mujoco_logger.warning("%s", message.strip())


if mujoco.get_mju_user_warning() is None:
    mujoco.set_mju_user_warning(_log_mujoco_warning)


_T = TypeVar("_T")

_gl_lock = threading.Lock()
_gl_executor: ThreadPoolExecutor | None = None
_gl_pid: int | None = None  # the process that made _gl_executor (a forked child makes its own)
_gl_thread: threading.Thread | None = None


def _note_gl_thread() -> None:
    global _gl_thread
    _gl_thread = threading.current_thread()


def _forget_gl_thread() -> None:
    """In a forked child: the parent's OpenGL thread is not there (nor its contexts); the
    child's first call makes its own. A new lock, in case a parent's thread held it."""
    global _gl_lock, _gl_executor, _gl_pid, _gl_thread
    _gl_lock = threading.Lock()
    _gl_executor, _gl_pid, _gl_thread = None, None, None


os.register_at_fork(after_in_child=_forget_gl_thread)


def submit_gl(fn: Callable[..., _T], /, *args: Any, **kwargs: Any) -> Future[_T]:
    """Queue ``fn(*args, **kwargs)`` for the process's OpenGL thread.

    One thread makes every OpenGL context current and draws in it, in the order the calls
    are queued (an EGL or OSMesa context is current on one thread at a time). The thread is
    made on the first call of each process (a forked child's first call makes its own).

    Returns
    -------
    concurrent.futures.Future
        Its ``result()`` is ``fn``'s, or raises what ``fn`` raised.
    """
    global _gl_executor, _gl_pid
    with _gl_lock:
        if _gl_executor is None or _gl_pid != os.getpid():
            _gl_executor = ThreadPoolExecutor(
                max_workers=1, thread_name_prefix="vnav-gl", initializer=_note_gl_thread
            )
            _gl_pid = os.getpid()
        return _gl_executor.submit(fn, *args, **kwargs)


def on_gl_thread(fn: Callable[..., _T], /, *args: Any, **kwargs: Any) -> _T:
    """``fn(*args, **kwargs)`` called on the process's OpenGL thread (at once when already on
    it); its result, or what it raised."""
    if threading.current_thread() is _gl_thread and _gl_pid == os.getpid():
        return fn(*args, **kwargs)
    return submit_gl(fn, *args, **kwargs).result()


def create_gl_context(width: int, height: int) -> Any:
    """Create and make current an off-screen OpenGL context for MuJoCo.

    Parameters
    ----------
    width, height : int
        Largest image size the context will render, in pixels.

    The context is made on the process's OpenGL thread (``on_gl_thread``), current there;
    call its ``make_current`` and ``free`` there too.

    Returns
    -------
    GLContext
        MuJoCo's context object for the chosen backend (``make_current``, ``free``).

    Raises
    ------
    GLBackendError
        If no backend could create a context; the message lists the backends tried and what
        to install.
    """
    backend = os.environ.get("MUJOCO_GL", "")
    tried = ", ".join(TRIED) if TRIED else f"MUJOCO_GL={backend or '(unset: glfw)'}"
    if backend.lower() in ("disable", "disabled", "off", "false", "0") or not hasattr(
        mujoco, "GLContext"
    ):
        raise GLBackendError(
            f"No OpenGL platform for off-screen rendering: tried {tried}; none of their "
            f"libraries (libEGL, libOSMesa) could be loaded. {_INSTALL_HINT}"
        )
    try:
        context = on_gl_thread(_new_context, width, height)
    except Exception as exc:  # the backends raise ImportError, RuntimeError, GLError...
        raise GLBackendError(
            f"Could not create an OpenGL context with MUJOCO_GL={backend!r} "
            f"(tried: {tried}): {type(exc).__name__}: {exc}. {_INSTALL_HINT}"
        ) from exc
    return context


def _new_context(width: int, height: int) -> Any:
    context = mujoco.GLContext(width, height)
    context.make_current()
    return context
