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

What is left out, and why: the estimators' own small model errors in noise-free images
(``depth_image`` is within about 0.2% of range there, docs/ACCURACY.md), which a covariance
from noise cannot describe; they are covered by a floor of ``DEPTH_FIT_FLOOR`` for
``depth_image`` only, whose errors are otherwise far smaller than its keypoint-free noise.
"""

from __future__ import annotations

import math

import numpy as np

from vnav.camera import PinholeCamera
from vnav.cone import ConeModel
from vnav.estimators import NoEstimate, _known_height, _solve_known_height
from vnav.sensor_noise import SensorNoise, keypoint_cov
from vnav.silhouette import SilhouetteView, triangle_fraction
from vnav.uncertainty import point_from_ground, se3_exp, transform_point

__all__ = [
    "DEPTH_FIT_FLOOR",
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

_PX_STEP = 0.05
"""Pixel step of the central differences of ``known_height_cov``, px (the solve is smooth
over a pixel; 0.05 px keeps the truncation error far below the keypoint noise)."""

_ANGLE_STEP = 1e-5
"""Rotation step of the central differences of ``known_height_cov``, radians."""


KNOWN_HEIGHT_MODEL_STD = 0.02
"""``known_height``'s own error along the bearing without noise, as a fraction of range:
its similar triangles rest on an apex and a bottom edge that the silhouette shows only
approximately (the body's shading, the plate's corners), an error that keypoint noise does
not describe. Measured: RMS 1.9% (orbit) to 3.4% (approach) of range in the noise-free
built-ins, biased away from the camera."""


def _plate_cov(
    p_w: np.ndarray,
    t_w_c: tuple[float, float, float],
    cone: ConeModel,
    model_std_per_m: float = 0.0,
) -> np.ndarray:
    """``(s_std^2 + (k range)^2) b b^T``: the base plate's unknown yaw and a method's own
    error ``k`` per metre of range, along the horizontal bearing ``b``."""
    bx, by = float(p_w[0]) - t_w_c[0], float(p_w[1]) - t_w_c[1]
    norm = math.hypot(bx, by)
    out = np.zeros((3, 3))
    if norm > 1e-9:
        b = np.array([bx / norm, by / norm])
        range_m = math.dist((float(p_w[0]), float(p_w[1]), float(p_w[2])), t_w_c)
        var = cone.base_axis_distance_std_m**2 + (model_std_per_m * range_m) ** 2
        out[:2, :2] = var * np.outer(b, b)
    return out


def ground_plane_cov(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    noise: SensorNoise,
    cone: ConeModel,
) -> np.ndarray:
    """Covariance of ``ground_plane``'s estimate ``p_w``, (3, 3), m^2 (rank 2: z is 0).

    The bottom pixel's covariance and the camera pose through
    ``vnav.uncertainty.point_from_ground``, plus the plate's yaw along the bearing. The step
    ``s b`` from the ground hit to the centre is taken as exact in ``b`` (its Jacobian is
    ``s / range`` of the ground hit's, a few percent).
    """
    vertical = view.vertical_at_blob()
    bottom = view.bottom(cone)
    down = vertical[0] if vertical is not None else np.array([0.0, 1.0])
    _, cov = point_from_ground(
        camera,
        T_w_c,
        bottom,
        cov_uv=keypoint_cov("bottom", noise.pixel_std, down),
        cov_T_w_c=cov_T_w_c,
    )
    return cov + _plate_cov(p_w, view.t, cone)


def _rotated_estimate(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    phi: np.ndarray,
    cone: ConeModel,
) -> np.ndarray:
    """``known_height``'s whole estimate with the camera pose turned by ``exp(phi^)`` (a left
    perturbation): the keypoints move too, since the apex fit and the bottom pixel follow
    the image of the vertical, which the attitude sets."""
    T = se3_exp(np.concatenate([np.zeros(3), phi])) @ T_w_c
    p = _known_height(SilhouetteView(view.detection, camera, T), cone)
    return np.full(3, np.nan) if isinstance(p, NoEstimate) else p


def known_height_cov(
    view: SilhouetteView,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    noise: SensorNoise,
    cone: ConeModel,
) -> np.ndarray:
    """Covariance of ``known_height``'s estimate ``p_w``, (3, 3), m^2.

    The estimate depends on the apex and bottom pixels and on the camera pose; its Jacobian
    by central differences of the same least-squares solve (``_solve_known_height``): four
    pixel coordinates and the three rotation components of a left perturbation of ``T_w_c``
    (a translation ``rho`` moves the camera centre and with it the estimate one to one:
    that block is the identity). Plus the plate's yaw along the bearing.
    """
    vertical = view.vertical_at_blob()
    assert vertical is not None  # known_height gave an estimate: the vertical exists
    d, elevation = vertical
    apex = view.apex(d, triangle_fraction(elevation, cone))
    assert apex is not None
    bottom = view.axis_exit(d, apex)
    H, s = cone.height_m, cone.base_axis_distance_m

    def at(px: list[float]) -> np.ndarray:
        """The same solve as ``estimators._known_height`` for moved keypoints."""
        solution = _solve_known_height(view.t, view.ray(px[0], px[1]), view.ray(px[2], px[3]), H, s)
        return np.full(3, np.nan) if solution is None else np.array(solution[0])

    base = [float(apex[0]), float(apex[1]), float(bottom[0]), float(bottom[1])]
    J_px = np.empty((3, 4))
    for i in range(4):
        hi, lo = list(base), list(base)
        hi[i] += _PX_STEP
        lo[i] -= _PX_STEP
        J_px[:, i] = (at(hi) - at(lo)) / (2.0 * _PX_STEP)
    J_xi = np.empty((3, 6))
    J_xi[:, :3] = np.eye(3)
    for i in range(3):
        phi = np.zeros(3)
        phi[i] = _ANGLE_STEP
        J_xi[:, 3 + i] = (
            _rotated_estimate(view, camera, T_w_c, phi, cone)
            - _rotated_estimate(view, camera, T_w_c, -phi, cone)
        ) / (2.0 * _ANGLE_STEP)
    cov_px = np.zeros((4, 4))
    cov_px[:2, :2] = keypoint_cov("apex", noise.pixel_std, d)
    cov_px[2:, 2:] = keypoint_cov("bottom", noise.pixel_std, d)
    cov = J_px @ cov_px @ J_px.T + J_xi @ cov_T_w_c @ J_xi.T
    if not np.isfinite(cov).all():  # a step left the solvable set: keep the pose's part only
        cov = J_xi[:, :3] @ cov_T_w_c[:3, :3] @ J_xi[:, :3].T
    return cov + _plate_cov(p_w, view.t, cone, KNOWN_HEIGHT_MODEL_STD)


def depth_image_cov(
    T_w_c: np.ndarray,
    cov_T_w_c: np.ndarray,
    p_w: np.ndarray,
    n_points: int,
    noise: SensorNoise,
) -> np.ndarray:
    """Covariance of ``depth_image``'s estimate ``p_w``, (3, 3), m^2.

    In the camera frame, with ``z`` the estimate's depth, ``r`` its range and
    ``s_z = noise.depth_std_at(z)``:

    - the axis (horizontal) is a least-squares fit to ``n_points`` depth pixels whose errors
      lie along their rays, nearly along the horizontal bearing: ``s_z^2 / n_points`` along it;
    - the base height is a low percentile of the points' heights, each off by ``s_z`` times
      the vertical part of its ray, not averaged: ``(s_z sin e)^2`` with ``e`` the elevation;
    - a floor ``DEPTH_FIT_FLOOR`` on every axis;

    then the camera pose through ``vnav.uncertainty.transform_point`` (a pose error moves the
    whole point cloud, and the fit with it, rigidly).
    """
    t_w_c = T_w_c[:3, 3]
    view_w = p_w - t_w_c
    range_m = float(np.linalg.norm(view_w))
    z_c = float(T_w_c[:3, 2] @ view_w)
    s_z = float(noise.depth_std_at(z_c))
    floor = DEPTH_FIT_FLOOR[0] + DEPTH_FIT_FLOOR[1] * range_m
    cov_w = np.diag([floor * floor] * 3)
    horizontal = math.hypot(view_w[0], view_w[1])
    if s_z > 0.0 and range_m > 0.0:
        if horizontal > 1e-9:
            b = np.array([view_w[0], view_w[1]]) / horizontal
            cov_w[:2, :2] += s_z * s_z / max(n_points, 1) * np.outer(b, b)
        sin_e = abs(float(view_w[2])) / range_m
        cov_w[2, 2] += (s_z * sin_e) ** 2
    R_c_w = T_w_c[:3, :3].T
    p_c = R_c_w @ view_w
    _, cov = transform_point(T_w_c, cov_T_w_c, p_c, R_c_w @ cov_w @ R_c_w.T)
    return cov


def naive_cov(
    T_w_b: np.ndarray,
    cov_T_w_b: np.ndarray,
    R_c_w: np.ndarray,
    cov_best_w: np.ndarray,
) -> np.ndarray:
    """Covariance of the naive estimate ``t_w_b + p_c``, (3, 3), m^2: the body position's
    (``[I, -t^]`` of the left perturbation) plus the best estimate's, turned into camera
    axes. Reported for completeness: the naive estimate's error is its mistake, not noise."""
    # The body origin's covariance: p_b = 0 through the body pose.
    _, cov_t_w_b = transform_point(T_w_b, cov_T_w_b, np.zeros(3), np.zeros((3, 3)))
    return cov_t_w_b + R_c_w @ cov_best_w @ R_c_w.T
