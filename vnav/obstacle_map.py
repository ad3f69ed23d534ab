"""The map of obstacles a navigating drone plans around: the cones it has seen, in the plane.

At every camera tick the estimates of one localisation method (``vnav.methods``) update the map:
each estimate of a cone's base centre in the world (ENU, metres) is matched to the nearest
obstacle already mapped within ``gate_m`` in the horizontal plane and fused into it, or starts a
new obstacle. A cone never estimated is not in the map. The planner (``vnav.navigate``) keeps
its clearance from each obstacle's vertical axis; the map is 2-D (docs/CONVENTIONS.md,
"Navigation").

Which estimates are obstacles
-----------------------------
A cone stands on the ground (its base centre at z = 0, ``vnav.cone``). An obstacle is a vertical
cylinder through the flight band; an estimate whose base lies outside
``[-ground_tolerance_m, flight_altitude_m + vertical_margin_m]`` describes no object the drone
can meet at its altitude, and is rejected (counted, not mapped):

- below the ground by more than the tolerance: nothing stands underground, the estimate is
  wrong;
- above the drone's altitude plus the margin: whatever is there the drone passes under.

This is what makes the lecture's naive chain (MIT 16.485 VNAV, lecture 1: ``t_w_b + p_c``,
camera coordinates taken for world offsets, ``vnav.estimators.naive``) fail honestly: the
optical z axis points forward, so the naive base sits at the drone's altitude *plus the range*
to the cone, in the sky for any range beyond the margin. The naive map stays empty of the real
cone, the planner flies the straight line, and the drone meets the cone. A base between the
ground and the flight band is kept whatever its height, as an obstacle reaching through the
band: a map that plans at one altitude avoids it rather than guess whether the drone clears
its top.

Fusion: running mean
--------------------
The cones do not move, and a method's per-tick errors are mostly fresh noise (pixels, depth,
the pose's noise; docs/ACCURACY.md), so the mean of the estimates of one cone is closer to it
than any one of them, its noise falling as ``1 / sqrt(n)``, and one bad tick moves an obstacle
seen ``n`` times by ``1/n`` of its error instead of all of it (keeping the newest would make
the path jump with every tick's noise). What the mean does not remove is a method's bias, which
no fusion can. Each camera tick sees a cone once, so within one update each obstacle takes at
most one estimate: the closest pairs are matched first, and an estimate left with no free
obstacle within the gate starts a new one (two estimates in one tick are two cones).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate
from vnav.cone import TRAFFIC_CONE, ConeModel

__all__ = ["MapUpdate", "Obstacle", "ObstacleMap", "footprint_radius_m"]

_log = logging.getLogger(__name__)


def footprint_radius_m(cone: ConeModel = TRAFFIC_CONE) -> float:
    """Radius of the smallest vertical cylinder about the cone's axis holding the whole cone.

    The base plate is the widest part: a square of side ``base_width_m``, whose corners are
    ``base_width_m / sqrt(2)`` from the axis (0.269 m for ``TRAFFIC_CONE``). A drone whose centre
    keeps ``clearance_m`` from the axis misses the cone when ``clearance_m`` exceeds this plus
    the drone's own radius (and the estimate's error).
    """
    return cone.base_width_m / math.sqrt(2.0)


@dataclass(frozen=True)
class Obstacle:
    """One mapped cone.

    Attributes
    ----------
    p_xy_w : ndarray, shape (2,)
        Mean of the estimates' base centres in the world's horizontal plane (x east, y north),
        metres: the obstacle's axis.
    base_z_m : float
        Mean of the estimates' base heights, metres (about 0 for a good method).
    method : str
        Name of the method whose estimate put the obstacle in the map.
    n_seen : int
        How many estimates were fused into it (camera ticks it was seen at).
    """

    p_xy_w: np.ndarray
    base_z_m: float
    method: str
    n_seen: int


@dataclass(frozen=True)
class MapUpdate:
    """What one ``ObstacleMap.update`` did with its estimates, by count.

    Attributes
    ----------
    fused : int
        Estimates matched to an obstacle already mapped.
    added : int
        Estimates that started a new obstacle.
    rejected : int
        Estimates whose base was outside the flight band (not obstacles; see the module).
    """

    fused: int
    added: int
    rejected: int


class ObstacleMap:
    """Cones seen so far, as vertical cylinders in the horizontal plane, fused over ticks.

    Parameters
    ----------
    flight_altitude_m : float
        Height of the drone's centre above the ground while navigating, metres (> 0).
    vertical_margin_m : float
        How far above the flight altitude an estimated base may be and still count, metres.
    ground_tolerance_m : float
        How far below the ground an estimated base may be and still count, metres.
    gate_m : float
        An estimate within this horizontal distance of an obstacle is that obstacle, metres
        (> 0). Below the distance between two cones, above a method's error.

    Raises
    ------
    ValueError
        A parameter that is not a finite number in its range, naming it.

    Notes
    -----
    Belongs to one thread (docs/CONVENTIONS.md, "Performance and threads").
    """

    def __init__(
        self,
        *,
        flight_altitude_m: float,
        vertical_margin_m: float = 0.5,
        ground_tolerance_m: float = 0.5,
        gate_m: float = 1.0,
    ) -> None:
        for name, value, positive in (
            ("flight_altitude_m", flight_altitude_m, True),
            ("vertical_margin_m", vertical_margin_m, False),
            ("ground_tolerance_m", ground_tolerance_m, False),
            ("gate_m", gate_m, True),
        ):
            if not isinstance(value, int | float) or isinstance(value, bool):
                raise ValueError(f"{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0.0 or (positive and value == 0.0):
                bound = "> 0" if positive else ">= 0"
                raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
        self.flight_altitude_m = float(flight_altitude_m)
        self.vertical_margin_m = float(vertical_margin_m)
        self.ground_tolerance_m = float(ground_tolerance_m)
        self.gate_m = float(gate_m)
        self._sum_xy = np.zeros((0, 2))
        self._sum_z = np.zeros(0)
        self._n = np.zeros(0, dtype=np.int64)
        self._methods: list[str] = []

    def __len__(self) -> int:
        return len(self._methods)

    @property
    def z_band_m(self) -> tuple[float, float]:
        """The base heights ``(low, high)`` an estimate must lie within to be an obstacle."""
        return (-self.ground_tolerance_m, self.flight_altitude_m + self.vertical_margin_m)

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        """The mapped obstacles, in the order they were first seen."""
        return tuple(
            Obstacle(
                p_xy_w=self._sum_xy[i] / self._n[i],
                base_z_m=float(self._sum_z[i] / self._n[i]),
                method=self._methods[i],
                n_seen=int(self._n[i]),
            )
            for i in range(len(self))
        )

    def centres_xy_w(self) -> np.ndarray:
        """The obstacles' axes, shape (M, 2), world x and y in metres (what the planner takes)."""
        return self._sum_xy / self._n[:, None] if len(self) else np.zeros((0, 2))

    def update(self, p_w: ArrayLike, method: str) -> MapUpdate:
        """Fuse one camera tick's estimates of cones' base centres into the map.

        Parameters
        ----------
        p_w : array_like, shape (N, 3)
            The estimates, world ENU metres, one cone each (N may be 0).
        method : str
            The method that made them (kept by the obstacles they start).

        Returns
        -------
        MapUpdate
            How many estimates were fused, added and rejected.

        Raises
        ------
        ValueError
            ``p_w`` not of shape (N, 3) or not finite, or ``method`` not a non-empty string.
        """
        if not isinstance(method, str) or not method:
            raise ValueError(f"method must be a non-empty string, got {method!r}")
        p_w = _validate.as_float(p_w, "p_w")
        if p_w.ndim != 2 or p_w.shape[1] != 3:
            raise ValueError(f"p_w must have shape (N, 3); got shape {p_w.shape}")
        _validate.check_finite(p_w, "p_w")
        low_m, high_m = self.z_band_m
        keep = (p_w[:, 2] >= low_m) & (p_w[:, 2] <= high_m)
        rejected = int(np.count_nonzero(~keep))
        if rejected:
            _log.debug(
                "%d %s estimate(s) outside the flight band [%.2f, %.2f] m",
                rejected,
                method,
                low_m,
                high_m,
            )
        p_w = p_w[keep]
        matched = self._associate(p_w[:, :2])
        new = [k for k, i in enumerate(matched) if i < 0]
        for k, i in enumerate(matched):
            if i >= 0:
                self._sum_xy[i] += p_w[k, :2]
                self._sum_z[i] += p_w[k, 2]
                self._n[i] += 1
        if new:
            self._sum_xy = np.vstack([self._sum_xy, p_w[new, :2]])
            self._sum_z = np.concatenate([self._sum_z, p_w[new, 2]])
            self._n = np.concatenate([self._n, np.ones(len(new), dtype=np.int64)])
            self._methods += [method] * len(new)
        return MapUpdate(fused=len(p_w) - len(new), added=len(new), rejected=rejected)

    def _associate(self, p_xy_w: np.ndarray) -> list[int]:
        """For each estimate, the obstacle it is (index) or -1: closest pairs within the gate
        first, each obstacle taking at most one estimate."""
        matched = [-1] * len(p_xy_w)
        if not len(self) or not len(p_xy_w):
            return matched
        dist_m = np.linalg.norm(p_xy_w[:, None, :] - self.centres_xy_w()[None, :, :], axis=2)
        taken: set[int] = set()
        for flat in np.argsort(dist_m, axis=None, kind="stable"):
            k, i = divmod(int(flat), dist_m.shape[1])
            if dist_m[k, i] > self.gate_m:
                break
            if matched[k] < 0 and i not in taken:
                matched[k] = i
                taken.add(i)
        return matched
