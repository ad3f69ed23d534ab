"""Perception speed: cone detection, localisation of one detection, depth image to world cloud.

Uses a 640x480 image rendered by the simulator (one cone 8 m ahead, the default camera); the
figures are the median and the best of ``--repeat`` timed calls, in milliseconds.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

TARGETS_MS = {"detect_cones": 3.0, "localize": None, "depth_to_world_points": 10.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=200, help="timed calls per figure")


def _time_ms(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    fn()  # warm-up
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(samples), min(samples)


def _frame() -> dict:
    from sim.config import SceneConfig
    from sim.render import Renderer
    from sim.world import World
    from vnav import se3, so3

    world = World.from_config(SceneConfig(cones_w=((8.0, 1.0, 0.0),)))
    world.set_pose(se3.make(so3.rot_z(np.arctan2(1.0, 8.0)), [0.0, 0.0, 3.0]))
    with Renderer(world) as renderer:
        frame = renderer.render(depth=True)
    far_m = 0.99 * world.model.vis.map.zfar * world.model.stat.extent
    return {"world": world, "rgb": frame.rgb, "depth": frame.depth, "far_m": far_m}


def run(args: argparse.Namespace) -> dict:
    from vnav.camera import depth_to_world_points
    from vnav.detect import detect_cones
    from vnav.localize import localize

    repeat = getattr(args, "repeat", 200)
    f = _frame()
    world, rgb, depth, far_m = f["world"], f["rgb"], f["depth"], f["far_m"]
    detections = detect_cones(rgb)
    if len(detections) != 1:
        raise RuntimeError(f"expected one cone in the benchmark frame, found {len(detections)}")
    det = detections[0]
    cam, T_w_b, T_b_c, T_w_c = world.camera, world.T_w_b, world.T_b_c, world.T_w_c

    calls: dict[str, Callable[[], object]] = {
        "detect_cones": lambda: detect_cones(rgb),
        "localize": lambda: localize(det, cam, T_w_b, T_b_c, depth, far_m=far_m),
        "depth_to_world_points": lambda: depth_to_world_points(depth, cam, T_w_c, far_m=far_m),
    }
    figures: dict[str, object] = {
        "image": f"{rgb.shape[1]}x{rgb.shape[0]}",
        "cone_area_px": det.area_px,
        "repeat": repeat,
    }
    rows = []
    for name, fn in calls.items():
        median_ms, best_ms = _time_ms(fn, repeat)
        figures[f"{name}_median_ms"] = median_ms
        figures[f"{name}_best_ms"] = best_ms
        target = TARGETS_MS[name]
        rows.append((name, median_ms, best_ms, "-" if target is None else f"<= {target:g}"))
    if not getattr(args, "json", False):
        print(f"perception, {figures['image']} frame, cone {det.area_px} px, {repeat} calls")
        print(f"{'step':24s} {'median ms':>10s} {'best ms':>9s} {'target ms':>10s}")
        for name, median_ms, best_ms, target in rows:
            print(f"{name:24s} {median_ms:10.3f} {best_ms:9.3f} {target:>10s}")
    return figures
