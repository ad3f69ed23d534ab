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

    A thin wrapper only because `se3.check_transform` also accepts stacks `(..., 4, 4)`, and
    every function here takes exactly one pose.
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
    d = vertical_direction_uv(camera, T_w_c, detection.centroid_uv)
    if d is None:
        return None
    ray = _ray_w(camera, T_w_c, detection.centroid_uv)
    return d, math.asin(float(np.clip(-ray[2], -1.0, 1.0)))


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
    uv = detection.pixels_uv()
    dp = np.array([-d[1], d[0]])
    t, s = uv @ d, uv @ dp
    t_top = float(t.min()) - 0.5
    length = float(t.max()) + 0.5 - t_top
    t_end = t_top + 0.85 * fraction * length
    tau = np.arange(t_top + 0.5, t_end + 1e-9, 0.5)
    if tau.size < 3:
        return None
    area = np.clip(tau[:, None] - t[None, :] + 0.5, 0.0, 1.0).sum(axis=1)
    use = area >= 3.0  # the first pixels of a thin tip are the least reliable
    if use.sum() < 3:
        return None
    A = np.column_stack((tau[use], np.ones(int(use.sum()))))
    (slope, offset), *_ = np.linalg.lstsq(A, np.sqrt(area[use]), rcond=None)
    if not slope > 0.0:
        return None
    t0 = -offset / slope
    upper = t <= t0 + 0.5 * (t_end - t0) + 0.5
    s0 = float(s[upper].mean()) if upper.any() else float(s.mean())
    return t0 * d + s0 * dp


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
    frame = _image_frame(detection, camera, T_w_c)
    if frame is None:
        return np.asarray(detection.base_uv, dtype=np.float64)
    d, elevation = frame
    if apex_uv is None:
        apex_uv = apex_pixel(detection, d, max(triangle_fraction(elevation), 0.5))
        if apex_uv is None:
            apex_uv = np.asarray(detection.apex_uv, dtype=np.float64)
    return _axis_exit(detection.pixels_uv(), d, np.asarray(apex_uv, dtype=np.float64))


def _axis_exit(uv: np.ndarray, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
    """Intersection of the line `apex_uv + lambda d` with the blob's lower boundary."""
    pts = _boundary_along(uv, d)
    dp = np.array([-d[1], d[0]])
    off = (pts - apex_uv) @ dp
    best = None
    if pts.shape[0] == 1 or np.all(off > 0) or np.all(off < 0):
        best = pts[int(np.argmin(np.abs(off)))]
    else:
        for j in range(pts.shape[0] - 1):
            o0, o1 = off[j], off[j + 1]
            if o0 == 0.0 or o0 * o1 < 0.0:
                p = pts[j] + (pts[j + 1] - pts[j]) * (o0 / (o0 - o1))
                if best is None or p @ d > best @ d:
                    best = p
        if off[-1] == 0.0 and (best is None or pts[-1] @ d > best @ d):
            best = pts[-1]
    assert best is not None
    # Back onto the axis line exactly (the interpolation is along the boundary).
    return apex_uv + float((best - apex_uv) @ d) * d


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
    t_w_c = T_w_c[:3, 3]
    d_w = _ray_w(camera, T_w_c, bottom_pixel(detection, camera, T_w_c))
    if t_w_c[2] <= 0.0 or d_w[2] >= -1e-9:
        logger.debug("ground plane: ray does not reach the ground (d_z = %.3g)", d_w[2])
        return None
    g_w = t_w_c + (-t_w_c[2] / d_w[2]) * d_w
    g_w[2] = 0.0
    b = _horizontal_unit(g_w - t_w_c)
    if b is None:
        return g_w
    return g_w + base_axis_distance(cone) * b


MIN_TRIANGLE_FRACTION = 0.10
"""`estimate_from_known_height` needs at least this `triangle_fraction` of the silhouette (the
apex clear of the base plate's image): up to about 69 deg of elevation for the standard cone."""

MAX_RANGE_ERROR_PER_PX = 0.10
"""`estimate_from_known_height` gives no estimate when one pixel of error in the apex or the
bottom pixel (along the image vertical) moves it by more than this fraction of its range."""


def _solve_known_height(
    c_w: np.ndarray,
    a_w: np.ndarray,
    g_w: np.ndarray,
    height_m: float,
    s: float,
) -> tuple[np.ndarray, float, float, float] | None:
    """`(p_w, alpha, gamma, residual)` of the 3x2 least-squares triangle, or None."""
    b = _horizontal_unit(g_w)
    if b is None or float(np.dot(a_w, g_w)) > math.cos(1e-4):
        return None
    A = np.column_stack((a_w, -g_w))
    rhs = np.array([0.0, 0.0, height_m]) + s * b
    (alpha, gamma), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    residual = float(np.linalg.norm(A @ np.array([alpha, gamma]) - rhs))
    return c_w + gamma * g_w + s * b, float(alpha), float(gamma), residual


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
    frame = _image_frame(detection, camera, T_w_c)
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
    apex_uv = apex_pixel(detection, d, fraction)
    if apex_uv is None:
        logger.debug("known height: no apex fit")
        return None
    bottom_uv = _axis_exit(detection.pixels_uv(), d, apex_uv)
    c_w = T_w_c[:3, 3]
    s = base_axis_distance(cone)

    def solve(apex: np.ndarray, bottom: np.ndarray):
        return _solve_known_height(
            c_w, _ray_w(camera, T_w_c, apex), _ray_w(camera, T_w_c, bottom), cone.height_m, s
        )

    solution = solve(apex_uv, bottom_uv)
    if solution is None:
        logger.debug("known height: degenerate rays")
        return None
    p_w, alpha, gamma, residual = solution
    if alpha <= 0.0 or gamma <= 0.0 or residual > 0.25 * cone.height_m:
        logger.debug(
            "known height: inconsistent (alpha %.3g, gamma %.3g, res %.3g)", alpha, gamma, residual
        )
        return None
    range_m = float(np.linalg.norm(p_w - c_w))
    for da, db in ((d, 0.0 * d), (0.0 * d, d)):
        moved = solve(apex_uv + da, bottom_uv + db)
        shift = np.inf if moved is None else float(np.linalg.norm(moved[0] - p_w))
        if shift > MAX_RANGE_ERROR_PER_PX * range_m:
            logger.debug("known height: 1 px moves the estimate %.3g m at %.3g m", shift, range_m)
            return None
    return p_w


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
    x0, y0, w, h = detection.bbox
    z_c = depth[y0 : y0 + h, x0 : x0 + w][detection.mask].astype(np.float64)
    if not np.isfinite(z_c).all():
        raise ValueError(
            f"depth must be finite under the detection's mask; got {int((~np.isfinite(z_c)).sum())}"
            f" non-finite of {z_c.size} pixels"
        )
    if detection.touches_border:
        return None
    uv = detection.pixels_uv()
    valid = (z_c > 0.0) & (z_c < far_m)
    if valid.sum() < _MIN_DEPTH_POINTS:
        return None
    uv, z_c = uv[valid], z_c[valid]
    keep = np.abs(z_c - np.median(z_c)) < 2.0
    uv, z_c = uv[keep], z_c[keep]
    if z_c.size < _MIN_DEPTH_POINTS:
        return None
    p_c = camera.backproject(uv, z_c)
    p_w = p_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]
    z_base = float(np.percentile(p_w[:, 2], 2.0))
    height = p_w[:, 2] - z_base
    t, H, r0 = cone.base_thickness_m, cone.height_m, cone.body_radius_m
    body = (height > t + 0.02) & (height < H - 0.03)
    if body.sum() < _MIN_DEPTH_POINTS:
        logger.debug("depth: too few body points (%d)", int(body.sum()))
        return None
    q = p_w[body, :2]
    r = r0 * (H - height[body]) / (H - t)
    view = q - T_w_c[:2, 3]
    view_norm = np.linalg.norm(view, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        b = np.where(view_norm > 1e-6, view / view_norm, 0.0)
    c0 = np.median(q + r[:, None] * b, axis=0)
    c = _fit_axis(q, r, c0)
    if c is None or np.linalg.norm(c - c0) > 2.0 * r0:
        c = c0
    return np.array([c[0], c[1], z_base])


def _fit_axis(q: np.ndarray, r: np.ndarray, c0: np.ndarray) -> np.ndarray | None:
    """Gauss-Newton for the centre `c` of circles of known radii `r_i` through points `q_i`.

    Residual `e_i = |q_i - c| - r_i`, Jacobian row `-(q_i - c)^T / |q_i - c|`.
    """
    c = c0.copy()
    use = np.ones(q.shape[0], dtype=bool)
    for it in range(12):
        diff = q[use] - c
        dist = np.linalg.norm(diff, axis=1)
        if (dist < 1e-9).any() or use.sum() < 3:
            return None
        e = dist - r[use]
        J = -diff / dist[:, None]
        step, *_ = np.linalg.lstsq(J, -e, rcond=None)
        c = c + step
        if it == 3:
            e_all = np.linalg.norm(q - c, axis=1) - r
            mad = 1.4826 * np.median(np.abs(e_all - np.median(e_all)))
            use = np.abs(e_all - np.median(e_all)) <= max(3.0 * mad, 0.005)
        elif np.linalg.norm(step) < 1e-7:
            break
    return c


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
    T_w_b = _check_transform(T_w_b, "T_w_b")
    T_b_c = _check_transform(T_b_c, "T_b_c")
    T_w_c = T_w_b @ T_b_c
    p_depth = (
        None
        if depth is None
        else estimate_from_depth(detection, depth, camera, T_w_c, cone, far_m=far_m)
    )
    p_ground = estimate_from_ground_plane(detection, camera, T_w_c, cone)
    p_height = estimate_from_known_height(detection, camera, T_w_c, cone)
    best = next((p for p in (p_depth, p_ground, p_height) if p is not None), None)
    p_naive = None
    if best is not None:
        p_c = T_w_c[:3, :3].T @ (best - T_w_c[:3, 3])
        p_naive = naive_estimate(p_c, T_w_b)
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
    rows, cols = np.nonzero((z > 0.0) & (z < far_m))
    zv = z[rows, cols].astype(np.float64)
    # Fold K^-1 and R_w_c into one 3x3: p_w = zv * (M @ [u, v, 1]) + t_w_c.
    M = T_w_c[:3, :3] @ np.linalg.inv(camera.K)
    u = (cols * stride).astype(np.float64)
    v = (rows * stride).astype(np.float64)
    p_w = np.empty((zv.size, 3), dtype=np.float64)
    for i in range(3):
        p_w[:, i] = zv * (M[i, 0] * u + M[i, 1] * v + M[i, 2]) + T_w_c[i, 3]
    return p_w
