"""From a cone detection to the cone's base-centre position in the world.

Every estimate goes through the lecture's chain (VNAV lecture 1, chapter 0)

    p_w = T_w_b @ T_b_c @ p_c = T_w_c @ p_c

and differs only in how the depth along the viewing ray is found. A detection that touches the
image border (the cone may be cut off) gets no estimate from any method.

1. `depth_image`: the rendered planar depth over the cone's mask, back-projected to world
   points on the cone's visible surface; the axis is found by fitting the cone's known
   radius profile `r(z)` to those points (a least-squares circle fit with known, height-
   dependent radius, started from the per-point correction "surface point + r(z) along the
   horizontal viewing direction" and its median). The base-centre height is the lowest
   surface point (2nd percentile). Needs no ground plane.
2. `ground_plane`: the ray through the bottom pixel (where the image of the cone's axis, the
   line through the apex along the image of the vertical, leaves the blob: the near bottom
   edge of the base plate) meets the ground z = 0 at `g_w`; the base centre lies behind it,
   away from the camera, by the plate's mean distance from centre to edge along the bearing,
   `1.122 a` for a square of half-width `a` and unknown yaw (between `a` and `a sqrt(2)`).
   A ray parallel to or pointing away from the ground gives no estimate.
3. `known_height`: similar triangles generalised to a tilted camera: the two rays through the
   apex pixel and the bottom pixel must hold the points `p_base + (0, 0, H)` and
   `p_base - s b` (`b` the horizontal bearing, `s` that edge distance); the two ray lengths
   are the least-squares solution of those three linear equations. Needs no ground plane.
   The apex is located from the area of the silhouette's top triangle (`apex_pixel`), not
   from its top-most pixel, which lies several pixels below the apex of a thin, distant tip.
   Refused when ill-conditioned (apex over the base plate's image in a steep view, or one
   pixel moving the estimate by more than 10% of range).
4. `naive`: the lecture's mistake, camera-frame coordinates added to the drone's position as
   if they were world coordinates, `p_naive = t_w_b + p_c`, with `p_c` the best available
   estimate (depth image, else ground plane, else known height) in the camera frame.

The image of the vertical direction at a pixel points at the vertical vanishing point
`n = K R_c_w (0, 0, -1)^T` (Hartley & Zisserman, 2nd ed., sec. 8.6): for a pixel `(u, v)` the
downward direction is `(n_x - u n_z, n_y - v n_z)` (the derivative of the projection of
`X + t e_down` at t = 0, up to a positive factor). The camera's nadir ground point projects to
that same vanishing point, so "down the image axis" is also "towards the camera on the ground".
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection

__all__ = [
    "MAX_RANGE_ERROR_PER_PX",
    "MIN_TRIANGLE_FRACTION",
    "ConeEstimates",
    "apex_pixel",
    "base_axis_distance",
    "bottom_pixel",
    "depth_to_world_points",
    "estimate_from_depth",
    "estimate_from_ground_plane",
    "estimate_from_known_height",
    "localize",
    "naive_estimate",
    "triangle_fraction",
    "vertical_direction_uv",
]

logger = logging.getLogger(__name__)

_MIN_DEPTH_POINTS = 5
"""Fewest valid depth pixels on a cone's body for a depth-image estimate."""


@dataclass(frozen=True)
class ConeEstimates:
    """The base-centre position of one cone in the world frame by each method, metres.

    Each field is a (3,) float64 array, or None when the method gives no estimate (no depth
    image or no valid depth on the cone; a ray that misses the ground; an ill-conditioned
    height triangle).

    Attributes
    ----------
    depth_image, ground_plane, known_height, naive : ndarray, shape (3,), or None
    """

    depth_image: np.ndarray | None
    ground_plane: np.ndarray | None
    known_height: np.ndarray | None
    naive: np.ndarray | None

    METHODS = ("depth_image", "ground_plane", "known_height", "naive")

    def as_dict(self) -> dict[str, np.ndarray | None]:
        """`{method name: p_w or None}` in the order of `METHODS`."""
        return {name: getattr(self, name) for name in self.METHODS}

    @property
    def best(self) -> np.ndarray | None:
        """The first available of depth image, ground plane, known height."""
        for name in ("depth_image", "ground_plane", "known_height"):
            value = getattr(self, name)
            if value is not None:
                return value
        return None


# ----------------------------------------------------------------------------- validation


def _check_transform(T: np.ndarray, name: str) -> np.ndarray:
    """One 4x4 rigid transform, validated by `vnav.se3.check_transform` (its default tolerance,
    1e-9 on `R^T R - I`: MuJoCo's float64 poses are orthonormal to about 1e-15).

    A thin wrapper because `se3.check_transform` also accepts stacks `(..., 4, 4)`, and every
    function here takes exactly one pose.
    """
    T = se3.check_transform(T, name)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a single 4x4 transform, got shape {T.shape}")
    return T


def _check_depth(depth: np.ndarray, camera: PinholeCamera, name: str = "depth") -> np.ndarray:
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(depth).__name__}")
    if depth.dtype not in (np.float32, np.float64):
        raise ValueError(f"{name} must have dtype float32 or float64 (metres), got {depth.dtype}")
    if depth.shape != (camera.height, camera.width):
        raise ValueError(
            f"{name} must have the camera's image size (H, W) = ({camera.height}, "
            f"{camera.width}), got shape {depth.shape}"
        )
    return depth


def _check_detection(detection: ConeDetection, camera: PinholeCamera) -> None:
    if not isinstance(detection, ConeDetection):
        raise ValueError(f"detection must be a ConeDetection, got {type(detection).__name__}")
    x, y, w, h = detection.bbox
    if x < 0 or y < 0 or x + w > camera.width or y + h > camera.height:
        raise ValueError(
            f"detection bbox {detection.bbox} does not fit the camera's image "
            f"{camera.width}x{camera.height}"
        )


def _depth_under_mask(detection: ConeDetection, depth: np.ndarray) -> np.ndarray:
    """The (validated) depth image's values over the detection's mask, float64, checked finite.

    In `pixels_uv` order (row-major over the mask)."""
    x0, y0, w, h = detection.bbox
    z_c = depth[y0 : y0 + h, x0 : x0 + w][detection.mask].astype(np.float64)
    if not np.isfinite(z_c).all():
        raise ValueError(
            f"depth must be finite under the detection's mask; got {int((~np.isfinite(z_c)).sum())}"
            f" non-finite of {z_c.size} pixels"
        )
    return z_c


# ------------------------------------------------------------------------------ geometry


def base_axis_distance(cone: ConeModel = TRAFFIC_CONE) -> float:
    """Mean distance from the base centre to the base plate's near edge along the bearing, m.

    The plate is a square of half-width `a` at an unknown yaw `psi` (folded into [0, pi/4])
    relative to the horizontal bearing from the camera; the vertical plane through the camera
    and the cone's axis (whose image is the cone's image axis) leaves the plate's footprint
    `a / cos(psi)` from the centre. Its mean over `psi` uniform in [0, pi/4] is
    `a (4 / pi) ln(1 + sqrt 2) = 1.122 a` (between `a` and `a sqrt 2`, so the error is at most
    0.29 a = 5.5 cm and its standard deviation 0.12 a = 2.3 cm for the standard cone).
    """
    return 0.5 * cone.base_width_m * 4.0 / math.pi * math.log(1.0 + math.sqrt(2.0))


class _View:
    """One detection seen by one validated camera pose: the pieces every method shares.

    The pose and the intrinsics are held as Python floats (3-vectors and 3x3 products in plain
    arithmetic cost a fraction of numpy's per-call overhead); the pixel list, the image
    vertical, the apex fits and the blob's lower boundary are computed once, on first use.
    """

    __slots__ = (
        "R",
        "_apex",
        "_boundary",
        "_exit",
        "_frame",
        "_uv",
        "cx",
        "cy",
        "detection",
        "fx",
        "fy",
        "t",
    )

    def __init__(self, detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray):
        self.detection = detection
        self.fx, self.fy, self.cx, self.cy = camera.fx, camera.fy, camera.cx, camera.cy
        rows = T_w_c.tolist()
        self.R = (rows[0][:3], rows[1][:3], rows[2][:3])
        self.t = (rows[0][3], rows[1][3], rows[2][3])
        self._uv: np.ndarray | None = None
        self._frame: tuple[np.ndarray, float] | bool | None = False
        self._apex: dict[float, np.ndarray | None] = {}
        self._boundary: np.ndarray | None = None
        self._exit: dict[tuple[float, float], np.ndarray] = {}

    def uv(self) -> np.ndarray:
        """`detection.pixels_uv()`, computed once."""
        if self._uv is None:
            self._uv = self.detection.pixels_uv()
        return self._uv

    def ray(self, u: float, v: float) -> tuple[float, float, float]:
        """Unit ray through pixel `(u, v)` in world coordinates (`R_w_c K^-1 [u, v, 1]`)."""
        x = (u - self.cx) / self.fx
        y = (v - self.cy) / self.fy
        norm = math.sqrt(x * x + y * y + 1.0)
        x, y, z = x / norm, y / norm, 1.0 / norm
        r0, r1, r2 = self.R
        return (
            r0[0] * x + r0[1] * y + r0[2] * z,
            r1[0] * x + r1[1] * y + r1[2] * z,
            r2[0] * x + r2[1] * y + r2[2] * z,
        )

    def vertical(self, u: float, v: float) -> tuple[float, float] | None:
        """`vertical_direction_uv` at pixel `(u, v)` as two floats, or None."""
        m0, m1, m2 = -self.R[2][0], -self.R[2][1], -self.R[2][2]
        n0 = self.fx * m0 + self.cx * m2
        n1 = self.fy * m1 + self.cy * m2
        d0, d1 = n0 - u * m2, n1 - v * m2
        norm = math.hypot(d0, d1)
        scale = math.sqrt(n0 * n0 + n1 * n1 + m2 * m2)
        if norm < 1e-9 * max(scale, 1.0):
            return None
        return d0 / norm, d1 / norm

    def frame(self) -> tuple[np.ndarray, float] | None:
        """`_image_frame`: `(d, elevation)` at the blob's centroid, or None; computed once."""
        if self._frame is False:
            u, v = (float(x) for x in self.detection.centroid_uv[:2])
            d = self.vertical(u, v)
            if d is None:
                self._frame = None
            else:
                ray_z = self.ray(u, v)[2]
                self._frame = (np.array(d), math.asin(min(max(-ray_z, -1.0), 1.0)))
        return self._frame  # type: ignore[return-value]

    def apex(self, d: np.ndarray, fraction: float) -> np.ndarray | None:
        """`apex_pixel(detection, d, fraction)` for the frame's `d`, memoised on `fraction`."""
        if fraction not in self._apex:
            self._apex[fraction] = _apex_pixel(self.uv(), d, fraction)
        return self._apex[fraction]

    def axis_exit(self, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
        """`_axis_exit` for the frame's `d`, the blob's lower boundary computed once, the exit
        memoised on the apex."""
        key = (float(apex_uv[0]), float(apex_uv[1]))
        if key not in self._exit:
            if self._boundary is None:
                self._boundary = _boundary_from_mask(self.detection, float(d[0]), float(d[1]))
            self._exit[key] = _exit_on_boundary(self._boundary, d, apex_uv)
        return self._exit[key]

    def bottom(self) -> np.ndarray:
        """`bottom_pixel(detection, camera, T_w_c)`."""
        frame = self.frame()
        if frame is None:
            return np.asarray(self.detection.base_uv, dtype=np.float64)
        d, elevation = frame
        apex_uv = self.apex(d, max(triangle_fraction(elevation), 0.5))
        if apex_uv is None:
            apex_uv = np.asarray(self.detection.apex_uv, dtype=np.float64)
        return self.axis_exit(d, apex_uv)


def _ray_w(camera: PinholeCamera, T_w_c: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Unit ray through pixel `uv` in world coordinates, (3,)."""
    return T_w_c[:3, :3] @ camera.rays(uv)[0]


def vertical_direction_uv(
    camera: PinholeCamera, T_w_c: np.ndarray, uv: np.ndarray
) -> np.ndarray | None:
    """Unit image direction of the world's downward vertical at pixel `uv`, or None.

    `n = K R_c_w (0, 0, -1)^T` is the vertical vanishing point (homogeneous); the direction at
    `(u, v)` is `(n_x - u n_z, n_y - v n_z)`, normalised. None when the pixel is the nadir's
    image itself (the camera looks straight down through it).

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
        Camera (optical frame) pose in the world.
    uv : ndarray, shape (2,)
    """
    n = camera.K @ (T_w_c[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
    d = np.array([n[0] - uv[0] * n[2], n[1] - uv[1] * n[2]])
    norm = float(np.hypot(d[0], d[1]))
    scale = float(np.linalg.norm(n))
    if norm < 1e-9 * max(scale, 1.0):
        return None
    return d / norm


def triangle_fraction(elevation_rad: float, cone: ConeModel = TRAFFIC_CONE) -> float:
    """Fraction of the silhouette's length, from the apex down, that is the body's triangle.

    Seen at elevation `e` (line of sight below the horizontal; orthographic approximation),
    the apex lies `(H - t) cos e` above the image of the body's base circle's centre and the
    plate's far top corners at most `a sin e` above it (`a` the plate's half-width), the
    plate's near bottom edge `a sin e + t cos e` below it. Down to the plate's far corners the
    silhouette is the triangle between the apex and the two tangents to the body's base, so
    `f(e) = ((H - t) cos e - a sin e) / ((H - t) cos e + 2 a sin e + t cos e)` when positive,
    else 0: at about 74 deg (standard cone) and steeper the apex projects onto the base plate
    and the cone's height cannot be read off the image.
    """
    H, t, a = cone.height_m, cone.base_thickness_m, 0.5 * cone.base_width_m
    c, s = math.cos(elevation_rad), math.sin(elevation_rad)
    top = (H - t) * c - a * s
    return max(top, 0.0) / ((H - t) * c + 2.0 * a * s + t * c)


def _image_frame(
    detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray
) -> tuple[np.ndarray, float] | None:
    """`(d, e)`: the image of the downward vertical at the blob and the elevation (radians)
    of the line of sight through the blob's centroid below the horizontal; None at the nadir."""
    return _View(detection, camera, T_w_c).frame()


def apex_pixel(detection: ConeDetection, d: np.ndarray, fraction: float) -> np.ndarray | None:
    """The apex's image from the area of the silhouette's top triangle, (2,) float64, or None.

    With `t` the pixel coordinate along the image vertical `d` (down), the triangle between
    the apex (at `t0`) and the two tangents to the body's base has cross-section width
    `k (t - t0)`, so its area above `tau` is `N(tau) = (k / 2) (tau - t0)^2`: `sqrt N` is a
    straight line in `tau` that crosses zero at the apex. `N` is counted from the mask, each
    pixel spread uniformly over `[t_i - 1/2, t_i + 1/2]` (a unit square's extent along `d`,
    matching its variance), and the line is fitted on `tau` from where `N` reaches 3 px down to
    `0.85 fraction` of the blob's length (`fraction` from `triangle_fraction`). Counting
    pixels measures area without bias, where the top-most pixel is several pixels below the
    apex of a thin tip and edge lines fitted to the top rows are biased by the rows whose
    width rounds up to one pixel. The apex's coordinate across `d` is the mean of the
    triangle's pixels in the upper half of that range (the triangle is symmetric about the
    image of the cone's axis).

    None when fewer than three samples are usable or the fit is not a widening triangle.
    """
    return _apex_pixel(detection.pixels_uv(), np.asarray(d, dtype=np.float64), fraction)


def _apex_pixel(uv: np.ndarray, d: np.ndarray, fraction: float) -> np.ndarray | None:
    """`apex_pixel` on the pixel centres `uv` (N, 2)."""
    d0, d1 = float(d[0]), float(d[1])
    t, s = uv @ d, uv @ np.array([-d1, d0])
    n = t.size
    ts = np.sort(t)
    t_top = float(ts[0]) - 0.5
    length = float(ts[-1]) + 0.5 - t_top
    t_end = t_top + 0.85 * fraction * length
    tau = np.arange(t_top + 0.5, t_end + 1e-9, 0.5)
    if tau.size < 3:
        return None
    # N(tau) = sum_i clip(tau - t_i + 1/2, 0, 1): of the sorted t_i, those at or above
    # tau - 1/2 count 1 each, those within (tau - 1/2, tau + 1/2) count tau + 1/2 - t_i
    # (cumulative sums of t_i - t_top: small, and exact for pixel-aligned t).
    ts -= t_top
    csum = np.empty(n + 1)
    csum[0] = 0.0
    np.cumsum(ts, out=csum[1:])
    rel = tau - t_top
    lo = np.searchsorted(ts, rel - 0.5, side="right")
    hi = np.searchsorted(ts, rel + 0.5, side="left")
    area = lo + (hi - lo) * (rel + 0.5) - (csum[hi] - csum[lo])
    use = area >= 3.0  # the first pixels of a thin tip are the least reliable
    n_use = int(np.count_nonzero(use))
    if n_use < 3:
        return None
    # Least-squares line sqrt(N) = slope tau + offset (centred normal equations).
    x, y = tau[use], np.sqrt(area[use])
    x_mean, y_mean = float(np.add.reduce(x)) / n_use, float(np.add.reduce(y)) / n_use
    x -= x_mean
    y -= y_mean
    slope = float(x @ y) / float(x @ x)
    offset = y_mean - slope * x_mean
    if not slope > 0.0:
        return None
    t0 = -offset / slope
    upper = t <= t0 + 0.5 * (t_end - t0) + 0.5
    n_upper = int(np.count_nonzero(upper))
    s0 = float(np.add.reduce(s[upper])) / n_upper if n_upper else float(np.add.reduce(s)) / n
    return np.array([t0 * d0 + s0 * -d1, t0 * d1 + s0 * d0])


def _boundary_along(uv: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The blob's boundary points farthest along `d`, one per image column (or row).

    Columns when `d` is closer to the image's v axis, else rows; in each, the extreme pixel
    centre moved half a pixel outwards along that axis (the silhouette's edge lies within half
    a pixel of it and this is its unbiased estimate over the unknown sub-pixel phase).
    Returns (M, 2) `(u, v)` points sorted along the other axis.
    """
    along = 1 if abs(d[1]) >= abs(d[0]) else 0
    lat = 1 - along
    sign = 1.0 if d[along] >= 0.0 else -1.0
    keys, inverse = np.unique(uv[:, lat], return_inverse=True)
    extreme = np.full(keys.size, -np.inf)
    np.maximum.at(extreme, inverse, sign * uv[:, along])
    out = np.empty((keys.size, 2))
    out[:, lat] = keys
    out[:, along] = sign * (extreme + 0.5)
    return out


def _boundary_from_mask(detection: ConeDetection, d0: float, d1: float) -> np.ndarray:
    """`_boundary_along(detection.pixels_uv(), (d0, d1))`, read off the cropped mask directly
    (first / last set pixel of each column or row), without the pixel list."""
    mask = detection.mask
    x0, y0 = detection.bbox[0], detection.bbox[1]
    if abs(d1) >= abs(d0):  # one point per column, extreme in v
        keys = np.flatnonzero(mask.any(axis=0))
        if d1 >= 0.0:
            along = (mask.shape[0] - 1 + y0 + 0.5) - np.argmax(mask[::-1], axis=0)[keys]
        else:
            along = np.argmax(mask, axis=0)[keys] + (y0 - 0.5)
        out = np.empty((keys.size, 2))
        out[:, 0] = keys + x0
        out[:, 1] = along
    else:  # one point per row, extreme in u
        keys = np.flatnonzero(mask.any(axis=1))
        if d0 >= 0.0:
            along = (mask.shape[1] - 1 + x0 + 0.5) - np.argmax(mask[:, ::-1], axis=1)[keys]
        else:
            along = np.argmax(mask, axis=1)[keys] + (x0 - 0.5)
        out = np.empty((keys.size, 2))
        out[:, 0] = along
        out[:, 1] = keys + y0
    return out


def bottom_pixel(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    apex_uv: np.ndarray | None = None,
) -> np.ndarray:
    """Where the image of the cone's axis leaves the blob at the bottom, (2,) float64.

    The image of the vertical through the apex (the line through `apex_uv` along the image of
    the downward vertical) meets the blob's lower boundary (`_boundary_along`, interpolated
    linearly between columns) at the image of the base plate's near bottom edge, in the
    vertical plane through the camera and the cone's axis: `base_axis_distance` from the base
    centre towards the camera. Without `apex_uv` the axis passes through `apex_pixel` (else
    the detector's apex). Falls back to `detection.base_uv` when the vertical is undefined at
    the blob (camera looking straight down at it).
    """
    view = _View(detection, camera, T_w_c)
    if apex_uv is None:
        return view.bottom()
    frame = view.frame()
    if frame is None:
        return np.asarray(detection.base_uv, dtype=np.float64)
    return view.axis_exit(frame[0], np.asarray(apex_uv, dtype=np.float64))


def _axis_exit(uv: np.ndarray, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
    """Intersection of the line `apex_uv + lambda d` with the blob's lower boundary."""
    return _exit_on_boundary(_boundary_along(uv, d), d, apex_uv)


def _exit_on_boundary(pts: np.ndarray, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
    """`_axis_exit` on the boundary points `pts` (`_boundary_along`), in plain floats.

    Where the boundary polyline crosses the axis line (or touches it at a vertex) the crossing
    farthest along `d` wins (the first of equals); without a crossing, the vertex nearest the
    line. The result is put back onto the axis line exactly.
    """
    a0, a1 = float(apex_uv[0]), float(apex_uv[1])
    d0, d1 = float(d[0]), float(d[1])
    xy = pts.tolist()
    off = [(x - a0) * -d1 + (y - a1) * d0 for x, y in xy]
    best = None
    if len(xy) == 1 or all(o > 0 for o in off) or all(o < 0 for o in off):
        best = xy[min(range(len(off)), key=lambda j: abs(off[j]))]
    else:
        best_along = 0.0
        for j in range(len(xy) - 1):
            o0, o1 = off[j], off[j + 1]
            if o0 == 0.0 or o0 * o1 < 0.0:
                (x0, y0), (x1, y1) = xy[j], xy[j + 1]
                f = o0 / (o0 - o1)
                p = (x0 + (x1 - x0) * f, y0 + (y1 - y0) * f)
                along = p[0] * d0 + p[1] * d1
                if best is None or along > best_along:
                    best, best_along = p, along
        if off[-1] == 0.0 and (best is None or xy[-1][0] * d0 + xy[-1][1] * d1 > best_along):
            best = xy[-1]
    assert best is not None
    # Back onto the axis line exactly (the interpolation is along the boundary).
    lam = (best[0] - a0) * d0 + (best[1] - a1) * d1
    return np.array([a0 + lam * d0, a1 + lam * d1])


def _horizontal_unit(v: np.ndarray) -> np.ndarray | None:
    h = np.array([v[0], v[1], 0.0])
    norm = float(np.linalg.norm(h))
    return h / norm if norm > 1e-9 else None


# ------------------------------------------------------------------------------ methods


def estimate_from_ground_plane(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
) -> np.ndarray | None:
    """Base centre from the ray through the blob's bottom pixel meeting the ground z = 0.

    `g_w = t_w_c + lambda d_w` with `lambda = -z_c / d_z` (`d_w` the unit ray in the world
    through `bottom_pixel`, the base plate's near bottom edge on the cone's image axis), then
    `p_w = g_w + s b` with `b` the horizontal bearing from the camera and `s` the mean distance
    from the base centre to that edge (`base_axis_distance`).

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the detection touches the image border (the cone may be cut off: its bottom
        may be outside the image), when the camera is not above the ground, or when the ray
        is parallel to the ground or points away from it (`d_z >= -1e-9`).
    """
    _check_detection(detection, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    if detection.touches_border:
        return None
    return _ground_plane(_View(detection, camera, T_w_c), cone)


def _ground_plane(view: _View, cone: ConeModel) -> np.ndarray | None:
    """`estimate_from_ground_plane` after validation, for a detection clear of the border."""
    bottom = view.bottom()
    tx, ty, tz = view.t
    dx, dy, dz = view.ray(float(bottom[0]), float(bottom[1]))
    if tz <= 0.0 or dz >= -1e-9:
        logger.debug("ground plane: ray does not reach the ground (d_z = %.3g)", dz)
        return None
    lam = -tz / dz
    gx, gy = tx + lam * dx, ty + lam * dy
    hx, hy = gx - tx, gy - ty
    norm = math.sqrt(hx * hx + hy * hy)
    if not norm > 1e-9:
        return np.array([gx, gy, 0.0])
    s = base_axis_distance(cone)
    return np.array([gx + s * (hx / norm), gy + s * (hy / norm), 0.0])


MIN_TRIANGLE_FRACTION = 0.10
"""`estimate_from_known_height` needs at least this `triangle_fraction` of the silhouette (the
apex clear of the base plate's image): up to about 69 deg of elevation for the standard cone."""

MAX_RANGE_ERROR_PER_PX = 0.10
"""`estimate_from_known_height` gives no estimate when one pixel of error in the apex or the
bottom pixel (along the image vertical) moves it by more than this fraction of its range."""


def _solve_known_height(
    c_w: tuple[float, float, float],
    a_w: tuple[float, float, float],
    g_w: tuple[float, float, float],
    height_m: float,
    s: float,
) -> tuple[tuple[float, float, float], float, float, float] | None:
    """`(p_w, alpha, gamma, residual)` of the 3x2 least-squares triangle, or None.

    `[a, -g] (alpha, gamma)^T = (0, 0, H) + s b` solved by a QR factorisation (Gram-Schmidt
    on the two columns, as well conditioned as the problem: the rays are at least 1e-4 rad
    apart), in plain floats.
    """
    ax, ay, az = a_w
    gx, gy, gz = g_w
    norm_b = math.sqrt(gx * gx + gy * gy)
    if not norm_b > 1e-9 or ax * gx + ay * gy + az * gz > math.cos(1e-4):
        return None
    bx, by = gx / norm_b, gy / norm_b
    rx, ry, rz = s * bx, s * by, height_m
    # Q R of A = [a, -g]: q1 = a / r11, q2 = (-g - r12 q1) / r22.
    r11 = math.sqrt(ax * ax + ay * ay + az * az)
    q1x, q1y, q1z = ax / r11, ay / r11, az / r11
    r12 = -(q1x * gx + q1y * gy + q1z * gz)
    wx, wy, wz = -gx - r12 * q1x, -gy - r12 * q1y, -gz - r12 * q1z
    r22 = math.sqrt(wx * wx + wy * wy + wz * wz)
    q2x, q2y, q2z = wx / r22, wy / r22, wz / r22
    gamma = (q2x * rx + q2y * ry + q2z * rz) / r22
    alpha = (q1x * rx + q1y * ry + q1z * rz - r12 * gamma) / r11
    ex = alpha * ax - gamma * gx - rx
    ey = alpha * ay - gamma * gy - ry
    ez = alpha * az - gamma * gz - rz
    residual = math.sqrt(ex * ex + ey * ey + ez * ez)
    cx, cy, cz = c_w
    p_w = (cx + gamma * gx + s * bx, cy + gamma * gy + s * by, cz + gamma * gz)
    return p_w, alpha, gamma, residual


def estimate_from_known_height(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
) -> np.ndarray | None:
    """Base centre from the cone's known height and its apparent size (generalised similar
    triangles).

    With `c = t_w_c`, unit world rays `a` (through `apex_pixel`) and `g` (through
    `bottom_pixel`, the plate's near bottom edge on the cone's image axis), horizontal
    bearing `b` and `s = base_axis_distance`, the apex `c + alpha a` and the edge point
    `c + gamma g` satisfy `alpha a - gamma g = (0, 0, H) + s b`; `(alpha, gamma)` is the
    least-squares solution and `p_w = c + gamma g + s b`. For a level camera and a distant cone
    this reduces to `Z = f H / h_px`.

    Conditioning. The estimate is refused (None) when the triangle cannot be measured well:

    - the apex must be clear of the base plate's image: `triangle_fraction(e) >=
      MIN_TRIANGLE_FRACTION` at the line of sight's elevation `e` (up to about 69 deg for the
      standard cone; looking down more steeply the apex projects inside the cone's outline
      and its height is foreshortened onto the plate);
    - one pixel of error in the apex or the bottom pixel, along the image vertical, may move
      the estimate by at most `MAX_RANGE_ERROR_PER_PX` of its range (the sensitivity of the
      least-squares solution, by finite differences): a cone only a few pixels tall gives no
      estimate rather than a wrong one.

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the detection touches the image border (apex or base may be cut off), the
        geometry is ill-conditioned (above), the two rays are (nearly) parallel, a ray length
        comes out non-positive or the equations are inconsistent (residual above 25% of H).
    """
    _check_detection(detection, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    if detection.touches_border:
        return None
    return _known_height(_View(detection, camera, T_w_c), cone)


def _known_height(view: _View, cone: ConeModel) -> np.ndarray | None:
    """`estimate_from_known_height` after validation, for a detection clear of the border."""
    frame = view.frame()
    if frame is None:
        logger.debug("known height: camera looks straight down at the cone")
        return None
    d, elevation = frame
    fraction = triangle_fraction(elevation, cone)
    if fraction < MIN_TRIANGLE_FRACTION:
        logger.debug(
            "known height: apex over the base plate (elevation %.1f deg)", math.degrees(elevation)
        )
        return None
    apex_uv = view.apex(d, fraction)
    if apex_uv is None:
        logger.debug("known height: no apex fit")
        return None
    bottom_uv = view.axis_exit(d, apex_uv)
    c_w = view.t
    s = base_axis_distance(cone)
    H = cone.height_m
    au, av = float(apex_uv[0]), float(apex_uv[1])
    bu, bv = float(bottom_uv[0]), float(bottom_uv[1])
    d0, d1 = float(d[0]), float(d[1])
    a_w, g_w = view.ray(au, av), view.ray(bu, bv)

    solution = _solve_known_height(c_w, a_w, g_w, H, s)
    if solution is None:
        logger.debug("known height: degenerate rays")
        return None
    p_w, alpha, gamma, residual = solution
    if alpha <= 0.0 or gamma <= 0.0 or residual > 0.25 * H:
        logger.debug(
            "known height: inconsistent (alpha %.3g, gamma %.3g, res %.3g)", alpha, gamma, residual
        )
        return None
    range_m = math.dist(p_w, c_w)
    for moved in (
        _solve_known_height(c_w, view.ray(au + d0, av + d1), g_w, H, s),
        _solve_known_height(c_w, a_w, view.ray(bu + d0, bv + d1), H, s),
    ):
        shift = math.inf if moved is None else math.dist(moved[0], p_w)
        if shift > MAX_RANGE_ERROR_PER_PX * range_m:
            logger.debug("known height: 1 px moves the estimate %.3g m at %.3g m", shift, range_m)
            return None
    return np.array(p_w)


def estimate_from_depth(
    detection: ConeDetection,
    depth: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
    far_m: float = np.inf,
) -> np.ndarray | None:
    """Base centre from the depth image over the detection's mask.

    1. Back-project every mask pixel with its planar depth, `p_w = T_w_c @ p_c` (pixels with
       depth <= 0 or >= `far_m` are dropped; far outliers beyond 2 m of the median depth too).
    2. `z_base` = 2nd percentile of the points' heights (the base plate's bottom edge).
    3. Body points (height above `z_base` between plate + 2 cm and apex - 3 cm) lie at the
       known radius `r(h) = r0 (H - h) / (H - t)` from the axis. Start each at
       `p_xy + r(h) b_i` (`b_i` the horizontal viewing direction), take the median, then
       minimise `sum_i (|p_xy,i - c| - r_i)^2` over the axis `c` by Gauss-Newton with one
       3-sigma (MAD) outlier trim.

    Parameters
    ----------
    detection : ConeDetection
    depth : ndarray, shape (H, W), float32 or float64
        Planar z-depth in metres, the camera's image size.
    camera : PinholeCamera
    T_w_c : ndarray, shape (4, 4)
    cone : ConeModel
    far_m : float
        Depths at or beyond this are "no return" (the renderer's far plane).

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the detection touches the image border (part of the cone is outside the
        image, so the lowest visible point need not be the base and the axis fit is
        unconstrained) or fewer than 5 valid depth pixels fall on the cone's body.

    Raises
    ------
    ValueError
        On a depth image of the wrong dtype or size, or NaN/inf depth under the mask.
    """
    _check_detection(detection, camera)
    _check_depth(depth, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    z_c = _depth_under_mask(detection, depth)
    if detection.touches_border:
        return None
    return _from_depth(_View(detection, camera, T_w_c), z_c, cone, far_m)


def _median(a: np.ndarray) -> float:
    """`np.median` of a non-empty 1-D float64 array without NaN (same value, less overhead)."""
    n = a.size
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, (k - 1, k))
    return (float(part[k - 1]) + float(part[k])) / 2.0


def _percentile(a: np.ndarray, q: float) -> float:
    """`np.percentile(a, q)` (linear method) of a non-empty 1-D float64 array without NaN."""
    n = a.size
    index = (n - 1) * (q / 100.0)
    lo = min(math.floor(index), n - 1)
    hi = min(lo + 1, n - 1)
    part = np.partition(a, (lo, hi)) if hi != lo else np.partition(a, lo)
    below, above = float(part[lo]), float(part[hi])
    gamma = index - lo
    diff = above - below
    # numpy's _lerp: from the nearer end.
    return above - diff * (1.0 - gamma) if gamma >= 0.5 else below + diff * gamma


def _from_depth(view: _View, z_c: np.ndarray, cone: ConeModel, far_m: float) -> np.ndarray | None:
    """`estimate_from_depth` after validation, for a detection clear of the border; `z_c` the
    depth under the mask (`_depth_under_mask`)."""
    uv = view.uv()
    u, v = uv[:, 0], uv[:, 1]
    valid = (z_c > 0.0) & (z_c < far_m)
    n_valid = int(np.count_nonzero(valid))
    if n_valid < _MIN_DEPTH_POINTS:
        return None
    z_v = z_c if n_valid == z_c.size else z_c[valid]
    # Far outliers: one selection for both masks.
    keep = valid
    keep[valid] = np.abs(z_v - _median(z_v)) < 2.0
    n_keep = int(np.count_nonzero(keep))
    if n_keep < _MIN_DEPTH_POINTS:
        return None
    if n_keep < z_c.size:
        u, v, z_c = u[keep], v[keep], z_c[keep]
    # p_c = backproject(uv, z_c); p_w = R p_c + t, per coordinate.
    x_c = (u - view.cx) * z_c / view.fx
    y_c = (v - view.cy) * z_c / view.fy
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = view.R
    tx, ty, tz = view.t
    z_w = x_c * r20 + y_c * r21 + z_c * r22 + tz
    z_base = _percentile(z_w, 2.0)
    height = z_w - z_base
    t, H, r0 = cone.base_thickness_m, cone.height_m, cone.body_radius_m
    body = (height > t + 0.02) & (height < H - 0.03)
    n_body = int(np.count_nonzero(body))
    if n_body < _MIN_DEPTH_POINTS:
        logger.debug("depth: too few body points (%d)", n_body)
        return None
    x_c, y_c, z_cb = x_c[body], y_c[body], z_c[body]
    qx = x_c * r00 + y_c * r01 + z_cb * r02 + tx
    qy = x_c * r10 + y_c * r11 + z_cb * r12 + ty
    r = r0 * (H - height[body]) / (H - t)
    vx, vy = qx - tx, qy - ty
    view_norm = np.sqrt(vx * vx + vy * vy)
    # b = view / |view|, 0 where |view| <= 1e-6 (dividing by inf there gives 0 exactly).
    inv = np.where(view_norm > 1e-6, view_norm, np.inf)
    c0 = (_median(qx + r * (vx / inv)), _median(qy + r * (vy / inv)))
    c = _fit_axis(qx, qy, r, c0)
    if c is None or math.hypot(c[0] - c0[0], c[1] - c0[1]) > 2.0 * r0:
        c = c0
    return np.array([c[0], c[1], z_base])


def _fit_axis(
    qx: np.ndarray, qy: np.ndarray, r: np.ndarray, c0: tuple[float, float]
) -> tuple[float, float] | None:
    """Gauss-Newton for the centre `c` of circles of known radii `r_i` through points `q_i`.

    Residual `e_i = |q_i - c| - r_i`, Jacobian row `-(q_i - c)^T / |q_i - c|`; each step solves
    the 2x2 normal equations (the rows are unit vectors, so `J^T J` is well conditioned
    whenever the points do not all lie in one direction from `c`).
    """
    cx, cy = c0
    ux, uy, ur = qx, qy, r
    buf = np.empty((3, qx.size))  # rows: the unit vectors (q_i - c) / |q_i - c| and e_i
    for it in range(12):
        m = ux.size
        if m < 3:
            return None
        ex, ey, e = buf[0, :m], buf[1, :m], buf[2, :m]
        np.subtract(ux, cx, out=ex)
        np.subtract(uy, cy, out=ey)
        dist = np.sqrt(ex * ex + ey * ey)
        if float(np.minimum.reduce(dist)) < 1e-9:
            return None
        np.subtract(dist, ur, out=e)
        ex /= dist
        ey /= dist
        # J = -(ex, ey): J^T J and -J^T e from one product of the stacked rows.
        (sxx, sxy, gx), (_, syy, gy) = (buf[:2, :m] @ buf[:, :m].T).tolist()
        det = sxx * syy - sxy * sxy
        if not det > 0.0:
            return None
        step_x = (syy * gx - sxy * gy) / det
        step_y = (sxx * gy - sxy * gx) / det
        cx, cy = cx + step_x, cy + step_y
        if it == 3:
            ax, ay = qx - cx, qy - cy
            e_all = np.sqrt(ax * ax + ay * ay) - r
            dev = np.abs(e_all - _median(e_all))
            mad = 1.4826 * _median(dev)
            use = dev <= max(3.0 * mad, 0.005)
            ux, uy, ur = qx[use], qy[use], r[use]
        elif math.hypot(step_x, step_y) < 1e-7:
            break
    return cx, cy


def naive_estimate(p_c: np.ndarray, T_w_b: np.ndarray) -> np.ndarray:
    """The lecture's mistake: `t_w_b + p_c`, camera coordinates taken for world offsets.

    Parameters
    ----------
    p_c : ndarray, shape (3,)
        The cone in the optical frame, metres.
    T_w_b : ndarray, shape (4, 4)
        Drone pose; only its translation is used, which is the mistake.
    """
    T_w_b = _check_transform(T_w_b, "T_w_b")
    p_c = np.asarray(p_c, dtype=np.float64)
    if p_c.shape != (3,):
        raise ValueError(f"p_c must have shape (3,), got {p_c.shape}")
    return T_w_b[:3, 3] + p_c


def localize(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_b: np.ndarray,
    T_b_c: np.ndarray,
    depth: np.ndarray | None = None,
    cone: ConeModel = TRAFFIC_CONE,
    far_m: float = np.inf,
) -> ConeEstimates:
    """Every estimate of one detected cone's base centre in the world frame.

    Parameters
    ----------
    detection : ConeDetection
        From `vnav.detect.detect_cones`.
    camera : PinholeCamera
    T_w_b : ndarray, shape (4, 4)
        Body (FLU) pose in the world.
    T_b_c : ndarray, shape (4, 4)
        Camera (optical frame) pose on the body; `T_w_c = T_w_b @ T_b_c`.
    depth : ndarray, shape (H, W), float32/float64, optional
        Planar z-depth, metres; without it `depth_image` is None.
    cone : ConeModel
    far_m : float
        Depth at or beyond which a pixel has no return.

    Returns
    -------
    ConeEstimates
        A method's field is None when it gives no estimate (see each `estimate_from_*`). Every
        field is None when the detection touches the image border (`touches_border`): part of
        the cone may be outside the image (apex or base missing, the depth-image axis fit
        unconstrained), and no estimate is better than a wrong one. Inputs are still
        validated first.

    Raises
    ------
    ValueError
        On malformed transforms, a depth image of the wrong dtype or size, or non-finite depth
        under the detection's mask.
    """
    # Validate once, in the order the methods would (detection, depth, T_w_c), then run the
    # methods' unvalidated cores on one shared `_View`.
    T_w_b = _check_transform(T_w_b, "T_w_b")
    T_b_c = _check_transform(T_b_c, "T_b_c")
    T_w_c = T_w_b @ T_b_c
    _check_detection(detection, camera)
    if depth is not None:
        _check_depth(depth, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    z_c = None if depth is None else _depth_under_mask(detection, depth)
    if detection.touches_border:
        return ConeEstimates(depth_image=None, ground_plane=None, known_height=None, naive=None)
    view = _View(detection, camera, T_w_c)
    p_depth = None if z_c is None else _from_depth(view, z_c, cone, far_m)
    p_ground = _ground_plane(view, cone)
    p_height = _known_height(view, cone)
    best = next((p for p in (p_depth, p_ground, p_height) if p is not None), None)
    p_naive = None
    if best is not None:
        # p_c = R_w_c^T (best - t_w_c); naive = t_w_b + p_c.
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = view.R
        tx, ty, tz = view.t
        bx, by, bz = best[0] - tx, best[1] - ty, best[2] - tz
        t_w_b = T_w_b[:3, 3].tolist()
        p_naive = np.array(
            [
                t_w_b[0] + (r00 * bx + r10 * by + r20 * bz),
                t_w_b[1] + (r01 * bx + r11 * by + r21 * bz),
                t_w_b[2] + (r02 * bx + r12 * by + r22 * bz),
            ]
        )
    return ConeEstimates(
        depth_image=p_depth, ground_plane=p_ground, known_height=p_height, naive=p_naive
    )


def depth_to_world_points(
    depth: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    stride: int = 1,
    far_m: float = np.inf,
) -> np.ndarray:
    """The depth image as a world-frame point cloud, `p_w = T_w_c @ backproject(uv, z)`.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32 or float64
        Planar z-depth, metres.
    camera : PinholeCamera
        Its size must match `depth`.
    T_w_c : ndarray, shape (4, 4)
    stride : int
        Use every `stride`-th row and column.
    far_m : float
        Pixels with depth >= far_m (the renderer's far plane: background), <= 0 or +inf are
        dropped.

    Returns
    -------
    p_w : ndarray, shape (M, 3), float64
        One point per valid pixel, row-major pixel order.

    Raises
    ------
    ValueError
        On a wrong dtype or size, NaN depth, `stride` < 1, or a malformed `T_w_c`.
    """
    _check_depth(depth, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    if isinstance(stride, bool) or not isinstance(stride, int | np.integer) or stride < 1:
        raise ValueError(f"stride must be a positive int, got {stride!r}")
    z = depth[::stride, ::stride]
    if np.isnan(z).any():
        raise ValueError(f"depth must not contain NaN; got {int(np.isnan(z).sum())} NaN pixels")
    valid = (z > 0.0) & (z < far_m)
    # Fold K^-1 and R_w_c into one 3x3: p_w = z * (M @ [u, v, 1]) + t_w_c. M @ [u, v, 1] is a
    # column term plus a row term, so each coordinate is one broadcast over the contiguous
    # grid, then gathered at the valid pixels (row-major order); no index arrays are built.
    M = T_w_c[:3, :3] @ np.linalg.inv(camera.K)
    u = np.arange(0, depth.shape[1], stride, dtype=np.float64)
    v = np.arange(0, depth.shape[0], stride, dtype=np.float64)[:, None]
    zv = z.astype(np.float64)
    p_w = np.empty((int(np.count_nonzero(valid)), 3), dtype=np.float64)
    for i in range(3):
        plane = zv * (M[i, 0] * u + (M[i, 1] * v + M[i, 2]))
        plane += T_w_c[i, 3]
        p_w[:, i] = plane[valid]
    return p_w
