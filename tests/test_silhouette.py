"""vnav.silhouette: the image of the vertical, the apex fit, the blob's lower boundary; the
fast kernels against the lecture forms that sit next to them in the library.

``SilhouetteView`` computes rays and image verticals in plain Python floats and
``boundary_from_mask`` reads the cropped mask directly; ``_ray_reference``,
``_vertical_reference`` and ``_boundary_reference`` compute the same with numpy, the way the
lecture writes them. The detections come from ``vnav.detect.detect_cones`` on synthetic and
rendered images, the camera poses are random.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from helpers import blank, random_poses, render_scene, synthetic_cone

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.detect import ConeDetection, detect_cones
from vnav.silhouette import (
    SilhouetteView,
    _boundary_reference,
    _ray_reference,
    _vertical_reference,
    apex_pixel,
    boundary_from_mask,
    triangle_fraction,
)

CAM = PinholeCamera.from_fovy(60.0, 640, 480)


def test_triangle_fraction() -> None:
    assert triangle_fraction(0.0) == pytest.approx(1.0 - 0.0 / 0.70, abs=0.05)
    fractions = [triangle_fraction(np.radians(e)) for e in range(0, 91, 5)]
    assert all(a >= b for a, b in itertools.pairwise(fractions))
    assert triangle_fraction(np.radians(75.0)) == 0.0
    assert triangle_fraction(np.radians(90.0)) == 0.0


@pytest.mark.parametrize("seed", range(6))
def test_apex_pixel_synthetic_thin_tip(seed: int) -> None:
    """A rasterised upright triangle (pixel-centre inclusion) 14-40 px tall, its axis on a pixel
    boundary or at a random phase: the area fit finds the apex to 0.6 px, where the top-most
    covered pixel lies up to 0.5 / slope (about 2 px) below it."""
    rng = np.random.default_rng(seed)
    apex = np.array([rng.choice([320.5, rng.uniform(300.0, 340.0)]), rng.uniform(100.0, 300.0)])
    height = rng.uniform(14.0, 40.0)
    v, u = np.mgrid[0:480, 0:640]
    t = (v - apex[1]) / height
    mask = (t >= 0) & (t <= 1) & (np.abs(u - apex[0]) <= 0.22 * height * t)
    rows, cols = np.nonzero(mask)
    x0, y0 = cols.min(), rows.min()
    crop = mask[y0 : rows.max() + 1, x0 : cols.max() + 1]
    detection = ConeDetection(
        bbox=(int(x0), int(y0), crop.shape[1], crop.shape[0]),
        area_px=int(crop.sum()),
        mask=crop,
        apex_uv=apex,
        base_uv=apex + np.array([0.0, height]),
        centroid_uv=np.array([cols.mean(), rows.mean()]),
        touches_border=False,
        apex_from_edges=False,
    )
    found = apex_pixel(detection, np.array([0.0, 1.0]), fraction=1.0)
    assert found is not None
    np.testing.assert_allclose(found, apex, atol=0.6)


# ------------------------------------------------------- fast kernels against lecture forms


def _synthetic_detections(seed: int) -> list[ConeDetection]:
    """Cones of random size and place; two of them overlap into one non-convex blob."""
    rng = np.random.default_rng(seed)
    image = blank()
    for apex in ((rng.uniform(60, 200), rng.uniform(30, 200)), (rng.uniform(420, 580), 60.0)):
        synthetic_cone(image, apex, rng.uniform(14, 120), half_angle=rng.uniform(0.15, 0.35))
    x = rng.uniform(250, 330)
    synthetic_cone(image, (x, 250.0), 90.0)
    synthetic_cone(image, (x + rng.uniform(25, 45), 270.0), 80.0)  # overlaps: one blob
    return detect_cones(image)


@pytest.fixture(scope="module")
def rendered_detections() -> list[ConeDetection]:
    """Three rendered cones seen from a rolled, pitched drone 3 m up."""
    T_w_b = se3.make(so3.from_rpy(0.15, 0.1, 0.05), [0.0, 0.0, 3.0])
    detections = detect_cones(
        render_scene(((6.0, 1.0, 0.0), (9.0, -2.0, 0.0), (5.0, -1.5, 0.0)), T_w_b)
    )
    assert len(detections) == 3
    return detections


@pytest.mark.parametrize("seed", range(4))
def test_ray_matches_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    (detection, *_) = _synthetic_detections(seed)
    for T_w_c in random_poses(rng, 25):
        view = SilhouetteView(detection, CAM, T_w_c)
        uv = np.vstack(
            [rng.uniform([-100.0, -100.0], [740.0, 580.0], size=(40, 2)), view.uv()[::37]]
        )
        fast = np.array([view.ray(float(u), float(v)) for u, v in uv])
        reference = np.array([_ray_reference(CAM, T_w_c, p) for p in uv])
        np.testing.assert_allclose(fast, reference, atol=1e-14)  # a few ulps of a unit vector
        np.testing.assert_allclose(np.linalg.norm(fast, axis=1), 1.0, atol=1e-14)


@pytest.mark.parametrize("seed", range(4))
def test_vertical_matches_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    (detection, *_) = _synthetic_detections(seed)
    for T_w_c in random_poses(rng, 25):
        view = SilhouetteView(detection, CAM, T_w_c)
        for u, v in rng.uniform([-100.0, -100.0], [740.0, 580.0], size=(40, 2)):
            fast = view.vertical(float(u), float(v))
            reference = _vertical_reference(CAM, T_w_c, np.array([u, v]))
            assert fast is not None and reference is not None
            np.testing.assert_allclose(fast, reference, atol=1e-12)
            assert np.hypot(*fast) == pytest.approx(1.0, abs=1e-14)


def test_vertical_by_hand_level_and_nadir_cameras() -> None:
    """A level camera: straight down the image everywhere. A camera looking straight down:
    towards the principal point (the nadir's image), where it is undefined (None)."""
    detection = _synthetic_detections(0)[0]
    level = se3.make(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [0, 0, 3])
    view = SilhouetteView(detection, CAM, level)
    for u, v in ((0.0, 0.0), (319.5, 239.5), (600.0, 400.0)):
        np.testing.assert_allclose(view.vertical(u, v), [0.0, 1.0], atol=1e-15)
        np.testing.assert_allclose(_vertical_reference(CAM, level, np.array([u, v])), [0.0, 1.0])
    nadir = se3.make(np.diag([1.0, -1.0, -1.0]), [2.0, 3.0, 10.0])  # optical z = world -z
    view = SilhouetteView(detection, CAM, nadir)
    assert view.vertical(CAM.cx, CAM.cy) is None
    assert _vertical_reference(CAM, nadir, np.array([CAM.cx, CAM.cy])) is None
    for u, v in ((100.0, 239.5), (319.5, 50.0), (500.0, 400.0)):
        towards_centre = np.array([CAM.cx - u, CAM.cy - v]) / np.hypot(CAM.cx - u, CAM.cy - v)
        np.testing.assert_allclose(view.vertical(u, v), towards_centre, atol=1e-15)
        np.testing.assert_allclose(
            _vertical_reference(CAM, nadir, np.array([u, v])), towards_centre, atol=1e-15
        )
    # The blob's vertical is undefined too when the nadir's image falls on its centroid: turn
    # the camera so that the ray through the centroid points straight down.
    u0, v0 = detection.centroid_uv
    ray_c = CAM.rays([u0, v0])[0]
    axis = np.cross(ray_c, [0.0, 0.0, 1.0])
    R_c = so3.exp(axis / np.linalg.norm(axis) * np.arccos(ray_c[2]))  # ray_c -> optical z
    centred = se3.make(nadir[:3, :3] @ R_c, nadir[:3, 3])
    np.testing.assert_allclose(centred[:3, :3] @ ray_c, [0.0, 0.0, -1.0], atol=1e-15)
    view = SilhouetteView(detection, CAM, centred)
    assert view.vertical(float(u0), float(v0)) is None
    assert _vertical_reference(CAM, centred, np.array([u0, v0])) is None
    assert view.vertical_at_blob() is None


DIRECTIONS = [
    (0.0, 1.0),  # columns, down
    (0.0, -1.0),  # columns, up
    (0.6, 0.8),  # columns, down
    (-0.6, -0.8),  # columns, up
    (np.sqrt(0.5), np.sqrt(0.5)),  # a tie: columns
    (1.0, 0.0),  # rows, right
    (-1.0, 0.0),  # rows, left
    (0.8, -0.6),  # rows, right
    (-0.8, 0.6),  # rows, left
]


@pytest.mark.parametrize("d", DIRECTIONS, ids=lambda d: f"{d[0]:+.2f},{d[1]:+.2f}")
@pytest.mark.parametrize("seed", range(3))
def test_boundary_from_mask_matches_reference_synthetic(seed: int, d: tuple) -> None:
    detections = _synthetic_detections(seed)
    assert len(detections) == 3
    for detection in detections:
        fast = boundary_from_mask(detection, *d)
        reference = _boundary_reference(detection.pixels_uv(), np.array(d))
        np.testing.assert_array_equal(fast, reference)


@pytest.mark.parametrize("d", DIRECTIONS, ids=lambda d: f"{d[0]:+.2f},{d[1]:+.2f}")
def test_boundary_from_mask_matches_reference_rendered(rendered_detections, d: tuple) -> None:
    for detection in rendered_detections:
        fast = boundary_from_mask(detection, *d)
        reference = _boundary_reference(detection.pixels_uv(), np.array(d))
        np.testing.assert_array_equal(fast, reference)


def test_boundary_from_mask_by_hand() -> None:
    """An L-shaped blob: one point per column (or row), half a pixel beyond the extreme
    pixel centre, sorted along the other axis."""
    mask = np.array([[1, 0, 0], [1, 0, 0], [1, 1, 1]], dtype=bool)
    detection = ConeDetection(
        bbox=(10, 20, 3, 3),
        area_px=5,
        mask=mask,
        apex_uv=np.array([10.0, 20.0]),
        base_uv=np.array([11.0, 22.0]),
        centroid_uv=np.array([10.4, 21.4]),
        touches_border=False,
        apex_from_edges=False,
    )
    expected = {
        (0.0, 1.0): [[10, 22.5], [11, 22.5], [12, 22.5]],
        (0.0, -1.0): [[10, 19.5], [11, 21.5], [12, 21.5]],
        (1.0, 0.0): [[10.5, 20], [10.5, 21], [12.5, 22]],
        (-1.0, 0.0): [[9.5, 20], [9.5, 21], [9.5, 22]],
    }
    for d, points in expected.items():
        np.testing.assert_array_equal(boundary_from_mask(detection, *d), points)
        np.testing.assert_array_equal(
            _boundary_reference(detection.pixels_uv(), np.array(d)), points
        )
