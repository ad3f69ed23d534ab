"""The localisation methods and their accuracy contract, declared once.

Every estimate of a cone's base centre goes through the same chain,
``p_w = T_w_b @ T_b_c @ p_c`` (VNAV lecture 1, chapter 0); the methods differ only in where
the depth along the viewing ray comes from. Everything that lists methods (the estimates of
``vnav.localize``, the checks and the report of a scenario, the recording's colours and
plots, the README's table) derives from ``METHODS``, in this order.

The accuracy contract (``docs/ACCURACY.md``) is stated here as data: each checked method has
an ``AccuracyBound``, promised over the ``CONTRACT_DOMAIN`` (a cone fully in view, at
least 12 px tall, 2 to 25 m away).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "CONTRACT_DOMAIN",
    "METHODS",
    "METHOD_NAMES",
    "PREFERENCE",
    "AccuracyBound",
    "ContractDomain",
    "Method",
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
    def text(self) -> str:
        """The bound in words, e.g. ``every error <= max(5 cm, 1% of range)``."""
        percent = f"{100.0 * self.fraction_of_range:g}% of range"
        allowed = f"max({100.0 * self.floor_m:g} cm, {percent})" if self.floor_m > 0.0 else percent
        return f"{'every error' if self.statistic == 'max' else 'median'} <= {allowed}"


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
    """

    name: str
    depth_from: str
    color_rgb: tuple[int, int, int]
    color_name: str
    bound: AccuracyBound | None

    @property
    def promise(self) -> str:
        """The accuracy promised, in words (``reported, never checked`` without a bound)."""
        return self.bound.text if self.bound is not None else "reported, never checked"


METHODS: tuple[Method, ...] = (
    Method(
        "depth_image",
        "the rendered depth image, fitted to the cone's shape",
        (40, 200, 255),
        "blue",
        AccuracyBound(0.05, 0.01, "max"),
    ),
    Method(
        "ground_plane",
        "the ray through the cone's base meets z = 0",
        (80, 230, 80),
        "green",
        AccuracyBound(0.10, 0.02, "median"),
    ),
    Method(
        "known_height",
        "the cone's 0.70 m height in pixels (similar triangles)",
        (230, 80, 230),
        "magenta",
        AccuracyBound(0.0, 0.05, "median"),
    ),
    Method(
        "triangulated",
        "the apex's rays over the last images, triangulated (motion alone, no depth)",
        (255, 165, 0),
        "orange",
        AccuracyBound(0.05, 0.01, "median"),
    ),
    Method(
        "naive",
        "the lecture's mistake: camera coordinates added to the drone's position",
        (255, 40, 40),
        "red",
        None,
    ),
)
"""Every method, in report order."""

METHOD_NAMES: tuple[str, ...] = tuple(m.name for m in METHODS)
"""The methods' names, in report order."""

PREFERENCE: tuple[str, ...] = tuple(m.name for m in METHODS if m.bound is not None)
"""The checked methods, best first: the "best estimate" of a cone is the first of these that
gives one (the naive estimate is built from it, detections are matched to cones by it)."""

_BY_NAME = {m.name: m for m in METHODS}


def method(name: str) -> Method:
    """The ``Method`` called ``name``.

    Raises
    ------
    ValueError
        If no method has that name (the message lists the valid ones).
    """
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; valid: {list(METHOD_NAMES)}") from None
