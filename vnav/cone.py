"""The traffic cone: its shape, shared by the simulator and the perception code, and how much
of it a camera sees.

The simulator builds its cone mesh from these numbers and the detector and localiser assume
them, so they live here, in the library both depend on (scenarios -> sim -> vnav).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera


@dataclass(frozen=True)
class ConeModel:
    """A road cone: a square base plate with a cone on top, apex straight above the base centre.

    The cone's reference point is the centre of its base, on the ground (z = 0 in world).

    Attributes
    ----------
    height_m : float
        Ground to apex.
    base_width_m : float
        Side of the square base plate.
    base_thickness_m : float
        Thickness of the base plate.
    body_radius_m : float
        Radius of the conical body where it meets the base plate.
    color_rgb : tuple of float
        Diffuse colour in [0, 1], linear RGB as given to the renderer.
    """

    height_m: float = 0.70
    base_width_m: float = 0.38
    base_thickness_m: float = 0.03
    body_radius_m: float = 0.15
    color_rgb: tuple[float, float, float] = (1.0, 0.35, 0.0)

    def __post_init__(self) -> None:
        for name in ("height_m", "base_width_m", "base_thickness_m", "body_radius_m"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f"ConeModel.{name} must be positive, got {value!r}")
        if self.base_thickness_m >= self.height_m:
            raise ValueError(
                f"ConeModel.base_thickness_m ({self.base_thickness_m}) must be below "
                f"height_m ({self.height_m})"
            )
        if 2.0 * self.body_radius_m > self.base_width_m:
            raise ValueError(
                f"ConeModel body diameter {2.0 * self.body_radius_m} m does not fit on a base "
                f"plate {self.base_width_m} m wide"
            )
        if len(self.color_rgb) != 3 or not all(0.0 <= c <= 1.0 for c in self.color_rgb):
            raise ValueError(
                f"ConeModel.color_rgb must be 3 values in [0, 1], got {self.color_rgb}"
            )

    def extreme_points(self, p_base_w: np.ndarray) -> np.ndarray:
        """The apex and the base plate's eight corners of a cone standing at ``p_base_w``.

        Parameters
        ----------
        p_base_w : array_like, shape (3,)
            The base centre, in any frame whose z axis is up (usually the world).

        Returns
        -------
        points : ndarray, shape (9, 3)
            The apex first, then the corners, in the same frame.
        """
        h = self.base_width_m / 2.0
        corners = np.array(
            [
                [sx * h, sy * h, z]
                for sx in (-1, 1)
                for sy in (-1, 1)
                for z in (0.0, self.base_thickness_m)
            ]
        )
        p_base_w = np.asarray(p_base_w, dtype=np.float64)
        return np.vstack([p_base_w + np.array([0.0, 0.0, self.height_m]), p_base_w + corners])

    @property
    def base_axis_distance_m(self) -> float:
        """Mean distance from the base centre to the base plate's near edge along the bearing.

        The plate is a square of half-width ``a`` at an unknown yaw ``psi`` (folded into
        [0, pi/4]) relative to the horizontal bearing from the camera; the vertical plane
        through the camera and the cone's axis (whose image is the cone's image axis) leaves
        the plate's footprint ``a / cos(psi)`` from the centre. Its mean over ``psi`` uniform
        in [0, pi/4] is ``a (4 / pi) ln(1 + sqrt 2) = 1.122 a`` (between ``a`` and
        ``a sqrt 2``, so the error is at most 0.29 a = 5.5 cm and its standard deviation
        0.12 a = 2.3 cm for the standard cone).
        """
        return 0.5 * self.base_width_m * 4.0 / math.pi * math.log(1.0 + math.sqrt(2.0))

    @property
    def base_axis_distance_std_m(self) -> float:
        """Standard deviation of that distance over the unknown yaw, metres.

        ``E[(a / cos psi)^2] = a^2 (4 / pi) tan(pi / 4) = 4 a^2 / pi``, so the variance is
        ``4 a^2 / pi - base_axis_distance_m^2`` (0.117 a = 2.2 cm for the standard cone): the
        along-bearing uncertainty every estimate that steps from the plate's edge to its
        centre carries (``vnav.covariance``).
        """
        a = 0.5 * self.base_width_m
        return math.sqrt(max(4.0 * a * a / math.pi - self.base_axis_distance_m**2, 0.0))


TRAFFIC_CONE = ConeModel()
"""A 0.70 m road cone on a 0.38 m square base, the size of a common 28-inch cone."""


def cones_fully_in_view(
    cones_w: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    min_height_px: float,
    cone: ConeModel = TRAFFIC_CONE,
) -> list[int]:
    """Indices of the cones whose apex and base corners all project inside the image.

    Parameters
    ----------
    cones_w : ndarray, shape (N, 3)
        Base centres in the world, metres.
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
        The camera (optical frame) in the world.
    min_height_px : float
        A cone counts only if its image spans at least this many pixels vertically.
    cone : ConeModel

    Returns
    -------
    list of int
        In the order of ``cones_w``.
    """
    cones_w = np.asarray(cones_w, dtype=np.float64).reshape(-1, 3)
    if len(cones_w) == 0:
        return []
    T_c_w = se3.invert(T_w_c)
    points_w = np.concatenate([cone.extreme_points(p_w) for p_w in cones_w])  # one call for all
    uv = camera.project(se3.apply(T_c_w, points_w)).reshape(len(cones_w), -1, 2)
    return [
        i
        for i, uv_i in enumerate(uv)
        if np.isfinite(uv_i).all()
        and camera.in_image(uv_i).all()
        and np.ptp(uv_i[:, 1]) >= min_height_px
    ]
