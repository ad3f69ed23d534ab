"""Stamped frame lookups: vnav's FrameBuffer against pytransform3d's TemporalTransformManager.

The same 3-edge chain in both (world -> body at 200 Hz, body -> gimbal at 50 Hz, gimbal ->
camera at 10 Hz, 10 s of samples), looked up world <- camera: vectorised at ``--n`` random
times (one call), and one time per call. Best of several repeats, the contenders taking turns.
Targets: vectorised at least 10x faster than pytransform3d; a single lookup under 20 us.
The two interpolate differently between samples (vnav: slerp and linear translation, as tf2;
pytransform3d: screw interpolation), so they are checked to agree at the stored stamps only.
pytransform3d is imported here only (``pip install -e '.[bench]'``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from vnav import quat, se3, so3
from vnav.frames import FrameBuffer

TARGETS = {"vectorised_ratio": 10.0, "single_us": 20.0}
EDGES = [("world", "body", 200.0), ("body", "gimbal", 50.0), ("gimbal", "camera", 10.0)]
DURATION_S = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``python -m benchmarks frames``."""
    parser.add_argument("--n", type=int, default=100_000, help="stamps per vectorised lookup")
    parser.add_argument("--singles", type=int, default=2000, help="single lookups timed")
    parser.add_argument("--repeats", type=int, default=5, help="repeats; the best one counts")
    parser.add_argument("--seed", type=int, default=0)


def _best(fns: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Seconds of the fastest call of each function, taking turns after one warm-up each."""
    for fn in fns.values():
        fn()
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def _samples(rng: np.random.Generator, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.arange(0.0, DURATION_S + 1e-9, 1.0 / rate_hz)
    rotvecs = np.cumsum(rng.normal(0.0, 0.05, (len(stamps), 3)), axis=0)
    poses = se3.make(so3.exp(rotvecs), np.cumsum(rng.normal(0.0, 0.02, (len(stamps), 3)), 0))
    return stamps, poses


def _both_chains(rng: np.random.Generator):
    """The same 3-edge chain (``EDGES``, random poses over ``DURATION_S``) in vnav's
    FrameBuffer and in pytransform3d's TemporalTransformManager.

    Returns
    -------
    buf : FrameBuffer
    tm : pytransform3d.transform_manager.TemporalTransformManager

    Raises
    ------
    SystemExit
        If pytransform3d is not installed (the bench extra).
    """
    try:
        from pytransform3d.transform_manager import (
            NumpyTimeseriesTransform,
            TemporalTransformManager,
        )
    except ImportError as exc:
        raise SystemExit(
            "benchmarks frames needs pytransform3d: pip install -e '.[bench]'"
        ) from exc

    buf = FrameBuffer(cache_s=2 * DURATION_S)
    tm = TemporalTransformManager()
    for parent, child, rate_hz in EDGES:
        stamps, poses = _samples(rng, rate_hz)
        buf.set_transform(parent, child, stamps, poses)
        q_wxyz = quat.xyzw_to_wxyz(quat.from_matrix(poses[:, :3, :3]))
        # pytransform3d names an edge (from, to): child coordinates into the parent's.
        tm.add_transform(
            child, parent, NumpyTimeseriesTransform(stamps, np.hstack([poses[:, :3, 3], q_wxyz]))
        )
    return buf, tm


def _difference_at_stamps(buf: FrameBuffer, tm) -> float:
    """Largest absolute difference of the two world <- camera lookups at the stamps every edge
    has (every 0.1 s), where their interpolations cannot differ."""
    at_stamps = np.arange(0.0, DURATION_S + 1e-9, 0.1)  # stamps of every edge
    ours = buf.lookup("world", "camera", at_stamps)
    theirs = tm.get_transform_at_time("camera", "world", at_stamps)
    return float(np.max(np.abs(ours - theirs)))


def _time_lookups(
    buf: FrameBuffer, tm, t: np.ndarray, singles: list[float], repeats: int
) -> tuple[dict[str, float], dict[str, float]]:
    """Best seconds of both contenders: one vectorised lookup at the times ``t``, and one
    lookup per call at each time of ``singles``.

    Returns
    -------
    vector : dict
        ``{"vnav": s, "pytransform3d": s}`` for the vectorised call.
    single : dict
        The same for the whole loop of single lookups.
    """

    def vnav_single() -> None:
        for x in singles:
            buf.lookup("world", "camera", x)

    def pt3d_single() -> None:
        for x in singles:
            tm.get_transform_at_time("camera", "world", x)

    vector = _best(
        {
            "vnav": lambda: buf.lookup("world", "camera", t),
            "pytransform3d": lambda: tm.get_transform_at_time("camera", "world", t),
        },
        repeats,
    )
    single = _best({"vnav": vnav_single, "pytransform3d": pt3d_single}, repeats)
    return vector, single


def _print_table(figures: dict, repeats: int) -> None:
    """The table of ``run``'s figures, against the targets."""
    vector_ms, single_us = figures["vectorised_ms"], figures["single_us"]
    vector_label = f"vectorised, {figures['n']} stamps (ms)"
    print(f"3-edge chain (200 / 50 / 10 Hz, {DURATION_S:g} s), world <- camera, best of {repeats}")
    print(f"{'':28}{'vnav':>12}{'pytransform3d':>16}{'ratio':>9}  target")
    print(
        f"{vector_label:28}{vector_ms['vnav']:12.2f}"
        f"{vector_ms['pytransform3d']:16.2f}{figures['vectorised_ratio']:9.1f}  "
        f">= {TARGETS['vectorised_ratio']:g}x"
    )
    print(
        f"{'single lookup (us)':28}{single_us['vnav']:12.1f}"
        f"{single_us['pytransform3d']:16.1f}{figures['single_ratio']:9.1f}  "
        f"vnav < {TARGETS['single_us']:g} us"
    )
    print(f"largest difference at the stored stamps: {figures['max_abs_difference_at_stamps']:.1e}")


def run(args: argparse.Namespace) -> dict:
    """Time both, check they agree at the stamps, print the table unless ``--json``."""
    rng = np.random.default_rng(args.seed)
    buf, tm = _both_chains(rng)
    t = rng.uniform(0.0, DURATION_S, args.n)
    singles = [float(x) for x in t[: args.singles]]
    agree = _difference_at_stamps(buf, tm)
    vector, single = _time_lookups(buf, tm, t, singles, args.repeats)
    single_us = {k: 1e6 * v / len(singles) for k, v in single.items()}
    figures = {
        "n": args.n,
        "vectorised_ms": {k: 1e3 * v for k, v in vector.items()},
        "vectorised_ratio": vector["pytransform3d"] / vector["vnav"],
        "single_us": single_us,
        "single_ratio": single_us["pytransform3d"] / single_us["vnav"],
        "max_abs_difference_at_stamps": agree,
        "targets": TARGETS,
    }
    if not args.json:
        _print_table(figures, args.repeats)
    return figures
