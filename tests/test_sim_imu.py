"""The simulated IMU: MuJoCo's accelerometer and gyro at the IMU site, against vnav.imu.

The site sits at the true mount (declared @ error); noise-free, MuJoCo's sensors agree with
``vnav.imu``'s chain fed the body's true motion at every physics step of controlled flights
along random waypoints; hand-computed cases (an exact hover, a pure spin) check both against
numbers worked out on paper; the sampler's rate, stamps and noise come from its figures.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from sim import names
from sim.config import ImuConfig, MountError, SceneConfig
from sim.flight import Autopilot, MinimumJerkTrajectory
from sim.imu import (
    ImuSampler,
    ImuSteps,
    chain_imu_i,
    chain_imu_many_i,
    imu_discrepancy,
    imu_discrepancy_many,
    mujoco_imu_i,
    rate_correction_i,
    to_stamp,
    to_stamp_many,
)
from sim.world import World
from vnav import so3
from vnav.imu import specific_force_i

G = 9.81


def _hover_thrust_N(world: World) -> float:
    """Each rotor's share of the weight."""
    m = world.model
    return float(m.body_subtreemass[world.body_id]) * -m.opt.gravity[2] / 4.0


def _hovering(imu: ImuConfig | None, omega_b=(0.0, 0.0, 0.0)) -> World:
    """A level drone at 10 m whose four rotors carry exactly its weight (no net force, no
    torque: the rotors sit symmetrically and their reaction torques cancel)."""
    world = World.from_config(SceneConfig(imu=imu))
    world.set_rotor_thrusts(np.full(4, _hover_thrust_N(world)))
    world.set_velocity(np.zeros(3), np.asarray(omega_b, dtype=float))
    return world


def test_without_imu_the_site_stays_at_the_body_origin():
    world = World.from_config(SceneConfig())
    np.testing.assert_array_equal(world.T_b_i, np.eye(4))
    np.testing.assert_array_equal(world.model.site_pos[world.imu_site_id], np.zeros(3))


def test_the_site_sits_at_the_true_mount():
    imu = ImuConfig(
        position_b=(0.05, -0.02, 0.03),
        rpy_deg=(0.0, 10.0, 90.0),
        mount_error=MountError(position_m=(0.01, 0.0, -0.02), rpy_deg=(2.0, -1.0, 3.0)),
    )
    world = World.from_config(SceneConfig(imu=imu))
    np.testing.assert_allclose(world.T_b_i, imu.T_b_i_declared @ imu.mount_error.T, atol=1e-12)
    assert np.abs(world.T_b_i - imu.T_b_i_declared).max() > 0.01
    # MuJoCo's own kinematics put the site there in the world.
    site_w = world.data.site_xpos[world.imu_site_id]
    np.testing.assert_allclose(site_w, (world.T_w_b @ imu.T_b_i)[:3, 3], atol=1e-12)
    R_w_site = world.data.site_xmat[world.imu_site_id].reshape(3, 3)
    np.testing.assert_allclose(R_w_site, (world.T_w_b @ imu.T_b_i)[:3, :3], atol=1e-12)


@pytest.mark.parametrize(
    ("rpy_deg", "expected_i"),
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, G)),
        ((90.0, 0.0, 0.0), (0.0, G, 0.0)),  # IMU y = body z
        ((0.0, -90.0, 0.0), (G, 0.0, 0.0)),  # Ry(-90): IMU x = body z
        ((180.0, 0.0, 0.0), (0.0, 0.0, -G)),  # mounted upside down
    ],
)
def test_an_exact_hover_reads_g_up_in_the_imu_frame(rpy_deg, expected_i):
    world = _hovering(ImuConfig(position_b=(0.1, 0.05, -0.02), rpy_deg=rpy_deg))
    accel_i, gyro_i = mujoco_imu_i(world)
    np.testing.assert_allclose(accel_i, expected_i, atol=1e-9)
    np.testing.assert_allclose(gyro_i, np.zeros(3), atol=1e-12)
    # It stays so after physics steps (nothing moves).
    world.step(10)
    np.testing.assert_allclose(mujoco_imu_i(world)[0], expected_i, atol=1e-9)


def test_a_pure_spin_reads_omega_squared_r_towards_the_axis():
    # Spinning at 3 rad/s about the body's z (a principal axis through the centre of mass:
    # the spin stays steady), the IMU 0.2 m forward reads 9 * 0.2 = 1.8 m/s^2 backwards.
    omega, r = 3.0, 0.2
    world = _hovering(ImuConfig(position_b=(r, 0.0, 0.0)), omega_b=(0.0, 0.0, omega))
    for _ in range(3):
        accel_i, gyro_i = mujoco_imu_i(world)
        np.testing.assert_allclose(accel_i, [-(omega**2) * r, 0.0, G], atol=1e-9)
        np.testing.assert_allclose(gyro_i, [0.0, 0.0, omega], atol=1e-12)
        world.step(7)


def test_a_mount_yawed_90_deg_permutes_the_axes():
    # Same flight, two IMUs at the same place: one along the body's axes, one turned by
    # Rz(90 deg) (x_i = y_b, y_i = -x_b): its reading (a, b, c) is the other's (b, -a, c).
    readings = []
    for yaw_deg in (0.0, 90.0):
        world = World.from_config(
            SceneConfig(imu=ImuConfig(position_b=(0.1, 0.0, 0.0), rpy_deg=(0.0, 0.0, yaw_deg)))
        )
        pilot = Autopilot(world, MinimumJerkTrajectory([0, 2], [[0, 0, 10], [2, 1, 11]], [0, 1]))
        pilot.run_until(1.0)
        readings.append(mujoco_imu_i(world))
    (a0, g0), (a1, g1) = readings
    assert np.linalg.norm(a0[:2]) > 0.1 and np.linalg.norm(g0) > 0.1  # it moves
    np.testing.assert_allclose(a1, [a0[1], -a0[0], a0[2]], atol=1e-9)
    np.testing.assert_allclose(g1, [g0[1], -g0[0], g0[2]], atol=1e-12)


def _random_imu(rng: np.random.Generator) -> ImuConfig:
    return ImuConfig(
        position_b=tuple(rng.uniform(-0.2, 0.2, 3)),
        rpy_deg=tuple(rng.uniform(-180.0, 180.0, 3)),
        mount_error=MountError(
            position_m=tuple(rng.uniform(-0.02, 0.02, 3)),
            rpy_deg=tuple(rng.uniform(-5.0, 5.0, 3)),
        ),
    )


def _random_flight(world: World, rng: np.random.Generator) -> Autopilot:
    """Waypoints 2 s apart, each within 3 m of the last, random headings."""
    p = [np.array([0.0, 0.0, 10.0])]
    for _ in range(3):
        p.append(p[-1] + rng.uniform(-3.0, 3.0, 3))
    yaws = [0.0, *rng.uniform(-math.pi, math.pi, 3)]
    return Autopilot(world, MinimumJerkTrajectory([0.0, 2.0, 4.0, 6.0], p, yaws))


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_mujocos_sensors_follow_the_chain_at_every_physics_step(seed):
    rng = np.random.default_rng(seed)
    imu = _random_imu(rng)
    world = World.from_config(SceneConfig(imu=imu))
    pilot = _random_flight(world, rng)
    worst, spin, lever_only = 0.0, 0.0, 0.0
    T_b_i_at_origin = imu.T_b_i.copy()
    T_b_i_at_origin[:3, 3] = 0.0
    while world.time_s < 7.0 - 1e-9:
        pilot.step()
        worst = max(worst, imu_discrepancy(world))
        spin = max(spin, float(np.linalg.norm(world.angular_velocity_b)))
        # The same chain with the lever arm left out: what the check must tell apart.
        f_origin = specific_force_i(
            world.T_w_b,
            T_b_i_at_origin,
            world.acceleration_w,
            world.angular_velocity_b,
            world.angular_acceleration_b,
        )
        lever_only = max(lever_only, float(np.linalg.norm(mujoco_imu_i(world)[0] - f_origin)))
    assert spin > 0.5  # the flight turns: lever-arm terms matter
    assert lever_only > 1e-3
    assert worst < 1e-6


def test_the_sampler_reads_at_its_rate_on_its_clock():
    imu = ImuConfig(rate_hz=50.0)
    world = _hovering(imu)
    sampler = ImuSampler(imu, world.model.opt.timestep, np.random.default_rng(0), 0.25)
    stamps = []
    for _ in range(41):  # 0.2 s of 5 ms steps, the first at t = 0
        if sampler.due(world):
            reading = sampler.sample(world)
            stamps.append(reading.t_s)
            np.testing.assert_array_equal(reading.accel_i, mujoco_imu_i(world)[0])
        world.step()
    np.testing.assert_allclose(stamps, 0.25 + np.arange(11) / 50.0, atol=1e-12)


def test_the_gyro_reads_the_rate_at_its_stamp_not_half_a_step_before():
    """MuJoCo's integrator turns the body by ``exp(omega_{n+1} dt)`` from step n to n + 1, so
    its gyro at step n is the rate over the step *before* (centred half a step, 2.5 ms, early:
    a camera-IMU calibration finds it in the clock offset). The reading must be the rate at its
    stamp: the mean of the rates over the steps on either side (central difference of the
    true IMU attitudes), to the second-order remainder, not the backward one."""
    rng = np.random.default_rng(12)
    imu = _random_imu(rng)
    world = World.from_config(SceneConfig(imu=imu))
    pilot = _random_flight(world, rng)
    sampler = ImuSampler(imu, world.model.opt.timestep, np.random.default_rng(0))
    R_w_i, gyro_i = [], []
    while world.time_s < 5.0 - 1e-9:
        pilot.step()
        R_w_i.append((world.T_w_b @ world.T_b_i)[:3, :3])
        gyro_i.append(sampler.sample(world).gyro_i)
    dt = world.model.opt.timestep
    R_w_i, gyro_i = np.array(R_w_i), np.array(gyro_i)
    # The rate over each step, in the IMU axes at its start (exact for a constant rate).
    step_rate_i = np.array([so3.log(a.T @ b) for a, b in itertools.pairwise(R_w_i)]) / dt
    central = 0.5 * (step_rate_i[:-1] + step_rate_i[1:])
    lag = np.abs(step_rate_i[:-1] - central).max()  # what half a step's lag costs here
    assert lag > 0.01  # the flight's angular acceleration makes the lag visible
    assert np.abs(gyro_i[1:-1] - central).max() < 0.25 * lag


def test_the_samplers_noise_has_kalibrs_discrete_sizes_and_follows_the_seed():
    imu = ImuConfig(accelerometer_noise_density=0.02, gyroscope_noise_density=0.003)
    world = _hovering(imu)
    truth_a, truth_g = mujoco_imu_i(world)
    runs = []
    for _ in range(2):
        sampler = ImuSampler(imu, world.model.opt.timestep, np.random.default_rng(4))
        readings = [sampler.sample(world) for _ in range(5_000)]
        runs.append(np.array([np.r_[r.accel_i, r.gyro_i] for r in readings]))
    np.testing.assert_array_equal(runs[0], runs[1])
    err = runs[0] - np.r_[truth_a, truth_g]
    sigma_a, sigma_g = imu.noise.white_std(1.0 / imu.rate_hz)
    # 5000 draws: a standard deviation within 1 % (one sigma) of the figure.
    np.testing.assert_allclose(err[:, :3].std(axis=0), sigma_a, rtol=0.05)
    np.testing.assert_allclose(err[:, 3:].std(axis=0), sigma_g, rtol=0.05)


def test_a_rate_above_the_physics_rate_is_refused():
    with pytest.raises(ValueError, match="physics rate"):
        SceneConfig(imu=ImuConfig(rate_hz=400.0))
    with pytest.raises(ValueError, match="physics rate"):
        ImuSampler(ImuConfig(rate_hz=400.0), 0.005, np.random.default_rng(0))


def test_the_sensor_names_are_the_models():
    world = World.from_config(SceneConfig())
    assert world.model.sensor(names.IMU_ACCEL).type[0] == 1  # mjSENS_ACCELEROMETER
    assert world.model.sensor(names.IMU_GYRO).objid[0] == world.imu_site_id


def test_the_accelerometer_reads_the_second_difference_of_the_imus_positions():
    """MuJoCo's step from n to n + 1 moves the body by ``v_{n+1} = v_n + dt a_n``, ``x_{n+1} =
    x_n + dt v_{n+1}`` and turns it by ``exp(omega_{n+1} dt)``, with ``a_n`` the acceleration
    of state n under the controls the step applies (the controller sets them from state n,
    just before the step). The reading stamped at step n must be the central second
    difference of the true IMU positions around it, to the second-order remainder: neither
    the acceleration under the previous step's controls (a step, 5 ms, behind: a camera-IMU
    calibration finds the lag in the lever arm, millimetres of it), nor a centripetal term
    ``omega x (omega x r)`` of the rate over the step before only (half a step behind)."""
    rng = np.random.default_rng(12)
    imu = _random_imu(rng)
    world = World.from_config(SceneConfig(imu=imu))
    pilot = _random_flight(world, rng)
    sampler = ImuSampler(imu, world.model.opt.timestep, np.random.default_rng(0))
    t_s, T_w_b, accel_i = [], [], []

    def read(w: World) -> None:
        reading = sampler.sample(w)
        t_s.append(reading.t_s)
        T_w_b.append(w.T_w_b)
        accel_i.append(reading.accel_i)

    world.on_step = read  # as the runner reads it
    pilot.run_until(5.0)
    dt = world.model.opt.timestep
    T_b_i = world.T_b_i
    T_w_b, accel_i = np.array(T_w_b), np.array(accel_i)
    np.testing.assert_allclose(np.diff(t_s), dt, atol=1e-12)  # one reading a step
    T_w_i = T_w_b @ T_b_i
    p_w = T_w_i[:, :3, 3]
    a_w = (p_w[2:] - 2.0 * p_w[1:-1] + p_w[:-2]) / dt**2
    # f_i = R_i_w (a_w - g_w), row-wise.
    central = np.einsum("nji,nj->ni", T_w_i[1:-1, :3, :3], a_w - world.model.opt.gravity)
    lag = np.abs(central[1:] - central[:-1]).max()  # what a step's lag costs here
    # The rate over each step (body axes, from the true attitudes) and the centripetal term
    # of the lever arm under it: half the change from one step to the next is what reading it
    # with the rate over the step before only costs.
    omega_b = np.array([so3.log(a.T @ b) for a, b in itertools.pairwise(T_w_b[:, :3, :3])]) / dt
    r_b = T_b_i[:3, 3]
    c_b = np.cross(omega_b, np.cross(omega_b, r_b))
    half_step = 0.5 * np.abs(c_b[1:] - c_b[:-1]).max()
    assert lag > 0.05 and half_step > 5e-3  # the flight makes both visible
    assert np.abs(accel_i[1:-1] - central).max() < 0.05 * half_step


def test_the_gyro_corrected_to_fourth_order_is_the_cubic_through_the_true_step_rates():
    """MuJoCo turns the body over each step at a constant rate (the true IMU attitudes give
    it: ``log(R_n^T R_{n+1}) / dt``), so the rate at the instant between two steps is, to
    fourth order, the cubic through four of those averages, ``(-w_{n-1} + 7 w_n + 7 w_{n+1} -
    w_{n+2}) / 12``; the sampler's mean of the two around it is off by ``dt^2 / 12`` times the
    change of angular acceleration (``vnav.imu_calibration`` integrates the readings to fourth
    order and would read that as lever arm). ``rate_correction_i`` makes up the difference."""
    rng = np.random.default_rng(13)
    imu = _random_imu(rng)
    world = World.from_config(SceneConfig(imu=imu))
    pilot = _random_flight(world, rng)
    sampler = ImuSampler(imu, world.model.opt.timestep, np.random.default_rng(0))
    R_w_i, gyro_i, omega_b = [], [], []

    def read(w: World) -> None:
        R_w_i.append((w.T_w_b @ w.T_b_i)[:3, :3])
        gyro_i.append(sampler.sample(w).gyro_i)
        omega_b.append(w.angular_velocity_b)

    world.on_step = read
    pilot.run_until(4.0)
    R_w_i.append((world.T_w_b @ world.T_b_i)[:3, :3])  # after the last step
    omega_b.append(world.angular_velocity_b)
    dt = world.model.opt.timestep
    R_w_i = np.array(R_w_i)
    fourth_i = np.array(gyro_i) + rate_correction_i(
        np.array(omega_b), np.arange(len(gyro_i)), world.T_b_i[:3, :3]
    )
    w = np.array([so3.log(a.T @ b) for a, b in itertools.pairwise(R_w_i)]) / dt  # w[n] = w_{n+1}
    truth = (-w[:-3] + 7.0 * w[1:-2] + 7.0 * w[2:-1] - w[3:]) / 12.0  # steps 2 .. N - 2
    second = np.abs(np.array(gyro_i)[2:-1] - truth).max()
    assert second > 1e-4  # what the mean of two leaves here
    np.testing.assert_allclose(fourth_i[2:-1], truth, atol=1e-9)


@pytest.mark.parametrize("rate_hz", [200.0, 70.0])
def test_the_steps_computed_at_once_equal_the_per_step_functions_to_the_last_bit(rate_hz):
    """The runner keeps each physics step's state (``ImuSteps``) and computes the readings,
    the chain and the discrepancy at the run's end: every number must be what the per-step
    functions (``chain_imu_i``, ``imu_discrepancy``, ``to_stamp``, ``ImuSampler.sample``,
    the references) give at the step, bit for bit, noise included; at 70 Hz not every step
    has a reading."""
    rng = np.random.default_rng(21)
    imu = dataclasses.replace(
        _random_imu(rng),
        rate_hz=rate_hz,
        accelerometer_noise_density=0.002,
        accelerometer_random_walk=0.003,
        gyroscope_noise_density=1.7e-4,
        gyroscope_random_walk=1.9e-5,
    )
    world = World.from_config(SceneConfig(imu=imu))
    pilot = _random_flight(world, rng)
    dt = world.model.opt.timestep
    reference = ImuSampler(imu, dt, np.random.default_rng(5), 0.015)
    batched = ImuSampler(imu, dt, np.random.default_rng(5), 0.015)
    state = ImuSteps(world)
    want: dict[str, list] = {k: [] for k in ("f", "w", "e", "t", "a", "g", "fc", "wc")}
    steps: list[int] = []

    def read(w: World) -> None:
        chain = chain_imu_i(w)
        want["f"].append(chain[0])
        want["w"].append(chain[1])
        want["e"].append(imu_discrepancy(w, chain))
        if reference.due(w):
            reading = reference.sample(w)
            want["t"].append(reading.t_s)
            want["a"].append(reading.accel_i)
            want["g"].append(reading.gyro_i)
            stamped = to_stamp(w, *chain)
            want["fc"].append(stamped[0])
            want["wc"].append(stamped[1])
        state.take(w)
        if batched.take_due(w):
            steps.append(len(state) - 1)

    world.on_step = read
    pilot.run_until(3.0)
    s = state.stacked()
    f_i, omega_i = chain_imu_many_i(
        s["T_w_b"],
        world.T_b_i,
        s["acceleration_w"],
        s["angular_velocity_b"],
        s["angular_acceleration_b"],
        world.model.opt.gravity,
    )
    np.testing.assert_array_equal(f_i, want["f"])
    np.testing.assert_array_equal(omega_i, want["w"])
    np.testing.assert_array_equal(
        imu_discrepancy_many(s["accel_i"], s["gyro_i"], f_i, omega_i), want["e"]
    )
    assert len(steps) == len(want["t"])
    assert (len(steps) == len(state)) == (rate_hz == 200.0)  # a reading a step at 200 Hz
    omega_b, alpha_b = s["angular_velocity_b"][steps], s["angular_acceleration_b"][steps]
    accel_i, gyro_i = to_stamp_many(
        dt, world.T_b_i, s["accel_i"][steps], s["gyro_i"][steps], omega_b, alpha_b
    )
    t_s, accel_i, gyro_i = batched.sample_many(s["time_s"][steps], accel_i, gyro_i)
    np.testing.assert_array_equal(t_s, want["t"])
    np.testing.assert_array_equal(accel_i, want["a"])
    np.testing.assert_array_equal(gyro_i, want["g"])
    chain_a, chain_g = to_stamp_many(dt, world.T_b_i, f_i[steps], omega_i[steps], omega_b, alpha_b)
    np.testing.assert_array_equal(chain_a, want["fc"])
    np.testing.assert_array_equal(chain_g, want["wc"])
