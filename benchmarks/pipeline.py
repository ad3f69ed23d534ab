"""End-to-end scenario speed: ticks per second, share of each stage, .rrd bytes per tick.

Runs built-in scenarios exactly as ``vnav-demo run`` does (640x480, recording to a temporary
directory) and prints, per scenario and in total: ticks, ticks per second, milliseconds per
tick of each stage (physics, render, detect, localize, log), the overhead ratio
(detect + localize + log) / render (target <= 0.5), the share of the tick spent on time
(``streams``: the pose and image streams, the estimator's ``FrameBuffer`` and its lookups;
target <= 10%: keeping the chain honest about time must not slow the pipeline by more), and
the average bytes of the .rrd per tick (target <= 60 KB). The total wall time of all
built-ins is the figure behind "``vnav-demo run --all`` finishes within 2 minutes" (target
<= 120 s).

``--against REV`` measures a change: the same scenarios (those both versions have) are run by
this checkout and by git revision REV (checked out in a temporary worktree), each in a fresh
process, alternating for ``--rounds`` rounds; the best wall time of each counts, and the ratio
now / REV is printed per scenario and in total.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from scenarios import pipeline
from scenarios.run.runner import STAGES
from scenarios.scenario import builtin

TARGETS = {
    "overhead_ratio": 0.5,
    "rrd_bytes_per_tick": 60_000,
    "all_wall_s": 120.0,
    "streams_share": 0.10,
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        action="append",
        choices=builtin.names(),
        help="scenario to run (repeatable; default: every built-in)",
    )
    parser.add_argument(
        "--against",
        metavar="REV",
        help="compare with git revision REV, side by side (see the module docstring)",
    )
    parser.add_argument("--rounds", type=int, default=2, help="rounds of --against")


def _run_one(name: str, out: Path) -> dict:
    spec = builtin.load(name)
    start = time.perf_counter()
    outcome = pipeline.run(spec, seed=1, out_dir=out)
    wall_s = time.perf_counter() - start
    result, rrd = outcome.result, outcome.rrd_path
    ticks = len(result.ticks)
    ms = {k: 1e3 * result.timing_s[k] / ticks for k in STAGES}
    return {
        "ticks": ticks,
        "wall_s": wall_s,
        "ticks_per_s": ticks / wall_s,
        "ms_per_tick": ms,
        "overhead_ratio": (ms["detect"] + ms["localize"] + ms["log"]) / ms["render"],
        "setup_s": result.timing_s["setup"],
        "rrd_bytes": rrd.stat().st_size,
        "rrd_bytes_per_tick": rrd.stat().st_size / ticks,
        "passed": outcome.passed,
    }


def run(args: argparse.Namespace) -> dict:
    if getattr(args, "against", None):
        return _against(args)
    names = getattr(args, "scenario", None) or builtin.names()
    with tempfile.TemporaryDirectory(prefix="vnav-bench-") as tmp:
        start = time.perf_counter()
        per = {name: _run_one(name, Path(tmp)) for name in names}
        all_wall_s = time.perf_counter() - start
    ticks = sum(p["ticks"] for p in per.values())
    total_ms = {
        k: sum(p["ms_per_tick"][k] * p["ticks"] for p in per.values()) / ticks for k in STAGES
    }
    figures = {
        "scenarios": per,
        "total": {
            "ticks": ticks,
            "all_wall_s": all_wall_s,
            "ticks_per_s": ticks / all_wall_s,
            "ms_per_tick": total_ms,
            "overhead_ratio": (total_ms["detect"] + total_ms["localize"] + total_ms["log"])
            / total_ms["render"],
            "streams_share": total_ms["streams"] / sum(total_ms.values()),
            "rrd_bytes_per_tick": sum(p["rrd_bytes"] for p in per.values()) / ticks,
            "setup_s": sum(p["setup_s"] for p in per.values()),
        },
        "targets": TARGETS,
    }
    if not args.json:
        header = (
            f"{'scenario':<19}{'ticks':>7}{'ticks/s':>8}"
            + "".join(f"{s:>10}" for s in STAGES)
            + f"{'overhead':>10}{'KB/tick':>10}{'setup s':>9}"
        )
        print(
            "pipeline at 640x480, ms per tick by stage; overhead = (detect + localize + log)"
            " / render;\nsetup = world, GL context, file header and close, once per run; JPEG/PNG"
            " encoding overlaps rendering on a worker thread"
        )
        print(header)
        print("-" * len(header))
        rows = [*per.items(), ("ALL", figures["total"])]
        for name, p in rows:
            print(
                f"{name:<19}{p['ticks']:>7}{p['ticks_per_s']:>8.1f}"
                + "".join(f"{p['ms_per_tick'][s]:>10.2f}" for s in STAGES)
                + f"{p['overhead_ratio']:>10.2f}{p['rrd_bytes_per_tick'] / 1e3:>10.1f}"
                + f"{p['setup_s']:>9.2f}"
            )
        t = figures["total"]
        print(
            f"\nwall time, {len(per)} scenarios: {all_wall_s:.1f} s (target <= "
            f"{TARGETS['all_wall_s']:.0f} s)"
        )
        print(f"overhead ratio: {t['overhead_ratio']:.2f} (target <= {TARGETS['overhead_ratio']})")
        print(
            f"time (streams, FrameBuffer, lookups): {t['streams_share']:.1%} of the tick "
            f"(target <= {TARGETS['streams_share']:.0%})"
        )
        print(
            f".rrd bytes per tick: {t['rrd_bytes_per_tick'] / 1e3:.1f} KB (target <= "
            f"{TARGETS['rrd_bytes_per_tick'] / 1e3:.0f} KB)"
        )
    return figures


_ROOT = Path(__file__).resolve().parent.parent


def _walls(root: Path, names: list[str]) -> dict[str, float]:
    """Wall time of each scenario, run by the code under ``root`` in a fresh process."""
    cmd = [sys.executable, "-m", "benchmarks", "pipeline", "--json"]
    for name in names:
        cmd += ["--scenario", name]
    # The checkout under ``root`` first on the path, whatever is installed.
    env = {**os.environ, "PYTHONPATH": str(root)}
    out = subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, text=True)
    return {n: p["wall_s"] for n, p in json.loads(out.stdout)["scenarios"].items()}


def _against(args: argparse.Namespace) -> dict:
    """This checkout against revision ``args.against``, alternating, best of rounds."""
    with tempfile.TemporaryDirectory(prefix="vnav-bench-rev-") as tmp:
        base = Path(tmp) / "rev"
        subprocess.run(
            ["git", "-C", str(_ROOT), "worktree", "add", "--detach", str(base), args.against],
            check=True,
            capture_output=True,
        )
        try:
            listed = subprocess.run(
                [sys.executable, "-c", "from scenarios import builtin; print(*builtin.names())"],
                cwd=base,
                env={**os.environ, "PYTHONPATH": str(base)},
                check=True,
                capture_output=True,
                text=True,
            ).stdout.split()
            wanted = getattr(args, "scenario", None) or builtin.names()
            names = [n for n in wanted if n in listed]
            best: dict[str, dict[str, float]] = {"now": {}, "rev": {}}
            for _ in range(args.rounds):
                for side, root in (("now", _ROOT), ("rev", base)):
                    for name, wall in _walls(root, names).items():
                        best[side][name] = min(wall, best[side].get(name, float("inf")))
        finally:
            subprocess.run(
                ["git", "-C", str(_ROOT), "worktree", "remove", "--force", str(base)],
                check=False,
                capture_output=True,
            )
    total = {side: sum(best[side].values()) for side in best}
    figures = {
        "against": args.against,
        "rounds": args.rounds,
        "wall_s": best,
        "ratio": {n: best["now"][n] / best["rev"][n] for n in names},
        "total_ratio": total["now"] / total["rev"],
    }
    if not args.json:
        print(
            f"wall time per scenario, best of {args.rounds} alternating rounds, "
            "each in a fresh process"
        )
        print(f"{'scenario':<19}{'now s':>8}{args.against[:10]:>12}{'ratio':>8}")
        for n in names:
            print(
                f"{n:<19}{best['now'][n]:>8.2f}{best['rev'][n]:>12.2f}{figures['ratio'][n]:>8.3f}"
            )
        print(f"{'ALL':<19}{total['now']:>8.2f}{total['rev']:>12.2f}{figures['total_ratio']:>8.3f}")
    return figures
