"""Calibration speed: the camera mount and clock offset from a 30 s flight at 30 Hz.

Two figures, each the best and the median of ``--repeat`` timed calls, in seconds:

- ``synthetic``: ``vnav.calibration.calibrate_camera`` on a 30 s flight imaged at 30 Hz (900
  images, 8 cones, apexes projected exactly then given 0.4 px of noise, a 200 Hz pose stream):
  the solver alone, target under 10 s on 2 cores;
- ``builtin``: ``scenarios.judge.calibration.calibrate_run`` (two passes, the second
  re-fitting every apex on its mask) on the built-in ``calibration`` run at its own 20 Hz for
  18 s (the simulation itself is not timed);
- ``imu``: the camera-IMU calibration (``scenarios.judge.imu_calibration.calibrate_imu_run``,
  two passes, ``vnav.imu_calibration``) of a 30 s controlled flight that rocks (``imu_flight``:
  camera and IMU both off their declared mounts, a 200 Hz IMU 12 ms off the camera's clock),
  from its images and IMU readings alone; target under 10 s on 2 cores. The same flight's
  readings with Kalibr-style noise added (``IMU_NOISE``, drawn by ``vnav.imu.ImuNoiseProcess``
  as the simulator draws it) show what the IMU's noise costs.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

TARGET_S = 10.0

IMU_NOISE = {
    "accelerometer_noise_density": 2.0e-3,
    "accelerometer_random_walk": 3.0e-3,
    "gyroscope_noise_density": 1.6968e-4,
    "gyroscope_random_walk": 1.9393e-5,
}
"""Kalibr-style noise figures (its wiki's example ``imu.yaml``, an ADIS16448), Kalibr's units."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=3, help="timed calls per figure")


def _synthetic_flight():
    from vnav import se3, so3
    from vnav.camera import PinholeCamera
    from vnav.frames import mount_rotation

    camera = PinholeCamera.from_fovy(60.0, 640, 480)
    rng = np.random.default_rng(0)
    cones = np.array(
        [[8, 0], [9, 2.5], [11, -2], [13, 1], [7.5, -1.5], [12, 3.5], [10, 0.5], [14, -1]],
        dtype=np.float64,
    )
    apex_w = np.column_stack([cones, np.full(len(cones), 0.7)])

    def pose(t: float) -> np.ndarray:
        rpy = [0.15 * math.sin(1.3 * t), 0.12 * math.sin(0.9 * t + 1), 0.3 * math.sin(0.5 * t)]
        p = [1.5 * math.sin(0.3 * t), math.sin(0.4 * t), 3.0 + 0.5 * math.sin(0.7 * t)]
        return se3.make(so3.from_rpy(*rpy), p)

    stamps = np.arange(0.0, 30.0 + 1e-9, 0.005)
    T_w_b = np.array([pose(t) for t in stamps])
    declared = se3.make(mount_rotation(math.radians(20.0)), [0.15, 0.0, 0.05])
    true = declared @ se3.make(so3.from_rpy(*np.radians([1.0, -1.5, 1.5])), [0.02, -0.015, 0.015])
    t_true = np.arange(0.5, 29.5, 1.0 / 30.0)
    apex_uv = []
    for t in t_true:
        T_c_w = se3.invert(pose(t) @ true)
        p_c = apex_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        uv = camera.project(p_c)
        seen = (p_c[:, 2] > 0) & camera.in_image(uv, 5.0)
        apex_uv.append(uv[seen] + rng.normal(0.0, 0.4, (int(seen.sum()), 2)))
    return camera, stamps, T_w_b, t_true - 0.03, apex_uv, apex_w, declared


def imu_flight(duration_s: float = 30.0) -> dict:
    """A controlled flight that rocks (waypoints 1 s apart, 0.3 m to either side, up and down
    0.2 m, yawing +-15 deg: about +-25 deg of roll) in front of 8 cones, camera at 20 Hz, with
    an IMU turned on the body (``rpy_deg`` 180, 0, 90) and both mounts off their declared
    poses, the IMU's clock 12 ms off the camera's."""
    cones = [[8.0, 0.0], [9.0, 2.5], [11.0, -2.0], [13.0, 1.0], [7.5, -1.5], [12.0, 3.5]]
    cones += [[10.0, 0.5], [14.0, -1.0]]
    waypoints = [{"t": 0.0, "position_w": [0.0, 0.0, 3.0], "yaw_deg": 0.0}]
    for k in range(1, int(duration_s)):
        waypoints.append(
            {
                "t": float(k),
                "position_w": [0.2 * ((k // 3) % 2), 0.3 * (-1) ** k, 3.0 + 0.2 * (-1) ** (k // 2)],
                "yaw_deg": 15.0 * (-1) ** (k // 2),
            }
        )
    return {
        "name": "imu-calibration",
        "camera_rate_hz": 20.0,
        "camera": {
            "pitch_down_deg": 20.0,
            "mount_error": {"position_m": [0.02, -0.015, 0.015], "rpy_deg": [1.0, -1.5, 1.5]},
        },
        "cones": [{"position_w": [x, y, 0.0]} for x, y in cones],
        "flight": {"mode": "controlled", "waypoints": waypoints},
        "duration_s": duration_s,
        "timing": {"camera_clock_offset_s": 0.03},
        "imu": {
            "rate_hz": 200.0,
            "position_b": [0.05, -0.03, 0.02],
            "rpy_deg": [180.0, 0.0, 90.0],
            "mount_error": {"position_m": [0.004, 0.003, -0.002], "rpy_deg": [1.0, -0.5, 2.0]},
            "time_offset_s": 0.012,
        },
        "checks": [
            {"kind": "calibration_imu_rotation", "limit": 0.1},
            {"kind": "calibration_imu_translation", "limit_m": 0.005},
            {"kind": "calibration_imu_time_offset", "limit": 0.001},
        ],
    }


def _with_imu_noise(result):
    """``result`` with Kalibr-style noise (``IMU_NOISE``) added to its IMU's readings."""
    import dataclasses

    from vnav.imu import ImuNoise, ImuNoiseProcess

    record = result.imu
    dt_s = float(np.median(np.diff(record.t_s)))
    da, dg = ImuNoiseProcess(ImuNoise(**IMU_NOISE), dt_s, np.random.default_rng(1)).series(
        len(record.t_s)
    )
    noisy = dataclasses.replace(record, accel_i=record.accel_i + da, gyro_i=record.gyro_i + dg)
    return dataclasses.replace(result, imu=noisy)


def _imu_line(label: str, record, med: float | None = None, best: float | None = None) -> str:
    if record.refused is not None:
        return f"{label}: refused: {record.refused}"
    e, s = record.errors, record.std
    timing = "" if med is None else f"best {best:.2f} s, median {med:.2f} s; "
    return (
        f"{label}: {timing}errors {e['rotation_deg']:.4f} deg, "
        f"{1e3 * e['translation_m']:.2f} mm, {1e3 * e['time_offset_s']:.3f} ms "
        f"(standard errors {s['rotation_deg']:.4f} deg, {1e3 * s['translation_m']:.2f} mm, "
        f"{1e3 * s['time_offset_s']:.3f} ms)"
    )


def _time_s(fn, repeat: int) -> tuple[float, float, object]:
    samples, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples), min(samples), out


def run(args: argparse.Namespace) -> dict:
    from scenarios import pipeline
    from scenarios.judge.calibration import calibrate_run
    from scenarios.scenario import builtin
    from vnav.calibration import calibrate_camera

    repeat = getattr(args, "repeat", 3)
    flight = _synthetic_flight()
    med, best, result = _time_s(lambda: calibrate_camera(*flight), repeat)
    figures: dict[str, object] = {
        "synthetic_images": len(flight[3]),
        "synthetic_observations": result.observations_used,
        "synthetic_median_s": med,
        "synthetic_best_s": best,
    }
    outcome = pipeline.run(builtin.load("calibration"), seed=1)
    med_b, best_b, record = _time_s(lambda: calibrate_run(outcome.result), repeat)
    figures.update(
        builtin_images=len(outcome.result.ticks),
        builtin_median_s=med_b,
        builtin_best_s=best_b,
        builtin_rotation_error_deg=record.errors.get("rotation_deg"),
    )
    from scenarios.judge.imu_calibration import calibrate_imu_run
    from scenarios.run.runner import run_scenario
    from scenarios.scenario.spec import from_dict

    imu_run = run_scenario(from_dict(imu_flight()), seed=1)
    med_i, best_i, imu_record = _time_s(lambda: calibrate_imu_run(imu_run), repeat)
    noisy_record = calibrate_imu_run(_with_imu_noise(imu_run))
    for key, rec in (("imu", imu_record), ("imu_noisy", noisy_record)):
        figures[f"{key}_refused"] = rec.refused
        for name, value in rec.errors.items():
            figures[f"{key}_error_{name}"] = value
        for name, value in rec.std.items():
            figures[f"{key}_std_{name}"] = value
    figures.update(imu_images=len(imu_run.ticks), imu_median_s=med_i, imu_best_s=best_i)
    if not getattr(args, "json", False):
        print(f"calibration, best and median of {repeat}, seconds (target < {TARGET_S:g} s)")
        print(
            f"synthetic 30 s at 30 Hz ({len(flight[3])} images, {result.observations_used} "
            f"apexes): best {best:.2f}, median {med:.2f}"
        )
        print(
            f"built-in calibration run ({len(outcome.result.ticks)} images, two passes): "
            f"best {best_b:.2f}, median {med_b:.2f}"
        )
        print(f"camera-IMU, 30 s rocking flight ({len(imu_run.ticks)} images, two passes)")
        print(_imu_line("  noise-free IMU", imu_record, med_i, best_i))
        print(_imu_line("  Kalibr-style IMU noise", noisy_record))
    return figures
