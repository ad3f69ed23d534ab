"""``[camera.mount_error]``: the simulator renders through the true mount, the estimator is told
the declared one (``sim.config.MountError``, ``scenarios.scenario.spec``,
``scenarios.run.runner``)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers import mujoco_T_w_c

from scenarios import pipeline
from scenarios.scenario import builtin
from scenarios.scenario.spec import ScenarioError, from_dict
from sim.config import CameraConfig, MountError, SceneConfig
from sim.world import World
from vnav import se3, so3

ERROR = {"position_m": [0.01, -0.02, 0.03], "rpy_deg": [2.0, -3.0, 1.5]}


def test_mount_error_is_the_camera_frame_transform_it_names() -> None:
    """``E = make(Rz Ry Rx, t)`` from the table by hand, and ``T_b_c = T_b_c_declared @ E``."""
    cfg = CameraConfig(mount_error=ERROR)
    roll, pitch, yaw = np.radians(ERROR["rpy_deg"])
    E = se3.make(so3.rot_z(yaw) @ so3.rot_y(pitch) @ so3.rot_x(roll), ERROR["position_m"])
    np.testing.assert_allclose(cfg.mount_error.T, E, atol=1e-15)
    np.testing.assert_allclose(cfg.T_b_c, cfg.T_b_c_declared @ E, atol=1e-15)
    np.testing.assert_array_equal(CameraConfig().T_b_c, CameraConfig().T_b_c_declared)


def test_mujoco_renders_through_the_true_mount() -> None:
    """MuJoCo's own camera pose (cam_xpos, cam_xmat) is ``T_w_b @ T_b_c_declared @ E``, also
    after the camera slides on the body."""
    world = World.from_config(SceneConfig(camera=CameraConfig(mount_error=ERROR)))
    world.set_pose(se3.make(so3.from_rpy(0.1, -0.2, 0.7), [1.0, 2.0, 3.0]))
    cfg = world.config.camera
    expected = world.T_w_b @ cfg.T_b_c_declared @ cfg.mount_error.T
    np.testing.assert_allclose(mujoco_T_w_c(world), expected, atol=1e-6)
    world.set_camera_position_b([0.3, 0.1, -0.05])
    declared = cfg.T_b_c_declared
    declared[:3, 3] = [0.3, 0.1, -0.05]
    np.testing.assert_allclose(
        mujoco_T_w_c(world), world.T_w_b @ declared @ cfg.mount_error.T, atol=1e-6
    )


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"rpy_deg": [50.0, 0.0, 0.0]}, r"camera\.mount_error\.rpy_deg"),
        ({"position_m": [0.0, 2.0, 0.0]}, r"camera\.mount_error\.position_m"),
        ({"yaw_deg": 1.0}, "yaw_deg"),
    ],
)
def test_bad_mount_error_is_refused_naming_the_key(table: dict, message: str) -> None:
    data = builtin.REGISTRY["approach"]()
    data["camera"] = {**data.get("camera", {}), "mount_error": table}
    with pytest.raises(ScenarioError, match=message):
        from_dict(data, "x.toml")


def test_mount_error_refuses_bad_values_in_the_library() -> None:
    with pytest.raises(ValueError, match="rpy_deg must be within"):
        MountError(rpy_deg=(0.0, 46.0, 0.0))
    with pytest.raises(ValueError, match="unknown MountError field"):
        CameraConfig(mount_error={"yaw_deg": 1.0})


def test_the_estimator_is_told_the_declared_mount(tmp_path) -> None:
    """A short run with a mount error: every tick records the true mount (declared @ E) and the
    one the estimator used (declared), and the depth_image estimates, made with the wrong
    mount, are off by about the mount's rotation times the range."""
    data = copy.deepcopy(builtin.REGISTRY["approach"]())
    data["camera"] = {**data.get("camera", {}), "mount_error": ERROR}
    data["duration_s"] = 2.0
    data["checks"] = []
    spec = from_dict(data, "x.toml")
    outcome = pipeline.run(spec, seed=0, out_dir=tmp_path)
    cfg = spec.scene.camera
    for tick in outcome.result.ticks:
        np.testing.assert_allclose(tick.T_b_c, cfg.T_b_c_declared @ cfg.mount_error.T, atol=1e-12)
        np.testing.assert_allclose(tick.T_b_c_est, cfg.T_b_c_declared, atol=1e-12)
    angle = np.linalg.norm(so3.log(cfg.mount_error.T[:3, :3]))
    errors = [
        (d.errors_m["depth_image"], d.range_m)
        for t in outcome.result.ticks
        for d in t.detections
        if "depth_image" in d.errors_m
    ]
    assert errors
    # A rotation of the camera by `angle` moves a point at range r by about r * angle; the
    # translation error (4 cm) and the estimator's own error (< 1% of range) add to it.
    for error_m, range_m in errors:
        assert 0.5 * angle * range_m < error_m < 1.5 * angle * range_m + 0.05
