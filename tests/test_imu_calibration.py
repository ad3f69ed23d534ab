"""``vnav.imu_calibration``: ``T_i_c`` and the camera-IMU clock offset recovered from synthetic
flights built by hand (an analytic IMU trajectory, its exact gyro and accelerometer readings,
the cone apexes' exact projections through a known ``T_i_c``, plus Gaussian noise), against the
truth they were made with; its closed-form pieces against SciPy; and refusals.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.frames import R_FLU_RDF
from vnav.imu import GRAVITY_W
from vnav.imu_calibration import (
    CalibrationError,
    ImuIntegral,
    calibrate_camera_imu,
    rotation_from_rates,
    time_offset_from_rates,
)

CAMERA = PinholeCamera.from_fovy(60.0, 640, 480)
CONES_W = np.array(
    [[8, 0, 0], [9, 2.5, 0], [11, -2, 0], [13, 1, 0], [7.5, -1.5, 0], [12, 3.5, 0], [10, 0.5, 0]],
    dtype=np.float64,
)
APEX_W = CONES_W + np.array([0.0, 0.0, 0.7])
IMU_DT_S = 0.005
CAMERA_DT_S = 0.05


class Trajectory:
    """The IMU's pose ``R_w_i = Rz(yaw) Ry(pitch) Rx(roll)`` of sinusoidal angles, position a
    sum of sinusoids: attitude, rate, position and acceleration in closed form."""

    def __init__(self, rocking: float = 1.0, speed: float = 2.0) -> None:
        self.amp_rad = rocking * np.array([0.2, 0.15, 0.3])
        self.freq = speed * np.array([1.3, 0.9, 0.5])
        self.phase = np.array([0.0, 1.0, 0.0])
        self.amp_m = np.array([1.5, 1.0, 0.3])
        self.freq_p = np.array([0.6, 0.8, 1.1])

    def T_w_i(self, t: float) -> np.ndarray:
        roll, pitch, yaw = self.amp_rad * np.sin(self.freq * t + self.phase)
        p = np.array([0.0, 0.0, 3.0]) + self.amp_m * np.sin(self.freq_p * t)
        return se3.make(so3.from_rpy(roll, pitch, yaw), p)

    def readings(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The exact gyro and accelerometer readings at ``t``: ``omega_i`` from the Euler
        angles' rates, ``f_i = R_i_w (a_w - g_w)``."""
        roll, pitch, yaw = self.amp_rad * np.sin(self.freq * t + self.phase)
        droll, dpitch, dyaw = self.amp_rad * self.freq * np.cos(self.freq * t + self.phase)
        Rx, Ry = so3.rot_x(roll), so3.rot_y(pitch)
        # d/dt of Rz Ry Rx = R [omega_i]x with omega_i = Rx^T Ry^T z dyaw + Rx^T y dpitch + x droll.
        omega_i = Rx.T @ Ry.T @ [0.0, 0.0, dyaw] + Rx.T @ [0.0, dpitch, 0.0] + [droll, 0.0, 0.0]
        a_w = -self.amp_m * self.freq_p**2 * np.sin(self.freq_p * t)
        R_w_i = so3.from_rpy(roll, pitch, yaw)
        return omega_i, R_w_i.T @ (a_w - GRAVITY_W)


def mount(rng: np.random.Generator) -> np.ndarray:
    """A camera looking forward and 20 deg down from an IMU along the body's axes, turned by
    up to 3 deg and moved by up to 15 cm: a held-out ``T_i_c``."""
    R = so3.exp(rng.uniform(-0.05, 0.05, 3)) @ so3.rot_y(math.radians(20.0)) @ R_FLU_RDF
    return se3.make(R, rng.uniform(-0.15, 0.15, 3))


def flight(
    T_i_c: np.ndarray,
    offset_s: float,
    *,
    trajectory: Trajectory | None = None,
    duration_s: float = 12.0,
    pixel_std: float = 0.0,
    rng: np.random.Generator | None = None,
):
    """Images every 50 ms from 0.5 s (camera clock = trajectory time), IMU readings every 5 ms
    stamped on the IMU clock ``t_imu = t_cam + offset_s``."""
    traj = trajectory or Trajectory()
    t_imu = np.arange(0.0, duration_s, IMU_DT_S)
    readings = [traj.readings(t) for t in t_imu]
    gyro_i = np.array([r[0] for r in readings])
    accel_i = np.array([r[1] for r in readings])
    t_cam = np.arange(0.5, duration_s - 0.5, CAMERA_DT_S)
    apex_uv = []
    for t in t_cam:
        T_c_w = se3.invert(traj.T_w_i(t) @ T_i_c)
        p_c = APEX_W @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        uv = CAMERA.project(p_c)
        seen = (p_c[:, 2] > 0) & CAMERA.in_image(uv, 5.0)
        noise = 0.0 if rng is None else rng.normal(0.0, pixel_std, (int(seen.sum()), 2))
        apex_uv.append(uv[seen] + noise)
    return t_cam, apex_uv, t_imu + offset_s, gyro_i, accel_i


def errors(result, T_i_c: np.ndarray, offset_s: float) -> tuple[float, float, float]:
    rot = math.degrees(np.linalg.norm(so3.log(result.T_i_c[:3, :3].T @ T_i_c[:3, :3])))
    return (
        rot,
        float(np.linalg.norm(result.T_i_c[:3, 3] - T_i_c[:3, 3])),
        abs(result.time_offset_s - offset_s),
    )


def solve(data, **kwargs):
    t_cam, apex_uv, t_imu, gyro_i, accel_i = data
    return calibrate_camera_imu(CAMERA, t_cam, apex_uv, APEX_W, t_imu, gyro_i, accel_i, **kwargs)


# ------------------------------------------------------------------------------ pieces


def test_the_integral_follows_a_known_motion():
    """A constant rate about a tilted axis and a constant world acceleration: ``G(t) =
    exp(omega t)`` and the IMU's path from its preintegration, in closed form."""
    omega_i = np.array([0.3, -0.2, 0.5])
    a_w = np.array([0.4, -0.1, 0.2])
    R_w_i0 = so3.from_rpy(0.1, -0.2, 0.3)
    t = np.arange(0.0, 3.0, IMU_DT_S)
    R_w_i = R_w_i0 @ so3.exp(t[:, None] * omega_i)
    f_i = np.einsum("nji,j->ni", R_w_i, a_w - GRAVITY_W)
    integral = ImuIntegral(t, np.tile(omega_i, (t.size, 1)), f_i)
    t_query = np.array([0.0123, 1.5, 2.9871])
    G, V, P = integral.at(t_query)
    np.testing.assert_allclose(G, so3.exp(t_query[:, None] * omega_i), atol=1e-12)
    # p(t) = R_w_i0 P(t) + g t^2 / 2 (from rest at the origin) must be a_w t^2 / 2: the
    # specific force's rotation is integrated with the force linear between readings, so the
    # error is second order in the 5 ms step.
    p_w = P @ R_w_i0.T + 0.5 * GRAVITY_W * t_query[:, None] ** 2
    np.testing.assert_allclose(p_w, 0.5 * a_w * t_query[:, None] ** 2, atol=1e-5)
    np.testing.assert_allclose(
        V @ R_w_i0.T + GRAVITY_W * t_query[:, None], a_w * t_query[:, None], atol=1e-5
    )


def test_the_integral_follows_a_smoothly_turning_motion():
    """Exact readings of a motion whose rate changes and turns its axis (the sinusoidal Euler
    angles of ``Trajectory``), every 5 ms: ``G`` at and between the readings is the true
    attitude to 1e-8 rad. The readings' mean over each interval (the trapezoid) is off by
    ``dt^2 / 12`` times the change of angular acceleration, about 1e-5 rad here: at 5 m, a
    camera turned by that moves an apex by as much as 5 mm of lever arm would."""
    traj = Trajectory(speed=3.0)
    t = np.arange(0.0, 3.0, IMU_DT_S)
    readings = [traj.readings(s) for s in t]
    integral = ImuIntegral(
        t, np.array([w for w, _ in readings]), np.array([f for _, f in readings])
    )
    t_query = np.r_[t[:-1], np.linspace(0.0013, 2.9917, 101)]
    G, _, _ = integral.at(t_query)
    R_w_i0 = traj.T_w_i(0.0)[:3, :3]
    truth = np.array([R_w_i0.T @ traj.T_w_i(s)[:3, :3] for s in t_query])
    error_rad = np.linalg.norm(so3.log(np.einsum("kji,kjl->kil", G, truth)), axis=1)
    assert error_rad.max() < 1e-8, error_rad.max()


def test_rotation_from_rates_matches_scipys_alignment():
    rng = np.random.default_rng(3)
    R_c_i = so3.exp(rng.normal(size=3))
    omega_i = rng.normal(size=(50, 3))
    omega_c = omega_i @ R_c_i.T + rng.normal(0.0, 0.01, (50, 3))
    found = rotation_from_rates(omega_c, omega_i)
    oracle, _ = Rotation.align_vectors(omega_c, omega_i)
    np.testing.assert_allclose(found, oracle.as_matrix(), atol=1e-10)
    assert np.degrees(np.linalg.norm(so3.log(found.T @ R_c_i))) < 0.5


def test_rotation_about_one_axis_is_refused():
    rates = np.outer(np.sin(np.arange(40.0)), [0.0, 0.0, 1.0])
    with pytest.raises(CalibrationError, match="not enough excitation"):
        rotation_from_rates(rates, rates)


def test_the_cross_correlation_finds_a_known_shift():
    traj = Trajectory()
    t = np.arange(0.0, 10.0, IMU_DT_S)
    gyro = np.array([traj.readings(s)[0] for s in t])
    integral = ImuIntegral(t + 0.0371, gyro, np.zeros_like(gyro))
    t0 = np.arange(1.0, 9.0, CAMERA_DT_S)
    t1 = t0 + CAMERA_DT_S
    angle_c = [
        np.linalg.norm(so3.log(traj.T_w_i(a)[:3, :3].T @ traj.T_w_i(b)[:3, :3]))
        for a, b in zip(t0, t1, strict=True)
    ]
    found = time_offset_from_rates(t0, t1, np.array(angle_c), integral, 0.1)
    assert abs(found - 0.0371) < 2e-4  # within the 0.5 ms grid, refined by the parabola


# ------------------------------------------------------------------------------ the solver


@pytest.mark.parametrize("seed", [0, 1])
def test_exact_data_gives_the_mount_and_offset(seed):
    """Held-out mounts and offsets, noise-free: the targets are 0.1 deg, 5 mm and 1 ms; what
    is left is the readings' integration between 5 ms samples."""
    rng = np.random.default_rng(seed)
    T_i_c = mount(rng)
    offset_s = float(rng.uniform(-0.04, 0.04))
    result = solve(flight(T_i_c, offset_s))
    rot_deg, trans_m, offset_err_s = errors(result, T_i_c, offset_s)
    assert rot_deg < 1e-3 and trans_m < 5e-4 and offset_err_s < 1e-5, (
        rot_deg,
        trans_m,
        offset_err_s,
    )
    assert result.reprojection_rms_px < 0.01
    # Kalibr's T_cam_imu is the inverse.
    np.testing.assert_allclose(result.T_c_i @ result.T_i_c, np.eye(4), atol=1e-12)


def test_pixel_noise_gives_errors_within_the_standard_errors():
    """0.4 px of Gaussian noise on every apex: the errors stay within 4 of the fit's standard
    errors (the translation's norm over three axes, each at most ``std_translation_m``)."""
    rng = np.random.default_rng(7)
    T_i_c = mount(rng)
    data = flight(
        T_i_c, 0.015, duration_s=20.0, pixel_std=0.4, rng=rng, trajectory=Trajectory(speed=3.0)
    )
    result = solve(data)
    rot_deg, trans_m, offset_err_s = errors(result, T_i_c, 0.015)
    assert rot_deg < 4.0 * math.sqrt(3.0) * result.std_rotation_deg
    assert trans_m < 4.0 * math.sqrt(3.0) * result.std_translation_m
    assert offset_err_s < 4.0 * result.std_offset_s
    # Per pixel coordinate, the residuals' RMS is the noise's (5000 residuals: within 10%).
    assert 0.36 < result.reprojection_rms_px / math.sqrt(2.0) < 0.44


def test_a_flight_without_rotation_is_refused():
    """Kalibr warns of "not enough excitation": an IMU that only translates gives neither
    ``R_i_c`` nor the offset."""
    still = Trajectory(rocking=0.0)
    with pytest.raises(CalibrationError, match="not enough excitation"):
        solve(flight(mount(np.random.default_rng(0)), 0.01, trajectory=still))


def test_too_few_images_are_refused():
    data = flight(mount(np.random.default_rng(0)), 0.01, duration_s=1.5)
    with pytest.raises(CalibrationError, match="too few images"):
        solve(data)


def _nan_apex(data):
    data[1] = [np.array([[1.0, np.nan]]), *data[1][1:]]


def _reversed_imu_stamps(data):
    data[2] = data[2][::-1].copy()


def _short_gyro(data):
    data[3] = data[3][:5]


@pytest.mark.parametrize(
    ("spoil", "message"),
    [
        (_nan_apex, r"apex_uv\[0\] must be finite"),
        (_reversed_imu_stamps, "t_s must increase"),
        (_short_gyro, "must match"),
    ],
)
def test_malformed_input_is_a_value_error_naming_it(spoil, message):
    data = list(flight(mount(np.random.default_rng(0)), 0.01, duration_s=3.0))
    spoil(data)
    with pytest.raises(ValueError, match=message):
        solve(tuple(data))
