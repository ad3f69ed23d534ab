"""Rendering and physics speed: FPS for RGB and RGB+depth (one pass), physics real-time factor.

Figures: images per second at 640x480 and 320x240 for RGB alone and for RGB + metric depth
from the same render pass, their ratio (target: time(RGB+depth) / time(RGB) <= 1.25), and the
physics real-time factor (simulated seconds per wall-clock second) at the default time step,
with and without the geometric controller in the loop.
"""

from __future__ import annotations

import argparse
import time

from sim.config import CameraConfig, SceneConfig
from sim.flight import Autopilot, MinimumJerkTrajectory
from sim.render import Renderer
from sim.world import World

SIZES = ((640, 480), (320, 240))
SCENE_CONES = ((6.0, 1.0, 0.0), (9.0, -2.0, 0.0), (12.0, 3.0, 0.0), (15.0, 0.0, 0.0))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--images", type=int, default=200, help="images timed per figure (in 5 rounds)"
    )
    parser.add_argument("--physics-s", type=float, default=20.0, help="simulated seconds timed")
    parser.add_argument("--quality", choices=("fast", "high"), default="fast")


ROUNDS = 5


def _rates(renderer: Renderer, images: int) -> tuple[float, float]:
    """(RGB images/s, RGB+depth images/s): interleaved rounds, best round of each (the
    machine is shared, so the fastest round is the least disturbed)."""
    for _ in range(5):  # warm up
        renderer.render(depth=True)
    per_round = max(1, images // ROUNDS)
    best = {False: float("inf"), True: float("inf")}
    for _ in range(ROUNDS):
        for depth in (False, True):
            start = time.perf_counter()
            for _ in range(per_round):
                renderer.render(depth=depth)
            best[depth] = min(best[depth], (time.perf_counter() - start) / per_round)
    return 1.0 / best[False], 1.0 / best[True]


def run(args: argparse.Namespace) -> dict:
    images = getattr(args, "images", 200)
    physics_s = getattr(args, "physics_s", 20.0)
    quality = getattr(args, "quality", "fast")
    figures: dict = {"quality": quality}
    for width, height in SIZES:
        cfg = SceneConfig(
            camera=CameraConfig(width=width, height=height),
            cones_w=SCENE_CONES,
            render_quality=quality,
        )
        world = World.from_config(cfg)
        with Renderer(world) as renderer:
            rgb, rgbd = _rates(renderer, images)
        key = f"{width}x{height}"
        figures[f"images_per_s_rgb_{key}"] = rgb
        figures[f"images_per_s_rgb_depth_{key}"] = rgbd
        figures[f"ratio_rgb_depth_over_rgb_{key}"] = rgb / rgbd

    world = World.from_config(SceneConfig())
    steps = round(physics_s / world.model.opt.timestep)
    start = time.perf_counter()
    world.step(steps)
    wall = time.perf_counter() - start
    figures["physics_step_us"] = wall / steps * 1e6
    figures["physics_real_time_factor"] = physics_s / wall

    world = World.from_config(SceneConfig())
    pilot = Autopilot(world, MinimumJerkTrajectory([0.0], [[0.0, 0.0, 10.0]], [0.0]))
    start = time.perf_counter()
    pilot.step(steps)
    wall = time.perf_counter() - start
    figures["controlled_step_us"] = wall / steps * 1e6
    figures["controlled_real_time_factor"] = physics_s / wall
    figures["timestep_s"] = float(world.model.opt.timestep)

    if not getattr(args, "json", False):
        print(f"render quality: {quality}, {images} images per figure, best of {ROUNDS} rounds")
        print(f"{'size':>9} | {'RGB img/s':>8} | {'RGB+depth img/s':>13} | {'ratio':>6}")
        print("-" * 46)
        for width, height in SIZES:
            key = f"{width}x{height}"
            print(
                f"{key:>9} | {figures[f'images_per_s_rgb_{key}']:8.1f} | "
                f"{figures[f'images_per_s_rgb_depth_{key}']:13.1f} | "
                f"{figures[f'ratio_rgb_depth_over_rgb_{key}']:6.2f}"
            )
        print()
        print(f"physics, timestep {figures['timestep_s']} s:")
        print(
            f"  free flight      {figures['physics_step_us']:8.1f} us/step, "
            f"real-time factor {figures['physics_real_time_factor']:8.0f}"
        )
        print(
            f"  with controller  {figures['controlled_step_us']:8.1f} us/step, "
            f"real-time factor {figures['controlled_real_time_factor']:8.0f}"
        )
    return figures
