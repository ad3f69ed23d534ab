"""The built-in scenarios, each a lesson of the lecture, with its own checks.

Each entry is a function returning the scenario in the TOML schema (user units, degrees), so
built-ins pass through exactly the validation a user's file does
(``scenarios.scenario.spec.from_dict``).
``load(name)`` with a name not registered raises a ScenarioError listing the valid names.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from scenarios.scenario.check_kinds import KINDS, default_checks
from scenarios.scenario.spec import GOAL_RADIUS_M, ScenarioError, ScenarioSpec, from_dict
from sim.config import MountError
from vnav.methods import METHODS, PREFERENCE, method

Scenario = dict[str, Any]


def _check(kind: str, limit: float, method: str = PREFERENCE[0], name: str = "") -> dict:
    """A ``[[checks]]`` entry: the method only where the kind uses one, the limit in metres
    (``limit_m``) where the kind measures metres."""
    entry: dict[str, Any] = {"kind": kind}
    if KINDS[kind].uses_method:
        entry["method"] = method
    entry[KINDS[kind].limit_key] = limit
    if name:
        entry["name"] = name
    return entry


ACCURACY_CHECKS = [
    _check(c.kind, c.limit, c.method, c.name)
    for c in default_checks()
    if c.kind == "error_bound" and not method(c.method).needs_several_images
]
"""The single-image methods' accuracy checks (every flight)."""

MOTION_CHECKS = [
    _check(c.kind, c.limit, c.method, c.name)
    for c in default_checks()
    if c.kind == "error_bound" and method(c.method).needs_several_images
]
"""The several-image methods' (``triangulated``), for flights that move across the line of
sight (a hover or a yaw in place gives its rays no parallax)."""
"""The accuracy bound of every checked method (``vnav.methods``), in PREFERENCE order."""


def frame_problem() -> Scenario:
    # Lecture chapter 0: hovering at 10 m, a cone 2 m ahead and 1 m to the left; then a 90 deg
    # clockwise yaw (the chapter's quiz). The camera looks 80 deg down, so its footprint holds
    # the cone at every heading.
    return {
        "name": "frame-problem",
        "description": "Chapter 0: a cone 2 m ahead, 1 m left of a drone at 10 m; the drone "
        "yaws 90 deg clockwise. Correct chain vs the naive mistake.",
        "lesson": "'2 m in front and 1 m to the left' of *what*? The camera reports the cone "
        "in its own frame (x right, y down, z forward). Adding those numbers to the "
        "drone's position (the naive estimate, red) is wrong by metres; "
        "p_w = T_w_b T_b_c p_c (blue, green, magenta) stays on the cone while the "
        "drone yaws.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 80.0},
        "cones": [{"position_w": [2.0, 1.0, 0.0]}],
        "flight": {
            "mode": "kinematic",
            "keyframes": [
                {"t": 0.0, "position_w": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, 0.0]},
                {"t": 1.0, "position_w": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, 0.0]},
                {"t": 4.0, "position_w": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, -90.0]},
                {"t": 5.0, "position_w": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, -90.0]},
            ],
        },
        # Seen from almost straight above, the cone's height is foreshortened to a few pixels:
        # the known-height triangle is degenerate there and that method (rightly) gives no
        # estimate, so only the depth image and the ground plane are held to their bounds.
        "checks": [
            *ACCURACY_CHECKS[:2],
            _check("detection_rate", 0.95, name="cone detected at every camera tick it is in view"),
            _check("naive_worse", 10.0, name="naive median error >= 10x depth_image"),
            _check(
                "world_estimate_spread",
                0.1,
                name="depth_image world estimate constant while yawing",
            ),
        ],
    }


def yaw_sweep() -> Scenario:
    # Chapters 0 and 3: p_c changes as R_w_b turns, p_w = R_w_b p_b + t does not.
    keyframes = [
        {"t": 2.0 * i, "position_w": [0.0, 0.0, 6.0], "rpy_deg": [0.0, 0.0, 90.0 * i]}
        for i in range(5)
    ]
    return {
        "name": "yaw-sweep",
        "view": "coordinates",
        "description": "Chapters 0 and 3: the drone yaws through 360 deg in place; the cone's "
        "camera coordinates change, its world estimate does not.",
        "lesson": "A rotation changes coordinates, not the point: p_b = R_b_w (p_w - t_w_b) "
        "moves with every degree of yaw, p_w stays put.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 45.0},
        "cones": [{"position_w": [6.0, 0.0, 0.0]}],
        "flight": {"mode": "kinematic", "keyframes": keyframes},
        "checks": [
            *ACCURACY_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check("camera_coords_span", 2.0, name="cone's camera coordinates move"),
            _check("world_estimate_spread", 0.15, name="depth_image world estimate constant"),
        ],
    }


def transform_composer() -> Scenario:
    # Chapter 8's showcase: body translation and yaw swept; the cone's coordinates in world,
    # body and camera frames are logged side by side; the world ones do not move.
    # Body translation, yaw and the camera's offset on the body all move, as the sliders of
    # the lecture's showcase.
    keyframes = [
        {
            "t": 0.0,
            "position_w": [0.0, 0.0, 5.0],
            "rpy_deg": [0.0, 0.0, 0.0],
            "camera_position_b": [0.2, 0.0, -0.05],
        },
        {
            "t": 2.0,
            "position_w": [2.0, 0.0, 5.0],
            "rpy_deg": [0.0, 0.0, 0.0],
            "camera_position_b": [0.5, 0.0, -0.05],
        },
        {
            "t": 4.0,
            "position_w": [2.0, 2.0, 5.0],
            "rpy_deg": [0.0, 0.0, -30.0],
            "camera_position_b": [0.5, 0.3, -0.05],
        },
        {
            "t": 6.0,
            "position_w": [0.0, 2.0, 4.0],
            "rpy_deg": [0.0, 0.0, -45.0],
            "camera_position_b": [0.2, 0.3, 0.1],
        },
        {
            "t": 8.0,
            "position_w": [0.0, 0.0, 5.0],
            "rpy_deg": [0.0, 0.0, 0.0],
            "camera_position_b": [0.2, 0.0, -0.05],
        },
    ]
    return {
        "name": "transform-composer",
        "view": "coordinates",
        # Framed where body translation, yaw and camera offset are all away from the start
        # (the flight ends back there).
        "show_at_s": 4.0,
        "description": "Chapter 8: body translation, yaw and camera offset swept; the cone "
        "in world, body and camera frames side by side.",
        "lesson": "T_w_c = T_w_b T_b_c: the composer of chapter 8, running on a simulated drone.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 45.0, "position_b": [0.2, 0.0, -0.05]},
        "cones": [{"position_w": [7.0, -1.0, 0.0]}],
        "flight": {"mode": "kinematic", "keyframes": keyframes},
        "checks": [
            *ACCURACY_CHECKS,
            *MOTION_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check("camera_coords_span", 1.0, name="cone's camera coordinates move"),
            _check("world_estimate_spread", 0.15, name="depth_image world estimate constant"),
        ],
    }


def gimbal_lock() -> Scenario:
    # Chapter 4: the body pitches nose-up through -90 deg (a 'straight up' attitude), back,
    # and up again to end held at -90 deg, where the viewer opens: locked. The camera, mounted
    # 80 deg down, then looks just below the horizon and still sees the cone.
    def kf(t: float, pitch_deg: float) -> dict:
        return {"t": t, "position_w": [0.0, 0.0, 2.0], "rpy_deg": [0.0, pitch_deg, 0.0]}

    return {
        "name": "gimbal-lock",
        "view": "attitude",
        "description": "Chapter 4: a kinematic pitch-up through 90 deg; roll/pitch/yaw "
        "degenerate, the quaternion and the estimates do not.",
        "lesson": "At pitch = -90 deg only yaw + roll is defined (gimbal lock): the extracted "
        "angles jump by 180 deg past it while the quaternion moves smoothly and the "
        "cone estimates do not notice.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 80.0},
        "cones": [{"position_w": [10.0, 0.0, 0.0]}],
        "flight": {
            "mode": "kinematic",
            "keyframes": [
                kf(0.0, -55.0),
                kf(2.0, -90.0),
                kf(3.0, -90.0),
                kf(4.0, -100.0),
                kf(6.0, -55.0),
                kf(7.5, -90.0),
                kf(8.0, -90.0),
            ],
        },
        "checks": [
            *ACCURACY_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check("gimbal_lock_seen", 1.0, name="camera ticks flagged as gimbal lock"),
        ],
    }


def orbit() -> Scenario:
    # The controller circles the cone at 6 m radius, 4 m up, heading always at the cone; the
    # camera is pitched down by the angle under which the cone is seen from the circle.
    radius_m, height_m = 6.0, 4.0
    return {
        "name": "orbit",
        "description": "The geometric controller flies a circle around the cone, camera on it.",
        "lesson": "The controller's attitude error lives on SO(3) (Lee et al. 2010); the "
        "estimates only need T_w_b from the simulator's state.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": math.degrees(math.atan2(height_m, radius_m))},
        "cones": [{"position_w": [0.0, 0.0, 0.0]}],
        "flight": {
            "mode": "orbit",
            "center_w": [0.0, 0.0, 0.0],
            "radius_m": radius_m,
            "height_m": height_m,
            "period_s": 16.0,
            "turns": 1.0,
        },
        "checks": [
            *ACCURACY_CHECKS,
            *MOTION_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check("tracking_error", 0.3, name="controller tracking error"),
        ],
    }


def approach() -> Scenario:
    return {
        "name": "approach",
        "description": "The controller flies from 30 m towards the cone; error against range.",
        "lesson": "Range costs pixels: at 20 m the 0.70 m cone is 14 px tall, so one pixel is "
        "7% of its height; the depth image and ground plane degrade far more slowly.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 12.0},
        "cones": [{"position_w": [0.0, 0.0, 0.0]}],
        "flight": {
            "mode": "controlled",
            "waypoints": [
                {"t": 0.0, "position_w": [-30.0, 0.0, 3.0], "yaw_deg": 0.0},
                {"t": 1.0, "position_w": [-30.0, 0.0, 3.0], "yaw_deg": 0.0},
                {"t": 13.0, "position_w": [-8.0, 0.0, 3.0], "yaw_deg": 0.0},
            ],
        },
        "duration_s": 14.0,
        "checks": [
            *ACCURACY_CHECKS,
            *MOTION_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check("tracking_error", 1.0, name="controller tracking error"),
        ],
    }


def multi_cone() -> Scenario:
    cones = [[8.0, 0.0], [10.0, 3.0], [12.0, -4.0], [7.0, -2.5], [14.0, 1.5]]
    return {
        "name": "multi-cone",
        "description": "Five cones at once; every estimate matched to its own true cone.",
        "lesson": "With several cones each estimate must be matched to the right truth "
        "(nearest one-to-one assignment) before it can be scored.",
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 30.0},
        "cones": [{"position_w": [x, y, 0.0]} for x, y in cones],
        "flight": {
            "mode": "kinematic",
            "keyframes": [
                {"t": 0.0, "position_w": [0.0, 0.0, 5.0], "rpy_deg": [0.0, 0.0, -15.0]},
                {"t": 3.0, "position_w": [2.0, 0.0, 5.0], "rpy_deg": [0.0, 0.0, 15.0]},
                {"t": 5.0, "position_w": [2.0, 0.0, 5.0], "rpy_deg": [0.0, 0.0, 0.0]},
            ],
        },
        "checks": [
            *ACCURACY_CHECKS,
            *MOTION_CHECKS,
            _check("detection_rate", 0.95, name="cones detected whenever fully in view"),
            _check("matched_cones", 5.0, name="distinct cones matched"),
        ],
    }


def latency() -> Scenario:
    # Time (the stamped frame buffer): the image arrives 50 ms after its exposure, stamped on a
    # camera clock 20 ms off the pose clock. Low (1.5 m) so that the range is almost the
    # horizontal distance, the lever arm a yaw swings the estimate by. First a fast yaw to
    # and fro (100 deg/s), then a sideways pass (2 m/s) with no turn: the stale pose's error
    # is range |omega| dt in the first, |v| dt in the second.
    keyframes = [
        {"t": t, "position_w": [0.0, y_m, 1.5], "rpy_deg": [0.0, 0.0, yaw]}
        for t, y_m, yaw in (
            (0.0, 0.0, 0.0),
            (0.25, 0.0, 25.0),
            (0.75, 0.0, -25.0),
            (1.25, 0.0, 25.0),
            (1.5, 0.0, 0.0),
            (2.0, 0.0, 0.0),
            (3.0, 2.0, 0.0),
            (5.0, -2.0, 0.0),
        )
    ]
    return {
        "name": "latency",
        "description": "Time: images arrive 50 ms late on a camera clock 20 ms off; the pose "
        "at the exposure stamp vs the newest pose, through a fast yaw and a sideways pass.",
        "lesson": "An image is stamped when it is exposed and reaches the estimator 50 ms "
        "later; by then the drone has moved. Looking the body pose up at the image's stamp "
        "(read on the pose clock: t_pose = t_cam + offset) in a buffer of stamped poses keeps "
        "p_w = T_w_b(t) T_b_c p_c exact. Taking the newest pose instead (what a pipeline "
        "ignoring stamps does) is off by what the drone moved in between: |v| dt + "
        "range |omega| dt, half a metre at 6 m while yawing 100 deg/s.",
        "camera_rate_hz": 10.0,
        # Framed in the middle of the fast yaw, where the newest pose is furthest off.
        "show_at_s": 0.5,
        "camera": {"pitch_down_deg": 15.0},
        "cones": [{"position_w": [6.0, 0.0, 0.0]}],
        "flight": {"mode": "kinematic", "keyframes": keyframes},
        "timing": {
            "pose_rate_hz": 200.0,
            "pose_latency_s": 0.0,
            "image_latency_s": 0.05,
            "camera_clock_offset_s": 0.02,
            "jitter_s": 0.002,
        },
        "checks": [
            *ACCURACY_CHECKS,
            *MOTION_CHECKS,
            _check("detection_rate", 0.95, name="cone detected whenever fully in view"),
            _check(
                "latency_prediction",
                0.25,
                name="newest-pose error as predicted, |v| dt + range |omega| dt",
            ),
        ],
    }


def uncertainty() -> Scenario:
    # Uncertainty: a noisy pose stream (5 cm, 1 deg), image noise below the detector's
    # thresholds and range-dependent depth noise, on an approach from 14 m to 4 m at a cone
    # seen from 3 m up (shallow enough for known_height at every range). The attitude noise
    # dominates the error and grows with range, as p_w = T_w_b T_b_c p_c predicts.
    keyframes = [
        {"t": 0.0, "position_w": [-14.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]},
        {"t": 12.0, "position_w": [-4.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]},
    ]
    return {
        "name": "uncertainty",
        "description": "Uncertainty: a noisy pose (5 cm, 1 deg), image and depth noise; each "
        "estimate's covariance through p_w = T_w_b T_b_c p_c, checked by its NEES.",
        "lesson": "Every estimate comes with a covariance: the pose's (the pose stream's "
        "noise, composed with the camera mount), the keypoints' and the depth's, pushed "
        "through the chain p_w = T_w_b T_b_c p_c to first order. The ellipsoids (3 sigma) "
        "stretch across the line of sight as the range grows: 1 deg of attitude error moves "
        "a cone 10 m away by 17 cm. The NEES plots say whether the covariance is honest: "
        "its mean over the run must sit in the chi-square band around the degrees of "
        "freedom (3; ground_plane 2, whose estimate lies on z = 0 by construction).",
        "camera_rate_hz": 10.0,
        "view": "nees",
        "close_up": "cone",
        "camera": {"pitch_down_deg": 12.0},
        "cones": [{"position_w": [0.0, 0.0, 0.0]}],
        "flight": {"mode": "kinematic", "keyframes": keyframes},
        "noise": {
            "position_std_m": 0.05,
            "attitude_std_deg": 1.0,
            "intensity_std_grey": 4.0,
            "depth_std_m": 0.005,
            "depth_std_per_m2": 0.0002,
        },
        "checks": [
            _check("consistent", 0.05, m, f"{m} covariance consistent (NEES in 95% band)")
            for m in (m.name for m in METHODS if m.bound and not m.needs_several_images)
        ]
        + [_check("detection_rate", 0.95, name="cone detected whenever fully in view")],
    }


CALIBRATION_MOUNT_ERROR = MountError(position_m=(0.02, -0.015, 0.015), rpy_deg=(1.0, -1.5, 1.5))
"""The ``calibration`` built-in's true mount's error from the declared one."""


def mount_error_text(error: MountError) -> str:
    """How far a mount is off, as the built-in's description, the README and the recording
    say it: the rotation's angle to 0.01 deg (``MountError.angle_deg``) and the camera
    centre's offset to the millimetre."""
    return f"{error.angle_deg:.2f} deg and {1e3 * error.offset_m:.0f} mm"


def _calibration_keyframes() -> list[dict[str, Any]]:
    """The calibration built-in's flight: a swing about all three axes each second, 18 s."""
    swings = [(8.0, -5.0, 12.0), (-8.0, 6.0, -10.0), (6.0, 5.0, 8.0), (-6.0, -6.0, -12.0)]
    keyframes = [{"t": 0.0, "position_w": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]}]
    for k in range(16):
        roll, pitch, yaw = swings[k % len(swings)]
        keyframes.append(
            {
                "t": 1.0 + k,
                "position_w": [0.1 * k, 0.8 * (-1) ** k, 3.0 + 0.3 * (-1) ** (k // 2)],
                "rpy_deg": [roll, pitch, yaw],
            }
        )
    keyframes.append({"t": 18.0, "position_w": [1.6, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]})
    return keyframes


def _mount_error_table(error: MountError) -> dict[str, list[float]]:
    """A ``[*.mount_error]`` table of ``error``."""
    return {"position_m": list(error.position_m), "rpy_deg": list(error.rpy_deg)}


def calibration() -> Scenario:
    # Calibration: the camera sits off where it is declared (CALIBRATION_MOUNT_ERROR) and its
    # clock runs 30 ms off the pose clock. Eight cones in view and a flight that rolls,
    # pitches and yaws (all three rotation axes, so that every axis of the mount and the offset
    # shows in the images) let vnav.calibration recover both from the apexes' reprojection
    # error.
    keyframes = _calibration_keyframes()
    cones = [
        [8.0, 0.0],
        [9.0, 2.5],
        [11.0, -2.0],
        [13.0, 1.0],
        [7.5, -1.5],
        [12.0, 3.5],
        [10.0, 0.5],
        [14.0, -1.0],
    ]
    return {
        "name": "calibration",
        "description": "Calibration: a camera mounted "
        f"{mount_error_text(CALIBRATION_MOUNT_ERROR)} off its declared pose, its clock 30 ms "
        "off; both recovered from the flight's cone apexes, and the estimates made again with "
        "the recovered mount.",
        "lesson": "The declared camera mount T_b_c is a measurement, and so is the camera's "
        "clock: when either is wrong every estimate through p_w = T_w_b T_b_c p_c is wrong. "
        "With a map of cones, each apex the camera sees must project where T_c_b "
        "T_b_w(t_cam + offset) says; over a flight that turns about every axis, least squares "
        "on those reprojection errors recovers the mount (here to a few thousandths of a "
        "degree) and the clock offset (to a fraction of a millisecond). The estimates made with "
        "the declared mount are off by what its error swings the cones through (depth_image "
        "by decimetres, beyond its bound: the mount error, not the method); the same images "
        "estimated again with the recovered mount are back within the accuracy contract. "
        "`vnav-demo calibrate` does the same from any recording.",
        "camera_rate_hz": 20.0,
        "camera": {
            "pitch_down_deg": 20.0,
            "mount_error": _mount_error_table(CALIBRATION_MOUNT_ERROR),
        },
        "cones": [{"position_w": [x, y, 0.0]} for x, y in cones],
        "flight": {"mode": "kinematic", "keyframes": keyframes},
        "timing": {"pose_rate_hz": 200.0, "camera_clock_offset_s": 0.03},
        "checks": [
            _check("calibration_rotation", 0.05, name="mount rotation recovered within 0.05 deg"),
            _check("calibration_translation", 0.005, name="mount position recovered within 5 mm"),
            _check("calibration_time_offset", 0.001, name="clock offset recovered within 1 ms"),
            _check("detection_rate", 0.9, name="cones detected whenever fully in view"),
        ],
    }


IMU_MOUNT_ERROR = MountError(position_m=(0.003, -0.002, 0.004), rpy_deg=(0.8, -0.6, 1.2))
"""The ``imu`` built-in's true IMU mount's error from the declared one (IMU frame)."""
IMU_NOISE = {
    "accelerometer_noise_density": 2.0e-3,
    "accelerometer_random_walk": 3.0e-3,
    "gyroscope_noise_density": 1.6968e-4,
    "gyroscope_random_walk": 1.9393e-5,
}
"""Kalibr's noise figures of a consumer MEMS IMU, in Kalibr's units: those published with the
EuRoC MAV dataset for its ADIS16448 (``imu0``, 200 Hz)."""


IMU_FLIGHT_S = 15.0
"""The ``imu`` built-in's flight: a second's hover, then rocking to the end."""


def imu_waypoints(duration_s: float = IMU_FLIGHT_S) -> list[dict[str, Any]]:
    """The ``imu`` built-in's waypoints: a second's hover at 3 m, then a waypoint every half
    second, 15 cm to either side in turn (the controller rolls the body 20-30 deg to get
    there and back), 20 cm forward or back every one and a half seconds (pitch), 20 cm up or
    down and a yaw of +-15 deg every second, so that the IMU turns and accelerates about and
    along every axis, fast (the lever arm shows in the accelerometer through angular rate and
    acceleration), while the cones stay in view."""
    hover = {"position_w": [0.0, 0.0, 3.0], "yaw_deg": 0.0}
    waypoints = [{"t": 0.0, **hover}, {"t": 1.0, **hover}]
    for k in range(3, round(2.0 * duration_s)):
        waypoints.append(
            {
                "t": 0.5 * k,
                "position_w": [
                    0.2 * (-1) ** (k // 3),
                    0.15 * (-1) ** k,
                    3.0 + 0.2 * (-1) ** (k // 2),
                ],
                "yaw_deg": 15.0 * (-1) ** (k // 2),
            }
        )
    return waypoints


def _imu_checks() -> list[dict]:
    """The ``imu`` built-in's checks: MuJoCo's IMU against vnav's chain, the camera-IMU
    calibration's three figures, the detections."""
    return [
        _check(
            "imu_consistent",
            1e-9,
            name="MuJoCo's IMU = vnav.imu's chain at every physics step",
        ),
        _check("calibration_imu_rotation", 0.1, name="T_i_c rotation within 0.1 deg"),
        _check("calibration_imu_translation", 0.005, name="T_i_c translation within 5 mm"),
        _check("calibration_imu_time_offset", 0.001, name="clock offset within 1 ms"),
        # No tracking check: the rocking asks for more than the controller follows (it
        # lags by decimetres), and the calibration needs the motion, not the reference.
        _check("detection_rate", 0.9, name="cones detected whenever fully in view"),
    ]


def imu() -> Scenario:
    # An IMU 4 cm forward, 2.5 cm right and 1.5 cm up of the body origin, yawed 90 deg and
    # pitched 30 deg on the body (a board mounted sideways on a wedge), a few millimetres and
    # about a degree off where it is declared, its clock 15 ms ahead of the camera's; the
    # camera off its declared mount too (as calibration's), so that the calibration cannot
    # take T_i_c from the declared mounts. Four cones (PnP needs four points: with three no
    # image gives a camera pose) 5-6.5 m ahead, near enough that each image places the
    # camera to about a centimetre.
    cones = [[5.0, 0.0], [5.5, 1.5], [6.0, -1.3], [6.5, 0.6]]
    return {
        "name": "imu",
        "description": "An IMU mounted off-centre and turned on the body, its mount a little "
        "off what is declared, its clock 15 ms off the camera's, with a consumer MEMS IMU's "
        "noise, and the camera off its declared mount; a flight that rocks about every axis "
        "and accelerates along each, in front of four cones, calibrates the camera against "
        "the IMU from the images and readings alone.",
        "lesson": "'An IMU measures accelerations in a body frame': its own. The accelerometer "
        "reads the specific force f_i = R_i_w (a_w(p_i) - g_w) in the IMU frame i, where the "
        "body's acceleration is carried to the IMU's position by the lever arm, a_w(p_i) = a_w "
        "+ alpha x r + omega x (omega x r), with r = R_w_b t_b_i; the gyroscope reads "
        "omega_i = R_i_b omega_b wherever it sits. Gravity's sign: hovering, the IMU is not "
        "accelerating, yet it reads +9.81 m/s^2 *up* (the thrust holding it against gravity; "
        "in free fall it would read 0), here along the IMU's axes that point up, turned by "
        "R_b_i. MuJoCo's own accelerometer and gyro agree with that chain at every physics "
        "step (imu_consistent), and the readings carry Kalibr's noise model with the figures "
        "of EuRoC's ADIS16448. As Kalibr does, the camera in the IMU frame T_i_c and the "
        "clock offset come back from the cones' images and the IMU's readings alone "
        "(calibration_imu_*): the rotation from the gyro's turns, the offset from when they "
        "start and stop, the translation from the lever arm the accelerometer feels.",
        "camera_rate_hz": 10.0,
        "camera": {
            "pitch_down_deg": 25.0,
            "width": 1280,
            "height": 960,
            "mount_error": _mount_error_table(CALIBRATION_MOUNT_ERROR),
        },
        "cones": [{"position_w": [x, y, 0.0]} for x, y in cones],
        "flight": {"mode": "controlled", "waypoints": imu_waypoints()},
        "duration_s": IMU_FLIGHT_S,
        "imu": {
            "rate_hz": 200.0,
            "position_b": [0.04, -0.025, 0.015],
            "rpy_deg": [0.0, 30.0, 90.0],
            "mount_error": _mount_error_table(IMU_MOUNT_ERROR),
            "time_offset_s": 0.015,
            **IMU_NOISE,
        },
        "checks": _imu_checks(),
    }


def _avoid_world(estimate: str, *, heading_deg: float = 0.0) -> Scenario:
    """A cone on the straight line from start to goal, 10 m ahead, the line ``heading_deg``
    from the world's x axis (counter-clockwise); the drone flies on ``estimate``'s map of it
    (``flight.mode = "navigate"``)."""
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    return {
        "camera_rate_hz": 10.0,
        "camera": {"pitch_down_deg": 15.0},
        "cones": [{"position_w": [round(10.0 * c, 12), round(10.0 * s, 12), 0.0]}],
        "flight": {
            "mode": "navigate",
            "start_w": [0.0, 0.0, 0.5],
            "goal_w": [round(20.0 * c, 12), round(20.0 * s, 12), 0.5],
            "speed_mps": 2.0,
            "clearance_m": 1.0,
            "estimate": estimate,
        },
    }


def avoid() -> Scenario:
    # Lecture chapter 0 made real: the drone must navigate around the cone it sees.
    return {
        "name": "avoid",
        "description": "Chapter 0, closed loop: a cone stands on the straight line to the goal; "
        "the drone maps it with the depth image and flies around it.",
        "lesson": "The planner avoids where the estimator says the cone is. With "
        "p_w = T_w_b T_b_c p_c the mapped cone (blue) sits on the real one, the plan bends "
        "round it at clearance_m, and MuJoCo's own distance between the drone and the cone "
        "never drops below 0.3 m.",
        **_avoid_world("depth_image"),
        # Mid-detour: the plan bends round the mapped cone's keep-out circle ahead.
        "show_at_s": 4.5,
        "checks": [
            *ACCURACY_CHECKS,
            _check("reached_goal", GOAL_RADIUS_M, name="reached the goal"),
            _check("no_collision", 0.0, name="never touched the cone"),
            _check("min_clearance", 0.3, name="true clearance at least 0.3 m"),
        ],
    }


def avoid_naive() -> Scenario:
    return {
        "name": "avoid-naive",
        "description": "Chapter 0's warning, flown: the same cone mapped by the naive chain; "
        "the drone flies into it.",
        "lesson": "'If you naively treat 2 m forward in the camera frame as 2 m forward in the "
        "world frame, you will command the drone to fly into the cone.' The camera's z axis "
        "points forward; added to the drone's position it becomes the world's z, up: the "
        "naive map puts the cone in the sky, metres above the drone, where no cone can be, so "
        "nothing is avoided and MuJoCo reports the contact.",
        **_avoid_world("naive"),
        "checks": [_check("collision", 1.0, name="the naive map flies into the cone")],
    }


def avoid_yawed() -> Scenario:
    return {
        "name": "avoid-yawed",
        "description": "Chapter 0's other case, flown: the drone heads north (yawed 90 deg), "
        "its map takes body axes for world axes; the cone lands off to the side and the drone "
        "flies into the real one.",
        "lesson": "'A cone 2 m in front, 1 m to the left': after a 90-degree yaw those body "
        "numbers are not world numbers. The body's x (forward) now points along the world's "
        "y; writing p_w = t_w_b + T_b_c p_c, the body rotation R_w_b dropped, puts the cone "
        "along the world's x instead, off to the drone's right, as far to the side as it "
        "really is ahead. The planner dodges that phantom, which is never on its way, flies "
        "the straight line, and MuJoCo reports the contact with the real cone. Heading along "
        "the world's x (yaw 0) the same mistake would be invisible: R_w_b = I there.",
        **_avoid_world("mistake:body-rotation-dropped", heading_deg=90.0),
        "checks": [_check("collision", 1.0, name="the body-axes map flies into the cone")],
    }


REGISTRY: dict[str, Callable[[], Scenario]] = {
    "frame-problem": frame_problem,
    "yaw-sweep": yaw_sweep,
    "transform-composer": transform_composer,
    "gimbal-lock": gimbal_lock,
    "orbit": orbit,
    "approach": approach,
    "multi-cone": multi_cone,
    "latency": latency,
    "uncertainty": uncertainty,
    "calibration": calibration,
    "imu": imu,
    "avoid": avoid,
    "avoid-naive": avoid_naive,
    "avoid-yawed": avoid_yawed,
}


def names() -> list[str]:
    """Registered scenario names, in teaching order."""
    return list(REGISTRY)


def load(name: str) -> ScenarioSpec:
    """The built-in scenario ``name``.

    Raises
    ------
    ScenarioError
        If no scenario has that name; the message lists the valid names.
    """
    if name not in REGISTRY:
        raise ScenarioError(f"unknown scenario {name!r}; valid names: {', '.join(REGISTRY)}")
    return from_dict(REGISTRY[name](), where=f"built-in {name}")
