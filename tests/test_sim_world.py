"""World ground truth against MuJoCo's own state, and the state guards."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import mujoco_T_w_c
from scipy.spatial.transform import Rotation

from sim import names
from sim.config import CameraConfig, SceneConfig
from sim.world import SimulationError, World
from vnav import se3, so3

REPO = Path(__file__).resolve().parents[1]


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    T[:3, 3] = rng.uniform([-50.0, -50.0, 0.5], [50.0, 50.0, 40.0])
    return T


@pytest.mark.parametrize("seed", range(6))
def test_T_w_b_T_b_c_equals_mujoco_camera_pose(seed: int) -> None:
    rng = np.random.default_rng(seed)
    camera = CameraConfig(
        position_b=tuple(rng.uniform(-0.3, 0.3, 3)),
        pitch_down_deg=float(rng.uniform(-90.0, 90.0)),
        fovy_deg=float(rng.uniform(20.0, 120.0)),
    )
    world = World.from_config(SceneConfig(camera=camera))
    for _ in range(20):
        T_w_b = _random_pose(rng)
        world.set_pose(T_w_b)
        np.testing.assert_allclose(world.T_w_b, T_w_b, atol=1e-12)
        np.testing.assert_allclose(world.T_w_b @ world.T_b_c, mujoco_T_w_c(world), atol=1e-9)
        np.testing.assert_allclose(world.T_w_c, mujoco_T_w_c(world), atol=1e-9)


def test_mount_matches_the_convention_by_hand() -> None:
    # Pitched 90 deg down the optical axis (z) is body -z, optical x (image right) is body -y.
    world = World.from_config(SceneConfig(camera=CameraConfig(pitch_down_deg=90.0)))
    R_b_c = world.T_b_c[:3, :3]
    np.testing.assert_allclose(R_b_c[:, 2], [0.0, 0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(R_b_c[:, 0], [0.0, -1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(world.T_b_c[:3, 3], [0.15, 0.0, 0.05])
    # Level camera on a drone yawed 90 deg (facing north): it looks along world +y.
    level = World.from_config(SceneConfig(camera=CameraConfig(pitch_down_deg=0.0)))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    level.set_pose(T)
    np.testing.assert_allclose(mujoco_T_w_c(level)[:3, 2], [0.0, 1.0, 0.0], atol=1e-12)


def test_intrinsics_describe_mujoco_camera() -> None:
    cfg = SceneConfig(camera=CameraConfig(fovy_deg=50.0, width=641, height=479))
    world = World.from_config(cfg)
    cam_id = world.model.camera(names.ONBOARD_CAMERA).id
    assert world.model.cam_fovy[cam_id] == pytest.approx(50.0)
    f = (479 / 2) / math.tan(math.radians(25.0))
    np.testing.assert_allclose(world.camera.K, [[f, 0, 320.0], [0, f, 239.0], [0, 0, 1]])
    assert (world.camera.width, world.camera.height) == (641, 479)


def test_start_pose_and_cones_come_from_config() -> None:
    q_xyzw = Rotation.from_euler("zyx", [40, 5, -3], degrees=True).as_quat()
    cones = ((4.0, -1.0, 0.0), (10.0, 3.5, 0.0))
    world = World.from_config(
        SceneConfig(cones_w=cones, start_position_w=(1.0, 2.0, 3.0), start_quat_xyzw=q_xyzw)
    )
    T = world.T_w_b
    np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(T[:3, :3], Rotation.from_quat(q_xyzw).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(world.cones_w, cones)
    for i, p_w in enumerate(cones):
        np.testing.assert_allclose(world.data.xpos[world.model.body(names.cone_body(i)).id], p_w)
    assert world.time_s == 0.0


def test_quadrotor_has_the_reference_physical_numbers() -> None:
    world = World.from_config()
    m = world.model
    body = m.body(names.DRONE_BODY)
    assert m.body_subtreemass[body.id] == pytest.approx(1.325)
    np.testing.assert_allclose(body.inertia, [0.0367, 0.0254, 0.0605])
    assert m.opt.timestep == SceneConfig().timestep_s
    for motor in names.MOTORS:
        act = m.actuator(motor)
        np.testing.assert_allclose(act.ctrlrange, [0.0, 13.0])
        assert abs(act.gear[5]) == pytest.approx(0.0201)
    assert sum(m.actuator(n).gear[5] for n in names.MOTORS) == pytest.approx(0.0)


def test_hover_thrust_balances_gravity_open_loop() -> None:
    world = World.from_config()
    world.set_rotor_thrusts(np.full(4, 1.325 * 9.81 / 4))
    world.step(100)
    np.testing.assert_allclose(world.position_w, [0.0, 0.0, 10.0], atol=1e-9)


def test_nan_state_stops_with_time_and_cause() -> None:
    world = World.from_config()
    world.step(3)
    world.data.qvel[0] = np.nan
    with pytest.raises(
        SimulationError,
        match=rf"t = {4 * world.model.opt.timestep:.4f} s: velocity \(qvel\) became NaN",
    ):
        world.step()


def test_exploding_state_stops_with_time_and_cause() -> None:
    world = World.from_config()
    world.set_velocity(np.array([0.0, 0.0, 1.0e4]), np.zeros(3))
    with pytest.raises(
        SimulationError, match=rf"t = {world.model.opt.timestep:.4f} s: state exploding, speed"
    ):
        world.step()


def test_set_pose_rejects_a_non_transform() -> None:
    world = World.from_config()
    T = np.eye(4)
    T[:3, :3] *= 2.0
    with pytest.raises(ValueError, match="T_w_b"):
        world.set_pose(T)


def test_missing_opengl_gives_one_clear_error() -> None:
    script = """
import ctypes, ctypes.util
ctypes.util.find_library = lambda name: None
_CDLL = ctypes.CDLL
class NoGL(_CDLL):
    def __init__(self, name, *args, **kwargs):
        if "EGL" in str(name) or "OSMesa" in str(name):
            raise OSError(f"{name}: cannot open shared object file")
        super().__init__(name, *args, **kwargs)
ctypes.CDLL = NoGL
import sim.gl as gl
from sim.world import World
World.from_config().step(10)  # physics works without OpenGL
try:
    gl.create_gl_context(64, 64)
except gl.GLBackendError as exc:
    print(exc)
"""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY")}
    env.pop("WAYLAND_DISPLAY", None)
    out = subprocess.run(
        [sys.executable, "-c", script],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    assert "tried egl, osmesa" in out
    assert "libegl1" in out and "libosmesa6" in out
    assert "OpenGL platform library has not been loaded" not in out


def test_ground_truth_is_current_after_physics_steps() -> None:
    world = World.from_config()
    world.set_rotor_thrusts(np.array([3.6, 3.2, 3.0, 3.4]))  # drift, tilt and spin
    world.step(37)
    assert world.time_s == pytest.approx(37 * world.model.opt.timestep)
    q_wxyz = world.data.qpos[3:7]
    R_qpos = Rotation.from_quat(q_wxyz[[1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(world.T_w_b[:3, 3], world.data.qpos[:3], atol=1e-12)
    np.testing.assert_allclose(world.T_w_b[:3, :3], R_qpos, atol=1e-12)
    assert _angle_between(R_qpos, np.eye(3)) > 0.01
    np.testing.assert_allclose(world.T_w_c, mujoco_T_w_c(world), atol=1e-9)


def _angle_between(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(Rotation.from_matrix(R_a.T @ R_b).magnitude())


def test_camera_slides_on_its_mount_and_mujoco_agrees():
    """After set_camera_position_b, T_w_b @ T_b_c is MuJoCo's own camera pose (optical)."""
    world = World.from_config(SceneConfig())
    world.set_pose(se3.make(so3.from_rpy(0.2, -0.3, 1.1), [1.0, 2.0, 5.0]))
    world.set_camera_position_b([0.3, -0.1, 0.2])
    np.testing.assert_allclose(world.T_w_b @ world.T_b_c, mujoco_T_w_c(world), atol=1e-9)
    np.testing.assert_allclose(world.T_b_c[:3, 3], [0.3, -0.1, 0.2])
    with pytest.raises(ValueError, match="position_b must be 3 finite numbers"):
        world.set_camera_position_b([0.0, np.nan, 0.0])
