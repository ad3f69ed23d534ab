"""The covariance of each method's estimate of a cone's base centre, first order.

Every estimate is ``p_w = f(keypoints or depth, T_w_c)`` through the lecture's chain
``p_w = T_w_b @ T_b_c @ p_c``; its covariance is the sum of independent contributions pushed
through ``f``'s Jacobians (Barfoot & Furgale 2014, first order):

- **the camera pose** ``T_w_c = T_w_b @ T_b_c``, a left-perturbation covariance composed from
  the pose stream's and the declared mount's (``vnav.uncertainty.compose``);
- **the keypoints** of the silhouette (``vnav.sensor_noise.keypoint_cov``: its quantisation and
  the image noise) for the methods that use them;
- **the depth noise** for ``depth_image`` (averaged over the cone's body for the axis, not for
  the base height, which is a low percentile of few points);
- **the cone's base plate**: a square at an unknown yaw, so the step from its near edge to its
  centre along the bearing is uncertain by ``ConeModel.base_axis_distance_std_m``.

Last, each method's own error in noise-free images, which no noise describes: a floor
``DEPTH_FIT_FLOOR`` for ``depth_image`` (within about 0.2% of range, docs/ACCURACY.md),
``GROUND_PLANE_MODEL_STD`` and ``KNOWN_HEIGHT_MODEL_STD`` for the others, measured on the
noise-free built-ins.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from vnav.camera import PinholeCamera
from vnav.cone import ConeModel
from vnav.estimators import solve_known_height
from vnav.noise_model import NoiseModel
from vnav.sensor_noise import keypoint_cov
from vnav.silhouette import SilhouetteView, triangle_fraction
from vnav.uncertainty import point_from_ground_unchecked, point_jacobian

__all__ = [
    "DEPTH_FIT_FLOOR",
    "GROUND_PLANE_MODEL_STD",
    "KNOWN_HEIGHT_MODEL_STD",
    "depth_image_cov",
    "ground_plane_cov",
    "known_height_cov",
    "naive_cov",
]

DEPTH_FIT_FLOOR = (0.003, 0.001)
"""``depth_image``'s error floor per axis without noise, ``(metres, fraction of range)``:
``sigma = 0.003 + 0.001 * range``. Measured: the noise-free built-ins give an RMS error of
0.12-0.25% of range over all three axes (``python -m benchmarks`` does not measure this; see
``tests/test_covariance.py``)."""


GROUND_PLANE_MODEL_STD = 0.0025
"""``ground_plane``'s own error without noise in each horizontal direction, as a fraction of
range: the bottom pixel is found on the image of the cone's axis through the fitted apex,
which at steep lines of sight (the apex over the plate's image) places it off the plane of
the camera and the axis, an error across the bearing that the keypoint figures, measured at
shallower views, do not describe. Measured: RMS 0.25% of range (2.8 cm at 11 m) in the
noise-free ``frame-problem``, looking down at 60-70 deg; at most that elsewhere."""

KNOWN_HEIGHT_MODEL_STD = 0.02
"""``known_height``'s own error along the bearing without noise, as a fraction of range:
its similar triangles rest on an apex and a bottom edge that the silhouette shows only
approximately (the body's shading, the plate's corners), an error that keypoint noise does
not describe. Measured: RMS 1.9% (orbit) to 3.4% (approach) of range in the noise-free
built-ins, biased away from the camera."""


def _add_plate(
    cov: np.ndarray,
    p_w: np.ndarray,
    t_w_c: tuple[float, float, float],
    cone: ConeModel,
    model_std_per_m: float = 0.0,
) -> np.ndarray:
    """``cov`` plus ``(s_std^2 + (k range)^2) b b^T``, in place: the base plate's unknown yaw
    and a method's own error ``k`` per metre of range, along the horizontal bearing ``b``."""
    x, y, z = (float(p_w[i]) - t_w_c[i] for i in range(3))
    norm = math.hypot(x, y)
    if norm > 1e-9:
        bx, by = x / norm, y / norm
        var = cone.base_axis_distance_std_m**2 + model_std_per_m**2 * (norm * norm + z * z)
        cov[0, 0] += var * bx * bx
        cov[0, 1] += var * bx * by
        cov[1, 0] += var * bx * by
        cov[1, 1] += var * by * by
    return cov


def ground_plane_cov(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    noise: NoiseModel,
    cone: ConeModel,
) -> np.ndarray:
    """Covariance of ``ground_plane``'s estimate ``p_w``, (3, 3), m^2 (rank 2: z is 0).

    The bottom pixel's covariance and the camera pose through
    ``vnav.uncertainty.point_from_ground``, plus the plate's yaw along the bearing and the
    method's own error ``GROUND_PLANE_MODEL_STD`` in x and y. The step
    ``s b`` from the ground hit to the centre is taken as exact in ``b`` (its Jacobian is
    ``s / range`` of the ground hit's, a few percent).
    """
    vertical = view.vertical_at_blob()
    bottom = view.bottom(cone)
    down = vertical[0] if vertical is not None else np.array([0.0, 1.0])
    _, cov = point_from_ground_unchecked(
        camera,
        T_w_c,
        float(bottom[0]),
        float(bottom[1]),
        keypoint_cov("bottom", noise.intensity_std_grey, down),
        cov_T_w_c,
    )
    cov = _add_plate(cov, p_w, view.t, cone)
    model_var = (GROUND_PLANE_MODEL_STD * math.dist(p_w.tolist(), view.t)) ** 2
    cov[0, 0] += model_var
    cov[1, 1] += model_var
    return cov


def known_height_cov(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    noise: NoiseModel,
    cone: ConeModel,
) -> np.ndarray:
    """Covariance of ``known_height``'s estimate ``p_w``, (3, 3), m^2.

    ``J Sigma J^T`` over the inputs ``[apex (u, v), bottom (u, v), xi]`` (``xi = [rho, phi]``
    the left perturbation of ``T_w_c``), with ``Sigma`` block-diagonal (``keypoint_cov`` and
    ``cov_T_w_c``) and ``J`` from ``_known_height_jacobian``. Plus the plate's yaw and the
    method's own error (``KNOWN_HEIGHT_MODEL_STD``) along the bearing.
    """
    vertical = view.vertical_at_blob()
    assert vertical is not None  # known_height gave an estimate: the vertical exists
    d, elevation = vertical
    apex = view.apex(d, triangle_fraction(elevation, cone))
    assert apex is not None
    bottom = view.axis_exit(d, apex)
    J = _known_height_jacobian(view, camera, T_w_c, apex, bottom, cone)
    S = np.zeros((10, 10))
    S[:2, :2] = keypoint_cov("apex", noise.intensity_std_grey, d)
    S[2:4, 2:4] = keypoint_cov("bottom", noise.intensity_std_grey, d)
    S[4:, 4:] = cov_T_w_c
    return _add_plate(J @ S @ J.T, p_w, view.t, cone, KNOWN_HEIGHT_MODEL_STD)


def _known_height_jacobian(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    apex: np.ndarray,
    bottom: np.ndarray,
    cone: ConeModel,
) -> np.ndarray:
    """``d p_w / d[apex (u, v), bottom (u, v), rho, phi]`` of ``solve_known_height``, (3, 10).

    The derivatives with respect to the two rays (``_known_height_ray_jacobian``), carried to
    the pixels and to a left perturbation of ``T_w_c`` (``_known_height_pixel_pose_jacobian``).
    (``tests/test_covariance.py`` checks this against central differences of the solve.)

    The keypoints are held where the image puts them: they also follow the image of the
    vertical, which the believed attitude sets, but the apex is a tip and the bottom pixel
    lies on the axis through it, a second-order effect (re-running the whole estimator on
    turned poses gave the same Jacobian to 3 digits, except where a step moved a pixel across
    the apex fit's window: a jump, not a slope).
    """
    H, s = cone.height_m, cone.base_axis_distance_m
    a_t = view.ray(float(apex[0]), float(apex[1]))
    g_t = view.ray(float(bottom[0]), float(bottom[1]))
    solution = solve_known_height(view.t, a_t, g_t, H, s)
    assert solution is not None  # the estimator solved these same rays
    _, alpha, gamma, _ = solution
    k_a, J_g = _known_height_ray_jacobian(a_t, g_t, alpha, gamma, H, s)
    return _known_height_pixel_pose_jacobian(
        camera, T_w_c, view.t, a_t, g_t, apex, bottom, k_a, J_g
    )


def _known_height_ray_jacobian(
    a: np.ndarray, g: np.ndarray, alpha: float, gamma: float, H: float, s: float
) -> tuple[list[float], list[list[float]]]:
    """The known-height point's derivatives with respect to its apex ray and its bottom ray.

    The solve is the least-squares ``A x = r`` with ``A = [a, -g]``, ``x = (alpha, gamma)``,
    ``r = (0, 0, H) + s b`` and ``p = c + gamma g + s b``, ``b`` the horizontal unit of ``g``.
    Differentiating the normal equations ``N x = A^T r`` (``N = A^T A``, residual
    ``e = A x - r``): ``N dx = -dA^T e + A^T (dr - dA x)``. Only ``gamma`` enters ``p``:

    - ``da``: ``d gamma = k_a . da``, ``k_a = (alpha (a.a) g - (a.g)(e + alpha a)) / det N``,
      so ``dp/da = g k_a^T`` (and ``k_a . a = 0``: the ray's length does not matter);
    - ``dg``: with ``s D = s (I - b b^T) / |g_h|`` on the horizontal block (``db = D dg``,
      ``D g = 0``), ``k_g = ((a.g)(s D a + gamma a) + (a.a)(e - gamma g)) / det N`` and
      ``dp/dg = g k_g^T + gamma I + s D``.

    Parameters
    ----------
    a, g : np.ndarray, shape (3,)
        The apex's and the bottom's unit rays, world frame.
    alpha, gamma : float
        The solve's lengths along ``a`` and ``g``, metres.
    H, s : float
        The cone's height and the distance of its base's bottom point from its axis, metres.

    Returns
    -------
    k_a : list of float, 3 items
        ``d gamma / da``: ``dp/da = g k_a^T``.
    J_g : list of 3 lists of 3 floats
        ``dp/dg``, row major.
    """
    # In plain floats: some 200 operations, where numpy would pay its per-call cost on ~30
    # arrays of 3 to 9 numbers.
    norm_h = math.hypot(g[0], g[1])
    bx, by = g[0] / norm_h, g[1] / norm_h
    r = (s * bx, s * by, H)
    e = [alpha * a[i] - gamma * g[i] - r[i] for i in range(3)]
    aa, ag, gg = _dot(a, a), _dot(a, g), _dot(g, g)
    det = aa * gg - ag * ag
    k_a = [(alpha * aa * g[i] - ag * (e[i] + alpha * a[i])) / det for i in range(3)]
    k = s / norm_h
    sD = ((k * (1.0 - bx * bx), -k * bx * by, 0.0), (-k * bx * by, k * (1.0 - by * by), 0.0))
    sDa = (_dot(sD[0], a), _dot(sD[1], a), 0.0)
    k_g = [(ag * (sDa[i] + gamma * a[i]) + aa * (e[i] - gamma * g[i])) / det for i in range(3)]
    J_g = [[g[i] * k_g[j] + (gamma if i == j else 0.0) for j in range(3)] for i in range(3)]
    for i in range(2):
        for j in range(2):
            J_g[i][j] += sD[i][j]
    return k_a, J_g


def _known_height_pixel_pose_jacobian(
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    c: np.ndarray,
    a: np.ndarray,
    g: np.ndarray,
    apex: np.ndarray,
    bottom: np.ndarray,
    k_a: list[float],
    J_g: list[list[float]],
) -> np.ndarray:
    """The rays' derivatives carried to the two pixels and to a perturbation of ``T_w_c``.

    A pixel: ``a = r / |r|`` with ``r = R_w_c K^-1 [u, v, 1]`` and ``p`` independent of a
    ray's length, so ``dp/d(u, v) = J_a [r_0 / fx, r_1 / fy] / |r|`` (``r_i`` the columns of
    ``R_w_c``); a left perturbation of ``T_w_c``: ``c -> c + rho + phi x c``,
    ``a -> a + phi x a``, ``g -> g + phi x g``, so ``dp/drho = I`` and
    ``dp/dphi = -(c^ + J_a a^ + J_g g^)``.

    Parameters
    ----------
    camera, T_w_c : PinholeCamera, np.ndarray of shape (4, 4)
        The camera and its believed pose.
    c, a, g : np.ndarray, shape (3,)
        The camera's centre (metres), the apex's and the bottom's unit rays, world frame.
    apex, bottom : np.ndarray, shape (2,)
        The two keypoints, pixels.
    k_a, J_g : list
        The rays' derivatives (``_known_height_ray_jacobian``).

    Returns
    -------
    np.ndarray, shape (3, 10)
        ``d p_w / d[apex (u, v), bottom (u, v), rho, phi]``.
    """
    # The unit ray a = r / |r| of r = R_w_c K^-1 [u, v, 1]: p does not depend on a ray's
    # length, so dp/dr = (dp/da) / |r|.
    col_u, col_v = _pixel_ray_steps(camera, T_w_c)
    n_a, n_b = _pixel_ray_length(camera, apex), _pixel_ray_length(camera, bottom)
    apex_u, apex_v = _dot(k_a, col_u) / n_a, _dot(k_a, col_v) / n_a
    k_a_x_a = _cross(k_a, a)
    skew_c = ((0.0, -c[2], c[1]), (c[2], 0.0, -c[0]), (-c[1], c[0], 0.0))
    rows = []
    for i in range(3):
        row_g = J_g[i]
        # Row i of J_a a^ + J_g g^: (row of J) x (its ray), as r^T v^ = (r x v)^T.
        turn = _cross(row_g, g)
        rows.append(
            [
                g[i] * apex_u,
                g[i] * apex_v,
                _dot(row_g, col_u) / n_b,
                _dot(row_g, col_v) / n_b,
                1.0 if i == 0 else 0.0,
                1.0 if i == 1 else 0.0,
                1.0 if i == 2 else 0.0,
            ]
            + [-(skew_c[i][j] + g[i] * k_a_x_a[j] + turn[j]) for j in range(3)]
        )
    return np.array(rows)


def _pixel_ray_steps(
    camera: PinholeCamera, T_w_c: np.ndarray
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """How a pixel's ray ``r = R_w_c K^-1 [u, v, 1]`` moves per pixel in u and in v.

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : np.ndarray, shape (4, 4)
        The camera's pose.

    Returns
    -------
    col_u, col_v : tuple of 3 floats
        ``dr/du = r_0 / fx`` and ``dr/dv = r_1 / fy`` (``r_i`` the columns of ``R_w_c``),
        world frame.
    """
    (r00, r01, _, _), (r10, r11, _, _), (r20, r21, _, _), _ = T_w_c.tolist()
    col_u = (r00 / camera.fx, r10 / camera.fx, r20 / camera.fx)
    col_v = (r01 / camera.fy, r11 / camera.fy, r21 / camera.fy)
    return col_u, col_v


def _dot(x: Sequence[float], y: Sequence[float]) -> float:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def _cross(x: Sequence[float], y: Sequence[float]) -> tuple[float, float, float]:
    return (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])


def _pixel_ray_length(camera: PinholeCamera, uv: np.ndarray) -> float:
    """``|K^-1 [u, v, 1]|``."""
    x, y = (float(uv[0]) - camera.cx) / camera.fx, (float(uv[1]) - camera.cy) / camera.fy
    return math.sqrt(x * x + y * y + 1.0)


def depth_image_cov(
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    n_points: int,
    noise: NoiseModel,
) -> np.ndarray:
    """Covariance of ``depth_image``'s estimate ``p_w``, (3, 3), m^2.

    With ``z`` the estimate's planar depth, ``r`` its range and ``s_z = noise.depth_std_at(z)``:

    - the axis (horizontal) is a least-squares fit to ``n_points`` depth pixels:
      ``s_z^2 / n_points`` in each horizontal direction (the pixels' errors lie along their
      rays, but the fit of the visible arc moves across the bearing about as much as along
      it: Monte Carlo in ``tests/test_covariance.py``);
    - the base height is a low percentile of the points' heights, each off by ``s_z`` times
      the vertical part of its ray, not averaged: ``(s_z sin e)^2`` with ``e`` the elevation;
    - a floor ``DEPTH_FIT_FLOOR`` on every axis;

    then the camera pose as ``vnav.uncertainty.transform_point`` adds it (a pose error moves the
    whole point cloud, and the fit with it, rigidly).
    """
    (_, _, r02, tx), (_, _, r12, ty), (_, _, r22, tz), _ = T_w_c.tolist()
    px, py, pz = p_w.tolist()
    x, y, z = px - tx, py - ty, pz - tz
    range_m = math.sqrt(x * x + y * y + z * z)
    s_z = float(noise.depth_std_at(r02 * x + r12 * y + r22 * z))
    floor = DEPTH_FIT_FLOOR[0] + DEPTH_FIT_FLOOR[1] * range_m
    f2 = floor * floor
    var_h = var_z = 0.0
    if s_z > 0.0 and range_m > 0.0:
        var_z = (s_z * z / range_m) ** 2
        var_h = s_z * s_z / max(n_points, 1)
    # The fit's world covariance, then the pose as transform_point adds it, with the point's
    # own covariance already in world axes.
    G = point_jacobian((px, py, pz))
    fit = np.array([[f2 + var_h, 0.0, 0.0], [0.0, f2 + var_h, 0.0], [0.0, 0.0, f2 + var_z]])
    return fit + G @ cov_T_w_c @ G.T


def naive_cov(
    T_w_b: np.ndarray,
    cov_T_w_b: np.ndarray,
    R_c_w: np.ndarray,
    cov_best_w: np.ndarray,
) -> np.ndarray:
    """Covariance of the naive estimate ``t_w_b + p_c``, (3, 3), m^2: the body position's
    (``[I, -t^]`` of the left perturbation) plus the best estimate's, turned into camera
    axes. Reported for completeness: the naive estimate's error is its mistake, not noise."""
    G = point_jacobian(T_w_b[:3, 3].tolist())  # the body origin through the body pose
    return G @ cov_T_w_b @ G.T + R_c_w @ cov_best_w @ R_c_w.T
