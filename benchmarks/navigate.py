"""Replanning cost: vnav.navigate.plan_path around 0 to --cones mapped cones, per call.

A navigating drone replans at every camera tick (10 Hz by default: 100 ms), so a plan must
take a small part of that. For each number of cones, ``--layouts`` random layouts (cones
uniform in a 20 m x 8 m field between the start and the goal, ``clearance_m`` 1 m, overlaps
allowed) are planned ``--repeats`` times each; the best repeat of each layout counts, and the
table gives the median and the worst layout. Target: the worst layout of 10 cones under 10 %
of the default camera tick; the median under 2 ms.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vnav.navigate import NoPathError, path_length_m, plan_path

TICK_S = 0.1
"""The default camera tick (``camera_rate_hz`` 10)."""

TARGETS = {"median_ms_10_cones": 2.0, "worst_ms_10_cones": 0.1 * TICK_S * 1e3}
START_XY_W = np.array([0.0, 0.0])
GOAL_XY_W = np.array([25.0, 0.0])
CLEARANCE_M = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``python -m benchmarks navigate``."""
    parser.add_argument("--cones", type=int, default=10, help="largest number of cones")
    parser.add_argument("--layouts", type=int, default=50, help="random layouts per count")
    parser.add_argument("--repeats", type=int, default=5, help="repeats; the best one counts")
    parser.add_argument("--seed", type=int, default=0)


def _layouts(rng: np.random.Generator, n_cones: int, n: int) -> list[np.ndarray]:
    """Layouts whose goal is outside every keep-out disc (the planner refuses the others)."""
    out: list[np.ndarray] = []
    while len(out) < n:
        centres = rng.uniform([2.0, -4.0], [22.0, 4.0], (n_cones, 2))
        if np.all(np.hypot(*(centres - GOAL_XY_W).T) >= CLEARANCE_M):
            out.append(centres)
    return out


def _best_s(centres: np.ndarray, repeats: int) -> tuple[float, bool]:
    """Seconds of the fastest of ``repeats`` plans (after one warm-up), and whether a path
    exists (an enclosed goal costs the whole search too)."""
    found = True
    best = np.inf
    for k in range(repeats + 1):
        start = time.perf_counter()
        try:
            plan_path(START_XY_W, GOAL_XY_W, centres, CLEARANCE_M)
        except NoPathError:
            found = False
        if k:
            best = min(best, time.perf_counter() - start)
    return best, found


def run(args: argparse.Namespace) -> dict:
    """Time the plans, print the table unless ``--json``."""
    rng = np.random.default_rng(args.seed)
    rows = {}
    for n_cones in sorted({0, 1, 2, 5, args.cones}):
        times_s, n_found = [], 0
        for centres in _layouts(rng, n_cones, args.layouts):
            best, found = _best_s(centres, args.repeats)
            times_s.append(best)
            n_found += found
        rows[n_cones] = {
            "median_ms": 1e3 * float(np.median(times_s)),
            "worst_ms": 1e3 * float(np.max(times_s)),
            "paths_found": n_found,
        }
    one_cone = plan_path(START_XY_W, GOAL_XY_W, [[12.5, 0.0]], CLEARANCE_M)
    figures = {
        "layouts": args.layouts,
        "by_cones": {str(k): v for k, v in rows.items()},
        "one_cone_path_length_m": path_length_m(one_cone),
        "targets": TARGETS,
    }
    if not args.json:
        print(
            f"plan_path, {args.layouts} random layouts per row (20 m x 8 m field, clearance "
            f"{CLEARANCE_M:g} m), best of {args.repeats} per layout"
        )
        print(f"{'cones':>6}{'median (ms)':>14}{'worst (ms)':>13}{'paths found':>14}")
        for n_cones, row in rows.items():
            print(
                f"{n_cones:6d}{row['median_ms']:14.3f}{row['worst_ms']:13.3f}"
                f"{row['paths_found']:>10d}/{args.layouts}"
            )
        print(
            f"targets with {args.cones} cones: median < {TARGETS['median_ms_10_cones']:g} ms, "
            f"worst < {TARGETS['worst_ms_10_cones']:g} ms (10 % of a {TICK_S * 1e3:g} ms "
            "camera tick)"
        )
    return figures
