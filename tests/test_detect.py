"""Cone detection: synthetic silhouettes with exact apex/base, rendered scenes, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ORANGE, blank, render_scene, synthetic_cone

from vnav import se3, so3
from vnav.detect import ConeDetection, HsvThresholds, _fit_line, detect_cones


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


def test_fit_line_matches_np_polyfit() -> None:
    """The closed-form regression of the edge fit is what ``np.polyfit(v, u, 1)`` solves."""
    rng = np.random.default_rng(0)
    for n in (3, 4, 10, 60):
        v = np.arange(n) + int(rng.integers(0, 400))
        u = rng.uniform(0, 640) + rng.uniform(-2, 2) * v + rng.normal(0, 0.5, n)
        a, b = _fit_line(v, np.round(u).astype(np.int64))
        slope, intercept = np.polyfit(v, np.round(u), 1)
        assert b == pytest.approx(slope, rel=1e-9, abs=1e-9)
        assert a == pytest.approx(intercept, rel=1e-9, abs=1e-6)
    assert _fit_line(np.array([1, 2]), np.array([3, 4])) is None  # fewer than 3 rows
    assert _fit_line(np.array([5, 5, 6]), np.array([1, 2, 3])) is None  # no spread in v
