"""From a cone detection to the cone's base-centre position in the world.

Every estimate goes through the lecture's chain (VNAV lecture 1, chapter 0)

    p_w = T_w_b @ T_b_c @ p_c = T_w_c @ p_c

and differs only in how the depth along the viewing ray is found:

1. `depth_image`: the rendered planar depth over the cone's mask, back-projected to world
   points on the cone's visible surface; the axis is found by fitting the cone's known
   radius profile `r(z)` to those points (a least-squares circle fit with known, height-
   dependent radius, started from the per-point correction "surface point + r(z) along the
   horizontal viewing direction" and its median). The base-centre height is the lowest
   surface point (2nd percentile). Needs no ground plane.
2. `ground_plane`: the ray through the bottom of the blob along the image of the vertical
   direction (the near bottom edge of the base plate) meets the ground z = 0 at `g_w`; the
   base centre lies behind it, away from the camera, by the base plate's mean support distance
   `a (4 / pi)` for a square of half-width `a` and unknown yaw (between `a` and `a sqrt(2)`).
   A ray parallel to or pointing away from the ground gives no estimate.
3. `known_height`: similar triangles generalised to a tilted camera: the two rays through the
   apex pixel and the blob's bottom pixel must hold the points `p_base + (0, 0, H)` and
   `p_base - s b` (`b` the horizontal bearing, `s` the support distance); the two ray lengths
   are the least-squares solution of those three linear equations. Needs no ground plane.
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

from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection, extreme_point

__all__ = [
    "ConeEstimates",
    "base_support_distance",
    "bottom_pixel",
    "depth_to_world_points",
    "estimate_from_depth",
    "estimate_from_ground_plane",
    "estimate_from_known_height",
    "localize",
    "naive_estimate",
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
    """A 4x4 finite rigid transform (rotation orthonormal to 1e-6, last row 0 0 0 1)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 transform, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise ValueError(f"{name} must be finite, got NaN or inf entries")
    if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0), atol=1e-12):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {T[3]}")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > 1e-6 or np.linalg.det(R) <= 0.0:
        raise ValueError(
            f"{name} must hold a rotation (R^T R = I to 1e-6, det +1), got |R^T R - I| = "
            f"{err:.2e}, det {np.linalg.det(R):.6f}"
        )
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


def base_support_distance(cone: ConeModel = TRAFFIC_CONE) -> float:
    """Mean distance from the base centre to the base plate's edge nearest the camera, metres.

    For a square of half-width `a` seen from a far point at bearing angle `psi` to a face
    normal, the support distance is `a (|cos psi| + |sin psi|)`; its mean over `psi` uniform
    in [0, pi/4] is `a (4 / pi)` (between `a` and `a sqrt(2)`, so the error is at most
    0.18 a = 3.4 cm for the standard cone).
    """
    return 0.5 * cone.base_width_m * 4.0 / math.pi


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


def bottom_pixel(detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray) -> np.ndarray:
    """The blob's extreme pixel along the image of the downward vertical, (2,) float64.

    The image of the base plate's bottom edge nearest the camera. Falls back to
    `detection.base_uv` when the vertical is undefined at the blob (camera looking straight
    down at it).
    """
    d = vertical_direction_uv(camera, T_w_c, detection.centroid_uv)
    if d is None:
        return np.asarray(detection.base_uv, dtype=np.float64)
    x0, y0, _, _ = detection.bbox
    return extreme_point(detection.mask, x0, y0, d)


def _top_pixel(detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray) -> np.ndarray:
    """The apex pixel.

    The blob's extreme pixel against the image of the downward vertical (the apex is the
    highest point of the cone, so it is the farthest from the vertical vanishing point while
    the camera sees it outside the body's outline). The detector's sub-pixel two-edge fit
    replaces it when the two agree to 3 px (the fit assumes an upright cone in the image and
    can lock onto the base plate's edges in a rolled or steep view).
    """
    d = vertical_direction_uv(camera, T_w_c, detection.centroid_uv)
    if d is None:
        return np.asarray(detection.apex_uv, dtype=np.float64)
    x0, y0, _, _ = detection.bbox
    top = extreme_point(detection.mask, x0, y0, -d)
    if detection.apex_from_edges and np.linalg.norm(detection.apex_uv - top) < 3.0:
        return np.asarray(detection.apex_uv, dtype=np.float64)
    return top


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

    `g_w = t_w_c + lambda d_w` with `lambda = -z_c / d_z` (`d_w` the unit ray in the world),
    then `p_w = g_w + s b` with `b` the horizontal bearing from the camera and `s` the
    base plate's mean support distance (`base_support_distance`).

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the camera is not above the ground or the ray is parallel to the ground or
        points away from it (`d_z >= -1e-9`).
    """
    _check_detection(detection, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
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
    return g_w + base_support_distance(cone) * b


def estimate_from_known_height(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
) -> np.ndarray | None:
    """Base centre from the cone's known height and its apparent size (generalised similar
    triangles).

    With `c = t_w_c`, unit world rays `a` (apex pixel) and `g` (bottom pixel), horizontal
    bearing `b` and support distance `s`, the apex `c + alpha a` and the bottom edge point
    `c + gamma g` satisfy `alpha a - gamma g = (0, 0, H) + s b`; `(alpha, gamma)` is the
    least-squares solution and `p_w = c + gamma g + s b`. For a level camera and a distant cone
    this reduces to `Z = f H / h_px`.

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the two rays are (nearly) parallel, a ray length comes out non-positive or
        the equations are inconsistent (residual above 25% of H).
    """
    _check_detection(detection, camera)
    T_w_c = _check_transform(T_w_c, "T_w_c")
    c_w = T_w_c[:3, 3]
    a_w = _ray_w(camera, T_w_c, _top_pixel(detection, camera, T_w_c))
    g_w = _ray_w(camera, T_w_c, bottom_pixel(detection, camera, T_w_c))
    b = _horizontal_unit(g_w)
    s = base_support_distance(cone)
    if b is None or float(np.dot(a_w, g_w)) > math.cos(1e-4):
        logger.debug("known height: degenerate rays")
        return None
    A = np.column_stack((a_w, -g_w))
    rhs = np.array([0.0, 0.0, cone.height_m]) + s * b
    (alpha, gamma), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    residual = float(np.linalg.norm(A @ np.array([alpha, gamma]) - rhs))
    if alpha <= 0.0 or gamma <= 0.0 or residual > 0.25 * cone.height_m:
        logger.debug(
            "known height: inconsistent (alpha %.3g, gamma %.3g, res %.3g)", alpha, gamma, residual
        )
        return None
    return c_w + gamma * g_w + s * b


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
        None when fewer than 5 valid depth pixels fall on the cone's body.

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
