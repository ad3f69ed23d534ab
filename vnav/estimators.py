"""The estimators: a cone's base centre in the world from one detection, by each method.

Every estimate goes through the lecture's chain (VNAV lecture 1, chapter 0)
``p_w = T_w_b @ T_b_c @ p_c = T_w_c @ p_c`` and differs only in how the depth along the viewing
ray is found (``vnav.methods``). A detection that touches the image border (the cone may be cut
off) gets no estimate from any method.

1. ``depth_image``: the rendered planar depth over the cone's mask, back-projected to world
   points on the cone's visible surface; the axis is found by fitting the cone's known radius
   profile ``r(z)`` to those points (a least-squares circle fit with known, height-dependent
   radius, started from the per-point correction "surface point + r(z) along the horizontal
   viewing direction" and its median). The base-centre height is the lowest surface point
   (2nd percentile). Needs no ground plane.
2. ``ground_plane``: the ray through the bottom pixel (``SilhouetteView.bottom``: the near
   bottom edge of the base plate on the cone's image axis) meets the ground z = 0 at ``g_w``;
   the base centre lies behind it, away from the camera, by the plate's mean distance from
   centre to edge along the bearing (``ConeModel.base_axis_distance_m``). A ray parallel to or
   pointing away from the ground gives no estimate.
3. ``known_height``: similar triangles generalised to a tilted camera: the two rays through the
   apex pixel and the bottom pixel must hold the points ``p_base + (0, 0, H)`` and
   ``p_base - s b`` (``b`` the horizontal bearing, ``s`` that edge distance); the two ray
   lengths are the least-squares solution of those three linear equations. Needs no ground
   plane. The apex is located from the area of the silhouette's top triangle
   (``vnav.silhouette.apex_pixel``), not from its top-most pixel, which lies several pixels
   below the apex of a thin, distant tip. Refused when ill-conditioned (apex over the base
   plate's image in a steep view, or one pixel moving the estimate by more than 10% of range).
4. ``naive``: the lecture's mistake, camera-frame coordinates added to the drone's position as
   if they were world coordinates, ``p_naive = t_w_b + p_c``.

The kernels run in plain floats or with hand-written statistics for speed; next to each is its
lecture form (``_world_points_reference``, ``_solve_known_height_reference``, ``np.median``
and ``np.percentile`` for ``_median`` and ``_percentile``), and the tests check that the two
agree.
"""

from __future__ import annotations

import enum
import logging
import math

import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera, check_depth_image
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection, check_detection
from vnav.silhouette import SilhouetteView, triangle_fraction

__all__ = [
    "MAX_RANGE_ERROR_PER_PX",
    "MIN_TRIANGLE_FRACTION",
    "NoEstimate",
    "depth_image_from_view",
    "depth_under_mask",
    "estimate_from_depth",
    "estimate_from_ground_plane",
    "estimate_from_known_height",
    "ground_plane_from_view",
    "known_height_from_view",
    "known_height_max_elevation_rad",
    "naive",
    "naive_estimate",
    "solve_known_height",
]

logger = logging.getLogger(__name__)

_MIN_DEPTH_POINTS = 5
"""Fewest valid depth pixels on a cone's body for a depth-image estimate."""


class NoEstimate(enum.Enum):
    """Why a method gave no estimate of a detection: what ``vnav.localize`` reports beside each
    missing estimate (``ConeEstimates.no_estimate``), decided where the estimator refuses.

    ``geometric`` reasons follow from where the cone is in view and how large (the view's
    angle, its size, the image border), not from what the image holds: a method refusing one
    cannot apply to that view by design (docs/ACCURACY.md). ``text`` says it in words, to
    follow a count of detections (``51 seen steeper than 69 deg ...``).
    """

    BORDER = "border"
    NO_DEPTH = "no_depth"
    GROUND_NOT_HIT = "ground_not_hit"
    NADIR = "nadir"
    STEEP = "steep"
    SMALL = "small"
    NO_APEX = "no_apex"
    INCONSISTENT = "inconsistent"
    NO_OTHER_ESTIMATE = "no_other_estimate"
    ONE_IMAGE = "one_image"
    PARALLAX = "parallax"
    FUNCTION_NONE = "function_none"
    FUNCTION_ERROR = "function_error"
    FUNCTION_STOPPED = "function_stopped"

    @property
    def text(self) -> str:
        """The reason in words, e.g. ``seen steeper than 69 deg (the apex over the base plate)``."""
        if self is NoEstimate.STEEP:
            limit_deg = math.degrees(known_height_max_elevation_rad())
            return f"seen steeper than {limit_deg:.0f} deg (the apex over the base plate)"
        if self is NoEstimate.SMALL:
            return (
                f"too small: 1 px moves the estimate by over {MAX_RANGE_ERROR_PER_PX:.0%} of range"
            )
        return _NO_ESTIMATE_TEXT[self]

    @property
    def geometric(self) -> bool:
        """Whether the reason is the view's geometry (the method cannot apply to it)."""
        return self in _GEOMETRIC


_NO_ESTIMATE_TEXT = {
    NoEstimate.BORDER: "cut by the image border",
    NoEstimate.NO_DEPTH: "with too few depth pixels on the cone's body",
    NoEstimate.GROUND_NOT_HIT: "whose ray through the base does not meet the ground",
    NoEstimate.NADIR: "seen from straight above",
    NoEstimate.NO_APEX: "with no apex found in the silhouette",
    NoEstimate.INCONSISTENT: "whose similar triangles do not close",
    NoEstimate.NO_OTHER_ESTIMATE: "with no other estimate to start from",
    NoEstimate.ONE_IMAGE: "from one image (triangulation needs a track over several)",
    NoEstimate.PARALLAX: "whose views do not cross widely enough (too little motion for the noise)",
    NoEstimate.FUNCTION_NONE: "for which the user's function returned None",
    NoEstimate.FUNCTION_ERROR: "where the user's function failed (the report's estimators say how)",
    NoEstimate.FUNCTION_STOPPED: "after the user's function was stopped for its time limit",
}
_GEOMETRIC = frozenset(
    {
        NoEstimate.BORDER,
        NoEstimate.GROUND_NOT_HIT,
        NoEstimate.NADIR,
        NoEstimate.STEEP,
        NoEstimate.SMALL,
        NoEstimate.PARALLAX,
    }
)


def _view_clear_of_border(
    detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray
) -> SilhouetteView | None:
    """Validate a detection and a camera pose; their shared view, or None for a detection
    that touches the image border (no method estimates a cone that may be cut off)."""
    check_detection(detection, camera)
    T_w_c = se3.check_pose(T_w_c, "T_w_c")
    return None if detection.touches_border else SilhouetteView(detection, camera, T_w_c)


def depth_under_mask(detection: ConeDetection, depth: np.ndarray) -> np.ndarray:
    """The (validated) depth image's values over the detection's mask, float64, (area_px,).

    In ``detection.pixels_uv()`` order (row-major over the mask).

    Raises
    ------
    ValueError
        If a depth under the mask is NaN or inf.
    """
    x0, y0, w, h = detection.bbox
    z_c = depth[y0 : y0 + h, x0 : x0 + w][detection.mask].astype(np.float64)
    if not np.isfinite(z_c).all():
        raise ValueError(
            f"depth must be finite under the detection's mask; got {int((~np.isfinite(z_c)).sum())}"
            f" non-finite of {z_c.size} pixels"
        )
    return z_c


# ------------------------------------------------------------------ depth image


def estimate_from_depth(
    detection: ConeDetection,
    depth: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
    far_m: float = np.inf,
) -> np.ndarray | None:
    """Base centre from the depth image over the detection's mask.

    1. Back-project every mask pixel with its planar depth, ``p_w = T_w_c @ p_c`` (pixels with
       depth <= 0 or >= ``far_m`` are dropped; far outliers beyond 2 m of the median depth too).
    2. ``z_base`` = 2nd percentile of the points' heights (the base plate's bottom edge).
    3. Body points (height above ``z_base`` between plate + 2 cm and apex - 3 cm) lie at the
       known radius ``r(h) = r0 (H - h) / (H - t)`` from the axis. Start each at
       ``p_xy + r(h) b_i`` (``b_i`` the horizontal viewing direction), take the median, then
       minimise ``sum_i (|p_xy,i - c| - r_i)^2`` over the axis ``c`` by Gauss-Newton with one
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
    view = _view_clear_of_border(detection, camera, T_w_c)
    check_depth_image(depth, camera)
    z_c = depth_under_mask(detection, depth)  # checked finite even when not used
    return None if view is None else _or_none(depth_image_from_view(view, z_c, cone, far_m))


def _or_none(p_w: np.ndarray | NoEstimate) -> np.ndarray | None:
    """An estimate, or None for a ``NoEstimate`` reason."""
    return None if isinstance(p_w, NoEstimate) else p_w


def _median(a: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D float64 array without NaN (same value, less overhead;
    the tests compare the two)."""
    n = a.size
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, (k - 1, k))
    return (float(part[k - 1]) + float(part[k])) / 2.0


def _percentile(a: np.ndarray, q: float) -> float:
    """``np.percentile(a, q)`` (linear method) of a non-empty 1-D float64 array without NaN
    (same value, less overhead; the tests compare the two)."""
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


def depth_image_from_view(
    view: SilhouetteView, z_c: np.ndarray, cone: ConeModel, far_m: float
) -> np.ndarray | NoEstimate:
    """``estimate_from_depth``'s method on a view its caller has validated: the estimate, or
    why there is none instead of None. ``vnav.localize`` validates a detection once and runs
    every method on one shared view.

    Parameters
    ----------
    view : SilhouetteView
        Of a detection clear of the image border, from a validated pose ``T_w_c``.
    z_c : ndarray, shape (area_px,), float64
        The planar depth under the detection's mask, metres (``depth_under_mask``: finite,
        in ``view.uv()`` order).
    cone : ConeModel
    far_m : float
        Depths at or beyond this are "no return".

    Returns
    -------
    p_w : ndarray, shape (3,), or NoEstimate
        The base centre in the world, metres, or ``NoEstimate.NO_DEPTH``.
    """
    uv = view.uv()
    u, v = uv[:, 0], uv[:, 1]
    valid = (z_c > 0.0) & (z_c < far_m)
    n_valid = int(np.count_nonzero(valid))
    if n_valid < _MIN_DEPTH_POINTS:
        return NoEstimate.NO_DEPTH
    z_v = z_c if n_valid == z_c.size else z_c[valid]
    # Far outliers: one selection for both masks.
    keep = valid
    keep[valid] = np.abs(z_v - _median(z_v)) < 2.0
    n_keep = int(np.count_nonzero(keep))
    if n_keep < _MIN_DEPTH_POINTS:
        return NoEstimate.NO_DEPTH
    if n_keep < z_c.size:
        u, v, z_c = u[keep], v[keep], z_c[keep]
    qx, qy, z_w = _world_points(view, u, v, z_c)
    z_base = _percentile(z_w, 2.0)
    height = z_w - z_base
    t, H, r0 = cone.base_thickness_m, cone.height_m, cone.body_radius_m
    body = (height > t + 0.02) & (height < H - 0.03)
    n_body = int(np.count_nonzero(body))
    if n_body < _MIN_DEPTH_POINTS:
        logger.debug("depth: too few body points (%d)", n_body)
        return NoEstimate.NO_DEPTH
    qx, qy = qx[body], qy[body]
    tx, ty = view.t[0], view.t[1]
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


def _world_points(
    view: SilhouetteView, u: np.ndarray, v: np.ndarray, z_c: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``p_w = T_w_c @ backproject(uv, z_c)`` per coordinate: the x, y, z rows, each (N,).

    Lecture form: ``_world_points_reference``.
    """
    x_c = (u - view.cx) * z_c / view.fx
    y_c = (v - view.cy) * z_c / view.fy
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = view.R
    tx, ty, tz = view.t
    return (
        x_c * r00 + y_c * r01 + z_c * r02 + tx,
        x_c * r10 + y_c * r11 + z_c * r12 + ty,
        x_c * r20 + y_c * r21 + z_c * r22 + tz,
    )


def _world_points_reference(
    camera: PinholeCamera, T_w_c: np.ndarray, uv: np.ndarray, z_c: np.ndarray
) -> np.ndarray:
    """Lecture form of ``_world_points``: ``se3.apply(T_w_c, camera.backproject(uv, z))``,
    (N, 3)."""
    return se3.apply(T_w_c, camera.backproject(uv, z_c))


def _fit_axis(
    qx: np.ndarray, qy: np.ndarray, r: np.ndarray, c0: tuple[float, float]
) -> tuple[float, float] | None:
    """Gauss-Newton for the centre ``c`` of circles of known radii ``r_i`` through points ``q_i``.

    Residual ``e_i = |q_i - c| - r_i``, Jacobian row ``-(q_i - c)^T / |q_i - c|``; each step solves
    the 2x2 normal equations (the rows are unit vectors, so ``J^T J`` is well conditioned
    whenever the points do not all lie in one direction from ``c``). Once, after the 4th step
    or at convergence if that comes first, points whose residual is more than 3 sigma (MAD)
    from the median residual are dropped and the fit goes on with the rest.
    """
    cx, cy = c0
    ux, uy, ur = qx, qy, r
    trimmed = False
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
        converged = math.hypot(step_x, step_y) < 1e-7
        if not trimmed and (it == 3 or converged):
            ax, ay = qx - cx, qy - cy
            e_all = np.sqrt(ax * ax + ay * ay) - r
            dev = np.abs(e_all - _median(e_all))
            mad = 1.4826 * _median(dev)
            use = dev <= max(3.0 * mad, 0.005)
            ux, uy, ur = qx[use], qy[use], r[use]
            trimmed = True
        elif converged:
            break
    return cx, cy


# ------------------------------------------------------------------ ground plane


def estimate_from_ground_plane(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
) -> np.ndarray | None:
    """Base centre from the ray through the blob's bottom pixel meeting the ground z = 0.

    ``g_w = t_w_c + lambda d_w`` with ``lambda = -z_c / d_z`` (``d_w`` the unit ray in the
    world through ``SilhouetteView.bottom``, the base plate's near bottom edge on the cone's
    image axis), then ``p_w = g_w + s b`` with ``b`` the horizontal bearing from the camera and
    ``s`` the mean distance
    from the base centre to that edge (``ConeModel.base_axis_distance_m``).

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the detection touches the image border (the cone may be cut off: its bottom
        may be outside the image), when the camera is not above the ground, or when the ray
        is parallel to the ground or points away from it (``d_z >= -1e-9``).
    """
    view = _view_clear_of_border(detection, camera, T_w_c)
    return None if view is None else _or_none(ground_plane_from_view(view, cone))


def ground_plane_from_view(view: SilhouetteView, cone: ConeModel) -> np.ndarray | NoEstimate:
    """``estimate_from_ground_plane``'s method on a view its caller has validated (a
    detection clear of the image border): the estimate, or why there is none instead of None.

    Returns
    -------
    p_w : ndarray, shape (3,), or NoEstimate
        The base centre in the world, metres (z = 0), or ``NoEstimate.GROUND_NOT_HIT``.
    """
    bottom = view.bottom(cone)
    tx, ty, tz = view.t
    dx, dy, dz = view.ray(float(bottom[0]), float(bottom[1]))
    if tz <= 0.0 or dz >= -1e-9:
        logger.debug("ground plane: ray does not reach the ground (d_z = %.3g)", dz)
        return NoEstimate.GROUND_NOT_HIT
    lam = -tz / dz
    gx, gy = tx + lam * dx, ty + lam * dy
    hx, hy = gx - tx, gy - ty
    norm = math.sqrt(hx * hx + hy * hy)
    if not norm > 1e-9:
        return np.array([gx, gy, 0.0])
    s = cone.base_axis_distance_m
    return np.array([gx + s * (hx / norm), gy + s * (hy / norm), 0.0])


MIN_TRIANGLE_FRACTION = 0.10
"""``estimate_from_known_height`` needs at least this ``triangle_fraction`` of the silhouette (the
apex clear of the base plate's image): up to about 69 deg of elevation for the standard cone."""

MAX_RANGE_ERROR_PER_PX = 0.10
"""``estimate_from_known_height`` gives no estimate when one pixel of error in the apex or the
bottom pixel (along the image vertical) moves it by more than this fraction of its range."""


def known_height_max_elevation_rad(cone: ConeModel = TRAFFIC_CONE) -> float:
    """The steepest line of sight (below the horizontal) at which ``estimate_from_known_height``
    can measure ``cone``: where ``triangle_fraction`` falls to ``MIN_TRIANGLE_FRACTION``.

    ``triangle_fraction(e) = F`` solved for ``e``, with ``k = H - t`` and ``a`` the plate's
    half-width: ``tan e = (k (1 - F) - F t) / (a (1 + 2 F))`` (about 69 deg for the standard
    cone). Steeper views give no estimate (``NoEstimate.STEEP``).
    """
    F, t = MIN_TRIANGLE_FRACTION, cone.base_thickness_m
    k, a = cone.height_m - t, 0.5 * cone.base_width_m
    return math.atan2(k * (1.0 - F) - F * t, a * (1.0 + 2.0 * F))


# ------------------------------------------------------------------ known height


def solve_known_height(
    c_w: tuple[float, float, float],
    a_w: tuple[float, float, float],
    g_w: tuple[float, float, float],
    height_m: float,
    s: float,
) -> tuple[tuple[float, float, float], float, float, float] | None:
    """``known_height``'s similar triangles: the 3x2 least-squares system, in plain floats.

    ``[a, -g] (alpha, gamma)^T = (0, 0, H) + s b`` (``b`` the horizontal unit of ``g``) solved
    by a QR factorisation (Gram-Schmidt on the two columns, as well conditioned as the
    problem: the rays are at least 1e-4 rad apart); ``p_w = c + gamma g + s b``. Shared with
    ``vnav.covariance``, whose Jacobian differentiates this solve. Inputs are not checked.
    Lecture form: ``_solve_known_height_reference`` (``np.linalg.lstsq``).

    Parameters
    ----------
    c_w : tuple of 3 floats
        The camera centre in the world, metres.
    a_w, g_w : tuple of 3 floats
        World rays through the apex and the bottom pixel (unit length; only their directions
        matter to ``p_w``).
    height_m : float
        The cone's height ``H``, metres.
    s : float
        The distance from the base centre to the plate's near edge along ``b``, metres.

    Returns
    -------
    (p_w, alpha, gamma, residual) or None
        ``p_w`` a tuple of 3 floats, metres; ``alpha``, ``gamma`` the ray lengths to the apex
        and the edge point; ``residual`` the least-squares residual's norm, metres. None when
        ``g_w`` is vertical or the two rays are within 1e-4 rad of each other.
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


def _solve_known_height_reference(
    c_w: np.ndarray, a_w: np.ndarray, g_w: np.ndarray, height_m: float, s: float
) -> tuple[np.ndarray, float, float, float]:
    """Lecture form of ``solve_known_height``: ``np.linalg.lstsq`` on the 3x2 system."""
    b = np.array([g_w[0], g_w[1], 0.0]) / math.hypot(g_w[0], g_w[1])
    A = np.column_stack([a_w, -np.asarray(g_w)])
    rhs = np.array([0.0, 0.0, height_m]) + s * b
    (alpha, gamma), *_ = np.linalg.lstsq(A, rhs, rcond=None)
    residual = float(np.linalg.norm(A @ [alpha, gamma] - rhs))
    return np.asarray(c_w) + gamma * np.asarray(g_w) + s * b, float(alpha), float(gamma), residual


def estimate_from_known_height(
    detection: ConeDetection,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cone: ConeModel = TRAFFIC_CONE,
) -> np.ndarray | None:
    """Base centre from the cone's known height and its apparent size (generalised similar
    triangles).

    With ``c = t_w_c``, unit world rays ``a`` (through ``apex_pixel``) and ``g`` (through
    ``SilhouetteView.bottom``, the plate's near bottom edge on the cone's image axis),
    horizontal bearing ``b`` and ``s = ConeModel.base_axis_distance_m``, the apex
    ``c + alpha a`` and the edge point
    ``c + gamma g`` satisfy ``alpha a - gamma g = (0, 0, H) + s b``; ``(alpha, gamma)`` is the
    least-squares solution and ``p_w = c + gamma g + s b``. For a level camera and a distant cone
    this reduces to ``Z = f H / h_px``.

    Conditioning. The estimate is refused (None) when the triangle cannot be measured well:

    - the apex must be clear of the base plate's image:
      ``triangle_fraction(e) >= MIN_TRIANGLE_FRACTION`` at the line of sight's elevation ``e``
      (up to about 69 deg for the standard cone; looking down more steeply the apex projects
      inside the cone's outline and its height is foreshortened onto the plate);
    - one pixel of error in the apex or the bottom pixel, along the image vertical, may move
      the estimate by at most ``MAX_RANGE_ERROR_PER_PX`` of its range (the sensitivity of the
      least-squares solution, by finite differences): a cone only a few pixels tall gives no
      estimate rather than a wrong one.

    Returns
    -------
    p_w : ndarray, shape (3,), or None
        None when the detection touches the image border (apex or base may be cut off), the
        geometry is ill-conditioned (above), the two rays are (nearly) parallel, a ray length
        comes out non-positive or the equations are inconsistent (residual above 25% of H).
    """
    view = _view_clear_of_border(detection, camera, T_w_c)
    return None if view is None else _or_none(known_height_from_view(view, cone))


def known_height_from_view(view: SilhouetteView, cone: ConeModel) -> np.ndarray | NoEstimate:
    """``estimate_from_known_height``'s method on a view its caller has validated (a
    detection clear of the image border): the estimate, or why there is none instead of None.

    Returns
    -------
    p_w : ndarray, shape (3,), or NoEstimate
        The base centre in the world, metres, or the reason: ``NADIR``, ``STEEP``,
        ``NO_APEX``, ``INCONSISTENT`` or ``SMALL`` (``NoEstimate``).
    """
    vertical = view.vertical_at_blob()
    if vertical is None:
        logger.debug("known height: camera looks straight down at the cone")
        return NoEstimate.NADIR
    d, elevation = vertical
    fraction = triangle_fraction(elevation, cone)
    if fraction < MIN_TRIANGLE_FRACTION:
        logger.debug(
            "known height: apex over the base plate (elevation %.1f deg)", math.degrees(elevation)
        )
        return NoEstimate.STEEP
    apex_uv = view.apex(d, fraction)
    if apex_uv is None:
        logger.debug("known height: no apex fit")
        return NoEstimate.NO_APEX
    bottom_uv = view.axis_exit(d, apex_uv)
    c_w = view.t
    s = cone.base_axis_distance_m
    H = cone.height_m
    au, av = float(apex_uv[0]), float(apex_uv[1])
    bu, bv = float(bottom_uv[0]), float(bottom_uv[1])
    d0, d1 = float(d[0]), float(d[1])
    a_w, g_w = view.ray(au, av), view.ray(bu, bv)

    solution = solve_known_height(c_w, a_w, g_w, H, s)
    if solution is None:
        logger.debug("known height: degenerate rays")
        return NoEstimate.INCONSISTENT
    p_w, alpha, gamma, residual = solution
    if alpha <= 0.0 or gamma <= 0.0 or residual > 0.25 * H:
        logger.debug(
            "known height: inconsistent (alpha %.3g, gamma %.3g, res %.3g)", alpha, gamma, residual
        )
        return NoEstimate.INCONSISTENT
    range_m = math.dist(p_w, c_w)
    for moved in (
        solve_known_height(c_w, view.ray(au + d0, av + d1), g_w, H, s),
        solve_known_height(c_w, a_w, view.ray(bu + d0, bv + d1), H, s),
    ):
        shift = math.inf if moved is None else math.dist(moved[0], p_w)
        if shift > MAX_RANGE_ERROR_PER_PX * range_m:
            logger.debug("known height: 1 px moves the estimate %.3g m at %.3g m", shift, range_m)
            return NoEstimate.SMALL
    return np.array(p_w)


# ------------------------------------------------------------------ naive


def naive_estimate(p_c: np.ndarray, T_w_b: np.ndarray) -> np.ndarray:
    """The lecture's mistake (chapter 0): ``t_w_b + p_c``, camera coordinates taken for world
    offsets.

    Parameters
    ----------
    p_c : ndarray, shape (3,)
        The cone in the optical frame, metres.
    T_w_b : ndarray, shape (4, 4)
        Drone pose; only its translation is used, which is the mistake.
    """
    T_w_b = se3.check_pose(T_w_b, "T_w_b")
    p_c = np.asarray(p_c, dtype=np.float64)
    if p_c.shape != (3,):
        raise ValueError(f"p_c must have shape (3,), got {p_c.shape}")
    return naive(p_c, T_w_b[:3, 3])


def naive(p_c: np.ndarray, t_w_b: np.ndarray) -> np.ndarray:
    """``naive_estimate`` without validation: ``t_w_b + p_c``, (3,)."""
    return t_w_b + p_c
