"""vnav.imu: the specific force and rate on a mount, Kalibr's noise model, the Allan deviation.

Known answers worked by hand (hover, a pure spin, a turned mount), the lever-arm chain
against finite differences of the IMU's own position, the noise model against Kalibr's
discrete-time figures, and the Allan deviation against a direct implementation of its
definition, the closed forms of white noise and random walk, and a simulated static hour whose
four figures it recovers. MuJoCo's own sensors are compared in tests/test_sim_imu.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vnav import se3, so3
from vnav.imu import (
    GRAVITY_W,
    ImuNoise,
    ImuNoiseProcess,
    allan_deviation,
    angular_rate_i,
    fit_allan_noise,
    point_acceleration_w,
    specific_force_i,
)

G = 9.81


def _mount(rpy_deg=(0.0, 0.0, 0.0), position_b=(0.0, 0.0, 0.0)) -> np.ndarray:
    R = Rotation.from_euler("ZYX", list(reversed(rpy_deg)), degrees=True).as_matrix()
    return se3.make(R, np.asarray(position_b, dtype=float))


# ------------------------------------------------------------------------------ hand cases


@pytest.mark.parametrize("yaw_deg", [0.0, 37.0, -120.0])
def test_hover_reads_g_up_in_the_imu_frame(yaw_deg):
    # Hovering: no acceleration, no rotation; the accelerometer reads the reaction to gravity,
    # +9.81 along the world's up axis, whatever the heading.
    T_w_b = se3.make(so3.rot_z(math.radians(yaw_deg)), [1.0, 2.0, 10.0])
    f_i = specific_force_i(T_w_b, np.eye(4), np.zeros(3), np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(f_i, [0.0, 0.0, G], atol=1e-12)


def test_a_mount_rolled_90_deg_reads_g_on_its_y_axis():
    # R_b_i = Rx(90 deg): the IMU's y axis is the body's z (up), its z the body's -y. At hover
    # the reading's +g moves from z to y: (0, 9.81, 0).
    f_i = specific_force_i(
        np.eye(4), _mount((90.0, 0.0, 0.0)), np.zeros(3), np.zeros(3), np.zeros(3)
    )
    np.testing.assert_allclose(f_i, [0.0, G, 0.0], atol=1e-12)


def test_a_mount_yawed_90_deg_permutes_the_axes():
    # R_b_i = Rz(90 deg): x_i = y_b, y_i = -x_b, z_i = z_b, so (a, b, c)_b reads (b, -a, c)_i,
    # for the gyro and for the accelerometer (here a forward acceleration of 2 m/s^2).
    T_b_i = _mount((0.0, 0.0, 90.0))
    omega_b = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(angular_rate_i(T_b_i, omega_b), [2.0, -1.0, 3.0], atol=1e-12)
    f_i = specific_force_i(np.eye(4), T_b_i, [2.0, 0.0, 0.0], np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(f_i, [0.0, -2.0, G], atol=1e-12)


def test_a_pure_spin_reads_the_centripetal_acceleration_at_the_lever_arm():
    # Spinning at omega = 2 rad/s about the body's z axis through its origin, the IMU 0.5 m
    # forward moves on a circle: its acceleration is omega^2 r = 2 m/s^2 towards the axis.
    omega, r = 2.0, 0.5
    T_b_i = _mount(position_b=(r, 0.0, 0.0))
    f_i = specific_force_i(np.eye(4), T_b_i, np.zeros(3), [0.0, 0.0, omega], np.zeros(3))
    np.testing.assert_allclose(f_i, [-(omega**2) * r, 0.0, G], atol=1e-12)
    # The gyro reads the same rate wherever it sits on the body.
    np.testing.assert_allclose(angular_rate_i(T_b_i, [0.0, 0.0, omega]), [0.0, 0.0, omega])


def test_an_angular_acceleration_reads_the_tangential_term():
    # alpha = 3 rad/s^2 about z, the IMU 0.5 m forward: alpha x r = 1.5 m/s^2 to the left.
    T_b_i = _mount(position_b=(0.5, 0.0, 0.0))
    f_i = specific_force_i(np.eye(4), T_b_i, np.zeros(3), np.zeros(3), [0.0, 0.0, 3.0])
    np.testing.assert_allclose(f_i, [0.0, 1.5, G], atol=1e-12)


def test_free_fall_reads_zero():
    f_i = specific_force_i(
        np.eye(4), _mount((10.0, 20.0, 30.0)), GRAVITY_W, np.zeros(3), np.zeros(3)
    )
    np.testing.assert_allclose(f_i, np.zeros(3), atol=1e-12)


# ------------------------------------------------------------------------------ the chain


def _motion(t_s: float):
    """A smooth rigid motion: T_w_b(t) (rotation about a turning axis, a curved path)."""
    rotvec = np.array([0.3 * t_s + 0.2 * t_s**2, -0.5 * math.sin(1.3 * t_s), 0.7 * t_s])
    R = Rotation.from_rotvec(rotvec).as_matrix()
    p = np.array([math.cos(0.9 * t_s), 0.4 * t_s**3, 2.0 + math.sin(2.1 * t_s)])
    return R, p


def test_the_chain_matches_finite_differences_of_the_imus_own_position():
    # Independent of the formula: differentiate the IMU's world position p_w + R_w_b t_b_i
    # twice numerically, and the body's rotation for omega_b (R^T dR/dt) and alpha_b.
    T_b_i = _mount((15.0, -40.0, 120.0), (0.12, -0.07, 0.05))
    h = 1e-4
    for t in (0.3, 1.1, 2.7):
        R, p = _motion(t)
        p_i = [(_motion(s)[1] + _motion(s)[0] @ T_b_i[:3, 3]) for s in (t - h, t, t + h)]
        a_i_w = (p_i[0] - 2.0 * p_i[1] + p_i[2]) / h**2
        a_w = (_motion(t - h)[1] - 2.0 * p + _motion(t + h)[1]) / h**2

        def omega_b(s, e=1e-6):
            Rs = _motion(s)[0]
            return so3.log(Rs.T @ _motion(s + e)[0]) / (2 * e) + so3.log(
                _motion(s - e)[0].T @ Rs
            ) / (2 * e)

        alpha_b = (omega_b(t + h) - omega_b(t - h)) / (2 * h)
        f_expected = (R @ T_b_i[:3, :3]).T @ (a_i_w - GRAVITY_W)
        f_i = specific_force_i(se3.make(R, p), T_b_i, a_w, omega_b(t), alpha_b)
        np.testing.assert_allclose(f_i, f_expected, atol=2e-5)


def test_batches_give_each_row_its_own_reading(rng):
    n = 7
    R = Rotation.random(n, random_state=1).as_matrix()
    T_w_b = np.stack([se3.make(R[k], rng.normal(size=3)) for k in range(n)])
    T_b_i = _mount((5.0, 6.0, 7.0), (0.1, 0.2, 0.3))
    a_w, omega_b, alpha_b = rng.normal(size=(3, n, 3))
    batch = specific_force_i(T_w_b, T_b_i, a_w, omega_b, alpha_b)
    rows = [specific_force_i(T_w_b[k], T_b_i, a_w[k], omega_b[k], alpha_b[k]) for k in range(n)]
    np.testing.assert_allclose(batch, rows, atol=1e-12)
    np.testing.assert_allclose(
        point_acceleration_w(a_w, omega_b, alpha_b, a_w),
        [point_acceleration_w(a_w[k], omega_b[k], alpha_b[k], a_w[k]) for k in range(n)],
    )


def test_bad_input_raises_naming_it():
    with pytest.raises(ValueError, match="T_b_i"):
        specific_force_i(np.eye(4), np.ones((4, 4)), np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="omega_b"):
        angular_rate_i(np.eye(4), [1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="a_w"):
        point_acceleration_w(np.zeros(2), np.zeros(3), np.zeros(3), np.zeros(3))


# ------------------------------------------------------------------------------ noise model

ADIS = ImuNoise(
    accelerometer_noise_density=2.0e-3,
    accelerometer_random_walk=3.0e-3,
    gyroscope_noise_density=1.6968e-4,
    gyroscope_random_walk=1.9393e-5,
)
"""The figures of Kalibr's example IMU (an ADIS16448, as in its imu.yaml)."""


def test_the_discrete_figures_are_kalibrs():
    dt = 1.0 / 200.0
    assert ADIS.white_std(dt) == pytest.approx(
        (2.0e-3 * math.sqrt(200.0), 1.6968e-4 * math.sqrt(200))
    )
    assert ADIS.bias_step_std(dt) == pytest.approx(
        (3.0e-3 / math.sqrt(200), 1.9393e-5 / math.sqrt(200))
    )


def test_the_process_draws_white_noise_and_bias_steps_of_those_sizes():
    dt, n = 0.01, 200_000
    process = ImuNoiseProcess(ADIS, dt, np.random.default_rng(5))
    accel, gyro = process.series(n)
    white_a, white_g = ADIS.white_std(dt)
    step_a, step_g = ADIS.bias_step_std(dt)
    for errors, white, step in ((accel, white_a, step_a), (gyro, white_g, step_g)):
        # Differences of consecutive errors: two white draws plus one bias step.
        d = np.diff(errors, axis=0)
        expected = math.sqrt(2.0 * white**2 + step**2)
        np.testing.assert_allclose(d.std(axis=0), expected, rtol=0.01)  # ~0.16 % per axis
    # Where the bias comes to after n steps is the sum of the last sample's walk.
    assert np.all(np.abs(process.bias_gyro_i) < 6.0 * step_g * math.sqrt(n))


def test_one_sample_at_a_time_draws_the_same_numbers_as_a_series():
    a = ImuNoiseProcess(ADIS, 0.005, np.random.default_rng(9))
    b = ImuNoiseProcess(ADIS, 0.005, np.random.default_rng(9))
    series_a, series_g = a.series(50)
    one = [b.next() for _ in range(50)]
    np.testing.assert_array_equal(series_a, [x for x, _ in one])
    np.testing.assert_array_equal(series_g, [g for _, g in one])
    np.testing.assert_array_equal(a.bias_accel_i, b.bias_accel_i)


def test_a_perfect_imu_draws_nothing():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    accel, gyro = ImuNoiseProcess(ImuNoise(), 0.005, rng).series(10)
    assert not accel.any() and not gyro.any()
    assert rng.bit_generator.state == state


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf, 11.0, "0.1", True])
def test_noise_figures_are_checked(bad):
    with pytest.raises(ValueError, match="gyroscope_random_walk"):
        ImuNoise(gyroscope_random_walk=bad)


# ------------------------------------------------------------------------------ Allan deviation


def _allan_by_definition(y: np.ndarray, dt: float, m: int) -> float:
    """Half the mean square difference of consecutive averages over m samples, every start."""
    n = len(y)
    averages = np.array([y[k : k + m].mean() for k in range(n - m + 1)])
    diffs = averages[m:] - averages[:-m]
    return math.sqrt(0.5 * np.mean(diffs**2))


def test_allan_deviation_is_its_definition(rng):
    y = rng.normal(size=(301, 2)) + np.linspace(0, 3, 301)[:, None]
    dt = 0.02
    ms = [1, 2, 7, 50, 150]
    adev = allan_deviation(y, dt, np.array(ms) * dt)
    for j, m in enumerate(ms):
        for c in range(2):
            assert adev[j, c] == pytest.approx(_allan_by_definition(y[:, c], dt, m), rel=1e-10)
    # One channel as (N,).
    np.testing.assert_allclose(allan_deviation(y[:, 1], dt, np.array(ms) * dt), adev[:, 1])


def _relative_scatter(n: int, m: int) -> float:
    """The relative standard deviation of an Allan deviation over n samples at cluster m
    (non-overlapping clusters, a bound for the overlapping estimate)."""
    return 1.0 / math.sqrt(2.0 * (n / m - 1.0))


def test_white_noise_follows_n_over_root_tau():
    density, dt, n = 0.05, 0.01, 400_000
    white = ImuNoiseProcess(
        ImuNoise(accelerometer_noise_density=density), dt, np.random.default_rng(1)
    )
    y = white.series(n)[0][:, 0]
    ms = np.array([1, 10, 100, 1000])
    adev = allan_deviation(y, dt, ms * dt)
    expected = density / np.sqrt(ms * dt)
    for m, got, want in zip(ms, adev, expected, strict=True):
        assert got == pytest.approx(want, rel=4.0 * _relative_scatter(n, m))


def test_a_random_walk_follows_k_root_tau_over_3():
    walk, dt, n = 0.02, 0.01, 400_000
    process = ImuNoiseProcess(ImuNoise(gyroscope_random_walk=walk), dt, np.random.default_rng(2))
    y = process.series(n)[1][:, 2]
    ms = np.array([100, 300, 1000, 3000])
    adev = allan_deviation(y, dt, ms * dt)
    expected = walk * np.sqrt(ms * dt / 3.0)
    for m, got, want in zip(ms, adev, expected, strict=True):
        assert got == pytest.approx(want, rel=4.0 * _relative_scatter(n, m))


def test_a_static_hour_gives_back_every_noise_figure_within_10_percent():
    # An hour of a resting IMU at 200 Hz (the noise model alone: no motion to remove), the
    # Allan variance of the three axes averaged (one figure per sensor), fitted with
    # N^2 / tau + K^2 tau / 3 over cluster times from one sample to a tenth of the hour.
    dt, n = 1.0 / 200.0, 3600 * 200
    accel, gyro = ImuNoiseProcess(ADIS, dt, np.random.default_rng(2026)).series(n)
    ms = np.unique(np.rint(np.logspace(0, math.log10(n / 10), 40)).astype(int))
    taus = ms * dt
    for errors, density, walk in (
        (accel, ADIS.accelerometer_noise_density, ADIS.accelerometer_random_walk),
        (gyro, ADIS.gyroscope_noise_density, ADIS.gyroscope_random_walk),
    ):
        adev = np.sqrt(np.mean(allan_deviation(errors, dt, taus) ** 2, axis=1))
        n_fit, k_fit = fit_allan_noise(taus, adev)
        assert n_fit == pytest.approx(density, rel=0.10)
        assert k_fit == pytest.approx(walk, rel=0.10)


def test_fit_recovers_the_closed_forms_exactly():
    taus = np.logspace(-2, 3, 30)
    adev = np.sqrt(0.01**2 / taus + 0.002**2 * taus / 3.0)
    assert fit_allan_noise(taus, adev) == pytest.approx((0.01, 0.002), rel=1e-9)


def test_allan_deviation_refuses_taus_outside_the_record():
    y = np.zeros(101)
    with pytest.raises(ValueError, match="taus must lie in"):
        allan_deviation(y, 0.1, [6.0])  # m = 60 > (101 - 1) / 2
    with pytest.raises(ValueError, match="taus must lie in"):
        allan_deviation(y, 0.1, [0.01])
    with pytest.raises(ValueError, match="samples"):
        allan_deviation(np.zeros((10, 3, 1)), 0.1, [0.1])
    with pytest.raises(ValueError, match="dt_s"):
        allan_deviation(y, 0.0, [0.1])
