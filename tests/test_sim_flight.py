"""Flight against ground truth: hover, yaw step, waypoint tracking, mixer, keyframes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim.config import SceneConfig
from sim.flight import (
    Autopilot,
    KeyframePlayer,
    KeyframeTrajectory,
    MinimumJerkTrajectory,
    Mixer,
)
from sim.gl import mujoco
from sim.world import World


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle between two attitudes (independent of vnav: SciPy)."""
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def _hold(p_w, yaw_rad: float = 0.0) -> MinimumJerkTrajectory:
    return MinimumJerkTrajectory([0.0], [p_w], [yaw_rad])


def test_hover_at_10_m_holds_position_and_attitude() -> None:
    # Start off the set point: 0.3 m away, tilted, moving and spinning.
    q_xyzw = Rotation.from_euler("xyz", [6.0, -5.0, 20.0], degrees=True).as_quat()
    world = World.from_config(
        SceneConfig(start_position_w=(0.3, -0.2, 9.7), start_quat_xyzw=tuple(q_xyzw))
    )
    world.set_velocity(np.array([0.5, 0.2, -0.3]), np.array([0.3, -0.2, 0.5]))
    pilot = Autopilot(world, _hold([0.0, 0.0, 10.0]))
    pilot.run_until(5.0)  # settling
    pos_err, att_err = [], []
    while world.time_s < 15.0 - 1e-9:
        pilot.step()
        pos_err.append(np.linalg.norm(world.T_w_b[:3, 3] - [0.0, 0.0, 10.0]))
        att_err.append(_angle_deg(np.eye(3), world.T_w_b[:3, :3]))
    assert len(pos_err) == round(10.0 / world.model.opt.timestep)  # every step of 10 s
    assert max(pos_err) < 0.02
    assert max(att_err) < 0.5


def test_yaw_step_of_90_deg_settles_within_3_s() -> None:
    world = World.from_config(SceneConfig())
    pilot = Autopilot(world, _hold([0.0, 0.0, 10.0], 0.0))
    pilot.run_until(1.0)
    pilot.trajectory = _hold([0.0, 0.0, 10.0], math.pi / 2)  # the step
    R_target = Rotation.from_euler("z", 90.0, degrees=True).as_matrix()
    errors = []
    while world.time_s < 6.0 - 1e-9:
        pilot.step()
        errors.append((world.time_s - 1.0, _angle_deg(R_target, world.T_w_b[:3, :3])))
    t_rel, err = np.array(errors).T
    assert err[0] > 85.0
    assert np.all(err[t_rel >= 3.0] < 2.0), f"error after 3 s: {err[t_rel >= 3.0].max():.2f} deg"
    # Thrust stays balanced while yawing: altitude barely moves.
    assert abs(world.T_w_b[2, 3] - 10.0) < 0.02


TRACKING_BOUND_M = 0.10
"""Waypoint tracking: 3-D distance to the reference at every step, legs of 5 m in 4 s."""


def test_waypoint_tracking_stays_within_bound() -> None:
    world = World.from_config(SceneConfig(start_position_w=(0.0, 0.0, 2.0)))
    waypoints_w = [[0, 0, 2], [5, 0, 3], [5, 5, 4], [0, 5, 3], [0, 0, 2], [0, 0, 2]]
    yaws = [0.0, 0.0, math.pi / 2, math.pi, -math.pi / 2, 0.0]
    trajectory = MinimumJerkTrajectory([0, 4, 8, 12, 16, 19], waypoints_w, yaws)
    pilot = Autopilot(world, trajectory)
    errors = []
    while world.time_s < 20.0 - 1e-9:
        pilot.step()
        ref = trajectory.sample(world.time_s)
        errors.append(np.linalg.norm(world.T_w_b[:3, 3] - ref.p_w))
    assert max(errors) < TRACKING_BOUND_M, f"max tracking error {max(errors):.3f} m"
    assert errors[-1] < 0.01
    assert _angle_deg(np.eye(3), world.T_w_b[:3, :3]) < 1.0  # final yaw 0, level


def test_minimum_jerk_reference_passes_waypoints_at_rest() -> None:
    traj = MinimumJerkTrajectory([0.0, 2.0, 5.0], [[0, 0, 1], [4, 2, 1], [4, 2, 6]], [0, 3, -3])
    for t, p in [(0.0, [0, 0, 1]), (2.0, [4, 2, 1]), (5.0, [4, 2, 6]), (9.0, [4, 2, 6])]:
        ref = traj.sample(t)
        np.testing.assert_allclose(ref.p_w, p, atol=1e-12)
        np.testing.assert_allclose(ref.v_w, 0.0, atol=1e-12)
        np.testing.assert_allclose(ref.a_w, 0.0, atol=1e-12)
    mid = traj.sample(1.0)
    np.testing.assert_allclose(mid.p_w, [2, 1, 1])  # symmetric profile: half way at half time
    np.testing.assert_allclose(mid.v_w, np.array([4, 2, 0]) * 1.875 / 2.0)  # peak 15/8 avg
    # Yaw 3 -> -3 rad goes the short way (through pi), not back through 0.
    assert abs(traj.sample(3.5).yaw_rad) > 3.0
    with pytest.raises(ValueError, match="times_s"):
        MinimumJerkTrajectory([0.0, 0.0], [[0, 0, 0], [1, 0, 0]], [0, 0])
    with pytest.raises(ValueError, match="positions_w"):
        MinimumJerkTrajectory([0.0, 1.0], [[0, 0, 0]], [0, 0])


def test_mixer_reproduces_wrench_and_respects_limits() -> None:
    world = World.from_config()
    mixer = Mixer.from_world(world)
    rng = np.random.default_rng(0)
    for _ in range(50):
        thrust = rng.uniform(8.0, 20.0)
        moment = rng.uniform(-0.3, 0.3, 3) * [1, 1, 0.2]
        u = mixer.thrusts(thrust, moment)
        # Against the physics: apply u and read MuJoCo's actuator force on the free joint.
        world.set_rotor_thrusts(u)
        mujoco.mj_forward(world.model, world.data)
        f_w = world.data.qfrc_actuator[:3]
        tau_b = world.data.qfrc_actuator[3:6]
        R_w_b = world.T_w_b[:3, :3]
        np.testing.assert_allclose(R_w_b.T @ f_w, [0, 0, thrust], atol=1e-9)
        np.testing.assert_allclose(tau_b, moment, atol=1e-9)
    # An impossible yaw demand is scaled down; thrust, roll and pitch are kept.
    u = mixer.thrusts(13.0, np.array([0.1, -0.05, 5.0]))
    assert np.all((u >= 0.0) & (u <= 13.0))
    thrust, moment = mixer.wrench(u)
    assert thrust == pytest.approx(13.0)
    np.testing.assert_allclose(moment[:2], [0.1, -0.05], atol=1e-12)
    assert 0.0 < moment[2] < 5.0


def test_keyframes_are_exact_including_90_deg_pitch() -> None:
    world = World.from_config()
    R1 = Rotation.from_euler("y", 90.0, degrees=True).as_matrix()  # nose straight down
    T0, T1 = np.eye(4), np.eye(4)
    T0[:3, 3] = [0.0, 0.0, 5.0]
    T1[:3, :3], T1[:3, 3] = R1, [2.0, 4.0, 7.0]
    player = KeyframePlayer(world, KeyframeTrajectory([0.0, 1.0], [T0, T1]))
    player.step(round(0.5 / world.model.opt.timestep))
    assert world.time_s == pytest.approx(0.5)
    T_mid = world.T_w_b
    np.testing.assert_allclose(T_mid[:3, 3], [1.0, 2.0, 6.0], atol=1e-12)
    R_half = Rotation.from_euler("y", 45.0, degrees=True).as_matrix()
    np.testing.assert_allclose(T_mid[:3, :3], R_half, atol=1e-12)
    player.step(round(0.6 / world.model.opt.timestep))  # past the last keyframe
    np.testing.assert_allclose(world.T_w_b, T1, atol=1e-12)
    np.testing.assert_allclose(world.data.qvel, 0.0)


def test_orbit_reference_derivatives_match_finite_differences():
    """Velocity and acceleration feed-forward are the derivatives of the position reference."""
    from sim.flight import OrbitTrajectory

    orbit = OrbitTrajectory([1.0, -2.0, 0.0], 6.0, 4.0, period_s=-12.0, start_angle_rad=0.3)
    h = 1e-4
    for t in (0.0, 0.7, 1.5, 2.9, 3.0, 3.1, 8.0):
        ref = orbit.sample(t)
        before, after = orbit.sample(t - h), orbit.sample(t + h)
        if t > 0.0:  # the reference holds still before t = 0
            assert np.allclose(ref.v_w, (after.p_w - before.p_w) / (2 * h), atol=1e-6)
            assert np.allclose(ref.a_w, (after.v_w - before.v_w) / (2 * h), atol=1e-5)
        assert np.linalg.norm(ref.p_w[:2] - [1.0, -2.0]) == pytest.approx(6.0, abs=1e-12)
        assert ref.p_w[2] == 4.0
        # Heading at the centre: the body x axis points from the drone to the centre.
        to_centre = np.array([1.0, -2.0]) - ref.p_w[:2]
        heading = np.array([np.cos(ref.yaw_rad), np.sin(ref.yaw_rad)])
        assert np.allclose(heading, to_centre / np.linalg.norm(to_centre), atol=1e-12)
    assert np.allclose(orbit.sample(0.0).v_w, 0.0)  # starts at rest
    # Full speed after the ramp: |v| = r |2 pi / period|.
    assert np.linalg.norm(orbit.sample(5.0).v_w) == pytest.approx(6.0 * 2 * np.pi / 12.0)


def test_orbit_flown_by_the_controller_stays_on_the_circle():
    from sim.flight import OrbitTrajectory

    orbit = OrbitTrajectory([0.0, 0.0, 0.0], 6.0, 4.0, period_s=16.0, start_angle_rad=np.pi)
    start = orbit.sample(0.0)
    world = World.from_config(
        SceneConfig(start_position_w=tuple(start.p_w), start_quat_xyzw=(0.0, 0.0, 0.0, 1.0))
    )
    pilot = Autopilot(world, orbit)
    worst_radius_m = 0.0
    for _ in range(round(17.5 / world.model.opt.timestep)):
        pilot.step(1)
        worst_radius_m = max(worst_radius_m, abs(np.linalg.norm(world.position_w[:2]) - 6.0))
    assert worst_radius_m < 0.1  # ground truth: MuJoCo's body position
