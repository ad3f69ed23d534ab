"""Your own estimator, judged beside the built-in methods: the plug-in contract.

A user's estimator is a function ``fn(obs) -> p_w``: given one detection as a
``PluginObservation`` (what the lecture's chain needs), it returns the cone's base centre in
the world, shape (3,), metres, or ``None`` for no estimate. The reference solution is the
lecture's chain (MIT 16.485 VNAV, lecture 1, chapter 0)::

    p_w = T_w_b @ T_b_c @ p_c

(``reference_estimate``). ``load_estimator`` finds a function from a spec,
``package.module:function`` or ``path/to/file.py:function``; ``plugin_method`` makes it a
``vnav.methods.Method`` named ``user:function``, judged with the ``depth_image`` accuracy
bound, which a run adds to the built-ins with ``vnav.methods.extended``. A function that
raises, returns something other than a finite array of shape (3,), never stops the run: each
failure is tallied by kind (``Failures``) and the detection gets no estimate
(``NoEstimate.FUNCTION_ERROR``). docs/CONVENTIONS.md ("Your own estimator") has a worked
example.
"""

from __future__ import annotations

import enum
import importlib
import importlib.util
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vnav import quat, so3
from vnav.diagnose import Diagnosis, diagnose
from vnav.estimators import NoEstimate
from vnav.methods import Method, method
from vnav.observation import Observation

__all__ = [
    "Failure",
    "Failures",
    "PluginEstimator",
    "PluginObservation",
    "function_method",
    "load_estimator",
    "observation_for",
    "plugin_method",
    "reference_estimate",
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


def observation_for(obs: Observation, p_w_depth: np.ndarray, t_s: float) -> PluginObservation:
    """The ``PluginObservation`` of one detection from what ``vnav.localize`` has of it.

    Parameters
    ----------
    obs : vnav.observation.Observation
        The detection and its image's exposure (pose, mount, camera).
    p_w_depth : ndarray, shape (3,)
        Its ``depth_image`` estimate in the world, metres.
    t_s : float
        The exposure stamp, seconds.
    """
    e = obs.exposure
    p_c = np.array(obs.view.camera_coordinates(p_w_depth), dtype=np.float64)
    K = e.camera.K
    uv = (K @ p_c)[:2] / p_c[2]
    R_w_b = e.T_w_b[:3, :3]
    return PluginObservation(
        p_c=_frozen(p_c, (3,)),
        uv=_frozen(uv, (2,)),
        depth_m=float(p_c[2]),
        K=_frozen(K, (3, 3)),
        T_w_b=_frozen(e.T_w_b, (4, 4)),
        quat_w_b_xyzw=_frozen(quat.from_matrix(R_w_b), (4,)),
        rpy_w_b_deg=_frozen(np.degrees(so3.to_rpy(R_w_b, warn=False)), (3,)),
        T_b_c=_frozen(e.T_b_c, (4, 4)),
        t_s=float(t_s),
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


@dataclass
class Failures:
    """A user function's failures over one run, by kind.

    Attributes
    ----------
    calls : int
        How many times it was called.
    returned_none : int
        How many times it returned None (no estimate: not a failure).
    count : dict of Failure to int
    first_message : dict of Failure to str
        The first failure of each kind, in words.
    stamps_s : dict of Failure to list of float
        The exposure stamps of the images it failed on, per kind.
    """

    calls: int = 0
    returned_none: int = 0
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


class PluginEstimator:
    """A user's function as a ``"user"`` method's estimator (``vnav.localize``): called with
    the ``PluginObservation`` of each detection that has a ``depth_image`` estimate, never
    letting its failures out (``failures`` tallies them; ``reset`` starts a new run's).

    Parameters
    ----------
    fn : callable
        ``fn(obs: PluginObservation) -> p_w`` (array-like, shape (3,)) or None.
    """

    def __init__(self, fn: Callable[[PluginObservation], Any]) -> None:
        self.fn = fn
        self.failures = Failures()
        self._seen: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def reset(self) -> None:
        """Forget the previous run's failures and estimates."""
        self.failures = Failures()
        self._seen = []

    def diagnosis(self) -> Diagnosis | None:
        """The frame-bug doctor (``vnav.diagnose``) on every estimate the function gave this
        run, from the observations it was given; None before any. The observation's ``p_c``
        and poses reproduce the correct chain exactly, sensor noise or not, so the default
        tolerance holds."""
        if not self._seen:
            return None
        p_c, T_w_b, T_b_c, p_w = (np.array(column) for column in zip(*self._seen, strict=True))
        return diagnose(p_c, T_w_b, T_b_c, p_w)

    def estimate(self, obs: Observation, p_w_depth: np.ndarray, t_s: float) -> Any:
        """``fn``'s estimate, (3,) float64, or ``NoEstimate.FUNCTION_NONE`` / ``FUNCTION_ERROR``."""
        return self.estimate_given(observation_for(obs, p_w_depth, t_s))

    def estimate_given(self, given: PluginObservation) -> Any:
        """``estimate`` on the ``PluginObservation`` made already (``observation_for``): what
        judging a function again on a stored run's detections calls."""
        t_s = given.t_s
        self.failures.calls += 1
        try:
            returned = self.fn(given)
        except (Exception, SystemExit) as exc:  # the user's code: its failure, even an exit()
            self.failures.add(Failure.RAISED, f"{type(exc).__name__}: {exc}", t_s)
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
        self._seen.append((given.p_c, given.T_w_b, given.T_b_c, p_w.copy()))
        return p_w.copy()

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        """No covariance is claimed: zero, rank 0, so the estimate has no NEES."""
        return np.zeros((3, 3))


def plugin_method(spec: str) -> Method:
    """A user's function as a method, ``user:<function>``, with ``depth_image``'s accuracy
    bound; its estimator is a ``PluginEstimator`` (``Method.estimator``).

    Raises
    ------
    ValueError
        As ``load_estimator``.
    """
    fn = load_estimator(spec)
    return function_method(fn, spec, getattr(fn, "__name__", None) or spec.rpartition(":")[2])


def function_method(fn: Callable[[PluginObservation], Any], spec: str, name: str) -> Method:
    """A function already in hand as the method ``user:<name>`` (``plugin_method`` without the
    import): ``spec`` says where it came from (the report's ``estimators.<name>.spec``)."""
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
    m.__dict__["estimator"] = PluginEstimator(fn)
    return m
