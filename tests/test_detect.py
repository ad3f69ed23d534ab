"""Cone detection: synthetic silhouettes with exact apex/base, rendered scenes, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from sim.config import SceneConfig
from sim.render import Renderer
from sim.world import World
from vnav import se3, so3
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection, HsvThresholds, detect_cones

ORANGE = np.array([round(255 * c) for c in TRAFFIC_CONE.color_rgb], dtype=np.uint8)
BACKGROUND = np.array([90, 110, 80], dtype=np.uint8)


def synthetic_cone(
    image: np.ndarray, apex_uv: tuple[float, float], height_px: float, half_angle: float = 0.22
) -> None:
    """Paint an upright triangle (apex at `apex_uv`, base `height_px` below) by pixel-centre
    inclusion, the rasterisation rule of OpenGL."""
    v, u = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    t = (v - apex_uv[1]) / height_px
    inside = (t >= 0) & (t <= 1) & (np.abs(u - apex_uv[0]) <= half_angle * height_px * t)
    image[inside] = ORANGE


def blank() -> np.ndarray:
    return np.tile(BACKGROUND, (480, 640, 1))


def test_empty_scene_gives_empty_list() -> None:
    assert detect_cones(blank()) == []


@pytest.mark.parametrize("seed", range(10))
def test_synthetic_apex_and_base_subpixel(seed: int) -> None:
    rng = np.random.default_rng(seed)
    image = blank()
    apex = (rng.uniform(50, 590), rng.uniform(20, 380))
    height = rng.uniform(14, 90)
    synthetic_cone(image, apex, height)
    (d,) = detect_cones(image)
    assert d.apex_from_edges
    np.testing.assert_allclose(d.apex_uv, apex, atol=1.5)  # a 14 px cone: few edge rows
    np.testing.assert_allclose(d.base_uv, (apex[0], apex[1] + height), atol=0.8)
    assert not d.touches_border
    assert d.area_px == int(d.mask.sum())
    assert d.mask.shape == (d.bbox[3], d.bbox[2])
    full = d.full_mask(image.shape)
    assert full.sum() == d.area_px
    np.testing.assert_allclose(d.pixels_uv().mean(axis=0), d.centroid_uv, atol=1e-9)


def test_several_cones_and_noise() -> None:
    image = blank()
    for apex in ((100.0, 100.0), (300.0, 200.0), (500.0, 300.0)):
        synthetic_cone(image, apex, 40.0)
    image[10:12, 600:602] = ORANGE  # 4 px speck: below min_area_px
    detections = detect_cones(image)
    assert len(detections) == 3
    apexes = sorted(tuple(np.round(d.apex_uv)) for d in detections)
    assert apexes == [(100.0, 100.0), (300.0, 200.0), (500.0, 300.0)]


def test_border_flag() -> None:
    image = blank()
    synthetic_cone(image, (5.0, 440.0), 60.0)
    (d,) = detect_cones(image)
    assert d.touches_border


def render_scene(cones_w: tuple, T_w_b: np.ndarray) -> np.ndarray:
    world = World.from_config(SceneConfig(cones_w=cones_w))
    world.set_pose(T_w_b)
    with Renderer(world) as renderer:
        return renderer.render(depth=False).rgb


def test_rendered_scene_with_three_cones() -> None:
    cones_w = ((6.0, 1.0, 0.0), (9.0, -2.0, 0.0), (14.0, 3.0, 0.0))
    rgb = render_scene(cones_w, se3.make(np.eye(3), [0.0, 0.0, 3.0]))
    detections = detect_cones(rgb)
    assert len(detections) == 3
    assert all(isinstance(d, ConeDetection) and not d.touches_border for d in detections)


def test_rendered_scene_looking_away_gives_nothing() -> None:
    rgb = render_scene(((6.0, 1.0, 0.0),), se3.make(so3.rot_z(np.pi), [0.0, 0.0, 3.0]))
    assert detect_cones(rgb) == []


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (np.zeros((480, 640, 3), dtype=np.float32), "rgb must have dtype uint8"),
        (np.zeros((480, 640), dtype=np.uint8), r"rgb must have shape \(H, W, 3\)"),
        (np.zeros((480, 640, 4), dtype=np.uint8), r"rgb must have shape \(H, W, 3\)"),
        (np.zeros((0, 640, 3), dtype=np.uint8), "rgb is empty"),
        ([[[0, 0, 0]]], "rgb must be a numpy array"),
    ],
)
def test_bad_images_raise(image: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        detect_cones(image)


def test_bad_parameters_raise() -> None:
    with pytest.raises(ValueError, match="min_area_px must be >= 1"):
        detect_cones(blank(), min_area_px=0)
    with pytest.raises(ValueError, match="h_min <= h_max"):
        HsvThresholds(h_min=30, h_max=10)
