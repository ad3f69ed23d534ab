"""Sweep throughput: episodes per second on 1 and 2 Ray workers, the scaling, Ray's start-up.

The workload is one scenario (default: the built-in ``approach``, 14 s at 10 Hz) run with
``--episodes`` seeds. Each engine first runs one episode per worker untimed (the worker's
OpenGL context and scene are built then; that first episode's extra cost is reported as
``first``), then the timed episodes. Rows: in this process (``--workers 0``, Mesa's default
threads), 1 and 2 Ray workers with one rendering thread each (``scenarios.sweep.engine
.WORKER_ENV``), and 2 workers left to Mesa's default (one rasteriser thread per core each):
what oversubscribing the cores costs. Target: 2 workers >= 1.8x the episodes per second of 1
on this 2-core machine. Ray's start-up (``ray.init`` and every actor ready) is timed apart.

Per row also the per-episode overhead: the share of the workers' time (the timed episodes'
wall time times the workers, one for the process itself) not spent in the runs' camera ticks
(the stages on the run's thread, ``scenarios.run.runner.STAGES``: physics, streams, render,
detect, localize, navigate, clearance, log; ``Episode.timing_s``): the set-up, the judging,
the rows, Ray's dispatch and results, and any idle worker. Target: under 5%.
"""

from __future__ import annotations

import argparse
import time

TARGET_SCALING = 1.8
TARGET_OVERHEAD = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="approach", help="a built-in scenario")
    parser.add_argument("--episodes", type=int, default=8, help="timed episodes per row")


def _tasks(scenario: str, seeds: range):
    from scenarios.sweep.engine import Task
    from scenarios.sweep.plan import plan

    sweep = plan({"scenario": scenario, "seeds": list(seeds)}, "benchmark")
    (point,) = sweep.points
    return [Task(0, s, point.scenario_toml) for s in seeds]


def _measure(engine, scenario: str, episodes: int) -> dict[str, float]:
    """Untimed warm-up (one episode per worker), then ``episodes`` timed ones."""
    warm = max(1, engine.workers)
    start = time.perf_counter()
    list(engine.run(_tasks(scenario, range(10_000, 10_000 + warm))))
    warm_s = time.perf_counter() - start
    start = time.perf_counter()
    results = list(engine.run(_tasks(scenario, range(1, episodes + 1))))
    wall_s = time.perf_counter() - start
    failed = [r for r in results if not hasattr(r, "row")]
    if failed:
        raise RuntimeError(f"{len(failed)} episodes failed: {failed[0]}")
    per_episode_s = wall_s / episodes * warm
    from scenarios.run.runner import STAGES

    ticks_s = sum(r.timing_s.get(k, 0.0) for r in results for k in STAGES)
    return {
        "episodes_per_s": episodes / wall_s,
        "wall_s": wall_s,
        "first_extra_s": warm_s - per_episode_s,
        "startup_s": engine.startup_s,
        "overhead": 1.0 - ticks_s / (wall_s * max(1, engine.workers)),
    }


def run(args: argparse.Namespace) -> dict:
    from scenarios.sweep import engine as engines

    rows: dict[str, dict[str, float]] = {}
    configs = [
        ("in process", 0, None),
        ("1 worker", 1, engines.WORKER_ENV),
        ("2 workers", 2, engines.WORKER_ENV),
        ("2 workers, Mesa threads", 2, {}),
    ]
    for name, workers, env in configs:
        if workers == 0:
            engine = engines.SerialEngine()
        else:
            engine = engines.RayEngine(workers, env=env)
        try:
            rows[name] = _measure(engine, args.scenario, args.episodes)
        finally:
            engine.close()
    scaling = rows["2 workers"]["episodes_per_s"] / rows["1 worker"]["episodes_per_s"]
    figures = {
        "rows": rows,
        "scaling_2_over_1": scaling,
        "target_scaling": TARGET_SCALING,
        "target_overhead": TARGET_OVERHEAD,
    }
    if not args.json:
        _print(rows, scaling, args)
    return figures


def _print(rows: dict[str, dict[str, float]], scaling: float, args) -> None:
    print(f"sweep throughput: {args.scenario}, {args.episodes} timed episodes per row")
    print(
        f"  {'engine':<25} {'episodes/s':>10} {'wall s':>8} {'first +s':>9} {'start-up s':>11}"
        f" {'overhead':>9}"
    )
    for name, r in rows.items():
        print(
            f"  {name:<25} {r['episodes_per_s']:>10.2f} {r['wall_s']:>8.1f} "
            f"{r['first_extra_s']:>9.2f} {r['startup_s']:>11.1f} {r['overhead']:>9.1%}"
        )
    verdict = "met" if scaling >= TARGET_SCALING else "NOT met"
    print(f"  scaling, 2 workers / 1: {scaling:.2f}x (target >= {TARGET_SCALING}x: {verdict})")
    worst = max(r["overhead"] for r in rows.values())
    verdict = "met" if worst < TARGET_OVERHEAD else "NOT met"
    print(
        "  per-episode overhead (time outside the camera ticks), worst row: "
        f"{worst:.1%} (target < {TARGET_OVERHEAD:.0%}: {verdict})"
    )
