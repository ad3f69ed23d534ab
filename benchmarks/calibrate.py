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
  two passes, ``vnav.imu_calibration``) of the ``imu`` built-in's flight, from its images and
  IMU readings alone, over ``--imu-seeds`` seeds: with the built-in's IMU noise (Kalibr's
  figures of EuRoC's ADIS16448, drawn by the simulator) and noise-free (the same run's
  noise-free readings, ``ImuRecord.accel_chain_i`` and ``gyro_chain_i``, which MuJoCo's
  sensors equal to 1e-15: same flight, same images), each error and its standard error;
  timed, target under 10 s on 2 cores. ``imu_held_out`` gives the held-out mounts the tests
  use; ``imu_long_flight`` is one of them flown for 30 s (the rocking twice over), whose
  calibration is timed too (target under 10 s).
- ``imu coverage``: over ``--imu-coverage-seeds`` of those held-out flights, noise-free and
  with the built-in's IMU noise (one run each, calibrated from both readings), how many
  camera-IMU answers lie within 3 standard errors of the truth on every one of the 7
  parameters (the rotation about each axis of the camera, the translation along each axis of
  the IMU, the offset; ``ImuCamCalibration.covariance``; the target: 19 of 20), and the
  largest ratio of error to standard error. Each flight is simulated once (12-27 s on 2 busy
  cores) and calibrated twice (2-5 s each).
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=3, help="timed calls per figure")
    parser.add_argument("--seeds", type=int, default=20, help="held-out mounts for coverage")
    parser.add_argument("--rate", type=float, default=10.0, help="camera rate of those, Hz")
    parser.add_argument(
        "--imu-seeds", type=int, default=3, help="seeds of the imu built-in, noisy and not"
    )
    parser.add_argument(
        "--only-imu", action="store_true", help="the camera-IMU figures alone (they are quick)"
    )
    parser.add_argument(
        "--imu-coverage-seeds",
        type=int,
        default=20,
        help="held-out flights of the imu built-in for its standard errors' coverage (0: none)",
    )


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


def imu_held_out(seed: int, noise: bool = False) -> dict:
    """The ``imu`` built-in with mounts and a clock offset it was not tuned on, noise-free (with
    ``noise``, the built-in's IMU noise), its calibration checks alone: the IMU's mount error
    uniform in +-2 deg about each axis and +-1 cm along each, the camera's in +-2 deg and
    +-3 cm, the camera-IMU clock offset (``time_offset_s``) in +-40 ms, all drawn from
    ``seed``."""
    from scenarios.scenario import builtin

    rng = np.random.default_rng(2000 + seed)
    data = builtin.imu()
    data["name"] = f"imu-held-out-{seed}"
    imu = {k: v for k, v in data["imu"].items() if noise or k not in builtin.IMU_NOISE}
    imu["mount_error"] = {
        "position_m": [float(v) for v in rng.uniform(-0.01, 0.01, 3)],
        "rpy_deg": [float(v) for v in rng.uniform(-2.0, 2.0, 3)],
    }
    imu["time_offset_s"] = float(rng.uniform(-0.04, 0.04))
    data["imu"] = imu
    data["camera"]["mount_error"] = {
        "position_m": [float(v) for v in rng.uniform(-0.03, 0.03, 3)],
        "rpy_deg": [float(v) for v in rng.uniform(-2.0, 2.0, 3)],
    }
    data["checks"] = [c for c in data["checks"] if c["kind"].startswith("calibration_imu_")]
    return data


def noise_free(result):
    """``result`` with its IMU's noise-free readings (``ImuRecord.accel_chain_i`` and
    ``gyro_chain_i``) in place of the noisy ones: the same flight and images."""
    import dataclasses

    record = dataclasses.replace(
        result.imu, accel_i=result.imu.accel_chain_i, gyro_i=result.imu.gyro_chain_i
    )
    return dataclasses.replace(result, imu=record)


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
    imu_seeds = getattr(args, "imu_seeds", 3)
    imu_coverage_seeds = getattr(args, "imu_coverage_seeds", 20)
    if getattr(args, "only_imu", False):
        figures = imu_noise(imu_seeds, repeat, quiet)
        figures.update(_imu_long_figures(repeat, quiet))
        if imu_coverage_seeds > 0:
            figures.update(_imu_coverage_figures(imu_coverage_seeds, quiet))
        return figures
    figures = _synthetic_figures(repeat, quiet)
    figures.update(_recording_figures(repeat, quiet))
    seeds = getattr(args, "seeds", 20)
    rate = getattr(args, "rate", 10.0)
    if seeds > 0:
        figures.update(_coverage_figures(seeds, rate, quiet))
    figures.update(imu_noise(imu_seeds, repeat, quiet))
    figures.update(_imu_long_figures(repeat, quiet))
    if imu_coverage_seeds > 0:
        figures.update(_imu_coverage_figures(imu_coverage_seeds, quiet))
    return figures


def imu_long_flight(seed: int = 1) -> dict:
    """``imu_held_out(seed)`` flown for 30 s: the ``imu`` built-in's rocking (its waypoints
    after the first second) flown twice over, no checks."""
    import copy

    data = imu_held_out(seed)
    waypoints = data["flight"]["waypoints"]
    again = [dict(copy.deepcopy(w), t=w["t"] + 15.0) for w in waypoints[2:]]
    data["flight"]["waypoints"] = waypoints + again
    data.update(name="imu-30s", duration_s=30.0, checks=[])
    return data


def _imu_long_figures(repeat: int, quiet: bool) -> dict[str, object]:
    """The camera-IMU calibration (``calibrate_imu_run``, two passes) of ``imu_long_flight``,
    best and median of ``repeat`` calls, wall time (numpy's BLAS may take both cores), target
    under 10 s; printed unless ``quiet``."""
    from scenarios.judge.imu_calibration import calibrate_imu_run
    from scenarios.run.runner import run_scenario
    from scenarios.scenario.spec import from_dict

    result = run_scenario(from_dict(imu_long_flight()), seed=1)
    med, best, record = _time_s(lambda: calibrate_imu_run(result), repeat)
    if not quiet:
        print(
            f"camera-IMU calibration of a 30 s flight ({len(result.ticks)} images, held-out "
            f"mounts, noise-free IMU): best {best:.2f} s, median {med:.2f} s "
            f"(target < {TARGET_S:g} s)"
        )
        print(_imu_line("  against the truth", record))
    return {"imu_30s_images": len(result.ticks), "imu_30s_median_s": med, "imu_30s_best_s": best}


def _synthetic_figures(repeat: int, quiet: bool) -> dict[str, object]:
    """``synthetic``: the solver alone on ``_synthetic_flight``, timed; printed (with the
    table's heading) unless ``quiet``."""
    from vnav.calibration import calibrate_camera

    flight = _synthetic_flight()
    med, best, result = _time_s(lambda: calibrate_camera(*flight), repeat)
    if not quiet:
        print(f"calibration, best and median of {repeat}, seconds (target < {TARGET_S:g} s)")
        print(
            f"synthetic 30 s at 30 Hz ({len(flight[3])} images, {result.observations_used} "
            f"apexes): best {best:.2f}, median {med:.2f}"
        )
    return {
        "synthetic_images": len(flight[3]),
        "synthetic_observations": result.observations_used,
        "synthetic_median_s": med,
        "synthetic_best_s": best,
    }


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


def imu_noise(seeds: int, repeat: int = 3, quiet: bool = False) -> dict:
    """The ``imu`` built-in run at seeds ``0 .. seeds - 1``, each calibrated from its noisy
    readings and from its noise-free ones (``noise_free``); the first timed."""
    from scenarios.judge.imu_calibration import calibrate_imu_run
    from scenarios.run.runner import run_scenario
    from scenarios.scenario import builtin

    figures: dict[str, object] = {"imu_seeds": seeds}
    spec = builtin.load("imu")
    rows: dict[str, list] = {"imu": [], "imu_noisy": []}
    for seed in range(seeds):
        result = run_scenario(spec, seed=seed)
        clean = noise_free(result)
        if seed == 0:
            med, best, record = _time_s(lambda r=clean: calibrate_imu_run(r), repeat)
            figures.update(imu_images=len(result.ticks), imu_median_s=med, imu_best_s=best)
        else:
            record = calibrate_imu_run(clean)
        noisy = calibrate_imu_run(result)
        rows["imu"].append(record)
        rows["imu_noisy"].append(noisy)
        if not quiet:
            print(f"imu built-in, seed {seed} ({len(result.ticks)} images, two passes)")
            print(_imu_line("  noise-free IMU", record))
            print(_imu_line("  Kalibr's IMU noise (the built-in's)", noisy))
    for key, records in rows.items():
        answered = [r for r in records if r.refused is None]
        figures[f"{key}_refused"] = len(records) - len(answered)
        for name in ("rotation_deg", "translation_m", "time_offset_s"):
            errors = [r.errors[name] for r in answered]
            figures[f"{key}_error_{name}_max"] = max(errors, default=math.nan)
            figures[f"{key}_error_{name}_median"] = (
                statistics.median(errors) if errors else math.nan
            )
            figures[f"{key}_std_{name}_median"] = (
                statistics.median(r.std[name] for r in answered) if answered else math.nan
            )
    if not quiet:
        print(
            f"camera-IMU calibration, median of {seeds} seeds (best and median of {repeat} "
            f"calls, seed 0: {figures.get('imu_best_s', math.nan):.2f} s, "
            f"{figures.get('imu_median_s', math.nan):.2f} s)"
        )
        for key, label in (("imu", "noise-free"), ("imu_noisy", "with noise")):
            print(
                f"  {label}: errors {figures[f'{key}_error_rotation_deg_median']:.4f} deg, "
                f"{1e3 * figures[f'{key}_error_translation_m_median']:.2f} mm, "
                f"{1e3 * figures[f'{key}_error_time_offset_s_median']:.3f} ms (worst "
                f"{figures[f'{key}_error_rotation_deg_max']:.4f} deg, "
                f"{1e3 * figures[f'{key}_error_translation_m_max']:.2f} mm, "
                f"{1e3 * figures[f'{key}_error_time_offset_s_max']:.3f} ms); standard errors "
                f"{figures[f'{key}_std_rotation_deg_median']:.4f} deg, "
                f"{1e3 * figures[f'{key}_std_translation_m_median']:.2f} mm, "
                f"{1e3 * figures[f'{key}_std_time_offset_s_median']:.3f} ms"
            )
    return figures


def imu_tangent_error(solved, T_i_c_true: np.ndarray, time_offset_true_s: float) -> np.ndarray:
    """The truth against a camera-IMU answer in ``ImuCamCalibration.covariance``'s
    coordinates, (7,): the rotation's error in the answer's camera frame (``R_i_c_true =
    R_i_c exp(phi^)``, rad), the translation's in the IMU frame (m), the offset's (s)."""
    from vnav import so3

    phi = so3.log(solved.T_i_c[:3, :3].T @ T_i_c_true[:3, :3])
    return np.r_[
        phi, T_i_c_true[:3, 3] - solved.T_i_c[:3, 3], time_offset_true_s - solved.time_offset_s
    ]


def imu_coverage_ratio(result) -> np.ndarray | str:
    """A finished run's camera-IMU error over its standard error on the 7 parameters, (7,)
    (``imu_tangent_error`` over the square roots of ``ImuCamCalibration.covariance``'s
    diagonal), or the reason it was refused."""
    from scenarios.judge.imu_calibration import imu_inputs_from_run
    from vnav.calibration import CalibrationError

    inputs = imu_inputs_from_run(result)
    try:
        solved = inputs.solve()
    except CalibrationError as exc:
        return str(exc)
    assert inputs.T_i_c_true is not None and inputs.time_offset_true_s is not None
    error = imu_tangent_error(solved, inputs.T_i_c_true, inputs.time_offset_true_s)
    return error / np.sqrt(np.diag(solved.covariance))


def imu_coverage(seeds: range, noise: bool = False) -> list[np.ndarray | str]:
    """``imu_coverage_ratio`` of the held-out flight ``imu_held_out(seed)`` run at ``seed``,
    for each of ``seeds``; with ``noise``, that of the flight with the built-in's IMU noise
    too, as ``(noise-free, noisy)`` pairs (one run each: the noise-free readings are the
    same run's, ``noise_free``)."""
    from scenarios import pipeline  # noqa: F401  (imports the run's modules in their order)
    from scenarios.run.runner import run_scenario
    from scenarios.scenario.spec import from_dict

    ratios: list = []
    for seed in seeds:
        result = run_scenario(from_dict(imu_held_out(seed, noise=noise)), seed=seed)
        clean = imu_coverage_ratio(noise_free(result) if noise else result)
        ratios.append((clean, imu_coverage_ratio(result)) if noise else clean)
    return ratios


def _coverage_line(ratios: list) -> tuple[int, int, float, np.ndarray]:
    """Answers within ``COVERAGE_SIGMAS`` on every parameter, refusals, the largest ratio and
    the RMS ratio per parameter."""
    answered = [r for r in ratios if not isinstance(r, str)]
    within = sum(bool(np.all(np.abs(r) <= COVERAGE_SIGMAS)) for r in answered)
    worst = max((float(np.max(np.abs(r))) for r in answered), default=math.nan)
    rms = np.sqrt(np.mean(np.square(answered), axis=0)) if answered else np.full(7, math.nan)
    return within, len(ratios) - len(answered), worst, rms


def _imu_coverage_figures(seeds: int, quiet: bool) -> dict[str, object]:
    """``imu coverage``: over ``seeds`` held-out flights, noise-free and with the built-in's
    IMU noise, how many camera-IMU answers hold the truth within ``COVERAGE_SIGMAS`` standard
    errors; printed unless ``quiet``."""
    t0 = time.perf_counter()
    pairs = imu_coverage(range(seeds), noise=True)
    elapsed_s = time.perf_counter() - t0
    figures: dict[str, object] = {"imu_coverage_seeds": seeds}
    if not quiet:
        print(
            f"camera-IMU standard errors over {seeds} held-out flights of the imu built-in "
            f"({elapsed_s / max(seeds, 1):.0f} s each: one run, two calibrations)"
        )
    for k, (key, label) in enumerate(
        (("imu_coverage", "noise-free IMU"), ("imu_coverage_noisy", "the built-in's IMU noise"))
    ):
        within, refused, worst, rms = _coverage_line([p[k] for p in pairs])
        figures.update(
            {
                f"{key}_refused": refused,
                f"{key}_within": within,
                f"{key}_worst_ratio": worst,
                f"{key}_rms_ratio": [float(v) for v in rms],
            }
        )
        if not quiet:
            print(
                f"  {label}: the truth within {COVERAGE_SIGMAS:g} standard errors on all 7 "
                f"parameters in {within} of {seeds - refused} answered ({refused} refused); "
                f"largest error / standard error {worst:.2f}; RMS per parameter (rotation "
                f"x y z, translation x y z, offset) {np.array2string(rms, precision=2)}"
            )
    return figures
