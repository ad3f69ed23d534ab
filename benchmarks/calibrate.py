"""Calibration: its speed, from a recording as from the run, and how honest its standard errors are.

Three figures:

- ``synthetic``: ``vnav.calibration.calibrate_camera`` on a 30 s flight imaged at 30 Hz (900
  images, 8 cones, apexes projected exactly then given 0.4 px of noise, a 200 Hz pose stream):
  the solver alone, best and median of ``--repeat`` calls, target under 10 s on 2 cores;
- ``recording``: ``vnav-demo calibrate``'s work on the recording of a 30 s flight of the
  ``calibration`` built-in's kind at its 20 Hz (``long_flight_spec``): reading the file
  (every blob made a detection again) and the two passes, best and median, target under
  10 s; its errors against the truth and against the run's own calibration (the simulation
  and the recording are not timed);
- ``coverage``: over ``--seeds`` held-out mounts (``held_out_spec``: the built-in with a mount
  error and a clock offset drawn from the seed) at ``--rate`` Hz, how many answers lie within
  3 standard errors of the truth on every one of the 7 parameters (the target: 19 of 20),
  and the largest ratio of error to standard error.
- ``imu``: the camera-IMU calibration (``scenarios.judge.imu_calibration.calibrate_imu_run``,
  two passes, ``vnav.imu_calibration``) of a 30 s controlled flight that rocks (``imu_flight``:
  camera and IMU both off their declared mounts, a 200 Hz IMU 12 ms off the camera's clock),
  from its images and IMU readings alone; target under 10 s on 2 cores. The same flight's
  readings with Kalibr-style noise added (``IMU_NOISE``, drawn by ``vnav.imu.ImuNoiseProcess``
  as the simulator draws it) show what the IMU's noise costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

TARGET_S = 10.0
COVERAGE_SIGMAS = 3.0

IMU_NOISE = {
    "accelerometer_noise_density": 2.0e-3,
    "accelerometer_random_walk": 3.0e-3,
    "gyroscope_noise_density": 1.6968e-4,
    "gyroscope_random_walk": 1.9393e-5,
}
"""Kalibr-style noise figures (its wiki's example ``imu.yaml``, an ADIS16448), Kalibr's units."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=3, help="timed calls per figure")
    parser.add_argument("--seeds", type=int, default=20, help="held-out mounts for coverage")
    parser.add_argument("--rate", type=float, default=10.0, help="camera rate of those, Hz")


def held_out_spec(seed: int, camera_rate_hz: float | None = None, duration_s: float | None = None):
    """The ``calibration`` built-in with a mount it was not tuned on: the mount error's
    angles uniform in +-2 deg about each axis, its offset uniform in +-3 cm along each, the
    clock offset uniform in +-40 ms, all drawn from ``seed``; the run's seed is ``seed`` too.

    Returns
    -------
    scenarios.scenario.spec.ScenarioSpec
    """
    from scenarios.scenario import builtin
    from sim.config import MountError

    rng = np.random.default_rng(1000 + seed)
    error = MountError(
        position_m=tuple(float(v) for v in rng.uniform(-0.03, 0.03, 3)),
        rpy_deg=tuple(float(v) for v in rng.uniform(-2.0, 2.0, 3)),
    )
    offset_s = float(rng.uniform(-0.04, 0.04))
    spec = builtin.load("calibration")
    camera = dataclasses.replace(spec.scene.camera, mount_error=error)
    return dataclasses.replace(
        spec,
        camera_rate_hz=spec.camera_rate_hz if camera_rate_hz is None else camera_rate_hz,
        duration_s=duration_s,
        scene=dataclasses.replace(spec.scene, camera=camera),
        timing=dataclasses.replace(spec.timing, camera_clock_offset_s=offset_s),
    )


def long_flight_spec(duration_s: float = 30.0):
    """The ``calibration`` built-in flown for ``duration_s``: its swings (a roll, pitch and
    yaw each second) repeated to the end."""
    from scenarios.scenario import builtin
    from scenarios.scenario.spec import from_dict

    scenario = builtin.calibration()
    swings = [(8.0, -5.0, 12.0), (-8.0, 6.0, -10.0), (6.0, 5.0, 8.0), (-6.0, -6.0, -12.0)]
    keyframes = [{"t": 0.0, "position_w": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]}]
    for k in range(int(duration_s) - 2):
        roll, pitch, yaw = swings[k % len(swings)]
        keyframes.append(
            {
                "t": 1.0 + k,
                "position_w": [0.1 * (k % 16), 0.8 * (-1) ** k, 3.0 + 0.3 * (-1) ** (k // 2)],
                "rpy_deg": [roll, pitch, yaw],
            }
        )
    keyframes.append({"t": duration_s, "position_w": [1.6, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 0.0]})
    scenario["flight"] = {"mode": "kinematic", "keyframes": keyframes}
    return from_dict(scenario, where=f"calibration flown {duration_s:g} s")


def tangent_error(result, truth) -> np.ndarray:
    """The truth against the answer in the answer's coordinates, (7,): ``xi`` with
    ``T_b_c_true = T_b_c @ exp(xi^)`` and the offset's difference
    (``CalibrationResult.covariance``'s coordinates)."""
    from vnav import se3

    xi = se3.log(se3.invert(result.T_b_c) @ truth.T_b_c)
    return np.r_[xi, truth.time_offset_s - result.time_offset_s]


def coverage(
    seeds: range, camera_rate_hz: float, duration_s: float | None = None
) -> list[np.ndarray | str]:
    """Each held-out mount's error over its standard error on the 7 parameters, (7,), or the
    reason it was refused. Computed on the run's own calibration inputs, which a recording
    carries exactly (tests/test_calibrate_command.py)."""
    from scenarios import pipeline
    from scenarios.judge.calibration import inputs_from_run
    from vnav.calibration import CalibrationError
    from vnav.camera import PinholeCamera

    ratios: list[np.ndarray | str] = []
    for seed in seeds:
        spec = held_out_spec(seed, camera_rate_hz, duration_s)
        # No calibration check: the run itself need not calibrate; done once here.
        spec = dataclasses.replace(
            spec, checks=tuple(c for c in spec.checks if not c.kind.startswith("calibration_"))
        )
        outcome = pipeline.run(spec, seed=seed)
        cam = spec.scene.camera
        inputs = inputs_from_run(
            outcome.result, PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
        )
        try:
            solved = inputs.solve()
        except CalibrationError as exc:
            ratios.append(str(exc))
            continue
        assert inputs.truth is not None
        std = np.sqrt(np.diag(solved.covariance))
        ratios.append(tangent_error(solved, inputs.truth) / std)
    return ratios


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
    repeat = getattr(args, "repeat", 3)
    quiet = getattr(args, "json", False)
    figures, synthetic_line = _synthetic_figures(repeat)
    imu_figures, imu_lines = _imu_figures(repeat)
    figures.update(imu_figures)
    if not quiet:
        print(f"calibration, best and median of {repeat}, seconds (target < {TARGET_S:g} s)")
        print(synthetic_line)
    figures.update(_recording_figures(repeat, quiet))
    seeds = getattr(args, "seeds", 20)
    rate = getattr(args, "rate", 10.0)
    if seeds > 0:
        figures.update(_coverage_figures(seeds, rate, quiet))
    if not quiet:
        for line in imu_lines:
            print(line)
    return figures


def _synthetic_figures(repeat: int) -> tuple[dict[str, object], str]:
    """``synthetic``: the solver alone on ``_synthetic_flight``, timed; its figures and its
    printed line."""
    from vnav.calibration import calibrate_camera

    flight = _synthetic_flight()
    med, best, result = _time_s(lambda: calibrate_camera(*flight), repeat)
    figures: dict[str, object] = {
        "synthetic_images": len(flight[3]),
        "synthetic_observations": result.observations_used,
        "synthetic_median_s": med,
        "synthetic_best_s": best,
    }
    line = (
        f"synthetic 30 s at 30 Hz ({len(flight[3])} images, {result.observations_used} "
        f"apexes): best {best:.2f}, median {med:.2f}"
    )
    return figures, line


def _imu_figures(repeat: int) -> tuple[dict[str, object], list[str]]:
    """``imu``: the camera-IMU calibration of ``imu_flight``, timed, and of its readings with
    ``IMU_NOISE`` added; its figures and its printed lines."""
    from scenarios.judge.imu_calibration import calibrate_imu_run
    from scenarios.run.runner import run_scenario
    from scenarios.scenario.spec import from_dict

    imu_run = run_scenario(from_dict(imu_flight()), seed=1)
    med_i, best_i, imu_record = _time_s(lambda: calibrate_imu_run(imu_run), repeat)
    noisy_record = calibrate_imu_run(_with_imu_noise(imu_run))
    figures: dict[str, object] = {}
    for key, rec in (("imu", imu_record), ("imu_noisy", noisy_record)):
        figures[f"{key}_refused"] = rec.refused
        for name, value in rec.errors.items():
            figures[f"{key}_error_{name}"] = value
        for name, value in rec.std.items():
            figures[f"{key}_std_{name}"] = value
    figures.update(imu_images=len(imu_run.ticks), imu_median_s=med_i, imu_best_s=best_i)
    lines = [
        f"camera-IMU, 30 s rocking flight ({len(imu_run.ticks)} images, two passes)",
        _imu_line("  noise-free IMU", imu_record, med_i, best_i),
        _imu_line("  Kalibr-style IMU noise", noisy_record),
    ]
    return figures, lines


def _recording_figures(repeat: int, quiet: bool) -> dict[str, object]:
    """``recording``: ``vnav-demo calibrate``'s work on the recording of ``long_flight_spec``,
    timed (not the run), against the truth and the run's own calibration; printed unless
    ``quiet``."""
    from scenarios import pipeline
    from scenarios.judge.calibration import errors_against
    from scenarios.record.reader import calibration_inputs
    from vnav import so3

    with tempfile.TemporaryDirectory(prefix="vnav-bench-calibrate-") as tmp:
        outcome = pipeline.run(long_flight_spec(30.0), seed=1, out_dir=Path(tmp))
        rrd = outcome.rrd_path

        def from_recording():
            inputs = calibration_inputs(rrd)
            return inputs, inputs.solve()

        med_r, best_r, (inputs, solved) = _time_s(from_recording, repeat)
    e = errors_against(solved, inputs.truth)
    in_run = outcome.result.calibration
    apart_deg = math.degrees(
        float(np.linalg.norm(so3.log(solved.T_b_c[:3, :3].T @ in_run.T_b_c[:3, :3])))
    )
    apart_mm = 1e3 * float(np.linalg.norm(solved.T_b_c[:3, 3] - in_run.T_b_c[:3, 3]))
    if not quiet:
        print(
            f"vnav-demo calibrate on the recording of a 30 s flight ({len(outcome.result.ticks)} "
            f"images, reading and two passes): best {best_r:.2f}, median {med_r:.2f}"
        )
        print(
            f"  against the truth: {e['rotation_deg']:.4f} deg, {e['translation_mm']:.2f} mm, "
            f"{e['time_offset_ms']:.3f} ms (standard errors {solved.std_rotation_deg:.4f} deg, "
            f"{1e3 * solved.std_translation_m:.2f} mm, {1e3 * solved.std_offset_s:.3f} ms); "
            f"from the run's own: {apart_deg:.1e} deg, {apart_mm:.1e} mm"
        )
    return {
        "recording_images": len(outcome.result.ticks),
        "recording_median_s": med_r,
        "recording_best_s": best_r,
        "recording_rotation_error_deg": e["rotation_deg"],
        "recording_translation_error_mm": e["translation_mm"],
        "recording_offset_error_ms": e["time_offset_ms"],
        "recording_from_in_run_deg": apart_deg,
        "recording_from_in_run_mm": apart_mm,
    }


def _coverage_figures(seeds: int, rate: float, quiet: bool) -> dict[str, object]:
    """``coverage``: over ``seeds`` held-out mounts at ``rate`` Hz, how many answers hold the
    truth within ``COVERAGE_SIGMAS`` standard errors; printed unless ``quiet``."""
    ratios = coverage(range(seeds), rate)
    answered = [r for r in ratios if not isinstance(r, str)]
    within = sum(bool(np.all(np.abs(r) <= COVERAGE_SIGMAS)) for r in answered)
    worst = max((float(np.max(np.abs(r))) for r in answered), default=math.nan)
    if not quiet:
        print(
            f"standard errors over {seeds} held-out mounts at {rate:g} Hz: the truth within "
            f"{COVERAGE_SIGMAS:g} standard errors on all 7 parameters in {within} of "
            f"{len(answered)} answered ({len(ratios) - len(answered)} refused); largest "
            f"error / standard error {worst:.2f}"
        )
    return {
        "coverage_seeds": seeds,
        "coverage_rate_hz": rate,
        "coverage_refused": len(ratios) - len(answered),
        "coverage_within": within,
        "coverage_worst_ratio": worst,
    }
