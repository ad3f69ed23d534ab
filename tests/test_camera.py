"""The pinhole camera: intrinsics from fovy, projection against OpenCV, exact inverses."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vnav.camera import PinholeCamera

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
