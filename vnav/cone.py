"""The traffic cone's physical description, shared by the simulator and the perception code.

The simulator builds its cone mesh from these numbers and the detector and localiser assume
them, so they live here, in the library both depend on (scenarios -> sim -> vnav).
"""

from __future__ import annotations

from dataclasses import dataclass


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


TRAFFIC_CONE = ConeModel()
"""A 0.70 m road cone on a 0.38 m square base, the size of a common 28-inch cone."""
