"""vnav.camera: intrinsics from fovy, projection against OpenCV, exact inverses, and the depth
image as a world point cloud (``depth_to_world_points``) against the rendered scene's truth."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vnav import se3
from vnav.camera import PinholeCamera, depth_to_world_points
from vnav.cone import TRAFFIC_CONE

CAM = PinholeCamera.from_fovy(60.0, 640, 480)


def test_from_fovy_matches_mujoco_model() -> None:
    f_px = 240.0 / math.tan(math.radians(30.0))
    assert CAM.fx == pytest.approx(f_px, rel=1e-15)
    assert CAM.fy == CAM.fx
    assert (CAM.cx, CAM.cy) == (319.5, 239.5)
    assert (CAM.width, CAM.height) == (640, 480)
    np.testing.assert_array_equal(CAM.K, [[f_px, 0, 319.5], [0, f_px, 239.5], [0, 0, 1]])
    assert CAM.fovy_deg == pytest.approx(60.0, abs=1e-12)


def test_principal_ray_hits_principal_point() -> None:
    np.testing.assert_allclose(CAM.project([0.0, 0.0, 5.0]), [[CAM.cx, CAM.cy]], atol=1e-12)
    np.testing.assert_allclose(CAM.rays([CAM.cx, CAM.cy]), [[0.0, 0.0, 1.0]], atol=1e-15)


def test_image_edges_at_half_fov() -> None:
    # The top edge of the top row (v = -0.5) is at fovy/2 above the axis.
    angle = math.radians(30.0)
    uv = CAM.project([0.0, -math.tan(angle), 1.0])
    np.testing.assert_allclose(uv, [[CAM.cx, -0.5]], atol=1e-9)


def test_project_matches_cv2_project_points() -> None:
    rng = np.random.default_rng(0)
    p_c = rng.uniform([-5, -5, 0.5], [5, 5, 30], size=(500, 3))
    uv_cv, _ = cv2.projectPoints(p_c, np.zeros(3), np.zeros(3), CAM.K, None)
    np.testing.assert_allclose(CAM.project(p_c), uv_cv.reshape(-1, 2), atol=1e-9)


def test_points_behind_camera_give_nan() -> None:
    uv = CAM.project([[1.0, 1.0, 0.0], [1.0, 1.0, -2.0], [1.0, 1.0, 2.0], [np.nan, 0, 1]])
    assert np.isnan(uv[0]).all() and np.isnan(uv[1]).all() and np.isnan(uv[3]).all()
    assert np.isfinite(uv[2]).all()


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-50, 50),
    y=st.floats(-50, 50),
    z=st.floats(0.05, 200),
    fovy=st.floats(5, 170),
)
def test_project_backproject_are_inverses(x: float, y: float, z: float, fovy: float) -> None:
    cam = PinholeCamera.from_fovy(fovy, 320, 240)
    p_c = np.array([x, y, z])
    uv = cam.project(p_c)
    back = cam.backproject(uv, z)
    np.testing.assert_allclose(back[0], p_c, rtol=1e-12, atol=1e-9)
    ray = cam.rays(uv)[0]
    assert np.linalg.norm(ray) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(ray, p_c / np.linalg.norm(p_c), atol=1e-12)


def test_backproject_per_pixel_depth_and_in_image() -> None:
    uv = np.array([[0.0, 0.0], [639.0, 479.0], [-0.6, 10.0], [700.0, 10.0]])
    p_c = CAM.backproject(uv, np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_allclose(p_c[:, 2], [1, 2, 3, 4])
    np.testing.assert_allclose(CAM.project(p_c), uv, atol=1e-12)
    np.testing.assert_array_equal(CAM.in_image(uv), [True, True, False, False])
    assert not CAM.in_image([np.nan, 3.0])[0]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fx": 0.0}, "fx must be a positive finite"),
        ({"fy": float("nan")}, "fy must be a positive finite"),
        ({"cx": float("inf")}, "cx must be finite"),
        ({"width": 0}, "width must be a positive int"),
        ({"height": 480.0}, "height must be a positive int"),
    ],
)
def test_invalid_intrinsics_raise(kwargs: dict, match: str) -> None:
    params = {"fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}
    params.update(kwargs)
    with pytest.raises(ValueError, match=match):
        PinholeCamera(**params)


@pytest.mark.parametrize("fovy", [0.0, 180.0, -10.0, float("nan")])
def test_invalid_fovy_raises(fovy: float) -> None:
    with pytest.raises(ValueError, match="fovy_deg must be in the open interval"):
        PinholeCamera.from_fovy(fovy, 640, 480)


def test_bad_shapes_raise() -> None:
    with pytest.raises(ValueError, match=r"p_c must have shape \(3,\) or \(N, 3\)"):
        CAM.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"uv must have shape \(2,\) or \(N, 2\)"):
        CAM.backproject(np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="depth must be a scalar or have shape"):
        CAM.backproject(np.zeros((3, 2)), np.ones(2))


def test_camera_is_frozen() -> None:
    with pytest.raises(AttributeError):
        CAM.fx = 1.0  # type: ignore[misc]


# ------------------------------------------------------------------ depth_to_world_points


def surface_residual_m(p_k: np.ndarray) -> np.ndarray:
    """Distance-like residual of points (cone frame, base centre origin) to the cone's surface.

    Points at the base plate's height inside its square count 0 distance from the plate; other
    points get their radial distance to the body, ``|r - r(z)|``, metres.
    """
    c = TRAFFIC_CONE
    a, t, H, r0 = c.base_width_m / 2, c.base_thickness_m, c.height_m, c.body_radius_m
    on_plate = (p_k[:, 2] <= t + 2e-3) & (np.abs(p_k[:, :2]) <= a + 2e-3).all(axis=1)
    r_model = r0 * np.clip(H - p_k[:, 2], 0.0, H - t) / (H - t)
    body = np.abs(np.hypot(p_k[:, 0], p_k[:, 1]) - r_model)
    return np.where(on_plate, 0.0, body)


def test_depth_cloud_lies_on_true_surfaces(one_view: dict) -> None:
    world, frame, far_m = one_view["world"], one_view["frame"], one_view["far_m"]
    T_w_c = world.T_w_c
    cloud_w = depth_to_world_points(frame.depth, world.camera, T_w_c, far_m=far_m)
    sky = frame.depth >= far_m
    assert cloud_w.shape == (int((~sky).sum()), 3)
    cone = one_view["detection"].full_mask(frame.depth.shape)[~sky]
    # Ground pixels lie on z = 0 (float32 depth: relative 1e-5 of up to ~300 m).
    ground_z = cloud_w[~cone, 2]
    assert np.abs(ground_z).max() < 0.02
    # Cone pixels lie on the cone's analytic surface.
    p_k = cloud_w[cone] - world.cones_w[0]
    assert np.median(surface_residual_m(p_k)) < 0.003
    # The strided cloud is the subset of pixels.
    sub = depth_to_world_points(frame.depth, world.camera, T_w_c, stride=4, far_m=far_m)
    assert sub.shape[0] == int((frame.depth[::4, ::4] < far_m).sum())


def test_depth_cloud_is_the_back_projection_of_every_valid_pixel(one_view: dict) -> None:
    """``p_w = T_w_c @ backproject(uv, z)`` pixel by pixel, row-major, sky dropped."""
    world, frame, far_m = one_view["world"], one_view["frame"], one_view["far_m"]
    depth = frame.depth.astype(np.float64)
    v, u = np.nonzero(depth < far_m)
    uv = np.column_stack([u, v]).astype(np.float64)
    expected = se3.apply(world.T_w_c, world.camera.backproject(uv, depth[v, u]))
    cloud_w = depth_to_world_points(frame.depth, world.camera, world.T_w_c, far_m=far_m)
    np.testing.assert_allclose(cloud_w, expected, rtol=0, atol=1e-9)


def test_bad_input_raises(one_view: dict) -> None:
    world, frame, detection = one_view["world"], one_view["frame"], one_view["detection"]
    cam = world.camera
    nan_depth = frame.depth.copy()
    x, y, w, h = detection.bbox
    nan_depth[y : y + h, x : x + w] = np.nan
    with pytest.raises(ValueError, match="depth must not contain NaN"):
        depth_to_world_points(nan_depth, cam, world.T_w_c)
    with pytest.raises(ValueError, match="stride must be a positive int"):
        depth_to_world_points(frame.depth, cam, world.T_w_c, stride=0)
