"""vnav.cone: the cone's shape, its extreme points and how much of it a camera sees, against
independent computations (corners written out by hand, the plate's edge distance integrated
numerically, projection by OpenCV)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from helpers import cone_corners_w
from scipy.integrate import quad

from vnav import frames, se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel, cones_fully_in_view

CAM = PinholeCamera.from_fovy(60.0, 640, 480)


def test_extreme_points_are_the_apex_and_the_plate_corners() -> None:
    p0_w = np.array([3.0, -2.0, 0.0])
    points = TRAFFIC_CONE.extreme_points(p0_w)
    assert points.shape == (9, 3)
    hand = cone_corners_w(p0_w)  # corners first, apex last
    np.testing.assert_allclose(points[0], hand[-1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(points[1:], hand[:-1], rtol=0, atol=1e-15)
    # A cone of another shape, its corners written out.
    cone = ConeModel(height_m=1.0, base_width_m=0.5, base_thickness_m=0.1, body_radius_m=0.2)
    expected = [
        [1.0, 2.0, 1.0],
        [0.75, 1.75, 0.0],
        [0.75, 1.75, 0.1],
        [0.75, 2.25, 0.0],
        [0.75, 2.25, 0.1],
        [1.25, 1.75, 0.0],
        [1.25, 1.75, 0.1],
        [1.25, 2.25, 0.0],
        [1.25, 2.25, 0.1],
    ]
    np.testing.assert_allclose(cone.extreme_points([1.0, 2.0, 0.0]), expected, atol=1e-15)


def test_base_axis_distance_is_the_mean_edge_distance_over_yaw() -> None:
    """The vertical plane through the camera and the axis leaves a square plate of
    half-width a at a / max(|cos psi|, |sin psi|) from the centre; its mean over the plate's
    yaw psi, integrated numerically over a whole turn."""
    for cone in (TRAFFIC_CONE, ConeModel(base_width_m=0.5, body_radius_m=0.2)):
        a = cone.base_width_m / 2.0

        def edge(psi: float, a: float = a) -> float:
            return a / max(abs(math.cos(psi)), abs(math.sin(psi)))

        breaks = [k * math.pi / 4 for k in range(1, 8)]
        mean, _ = quad(edge, 0.0, 2.0 * math.pi, points=breaks, epsabs=1e-14, epsrel=1e-13)
        mean /= 2.0 * math.pi
        assert cone.base_axis_distance_m == pytest.approx(mean, rel=1e-12)
        assert a < cone.base_axis_distance_m < a * math.sqrt(2.0)
    assert TRAFFIC_CONE.base_axis_distance_m == pytest.approx(1.122 * 0.19, abs=1e-4)


def _cv2_fully_in_view(cones_w, camera, T_w_c, min_height_px) -> tuple[list, list]:
    """``cones_fully_in_view`` of the standard cone computed from its hand-written corners
    with cv2.projectPoints (which projects points behind the camera too: those are excluded
    by their depth); also the cones too close to a threshold (1e-6 px) for two
    implementations to be expected to agree."""
    T_c_w = np.linalg.inv(T_w_c)
    rvec, _ = cv2.Rodrigues(T_c_w[:3, :3])
    inside, borderline = [], []
    for i, p0_w in enumerate(cones_w):
        points_w = cone_corners_w(p0_w)
        z_c = points_w @ T_c_w[2, :3] + T_c_w[2, 3]
        uv, _ = cv2.projectPoints(points_w, rvec, T_c_w[:3, 3], camera.K, None)
        uv = uv.reshape(-1, 2)
        margins = np.concatenate(
            [
                uv[:, 0] + 0.5,
                camera.width - 0.5 - uv[:, 0],
                uv[:, 1] + 0.5,
                camera.height - 0.5 - uv[:, 1],
                [np.ptp(uv[:, 1]) - min_height_px],
            ]
        )
        if np.all(z_c > 0.0) and np.any(np.abs(margins) < 1e-6):
            borderline.append(i)
        elif np.all(z_c > 0.0) and np.all(margins[:-1] > 0.0) and margins[-1] >= 0.0:
            inside.append(i)
    return inside, borderline


@pytest.mark.parametrize("seed", range(8))
def test_cones_fully_in_view_matches_cv2_project_points(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pitch = math.radians(rng.uniform(0.0, 80.0))
    R_w_b = so3.from_rpy(*np.radians([rng.uniform(-20, 20), rng.uniform(-20, 20), 0.0]))
    R_w_b = so3.rot_z(rng.uniform(-np.pi, np.pi)) @ R_w_b
    T_w_c = se3.make(R_w_b @ frames.mount_rotation(pitch), [0.0, 0.0, rng.uniform(2.0, 15.0)])
    # Cones where the camera looks (rays through random pixels, some outside the image, meet
    # the ground) and anywhere around, behind the camera included.
    uv = rng.uniform([-80.0, -80.0], [720.0, 560.0], size=(150, 2))
    d_w = CAM.rays(uv) @ T_w_c[:3, :3].T
    down = d_w[:, 2] < -1e-3
    s = -T_w_c[2, 3] / d_w[down, 2]
    seen = T_w_c[:3, 3] + s[:, None] * d_w[down]
    around = np.column_stack([rng.uniform(-40.0, 40.0, (100, 2)), np.zeros(100)])
    cones_w = np.vstack([seen, around])
    cones_w[:, 2] = 0.0
    min_height_px = 12.0
    inside, borderline = _cv2_fully_in_view(cones_w, CAM, T_w_c, min_height_px)
    got = cones_fully_in_view(cones_w, CAM, T_w_c, min_height_px)
    assert got == sorted(got)  # in the order of cones_w
    assert [i for i in got if i not in borderline] == inside
    assert len(borderline) <= 2
    assert 0 < len(inside) < len(cones_w)  # both kinds are there


def test_cones_fully_in_view_by_hand() -> None:
    """A level camera 0.35 m up looking along world x: a cone 5 m ahead is in view (about
    58 px tall), one 5 m behind is not, one far to the side is not, and at 60 m (5 px) it is
    too small."""
    R_w_c = frames.mount_rotation(0.0)  # body = world here
    T_w_c = se3.make(R_w_c, [0.0, 0.0, 0.35])
    cones_w = [[5.0, 0.0, 0.0], [-5.0, 0.0, 0.0], [5.0, 10.0, 0.0], [60.0, 0.0, 0.0]]
    assert cones_fully_in_view(cones_w, CAM, T_w_c, 12.0) == [0]
    assert cones_fully_in_view(cones_w, CAM, T_w_c, 0.0) == [0, 3]
    height_px = CAM.fy * TRAFFIC_CONE.height_m / 5.0  # the apex-to-ground span, near enough
    assert cones_fully_in_view(cones_w[:1], CAM, T_w_c, height_px + 5.0) == []
    assert cones_fully_in_view(np.zeros((0, 3)), CAM, T_w_c, 12.0) == []


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"height_m": 0.0}, r"ConeModel.height_m must be positive"),
        ({"body_radius_m": -0.1}, r"ConeModel.body_radius_m must be positive"),
        ({"base_thickness_m": 0.8}, r"base_thickness_m \(0.8\) must be below height_m"),
        ({"body_radius_m": 0.2}, r"body diameter 0.4 m does not fit on a base plate 0.38 m"),
        ({"color_rgb": (1.0, 0.5)}, r"color_rgb must be 3 values in \[0, 1\]"),
        ({"color_rgb": (1.0, 0.5, 1.5)}, r"color_rgb must be 3 values in \[0, 1\]"),
    ],
)
def test_invalid_cone_raises(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ConeModel(**kwargs)
