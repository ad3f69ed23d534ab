"""Perception speed: cone detection, localisation of one detection, depth image to world cloud.

Uses a 640x480 image rendered by the simulator (one cone 8 m ahead, the default camera); the
figures are the median and the best of ``--repeat`` timed calls, in milliseconds.
``localize`` runs with the built-in ``uncertainty`` scenario's noise (pose stream, image and
depth), every estimate with its covariance; ``localize_points`` is the same call with
``with_covariance=False``. The two are timed interleaved, call by call, so that the ratio
``covariance_overhead`` (target at most 1.3) compares like with like on a busy machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from vnav.noise_model import NoiseModel

TARGETS_MS = {
    "detect_cones": 3.0,
    "localize": None,
    "localize_points": None,
    "depth_to_world_points": 10.0,
}
COVARIANCE_OVERHEAD_TARGET = 1.3
"""``localize`` with covariances over ``localize`` without, median time: at most this."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=1000, help="timed calls per figure")


def _time_ms(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    (median_ms, best_ms), *_ = _time_interleaved_ms([fn], repeat)
    return median_ms, best_ms


def _time_interleaved_ms(fns: list[Callable[[], object]], repeat: int) -> list[tuple[float, float]]:
    """``(median, best)`` in ms of each of ``fns``, called in turn ``repeat`` times."""
    for fn in fns:
        fn()  # warm-up
    samples: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for fn, out in zip(fns, samples, strict=True):
            t0 = time.perf_counter()
            fn()
            out.append((time.perf_counter() - t0) * 1e3)
    return [(statistics.median(out), min(out)) for out in samples]


def benchmark_frame() -> dict:
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


def uncertainty_noise(T_w_b: np.ndarray) -> tuple[NoiseModel, np.ndarray]:
    """The built-in ``uncertainty`` scenario's sensor noise and pose covariance at ``T_w_b``."""
    from scenarios.scenario.builtin import load
    from vnav.sensor_noise import body_pose_covariance

    noise = load("uncertainty").noise
    return noise, body_pose_covariance(T_w_b, noise)


def run(args: argparse.Namespace) -> dict:
    from vnav.camera import depth_to_world_points
    from vnav.detect import detect_cones
    from vnav.localize import localize

    repeat = getattr(args, "repeat", 1000)
    f = benchmark_frame()
    world, rgb, depth, far_m = f["world"], f["rgb"], f["depth"], f["far_m"]
    detections = detect_cones(rgb)
    if len(detections) != 1:
        raise RuntimeError(f"expected one cone in the benchmark frame, found {len(detections)}")
    det = detections[0]
    cam, T_w_b, T_b_c, T_w_c = world.camera, world.T_w_b, world.T_b_c, world.T_w_c

    noise, cov_T_w_b = uncertainty_noise(T_w_b)

    def localize_call(with_covariance: bool) -> Callable[[], object]:
        return lambda: localize(
            det,
            cam,
            T_w_b,
            T_b_c,
            depth,
            far_m=far_m,
            noise=noise,
            cov_T_w_b=cov_T_w_b,
            with_covariance=with_covariance,
        )

    figures: dict[str, object] = {
        "image": f"{rgb.shape[1]}x{rgb.shape[0]}",
        "cone_area_px": det.area_px,
        "repeat": repeat,
    }
    timed = {
        "detect_cones": _time_ms(lambda: detect_cones(rgb), repeat),
        "depth_to_world_points": _time_ms(
            lambda: depth_to_world_points(depth, cam, T_w_c, far_m=far_m), repeat
        ),
    }
    timed["localize"], timed["localize_points"] = _time_interleaved_ms(
        [localize_call(True), localize_call(False)], repeat
    )
    for name, (median_ms, best_ms) in timed.items():
        figures[f"{name}_median_ms"] = median_ms
        figures[f"{name}_best_ms"] = best_ms
    figures["covariance_overhead"] = timed["localize"][0] / timed["localize_points"][0]
    if not getattr(args, "json", False):
        _print_table(figures, timed)
    return figures


def _print_table(figures: dict, timed: dict[str, tuple[float, float]]) -> None:
    print(
        f"perception, {figures['image']} frame, cone {figures['cone_area_px']} px, "
        f"{figures['repeat']} calls"
    )
    print(f"{'step':24s} {'median ms':>10s} {'best ms':>9s} {'target ms':>10s}")
    for name, target in TARGETS_MS.items():
        median_ms, best_ms = timed[name]
        shown = "-" if target is None else f"<= {target:g}"
        print(f"{name:24s} {median_ms:10.3f} {best_ms:9.3f} {shown:>10s}")
    print(
        f"covariance overhead: localize / localize_points = {figures['covariance_overhead']:.2f} "
        f"(target <= {COVARIANCE_OVERHEAD_TARGET:g})"
    )
