"""Scene configuration rejects nonsense with a ValueError naming the field."""

from __future__ import annotations

import math

import pytest

from sim.config import CameraConfig, SceneConfig


def test_defaults_are_the_documented_scene() -> None:
    cfg = SceneConfig()
    assert cfg.camera == CameraConfig((0.15, 0.0, 0.05), 30.0, 60.0, 640, 480)
    assert cfg.cones_w == ((6.0, 1.0, 0.0),)
    assert cfg.start_position_w == (0.0, 0.0, 10.0)
    assert cfg.start_quat_xyzw == (0.0, 0.0, 0.0, 1.0)
    assert cfg.timestep_s == 0.005  # 200 Hz: the pose stream's default rate
    assert cfg.render_quality == "fast"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"width": -640}, "width"),
        ({"width": 0}, "width"),
        ({"height": -1}, "height"),
        ({"width": 640.5}, "width"),
        ({"fovy_deg": 0.0}, "fovy_deg"),
        ({"fovy_deg": 180.0}, "fovy_deg"),
        ({"fovy_deg": 1e-300}, r"fovy_deg must be in \[1, 170\] degrees, got 1e-300"),
        ({"fovy_deg": 0.999}, "fovy_deg"),
        ({"fovy_deg": 170.001}, "fovy_deg"),
        ({"fovy_deg": 179.99999999999997}, "fovy_deg"),
        ({"fovy_deg": -30.0}, "fovy_deg"),
        ({"fovy_deg": math.nan}, "fovy_deg"),
        ({"pitch_down_deg": 91.0}, "pitch_down_deg"),
        ({"position_b": (0.0, 0.0)}, "position_b"),
        ({"position_b": (0.0, math.inf, 0.0)}, "position_b"),
    ],
)
def test_camera_config_rejects_nonsense(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        CameraConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cones_w": ((5.0, 0.0, -0.1),)}, "under the ground"),
        ({"cones_w": ((5.0, 0.0, 0.3),)}, "above the ground"),
        ({"cones_w": ((5.0, 0.0),)}, r"cones_w\[0\]"),
        ({"cones_w": ((1.0, 0.0, 0.0), (2.0, math.nan, 0.0))}, r"cones_w\[1\]"),
        ({"start_quat_xyzw": (0.0, 0.0, 0.0, 2.0)}, "start_quat_xyzw"),
        ({"start_position_w": (0.0, 0.0, math.nan)}, "start_position_w"),
        ({"timestep_s": -0.01}, "timestep_s"),
        ({"timestep_s": 0.0}, "timestep_s"),
        ({"render_quality": "ultra"}, "render_quality"),
        ({"camera": "front"}, "camera"),
        ({"znear_m": 0.0}, "znear_m"),
        ({"znear_m": 10.0, "zfar_m": 5.0}, "znear_m"),
        ({"ground_size_m": -1.0}, "ground_size_m"),
        ({"ground_size_m": 500.0}, "zfar_m"),
    ],
)
def test_scene_config_rejects_nonsense(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SceneConfig(**kwargs)


def test_unknown_names_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"unknown SceneConfig field\(s\) \['cones'\]"):
        SceneConfig.from_dict({"cones": [[1.0, 0.0, 0.0]]})
    with pytest.raises(ValueError, match=r"unknown CameraConfig field\(s\) \['fov'\]"):
        SceneConfig.from_dict({"camera": {"fov": 60.0}})


def test_from_dict_builds_nested_config() -> None:
    cfg = SceneConfig.from_dict(
        {"camera": {"fovy_deg": 75, "width": 320, "height": 240}, "cones_w": [[3, 1, 0]]}
    )
    assert cfg.camera.fovy_deg == 75.0
    assert cfg.camera.width == 320
    assert cfg.cones_w == ((3.0, 1.0, 0.0),)
