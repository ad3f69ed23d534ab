"""Scenario specifications: TOML keys, units and the start pose they imply."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from scenarios import builtin
from scenarios.cli import main
from scenarios.spec import OrbitFlight, ScenarioError, from_dict, load_toml
from vnav import quat, so3


def _base(**flight) -> dict:
    return {"name": "t", "cones": [{"position_w": [0.0, 0.0, 0.0]}], "flight": flight}


def test_rpy_deg_keyframe_becomes_the_lecture_rotation():
    spec = from_dict(
        _base(
            mode="kinematic",
            keyframes=[
                {"t": 0.0, "position_w": [1.0, 2.0, 3.0], "rpy_deg": [10.0, 90.0, -30.0]},
            ],
        )
    )
    R = quat.to_matrix(spec.flight.keyframes[0].quat_xyzw)
    # R = Rz(yaw) Ry(pitch) Rx(roll), built independently from the elementary rotations.
    expected = so3.rot_z(math.radians(-30)) @ so3.rot_y(math.pi / 2) @ so3.rot_x(math.radians(10))
    assert np.allclose(R, expected, atol=1e-12)
    assert spec.scene.start_position_w == (1.0, 2.0, 3.0)


def test_orbit_mode_start_pose_and_duration():
    spec = from_dict(
        _base(
            mode="orbit",
            center_w=[2.0, 1.0, 0.0],
            radius_m=5.0,
            height_m=3.0,
            period_s=-10.0,
            turns=2.0,
            start_angle_deg=90.0,
            ramp_s=2.0,
        )
    )
    assert isinstance(spec.flight, OrbitFlight)
    assert np.allclose(spec.scene.start_position_w, [2.0, 6.0, 3.0])
    # Heading at the centre from the +y side: yaw = -90 deg.
    R = quat.to_matrix(spec.scene.start_quat_xyzw)
    assert np.allclose(R[:, 0], [0.0, -1.0, 0.0], atol=1e-12)
    assert spec.end_s == pytest.approx(1.0 + 2 * 10.0)


@pytest.mark.parametrize(
    ("flight", "message"),
    [
        (
            {"mode": "orbit", "radius_m": 5.0, "height_m": 3.0, "period_s": 10.0},
            r"flight\.center_w: missing",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": -1.0,
                "height_m": 3.0,
                "period_s": 10.0,
            },
            r"flight\.radius_m: must be > 0",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": 5.0,
                "height_m": 3.0,
                "period_s": 0.2,
            },
            r"flight\.period_s: must be at least 1 s",
        ),
        (
            {
                "mode": "orbit",
                "center_w": [0, 0, 0],
                "radius_m": 5.0,
                "height_m": 3.0,
                "period_s": 10.0,
                "speed": 3,
            },
            r"flight\.speed: unknown key",
        ),
        ({"mode": "controlled", "waypoints": []}, r"flight\.waypoints: must be a non-empty"),
    ],
)
def test_bad_flights_name_the_key(flight, message):
    with pytest.raises(ScenarioError, match=message):
        from_dict(_base(**flight), where="f.toml")


@pytest.mark.parametrize("name", builtin.names())
def test_show_prints_a_file_that_parses_to_the_same_scenario(tmp_path, capsys, name):
    """``vnav-demo show NAME`` output, parsed by tomllib (the independent reader) and by
    load_toml, gives the built-in's own dict and spec back."""
    assert main(["show", name]) == 0
    text = capsys.readouterr().out
    assert tomllib.loads(text) == builtin.REGISTRY[name]()
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    assert load_toml(path) == builtin.load(name)


def test_show_unknown_name_exit_2(capsys):
    assert main(["show", "nope"]) == 2
    assert "unknown scenario 'nope'; valid names: frame-problem" in capsys.readouterr().err
