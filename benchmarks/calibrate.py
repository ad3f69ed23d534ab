"""Calibration speed: the camera mount and clock offset from a 30 s flight at 30 Hz.

Two figures, each the best and the median of ``--repeat`` timed calls, in seconds:

- ``synthetic``: ``vnav.calibration.calibrate_camera`` on a 30 s flight imaged at 30 Hz (900
  images, 8 cones, apexes projected exactly then given 0.4 px of noise, a 200 Hz pose stream):
  the solver alone, target under 10 s on 2 cores;
- ``builtin``: ``scenarios.judge.calibration.calibrate_run`` (two passes, the second
  re-fitting every apex on its mask) on the built-in ``calibration`` run at its own 20 Hz for
  18 s (the simulation itself is not timed).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

TARGET_S = 10.0


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
    return figures
