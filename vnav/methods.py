"""The localisation methods and their accuracy contract, declared once.

Every estimate of a cone's base centre goes through the same chain,
``p_w = T_w_b @ T_b_c @ p_c`` (MIT 16.485 VNAV, lecture 1, chapter 0); the methods differ only
in where the depth along the viewing ray comes from. Everything that lists methods (the
estimates of ``vnav.localize``, the checks and the report of a scenario, the recording's
colours and plots, the README's table) derives from ``METHODS``, in this order.

A method carries its behaviour: its estimator (named here as ``module:attribute`` and imported
when first used, so that this module stays data), the degrees of freedom of its estimates, how
many images it needs, and its accuracy contract. ``vnav.localize`` loops over the methods and
nothing else branches on a method's name. An estimator is one of four kinds:

- ``"one"`` image: ``estimate(obs) -> p_w | NoEstimate`` and ``covariance(obs, p_w)``, on one
  ``vnav.observation.Observation`` (``SingleImageEstimator``);
- ``"several"`` images: ``start(camera, cone)`` gives a per-run track whose ``update`` takes
  each image's exposure and observations (``SeveralImageEstimator``);
- ``"from_best"``: built from the best single-image estimate (``FromBestEstimator``), as the
  lecture's naive mistake is;
- ``"user"``: a user's function ``fn(obs) -> p_w`` given the ``depth_image`` estimate in the
  camera frame (``vnav.plugin``), added for one run with ``extended``.

``METHODS`` is the built-ins, fixed; a run that judges a user's function beside them wraps
itself in ``with extended(methods):``, and whatever lists the methods of a run (the
``Localizer``, the checks, the report) asks ``active_methods()``. A module-level tuple that
other modules import by value cannot grow, and the built-ins' order, colours and
``PREFERENCE`` (which matches detections to cones) must not change when a user's function
runs beside them: the extension is explicit, scoped to the ``with`` block, and never part of
``PREFERENCE``.

The accuracy contract (``docs/ACCURACY.md``) is stated here as data: each checked method has
an ``AccuracyBound``, promised over the ``CONTRACT_DOMAIN`` (a cone fully in view, at
least 12 px tall, 2 to 25 m away).
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import importlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np

if TYPE_CHECKING:
    from vnav.camera import PinholeCamera
    from vnav.cone import ConeModel
    from vnav.estimators import NoEstimate
    from vnav.observation import Exposure, Observation

__all__ = [
    "CONTRACT_DOMAIN",
    "METHODS",
    "METHOD_NAMES",
    "NAIVE",
    "NEWEST_POSE_METHOD",
    "PREFERENCE",
    "AccuracyBound",
    "ContractDomain",
    "FromBestEstimator",
    "Method",
    "SeveralImageEstimator",
    "SeveralImageTrack",
    "SingleImageEstimator",
    "active_methods",
    "extended",
    "method",
]


@dataclass(frozen=True)
class AccuracyBound:
    """Allowed position error as a function of range: ``max(floor_m, fraction * range_m)``.

    Attributes
    ----------
    floor_m : float
        The bound never drops below this, metres.
    fraction_of_range : float
        The bound's growth with range (0.01 is 1% of range).
    statistic : {"max", "median"}
        ``max``: every error is within its bound; ``median``: the median ratio of error to
        bound is at most 1.
    """

    floor_m: float
    fraction_of_range: float
    statistic: Literal["max", "median"]

    def allowed_m(self, range_m: np.ndarray) -> np.ndarray:
        """The bound at each range, metres, same shape as ``range_m``."""
        return np.maximum(self.floor_m, self.fraction_of_range * np.asarray(range_m))

    @property
    def allowed_text(self) -> str:
        """The allowed error in words, e.g. ``max(5 cm, 1% of range)``."""
        percent = f"{100.0 * self.fraction_of_range:g}% of range"
        return f"max({100.0 * self.floor_m:g} cm, {percent})" if self.floor_m > 0.0 else percent

    @property
    def text(self) -> str:
        """The bound in words, e.g. ``every error <= max(5 cm, 1% of range)``."""
        statistic = "every error" if self.statistic == "max" else "median"
        return f"{statistic} <= {self.allowed_text}"


@dataclass(frozen=True)
class ContractDomain:
    """Where the accuracy bounds are promised.

    Attributes
    ----------
    min_range_m, max_range_m : float
        Distance from the camera to the cone's base centre, metres.
    min_height_px : float
        The cone's image spans at least this many pixels vertically, fully inside the image.
    """

    min_range_m: float
    max_range_m: float
    min_height_px: float

    def contains_range(self, range_m: float) -> bool:
        """Whether ``range_m`` lies in ``[min_range_m, max_range_m]``."""
        return self.min_range_m <= range_m <= self.max_range_m

    @property
    def text(self) -> str:
        """The domain in words, as the README's table heading states it."""
        return (
            f"cone fully in view, >= {self.min_height_px:g} px, "
            f"{self.min_range_m:g}-{self.max_range_m:g} m"
        )


CONTRACT_DOMAIN = ContractDomain(min_range_m=2.0, max_range_m=25.0, min_height_px=12.0)
"""The domain of the accuracy contract."""


class SingleImageEstimator(Protocol):
    """A method that estimates from one image (``Method.images == "one"``)."""

    def estimate(self, obs: Observation) -> np.ndarray | NoEstimate:
        """The cone's base centre in the world, (3,), metres, or why there is none."""
        ...

    def covariance(self, obs: Observation, p_w: np.ndarray) -> np.ndarray:
        """The world covariance of ``estimate(obs)``, (3, 3), m^2, first order."""
        ...


class SeveralImageTrack(Protocol):
    """A several-image method's state over one run (``SeveralImageEstimator.start``)."""

    def update(
        self, t_s: float, exposure: Exposure, observations: Sequence[Observation | None]
    ) -> dict[int, tuple[np.ndarray, np.ndarray] | NoEstimate]:
        """Take one image, exposed at ``t_s`` (seconds, the estimator's clock), and its
        detections' observations (None for a detection with no usable view, one touching the
        border); return, by detection index, ``(p_w, cov_w)`` or why there is none.
        Detections left out keep the reason ``vnav.localize.localize`` gave."""
        ...


class SeveralImageEstimator(Protocol):
    """A method that estimates from several images (``Method.images == "several"``)."""

    def start(self, camera: PinholeCamera, cone: ConeModel) -> SeveralImageTrack:
        """A new run's state."""
        ...


class FromBestEstimator(Protocol):
    """A method built from the best single-image estimate (``Method.images == "from_best"``)."""

    def estimate(self, obs: Observation, p_w_best: np.ndarray) -> np.ndarray:
        """The estimate, (3,), metres, from the best one ``p_w_best``."""
        ...

    def covariance(self, obs: Observation, cov_w_best: np.ndarray) -> np.ndarray:
        """Its world covariance, (3, 3), m^2, from the best estimate's ``cov_w_best``."""
        ...


@dataclass(frozen=True)
class Method:
    """One way of finding the depth along the viewing ray.

    Attributes
    ----------
    name : str
        Identifier used in code, files and recordings (``depth_image``).
    depth_from : str
        Where the depth comes from, one line.
    color_rgb : tuple of int
        The method's colour (0-255) in every recording and plot, so that they agree.
    color_name : str
        That colour in words, for text that refers to it.
    bound : AccuracyBound or None
        The accuracy promised; None for a method that is reported but never checked.
    implementation : str
        Where its estimator is, ``"module:attribute"`` (``estimator`` imports it).
    images : {"one", "several", "from_best", "user"}
        What it estimates from (see the module's docstring).
    dof : int
        Degrees of freedom of its estimates: the rank of their covariance, the chi-square
        degrees of freedom of their NEES (2 for a point confined to a plane by construction).
    """

    name: str
    depth_from: str
    color_rgb: tuple[int, int, int]
    color_name: str
    bound: AccuracyBound | None
    implementation: str
    images: Literal["one", "several", "from_best", "user"] = "one"
    dof: int = 3

    @property
    def promise(self) -> str:
        """The accuracy promised, in words (``reported, never checked`` without a bound)."""
        return self.bound.text if self.bound is not None else "reported, never checked"

    @property
    def needs_several_images(self) -> bool:
        """Whether its estimates come from several images (no estimate from one alone)."""
        return self.images == "several"

    @functools.cached_property
    def estimator(self) -> Any:
        """The estimator ``implementation`` names, imported on first use: a
        ``SingleImageEstimator``, ``SeveralImageEstimator`` or ``FromBestEstimator`` as
        ``images`` says (a ``"user"`` method's is given when it is made, ``vnav.plugin``)."""
        module, _, attribute = self.implementation.partition(":")
        return getattr(importlib.import_module(module), attribute)


METHODS: tuple[Method, ...] = (
    Method(
        "depth_image",
        "the rendered depth image, fitted to the cone's shape",
        (40, 200, 255),
        "blue",
        AccuracyBound(0.05, 0.01, "max"),
        "vnav.single_image:DEPTH_IMAGE",
    ),
    Method(
        "ground_plane",
        "the ray through the cone's base meets z = 0",
        (80, 230, 80),
        "green",
        AccuracyBound(0.10, 0.02, "median"),
        "vnav.single_image:GROUND_PLANE",
        dof=2,  # on z = 0 by construction
    ),
    Method(
        "known_height",
        "the cone's 0.70 m height in pixels (similar triangles)",
        (230, 80, 230),
        "magenta",
        AccuracyBound(0.0, 0.05, "median"),
        "vnav.single_image:KNOWN_HEIGHT",
    ),
    Method(
        "triangulated",
        "the apex's rays over the last images, triangulated (motion alone, no depth)",
        (255, 165, 0),
        "orange",
        AccuracyBound(0.05, 0.01, "median"),
        "vnav.tracking:TRIANGULATED",
        images="several",
    ),
    Method(
        "naive",
        "the lecture's mistake: camera coordinates added to the drone's position",
        (255, 40, 40),
        "red",
        None,
        "vnav.single_image:NAIVE",
        images="from_best",
    ),
)
"""Every method, in report order."""

METHOD_NAMES: tuple[str, ...] = tuple(m.name for m in METHODS)
"""The methods' names, in report order."""

PREFERENCE: tuple[str, ...] = tuple(m.name for m in METHODS if m.bound is not None)
"""The checked methods, best first: the "best estimate" of a cone is the first of these that
gives one (the naive estimate is built from it, detections are matched to cones by it)."""

NAIVE = "naive"
"""The lecture's mistake, reported beside the others and never checked: the ``naive_worse``
check and the recording's naive rays compare with it."""

NEWEST_POSE_METHOD = PREFERENCE[0]
"""The method whose estimate is made a second time with the newest pose received when an
image arrived (what a pipeline ignoring stamps does): the first-preferred one."""

_BY_NAME = {m.name: m for m in METHODS}


def method(name: str) -> Method:
    """The ``Method`` called ``name``.

    Raises
    ------
    ValueError
        If no method has that name (the message lists the valid ones).
    """
    found = _BY_NAME.get(name) or next((m for m in active_methods() if m.name == name), None)
    if found is None:
        valid = [m.name for m in active_methods()]
        raise ValueError(f"unknown method {name!r}; valid: {valid}")
    return found


_ACTIVE: contextvars.ContextVar[tuple[Method, ...]] = contextvars.ContextVar(
    "vnav_active_methods", default=METHODS
)
"""The active methods, per thread (a context variable): a run extending them in one thread
leaves another thread's ``active_methods()`` as it was."""


def active_methods() -> tuple[Method, ...]:
    """The methods of the run under way in this thread: ``METHODS``, then those ``extended``
    added (the same tuple object for the whole ``with`` block)."""
    return _ACTIVE.get()


@contextlib.contextmanager
def extended(extra: Sequence[Method]) -> Iterator[tuple[Method, ...]]:
    """``METHODS`` and ``extra`` as the active methods within a ``with`` block (one run's
    user functions, ``vnav.plugin``); the previous ones again after it. The change holds for
    this thread only (``_ACTIVE``): runs in two threads each see their own methods.

    Raises
    ------
    ValueError
        If a name in ``extra`` is already a method's or appears twice.
    """
    active = _ACTIVE.get()
    if not extra:  # nothing to add: the active tuple itself, as without the block
        yield active
        return
    names = [m.name for m in active] + [m.name for m in extra]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"two methods are named {twice[0]!r}")
    token = _ACTIVE.set((*active, *extra))
    try:
        yield _ACTIVE.get()
    finally:
        _ACTIVE.reset(token)
