"""Your own estimator, judged beside the built-in methods: the plug-in contract.

A user's estimator is a function ``fn(obs) -> p_w``: given one detection as a
``PluginObservation`` (what the lecture's chain needs), it returns the cone's base centre in
the world, shape (3,), metres, or ``None`` for no estimate. The reference solution is the
lecture's chain (MIT 16.485 VNAV, lecture 1, chapter 0)::

    p_w = T_w_b @ T_b_c @ p_c

(``reference_estimate``). ``load_estimator`` finds a function from a spec,
``package.module:function`` or ``path/to/file.py:function``; ``plugin_method`` makes it a
``vnav.methods.Method`` named ``user:function`` with the ``depth_image`` accuracy bound,
which a run adds to the built-ins with ``vnav.methods.extended`` (and judges against the
correct chain on the same inputs, ``scenarios.scenario.check_kinds.user_checks``). A function that
raises, returns something other than a finite array of shape (3,), never stops the run: each
failure is tallied by kind (``Failures``) and the detection gets no estimate
(``NoEstimate.FUNCTION_ERROR``). Each call is timed (``CallTimes``); with a time limit
(``timeout_s``) a call that exceeds it is stopped (on the main thread; elsewhere it is
counted once it returns), is a failure of kind ``TIMED_OUT``, and the function is not called
again that run. docs/CONVENTIONS.md ("Your own estimator") has a worked example.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import importlib.util
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vnav import quat, so3
from vnav.diagnose import Diagnosis, diagnose
from vnav.estimators import NoEstimate
from vnav.methods import Method, method
from vnav.observation import Exposure, Observation

__all__ = [
    "CallTimes",
    "Failure",
    "Failures",
    "PluginEstimator",
    "PluginObservation",
    "function_method",
    "load_estimator",
    "observation_for",
    "plugin_method",
    "reference_estimate",
    "second_pass_methods",
]

USER_PREFIX = "user:"
"""A user method's name is this and its function's name (``user:my_estimate``)."""

_USER_COLOR_RGB = (255, 255, 255)


def _frozen(a: Any, shape: tuple[int, ...]) -> np.ndarray:
    out = np.array(a, dtype=np.float64).reshape(shape)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class PluginObservation:
    """One detected cone, as a user's estimator is given it. Every array is read-only.

    Attributes
    ----------
    p_c : ndarray, shape (3,)
        The cone's base centre in the camera (optical) frame, metres, as the depth image
        measures it: the ``depth_image`` estimate expressed in the camera frame with the
        pose and mount below, so that ``T_w_b @ T_b_c @ [p_c, 1]`` gives that estimate back
        (to rounding, about 1e-15 of the coordinates).
    uv : ndarray, shape (2,)
        Its pixel, ``K p_c / z`` (u right, v down).
    depth_m : float
        Its z in the camera frame, metres (``p_c[2]``).
    K : ndarray, shape (3, 3)
        The camera's intrinsics.
    T_w_b : ndarray, shape (4, 4)
        The body (FLU) pose at the image's exposure, as the estimator was told it.
    quat_w_b_xyzw : ndarray, shape (4,)
        Its rotation as a unit quaternion, scalar last.
    rpy_w_b_deg : ndarray, shape (3,)
        Its rotation as roll, pitch, yaw, degrees: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
    T_b_c : ndarray, shape (4, 4)
        The declared camera mount, the optical frame in the body.
    t_s : float
        The image's exposure stamp, seconds (the estimator's clock).
    T_w_b_newest : ndarray, shape (4, 4), or None
        The newest body pose received when the image arrived (what a pipeline that ignores
        stamps would use); ``T_w_b`` itself where none newer than the exposure had arrived
        (a run without latency). None only in an observation built without it.
    """

    p_c: np.ndarray
    uv: np.ndarray
    depth_m: float
    K: np.ndarray
    T_w_b: np.ndarray
    quat_w_b_xyzw: np.ndarray
    rpy_w_b_deg: np.ndarray
    T_b_c: np.ndarray
    t_s: float
    T_w_b_newest: np.ndarray | None = None


def _exposure_fields(e: Exposure, T_w_b_newest: np.ndarray | None) -> dict[str, Any]:
    """The fields of a ``PluginObservation`` that the image's exposure alone decides (the
    same for each of its detections): its pose in three forms, the mount, ``K``, the newest
    pose."""
    R_w_b = e.T_w_b[:3, :3]
    T_w_b = _frozen(e.T_w_b, (4, 4))
    return {
        "K": _frozen(e.camera.K, (3, 3)),
        "T_w_b": T_w_b,
        "quat_w_b_xyzw": _frozen(quat.from_matrix(R_w_b), (4,)),
        "rpy_w_b_deg": _frozen(np.degrees(so3.to_rpy(R_w_b, warn=False)), (3,)),
        "T_b_c": _frozen(e.T_b_c, (4, 4)),
        # Read-only, so one array may be both.
        "T_w_b_newest": T_w_b if T_w_b_newest is None else _frozen(T_w_b_newest, (4, 4)),
    }


def observation_for(
    obs: Observation,
    p_w_depth: np.ndarray,
    t_s: float,
    T_w_b_newest: np.ndarray | None = None,
    *,
    exposure_fields: dict[str, Any] | None = None,
) -> PluginObservation:
    """The ``PluginObservation`` of one detection from what ``vnav.localize`` has of it.

    Parameters
    ----------
    obs : vnav.observation.Observation
        The detection and its image's exposure (pose, mount, camera).
    p_w_depth : ndarray, shape (3,)
        Its ``depth_image`` estimate in the world, metres.
    t_s : float
        The exposure stamp, seconds.
    T_w_b_newest : ndarray, shape (4, 4), optional
        The newest pose received when the image arrived; default the exposure pose.
    exposure_fields : dict, optional
        The fields the exposure decides, made once per image by the caller
        (``PluginEstimator``: several detections share an image); made here without it.
    """
    fields = exposure_fields or _exposure_fields(obs.exposure, T_w_b_newest)
    p_c = np.array(obs.view.camera_coordinates(p_w_depth), dtype=np.float64)
    uv = (fields["K"] @ p_c)[:2] / p_c[2]
    return PluginObservation(
        p_c=_frozen(p_c, (3,)),
        uv=_frozen(uv, (2,)),
        depth_m=float(p_c[2]),
        t_s=float(t_s),
        **fields,
    )


def reference_estimate(obs: PluginObservation) -> np.ndarray:
    """The lecture's chain, the reference solution: ``p_w = T_w_b @ T_b_c @ p_c``, (3,)."""
    p_c_h = np.append(obs.p_c, 1.0)
    return (obs.T_w_b @ obs.T_b_c @ p_c_h)[:3]


def load_estimator(spec: str) -> Callable[[PluginObservation], Any]:
    """The function a spec names: ``package.module:function`` (looked up on ``sys.path`` and
    in the current directory) or ``path/to/file.py:function``.

    Raises
    ------
    ValueError
        If the spec has no ``:function``, its module or file does not import (with the
        import's own reason), it has no such attribute, or that attribute is not callable.
    """
    where, sep, name = spec.rpartition(":")
    if not sep or not where or not name.isidentifier():
        raise ValueError(
            f"estimator {spec!r}: expected package.module:function or path/to/file.py:function"
        )
    if not where.endswith(".py") and os.getcwd() not in sys.path and "" not in sys.path:
        # As ``python -m`` would: a module beside the user is found (an installed console
        # script's sys.path holds only its own environment's).
        sys.path.insert(0, os.getcwd())
    try:
        module = _import_file(where) if where.endswith(".py") else importlib.import_module(where)
    except Exception as exc:  # the user's module may raise anything while importing
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"estimator {spec!r}: {where} does not import: {reason}") from None
    if not hasattr(module, name):
        raise ValueError(f"estimator {spec!r}: {where} has no attribute {name!r}")
    fn = getattr(module, name)
    if not callable(fn):
        raise ValueError(f"estimator {spec!r}: {where}.{name} is not callable")
    return fn


def _import_file(path_text: str) -> Any:
    """The module in a ``.py`` file, imported under a name of its own."""
    path = Path(path_text)
    if not path.is_file():
        raise FileNotFoundError(f"no such file {path_text}")
    module_name = f"_vnav_user_{abs(hash(str(path.resolve())))}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path_text}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling look modules up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[module_name]
        raise
    return module


class Failure(enum.Enum):
    """How a user's function failed on one detection."""

    RAISED = "raised"
    NOT_ARRAY = "not_array"
    WRONG_SHAPE = "wrong_shape"
    NOT_FINITE = "not_finite"
    TIMED_OUT = "timed_out"


@dataclass
class Failures:
    """A user function's failures over one run, by kind.

    Attributes
    ----------
    calls : int
        How many times it was called.
    returned_none : int
        How many times it returned None (no estimate: not a failure).
    skipped : int
        Detections it was not called on because it had timed out earlier in the run.
    count : dict of Failure to int
    first_message : dict of Failure to str
        The first failure of each kind, in words.
    stamps_s : dict of Failure to list of float
        The exposure stamps of the images it failed on, per kind.
    """

    calls: int = 0
    returned_none: int = 0
    skipped: int = 0
    count: dict[Failure, int] = field(default_factory=dict)
    first_message: dict[Failure, str] = field(default_factory=dict)
    stamps_s: dict[Failure, list[float]] = field(default_factory=dict)

    def add(self, kind: Failure, message: str, t_s: float) -> None:
        """Count one failure of ``kind`` at exposure ``t_s``; keep the first message."""
        self.count[kind] = self.count.get(kind, 0) + 1
        self.first_message.setdefault(kind, message)
        self.stamps_s.setdefault(kind, []).append(t_s)

    @property
    def total(self) -> int:
        """Failures of every kind."""
        return sum(self.count.values())


@dataclass
class CallTimes:
    """The wall time of a user function's calls over one run (``time.perf_counter``).

    Attributes
    ----------
    calls : int
        Calls timed (every call, a timed-out one included).
    total_s : float
        Their summed wall time, seconds.
    max_s : float
        The longest, seconds.
    """

    calls: int = 0
    total_s: float = 0.0
    max_s: float = 0.0

    def add(self, elapsed_s: float) -> None:
        """Count one call of ``elapsed_s`` seconds."""
        self.calls += 1
        self.total_s += elapsed_s
        self.max_s = max(self.max_s, elapsed_s)

    @property
    def mean_s(self) -> float:
        """The mean call, seconds (0 before any)."""
        return self.total_s / self.calls if self.calls else 0.0


class _TimedOut(BaseException):
    """Raised inside the user's function by the time limit's alarm. A ``BaseException``, so
    that the user's own ``except Exception`` does not swallow it."""


def _check_timeout(timeout_s: float | None) -> float | None:
    if timeout_s is None:
        return None
    if isinstance(timeout_s, bool) or not isinstance(timeout_s, int | float):
        raise ValueError(f"timeout_s must be a number of seconds or None; got {timeout_s!r}")
    if not (math.isfinite(timeout_s) and timeout_s > 0.0):
        raise ValueError(f"timeout_s must be a finite number of seconds > 0; got {timeout_s}")
    return float(timeout_s)


def _can_interrupt() -> bool:
    """Whether a call here can be stopped by SIGALRM: on the main thread, where Python runs
    signal handlers, and where the platform has interval timers."""
    return hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()


def _call_with_alarm(
    fn: Callable[[PluginObservation], Any], obs: PluginObservation, limit_s: float
) -> Any:
    """``fn(obs)``, stopped by ``_TimedOut`` after ``limit_s`` seconds (main thread only).

    The previous SIGALRM handler and real-time timer are put back afterwards (the timer with
    what was left of it), so no alarm of ours is ever left armed."""
    armed = [True]

    def on_alarm(signum: int, frame: Any) -> None:
        if armed[0]:  # a late alarm, once the call has returned, does nothing
            armed[0] = False
            raise _TimedOut

    started_s = time.perf_counter()
    previous_handler = signal.signal(signal.SIGALRM, on_alarm)
    previous_delay_s, previous_interval_s = signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        try:
            return fn(obs)
        finally:
            armed[0] = False
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous_handler)
        if previous_delay_s > 0.0:  # someone else's timer: what was left of it
            left_s = previous_delay_s - (time.perf_counter() - started_s)
            signal.setitimer(signal.ITIMER_REAL, max(left_s, 1e-6), previous_interval_s)


_LAST_FIELDS: tuple[Exposure | None, np.ndarray | None, dict[str, Any]] = (None, None, {})
"""The exposure fields (``_exposure_fields``) of the last image a user's function was given:
the image's other detections, and the other users' functions, share them (they are
read-only)."""


class PluginEstimator:
    """A user's function as a ``"user"`` method's estimator (``vnav.localize``): called with
    the ``PluginObservation`` of each detection that has a ``depth_image`` estimate, never
    letting its failures out (``failures`` tallies them, ``times`` its calls' wall time;
    ``reset`` starts a new run's).

    Parameters
    ----------
    fn : callable
        ``fn(obs: PluginObservation) -> p_w`` (array-like, shape (3,)) or None.
    timeout_s : float, optional
        The longest a call may take, seconds (finite, > 0); default no limit. A call that
        takes longer is a ``TIMED_OUT`` failure: on the main thread it is stopped when the
        limit passes (SIGALRM: ``signal.setitimer``, the previous handler and timer put back
        afterwards); on another thread, where Python cannot interrupt it, its estimate is
        thrown away once it returns. After a timeout the function is not called again until
        ``reset`` (each later detection counts in ``failures.skipped``), so a run with a slow
        function still ends in bounded time.

    Raises
    ------
    ValueError
        If ``timeout_s`` is not None or a finite number > 0.
    """

    def __init__(
        self, fn: Callable[[PluginObservation], Any], timeout_s: float | None = None
    ) -> None:
        self.fn = fn
        self.timeout_s = _check_timeout(timeout_s)
        self.again: PluginEstimator | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the previous run's failures, times and estimates (and its second pass)."""
        self.failures = Failures()
        self.times = CallTimes()
        self.stopped = False
        self.again = None
        self._seen: list[tuple[np.ndarray, ...]] = []

    def second_pass(self) -> PluginEstimator:
        """A new estimator of the same function and limit for this run's detections
        estimated again (a calibrated run's recovered mount): its own tallies (kept as
        ``again``), and stopped from the start if this one was stopped for its time."""
        again = PluginEstimator(self.fn, self.timeout_s)
        again.stopped = self.stopped
        self.again = again
        return again

    def diagnosis(self) -> Diagnosis | None:
        """The frame-bug doctor (``vnav.diagnose``) on every estimate the function gave this
        run, from the observations it was given (the newest poses too, for the stale-pose
        mistake); None before any. The observation's ``p_c`` and poses reproduce the correct
        chain exactly, sensor noise or not, so the default tolerance holds."""
        if not self._seen:
            return None
        p_c, T_w_b, T_b_c, newest, p_w = (
            np.array(column) for column in zip(*self._seen, strict=True)
        )
        return diagnose(p_c, T_w_b, T_b_c, p_w, T_w_b_newest=newest)

    def _observation(
        self, obs: Observation, p_w_depth: np.ndarray, t_s: float, T_w_b_newest: Any
    ) -> PluginObservation:
        """``observation_for``, with the exposure's fields made once per image (for every
        user's function, ``_LAST_FIELDS``)."""
        global _LAST_FIELDS
        exposure, newest, fields = _LAST_FIELDS
        if exposure is not obs.exposure or newest is not T_w_b_newest:
            fields = _exposure_fields(obs.exposure, T_w_b_newest)
            # One tuple, assigned at once: another thread reads the old entry or the new.
            _LAST_FIELDS = (obs.exposure, T_w_b_newest, fields)
        return observation_for(obs, p_w_depth, t_s, exposure_fields=fields)

    def estimate(
        self,
        obs: Observation,
        p_w_depth: np.ndarray,
        t_s: float,
        T_w_b_newest: np.ndarray | None = None,
    ) -> Any:
        """``fn``'s estimate, (3,) float64, or ``NoEstimate.FUNCTION_NONE`` /
        ``FUNCTION_ERROR`` / ``FUNCTION_STOPPED``. ``T_w_b_newest``: the newest pose received
        when the image arrived (default the exposure pose)."""
        if self.stopped:
            self.failures.skipped += 1
            return NoEstimate.FUNCTION_STOPPED
        return self.estimate_given(self._observation(obs, p_w_depth, t_s, T_w_b_newest))

    def estimate_given(self, given: PluginObservation) -> Any:
        """``estimate`` on the ``PluginObservation`` made already (``observation_for``): what
        judging a function again on a stored run's detections calls."""
        t_s = given.t_s
        if self.stopped:
            self.failures.skipped += 1
            return NoEstimate.FUNCTION_STOPPED
        self.failures.calls += 1
        returned, raised = self._call(given)
        if raised is not None:
            kind, message = raised
            self.failures.add(kind, message, t_s)
            return NoEstimate.FUNCTION_ERROR
        if returned is None:
            self.failures.returned_none += 1
            return NoEstimate.FUNCTION_NONE
        try:
            p_w = np.asarray(returned, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            self.failures.add(
                Failure.NOT_ARRAY, f"returned a {type(returned).__name__}, not an array: {exc}", t_s
            )
            return NoEstimate.FUNCTION_ERROR
        if p_w.shape != (3,):
            self.failures.add(Failure.WRONG_SHAPE, f"returned shape {p_w.shape}, not (3,)", t_s)
            return NoEstimate.FUNCTION_ERROR
        if not all(math.isfinite(v) for v in p_w):
            self.failures.add(Failure.NOT_FINITE, f"returned {p_w.tolist()}", t_s)
            return NoEstimate.FUNCTION_ERROR
        self._seen.append((given.p_c, given.T_w_b, given.T_b_c, given.T_w_b_newest, p_w.copy()))
        return p_w.copy()

    def _call(self, given: PluginObservation) -> tuple[Any, tuple[Failure, str] | None]:
        """``fn(given)``, timed and held to the limit: what it returned, or how it failed."""
        limit_s = self.timeout_s
        interruptible = limit_s is not None and _can_interrupt()
        started_s = time.perf_counter()
        try:
            if interruptible:
                assert limit_s is not None
                returned = _call_with_alarm(self.fn, given, limit_s)
            else:
                returned = self.fn(given)
        except _TimedOut:
            returned = None  # the limit's own: counted below
        except (Exception, SystemExit) as exc:  # the user's code: its failure, even an exit()
            self.times.add(time.perf_counter() - started_s)
            return None, (Failure.RAISED, f"{type(exc).__name__}: {exc}")
        elapsed_s = time.perf_counter() - started_s
        self.times.add(elapsed_s)
        if limit_s is not None and elapsed_s > limit_s:
            # Stopped by the alarm, or (off the main thread, or its own ``except:`` swallowed
            # the alarm) returned too late: either way over the limit, and never called again.
            self.stopped = True
            how = "stopped" if interruptible else "returned after it"
            return None, (
                Failure.TIMED_OUT,
                f"took longer than the {limit_s:g} s limit at t = {given.t_s:.3f} s ({how}; "
                "not called again this run)",
            )
        return returned, None

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        """No covariance is claimed: zero, rank 0, so the estimate has no NEES."""
        return np.zeros((3, 3))


def plugin_method(spec: str, timeout_s: float | None = None) -> Method:
    """A user's function as a method, ``user:<function>``, with ``depth_image``'s accuracy
    bound; its estimator is a ``PluginEstimator`` (``Method.estimator``) holding each call to
    ``timeout_s`` seconds if given.

    Raises
    ------
    ValueError
        As ``load_estimator``; or a ``timeout_s`` that is not a finite number > 0.
    """
    timeout_s = _check_timeout(timeout_s)
    fn = load_estimator(spec)
    name = getattr(fn, "__name__", None) or spec.rpartition(":")[2]
    return function_method(fn, spec, name, timeout_s)


def function_method(
    fn: Callable[[PluginObservation], Any],
    spec: str,
    name: str,
    timeout_s: float | None = None,
) -> Method:
    """A function already in hand as the method ``user:<name>`` (``plugin_method`` without the
    import): ``spec`` says where it came from (the report's ``estimators.<name>.spec``);
    ``timeout_s`` as ``plugin_method``'s."""
    m = Method(
        f"{USER_PREFIX}{name}",
        f"your function {spec}, given the depth_image estimate in the camera frame",
        _USER_COLOR_RGB,
        "white",
        method("depth_image").bound,
        spec,
        images="user",
    )
    # Method.estimator is a cached property that imports ``implementation`` by module name;
    # a file path does not import that way, so the estimator is put in its cache here.
    m.__dict__["estimator"] = PluginEstimator(fn, timeout_s)
    return m


def second_pass_methods(methods: tuple[Method, ...]) -> tuple[Method, ...]:
    """``methods`` with each user's method given a second-pass estimator
    (``PluginEstimator.second_pass``): for a run's detections estimated again (a calibrated
    run's recovered mount), so that the function is called again with what that pass gives
    it, its tallies kept apart from the run's own."""
    if not any(m.images == "user" for m in methods):
        return methods  # the same tuple: nothing to give a second pass
    out = []
    for m in methods:
        if m.images == "user":
            again = dataclasses.replace(m)
            again.__dict__["estimator"] = m.estimator.second_pass()
            m = again
        out.append(m)
    return tuple(out)
