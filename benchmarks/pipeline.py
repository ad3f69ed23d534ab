"""End-to-end scenario speed: ticks per second, share of each stage, .rrd bytes per tick.

Runs built-in scenarios exactly as ``vnav-demo run`` does (640x480, recording to a temporary
directory) and prints, per scenario and in total: ticks, ticks per second, milliseconds per
tick of each stage (physics, render, detect, localize, log) on the run's thread (``render``
there: drawing the scene and waiting for the image) and of the OpenGL thread's rendering
(``render_gl``, which overlaps the stages), the overhead ratio
(detect + localize + log) / render_gl (target <= 0.5), the share of the tick spent on time
(``streams``: the pose and image streams, the estimator's ``FrameBuffer`` and its lookups;
target <= 10%: keeping the chain honest about time must not slow the pipeline by more), the
share of a navigating built-in's tick spent on its map and planner (``navigate``: the
``Navigator``'s ``on_tick``, the map's update, the replanning and the carrot; target <= 10%)
and on reading MuJoCo's truth for it (``clearance``: contacts and clearances after each pose
sample's physics, the judge's measure, not the drone's), and the average bytes of the .rrd per
tick (target <= 60 KB). The total wall time of all
built-ins is the figure behind "``vnav-demo run --all`` finishes within 2 minutes" (target
<= 120 s).

``--plugin`` measures a user's estimator (``vnav.plugin``): one scenario (``--scenario``,
default frame-problem) run with the reference solution plugged in and without it, alternating
for ``--rounds`` rounds, in this process, recording to a temporary directory as ``vnav-demo
run`` does; the best wall and CPU time of each, their ratio, the function's own time (the
report's ``time_s``) and the target: plugged in <= 1.05 x without + the function's own time.
Also the cost of what a plug-in adds per detection (``PluginEstimator.estimate`` around a
function that returns at once: the observation it is given, the checks of what it returns),
for one detection in an image and for each further one in the same image; and the frame-bug
doctor on a 30 s flight's worth of observations (900, every hypothesis, the newest poses
included; target < 1 s).

``--export FORMAT[,FORMAT]`` measures the exports (``scenarios.export``): a 30 s flight at
30 Hz (``--scenario``, default orbit, its duration and camera rate set so) run with the
exports and without, alternating for ``--rounds`` rounds, as ``vnav-demo run`` does; the best
wall and CPU time of each side by side, their ratio (target <= 1.30), the bytes exported
per tick, the observers' time on the run's own thread (the ``log`` stage) with and without,
and the CPU time of the run's thread and of the others (the recording's encoder, the renderer,
and the export process, ``scenarios.export.process``, counted once it has ended): the images
are encoded and written in that process, at a lower priority, on what the run leaves of the
cores; on a 2-core machine that the run already keeps 1.5 cores busy, the ratio's floor is the
CPU time with exports over twice the wall time without.

``--imu`` measures the simulated IMU (``sim.imu``, read at every physics step): one scenario
(``--scenario``, default orbit) run with the ``imu`` built-in's ``[imu]`` table added and
without, alternating for ``--rounds`` rounds, in this process, recording to a temporary
directory as ``vnav-demo run`` does (``--duration S`` shortens the flight). Per camera tick it
prints each stage's milliseconds (the report's ``timing_s`` over the ticks: the stage timers
read wall time, ``time.perf_counter``) with and without, the whole tick's CPU milliseconds
(``time.process_time``, every thread, from the first tick's end to the last's) and wall
milliseconds, the ratio with / without against the target (the IMU adds at most 5% to a
tick: <= 1.05) and the stages that grew; what comes after the last tick (the IMU's readings
and chain made, the recording finished) and the judging in it (checks such as
``imu_consistent``, calibrations) are printed apart, not as tick time. Best of the rounds for
each figure.

``--against REV`` measures a change: the same scenarios (those both versions have) are run by
this checkout and by git revision REV (checked out in a temporary worktree), each in a fresh
process, alternating for ``--rounds`` rounds; the best wall time of each counts, and the ratio
now / REV is printed per scenario and in total.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from scenarios import pipeline
from scenarios.run.runner import STAGES
from scenarios.scenario import builtin
from scenarios.scenario.spec import ScenarioSpec, from_dict
from sim.scene_cache import SceneCache

COLUMNS = (*STAGES, "render_gl")
"""The stages on the run's thread, then the OpenGL thread's rendering."""

TARGETS = {
    "overhead_ratio": 0.5,
    "rrd_bytes_per_tick": 60_000,
    "all_wall_s": 120.0,
    "streams_share": 0.10,
    "navigate_share": 0.10,
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
    parser.add_argument("--rounds", type=int, default=2, help="rounds of --against and of --plugin")
    parser.add_argument(
        "--export",
        metavar="FORMAT[,FORMAT]",
        help="a 30 s flight at 30 Hz with these exports against without (see the module docstring)",
    )
    parser.add_argument(
        "--imu",
        action="store_true",
        help="a scenario with the imu built-in's [imu] table against without (see the module "
        "docstring)",
    )
    parser.add_argument(
        "--duration",
        type=_positive_seconds,
        metavar="S",
        help="with --imu: stop the flight after S simulated seconds",
    )
    parser.add_argument(
        "--plugin",
        action="store_true",
        help="a scenario with the reference solution plugged in against without it, "
        "the plug-in's cost per detection and the doctor's time (see the module docstring)",
    )


def _run_one(name: str, out: Path, scenes: SceneCache | None = None) -> dict:
    spec = builtin.load(name)
    start = time.perf_counter()
    outcome = pipeline.run(spec, seed=1, out_dir=out, scenes=scenes)
    wall_s = time.perf_counter() - start
    result, rrd = outcome.result, outcome.rrd_path
    ticks = len(result.ticks)
    ms = {k: 1e3 * result.timing_s[k] / ticks for k in COLUMNS}
    return {
        "navigates": result.navigation is not None,
        "ticks": ticks,
        "wall_s": wall_s,
        "ticks_per_s": ticks / wall_s,
        "ms_per_tick": ms,
        "overhead_ratio": (ms["detect"] + ms["localize"] + ms["log"]) / ms["render_gl"],
        "setup_s": result.timing_s["setup"],
        "rrd_bytes": rrd.stat().st_size,
        "rrd_bytes_per_tick": rrd.stat().st_size / ticks,
        "passed": outcome.passed,
    }


def _positive_seconds(text: str) -> float:
    """``--duration``'s value: a positive, finite number of seconds (argparse's error else)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}")
    return value


def run(args: argparse.Namespace) -> dict:
    if getattr(args, "against", None):
        return _against(args)
    if getattr(args, "plugin", False):
        return _plugin(args)
    if getattr(args, "export", None):
        return _export(args)
    if getattr(args, "imu", False):
        return _imu(args)
    names = getattr(args, "scenario", None) or builtin.names()
    with tempfile.TemporaryDirectory(prefix="vnav-bench-") as tmp:
        start = time.perf_counter()
        # One OpenGL context and scene cache for them all, as ``vnav-demo run`` has.
        with SceneCache(capacity=2) as scenes:
            per = {name: _run_one(name, Path(tmp), scenes) for name in names}
        all_wall_s = time.perf_counter() - start
    ticks = sum(p["ticks"] for p in per.values())
    total_ms = {
        k: sum(p["ms_per_tick"][k] * p["ticks"] for p in per.values()) / ticks for k in COLUMNS
    }
    figures = {
        "scenarios": per,
        "total": {
            "ticks": ticks,
            "all_wall_s": all_wall_s,
            "ticks_per_s": ticks / all_wall_s,
            "ms_per_tick": total_ms,
            "overhead_ratio": (total_ms["detect"] + total_ms["localize"] + total_ms["log"])
            / total_ms["render_gl"],
            # Of the run's thread's time (render_gl overlaps it).
            "streams_share": total_ms["streams"] / sum(total_ms[k] for k in STAGES),
            "rrd_bytes_per_tick": sum(p["rrd_bytes"] for p in per.values()) / ticks,
            "setup_s": sum(p["setup_s"] for p in per.values()),
            "navigate": _navigate_shares(per),
        },
        "targets": TARGETS,
    }
    if not args.json:
        _print_table(per, figures)
    return figures


def _print_table(per: dict[str, dict], figures: dict) -> None:
    """The per-scenario table and the totals against their targets."""
    all_wall_s = figures["total"]["all_wall_s"]
    header = (
        f"{'scenario':<19}{'ticks':>7}{'ticks/s':>8}"
        + "".join(f"{s:>10}" for s in COLUMNS)
        + f"{'overhead':>10}{'KB/tick':>10}{'setup s':>9}"
    )
    print(
        "pipeline at 640x480, ms per tick by stage; overhead = (detect + localize + log)"
        " / render_gl;\nrender = the run's thread drawing the scene and waiting for the"
        " image; render_gl = the OpenGL thread's rendering (wall time), overlapping the"
        " other stages;\nsetup = world, GL context, file header and close, once per run;"
        " JPEG/PNG encoding overlaps rendering on a worker thread"
    )
    print(header)
    print("-" * len(header))
    rows = [*per.items(), ("ALL", figures["total"])]
    for name, p in rows:
        print(
            f"{name:<19}{p['ticks']:>7}{p['ticks_per_s']:>8.1f}"
            + "".join(f"{p['ms_per_tick'][s]:>10.2f}" for s in COLUMNS)
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
    nav = t["navigate"]
    for name, share in nav["scenarios"].items():
        print(
            f"{name}: map and planner {share['navigate']:.1%} of the tick, MuJoCo's truth "
            f"(contacts, clearances) {share['clearance']:.1%}"
        )
    if nav["scenarios"]:
        print(
            f"map and planner, navigating built-ins: {nav['navigate_share']:.1%} of the tick "
            f"(target <= {TARGETS['navigate_share']:.0%}); MuJoCo's truth "
            f"{nav['clearance_share']:.1%}"
        )
    print(
        f".rrd bytes per tick: {t['rrd_bytes_per_tick'] / 1e3:.1f} KB (target <= "
        f"{TARGETS['rrd_bytes_per_tick'] / 1e3:.0f} KB)"
    )


def _navigate_shares(per: dict[str, dict]) -> dict:
    """The navigating scenarios' ``navigate`` and ``clearance`` shares of their ticks' time,
    each and over all of them (weighted by ticks; None without one)."""
    navigating = {n: p for n, p in per.items() if p["navigates"]}

    def share(stage: str, ps: list[dict]) -> float | None:
        total = sum(sum(p["ms_per_tick"].values()) * p["ticks"] for p in ps)
        return sum(p["ms_per_tick"][stage] * p["ticks"] for p in ps) / total if ps else None

    return {
        "scenarios": {
            n: {"navigate": share("navigate", [p]), "clearance": share("clearance", [p])}
            for n, p in navigating.items()
        },
        "navigate_share": share("navigate", list(navigating.values())),
        "clearance_share": share("clearance", list(navigating.values())),
    }


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


EXPORT_TARGET = 1.30
"""A run with its exports takes at most this times the run without."""


def _export(args: argparse.Namespace) -> dict:
    """A 30 s flight at 30 Hz with ``args.export`` against without, alternating (ABBA)."""
    from scenarios import export

    formats = export.parse(args.export)
    name = (getattr(args, "scenario", None) or ["orbit"])[0]
    spec = dataclasses.replace(builtin.load(name), duration_s=30.0, camera_rate_hz=30.0)
    best = {"plain": [float("inf")] * 2, "export": [float("inf")] * 2}
    log_ms = {"plain": float("inf"), "export": float("inf")}
    # CPU seconds of the run's own thread and of every other thread (the export process's
    # included), best of the rounds.
    threads_s = {"plain": [float("inf")] * 2, "export": [float("inf")] * 2}
    exported_bytes, ticks = 0, 0
    with tempfile.TemporaryDirectory(prefix="vnav-bench-export-") as tmp:
        for i in range(max(1, args.rounds)):
            for side in ("plain", "export")[:: 1 if i % 2 == 0 else -1]:
                wall_s, cpu_s, own_s = time.perf_counter(), _cpu_s(), time.thread_time()
                outcome = pipeline.run(
                    spec, seed=1, out_dir=Path(tmp), exports=formats if side == "export" else ()
                )
                wall_s, cpu_s = time.perf_counter() - wall_s, _cpu_s() - cpu_s
                own_s = time.thread_time() - own_s
                best[side] = [min(best[side][0], wall_s), min(best[side][1], cpu_s)]
                threads_s[side] = [
                    min(threads_s[side][0], own_s),
                    min(threads_s[side][1], cpu_s - own_s),
                ]
                ticks = len(outcome.result.ticks)
                log_ms[side] = min(log_ms[side], 1e3 * outcome.result.timing_s["log"] / ticks)
                if side == "export":
                    exported_bytes = sum(
                        f["bytes"] for e in outcome.report["exports"].values() for f in e["files"]
                    )
    ratio = {k: best["export"][i] / best["plain"][i] for i, k in enumerate(("wall", "cpu"))}
    figures = {
        "scenario": name,
        "formats": list(formats),
        "ticks": ticks,
        "rounds": args.rounds,
        "plain_s": dict(zip(("wall", "cpu"), best["plain"], strict=True)),
        "export_s": dict(zip(("wall", "cpu"), best["export"], strict=True)),
        "ratio": ratio,
        "exported_bytes_per_tick": exported_bytes / max(ticks, 1),
        "log_ms_per_tick": log_ms,
        "run_thread_cpu_s": {k: v[0] for k, v in threads_s.items()},
        "other_threads_cpu_s": {k: v[1] for k, v in threads_s.items()},
        "target_ratio": EXPORT_TARGET,
    }
    if not args.json:
        _print_export(figures, args.export)
    return figures


def _cpu_s() -> float:
    """CPU seconds of this process and of its children that have ended (the export process,
    which ``pipeline.run`` waits for)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def _print_export(figures: dict, formats: str) -> None:
    """``_export``'s figures: both sides, their ratio against the target, the bytes, the run's
    thread's observers and the CPU of the threads."""
    ticks, ratio, log_ms = figures["ticks"], figures["ratio"], figures["log_ms_per_tick"]
    print(
        f"{figures['scenario']}, 30 s at 30 Hz ({ticks} ticks), best of {figures['rounds']} "
        "alternating rounds, recording as vnav-demo run does"
    )
    for side, label in (("plain", "without export"), ("export", f"--export {formats}")):
        wall_cpu = figures[f"{side}_s"]
        print(f"  {label:<26}{wall_cpu['wall']:>8.2f} s wall {wall_cpu['cpu']:>8.2f} s CPU")
    print(
        f"  ratio: wall {ratio['wall']:.3f}, CPU {ratio['cpu']:.3f} (target <= "
        f"{EXPORT_TARGET:.2f}); exported {figures['exported_bytes_per_tick'] / 1e3:.0f} KB per "
        "tick"
    )
    print(
        f"  on the run's thread (the observers' 'log' stage): {log_ms['plain']:.2f} ms per "
        f"tick without, {log_ms['export']:.2f} ms with (copying each tick's images for the "
        "export process, which encodes and writes them, and waiting for it when it is behind)"
    )
    for side, label in (("plain", "without export"), ("export", "with")):
        run_s, other_s = figures["run_thread_cpu_s"][side], figures["other_threads_cpu_s"][side]
        print(
            f"  CPU {label}: the run's thread {run_s:.2f} s, the other threads and processes "
            f"{other_s:.2f} s"
        )


IMU_TARGET = 1.05
"""A camera tick with the IMU takes at most this times one without."""


def _imu_specs(name: str, duration_s: float | None) -> dict[str, ScenarioSpec]:
    """Scenario ``name`` without an IMU (``plain``) and with the ``imu`` built-in's ``[imu]``
    table added (``imu``), stopped after ``duration_s`` if given.

    Raises
    ------
    ValueError
        If ``name`` has an ``[imu]`` of its own.
    """
    table = builtin.REGISTRY[name]()
    if "imu" in table:
        raise ValueError(f"scenario {name!r} has an [imu] already: choose one without")
    specs = {
        "plain": from_dict(table, where=f"built-in {name}"),
        "imu": from_dict(
            {**table, "imu": builtin.imu()["imu"]}, where=f"built-in {name} with [imu]"
        ),
    }
    if duration_s is not None:
        specs = {
            k: dataclasses.replace(s, duration_s=min(duration_s, s.end_s)) for k, s in specs.items()
        }
    return specs


def _imu_run(spec: ScenarioSpec, out: Path) -> dict:
    """One run as ``vnav-demo run`` makes it: the stages' milliseconds per tick, the ticks' CPU
    and wall milliseconds (from the first tick's end to the last's), the CPU seconds after the
    last tick (the images still in flight, the IMU's readings made, the judging, the
    recording finished, the report written) and the judging's own (wall) seconds."""
    marks: list[tuple[float, float]] = []

    def progress(done: int, total: int) -> None:
        marks.append((time.process_time(), time.perf_counter()))

    outcome = pipeline.run(spec, seed=1, out_dir=out, progress=progress)
    after_ticks_cpu_s = time.process_time() - marks[-1][0]
    timing = outcome.result.timing_s
    ticks = len(outcome.result.ticks)
    timed = max(len(marks) - 1, 1)  # the ticks between the first mark and the last
    return {
        "ticks": ticks,
        "stage_ms": {k: 1e3 * timing[k] / ticks for k in STAGES},
        "tick_cpu_ms": 1e3 * (marks[-1][0] - marks[0][0]) / timed,
        "tick_wall_ms": 1e3 * (marks[-1][1] - marks[0][1]) / timed,
        "after_ticks_cpu_s": after_ticks_cpu_s,
        "judge_s": timing["calibrate"] + timing["judge"],
        "total_cpu_s": timing["total_cpu"],
    }


def _keep_best(best: dict[str, dict], side: str, got: dict) -> None:
    """``best[side]`` made the least of itself and ``got`` (an ``_imu_run``), figure by figure."""
    if side not in best:
        best[side] = got
        return
    b = best[side]
    b["stage_ms"] = {k: min(v, got["stage_ms"][k]) for k, v in b["stage_ms"].items()}
    for k in ("tick_cpu_ms", "tick_wall_ms", "after_ticks_cpu_s", "judge_s", "total_cpu_s"):
        b[k] = min(b[k], got[k])


def _print_imu(figures: dict) -> None:
    """``_imu``'s figures: each stage with and without, the ratio, what grew, what is not tick
    time."""
    name, plain, imu, grew = (
        figures["scenario"],
        figures["plain"],
        figures["imu"],
        figures["stages_grew_ms"],
    )
    ratio, rounds = figures["tick_cpu_ratio"], figures["rounds"]
    print(
        f"{name}, {imu['ticks']} camera ticks, with the imu built-in's [imu] and without, "
        f"best of {rounds} alternating rounds, recording as vnav-demo run does "
        f"(load average {figures['load_average'][0]:.1f})"
    )
    print("ms per camera tick by stage (the stage timers read wall time):")
    print(f"  {'stage':<12}{'without':>10}{'with':>10}{'change':>10}")
    for k in STAGES:
        a, b = plain["stage_ms"][k], imu["stage_ms"][k]
        print(f"  {k:<12}{a:>10.2f}{b:>10.2f}{b - a:>+10.2f}")
    for key, label in (("tick_cpu_ms", "CPU"), ("tick_wall_ms", "wall")):
        print(f"  {'tick, ' + label:<12}{plain[key]:>10.2f}{imu[key]:>10.2f}")
    print(
        f"ratio with / without, a tick's CPU: {ratio:.3f} (target <= {IMU_TARGET:.2f}); "
        f"wall {figures['tick_wall_ratio']:.3f}"
    )
    where = ", ".join(f"{k} {v:+.2f} ms" for k, v in sorted(grew.items(), key=lambda x: -x[1]))
    print(f"where the IMU's time goes (stages that grew): {where or 'none'}")
    print(
        "not tick time: after the last tick (the IMU's readings made, judging, the "
        f"recording finished) {plain['after_ticks_cpu_s']:.2f} -> "
        f"{imu['after_ticks_cpu_s']:.2f} s CPU, of which judging (checks such as "
        f"imu_consistent, calibrations) {plain['judge_s']:.3f} -> {imu['judge_s']:.3f} s "
        "wall; the whole run "
        f"{plain['total_cpu_s']:.2f} -> {imu['total_cpu_s']:.2f} s CPU"
    )


def _imu(args: argparse.Namespace) -> dict:
    """A scenario with the ``imu`` built-in's ``[imu]`` against without, alternating (ABBA),
    best of the rounds for each figure."""
    name = (getattr(args, "scenario", None) or ["orbit"])[0]
    try:
        specs = _imu_specs(name, getattr(args, "duration", None))
    except ValueError as e:
        print(f"python -m benchmarks pipeline --imu: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    best: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="vnav-bench-imu-") as tmp:
        _imu_run(specs["plain"], Path(tmp))  # warm: imports, the first OpenGL context
        for i in range(max(1, args.rounds)):
            for side in ("plain", "imu")[:: 1 if i % 2 == 0 else -1]:
                _keep_best(best, side, _imu_run(specs[side], Path(tmp)))
    plain, imu = best["plain"], best["imu"]
    ratio = imu["tick_cpu_ms"] / plain["tick_cpu_ms"]
    # A stage grew by at least what its figure prints (0.01 ms): not a rounding's difference.
    grew = {
        k: imu["stage_ms"][k] - plain["stage_ms"][k]
        for k in STAGES
        if imu["stage_ms"][k] - plain["stage_ms"][k] >= 0.005
    }
    figures = {
        "scenario": name,
        "ticks": imu["ticks"],
        "rounds": args.rounds,
        "plain": plain,
        "imu": imu,
        "tick_cpu_ratio": ratio,
        "tick_wall_ratio": imu["tick_wall_ms"] / plain["tick_wall_ms"],
        "stages_grew_ms": grew,
        "load_average": os.getloadavg(),
        "target_ratio": IMU_TARGET,
    }
    if not args.json:
        _print_imu(figures)
    return figures


PLUGIN_TARGETS = {"plugged_over_plain": 1.05, "doctor_900_s": 1.0}


def _timed_run(spec, out: Path, methods: tuple) -> tuple[float, float, dict]:
    """One run of ``spec`` with ``methods`` added: wall and CPU seconds, the report."""
    from vnav.methods import extended

    wall_s, cpu_s = time.perf_counter(), time.process_time()
    with extended(methods):
        outcome = pipeline.run(spec, seed=1, out_dir=out)
    return time.perf_counter() - wall_s, time.process_time() - cpu_s, outcome.report


def _plugin(args: argparse.Namespace) -> dict:
    """The reference solution plugged in against not, side by side; the plug-in's cost per
    detection; the doctor on 900 observations."""
    from vnav.plugin import plugin_method

    name = (getattr(args, "scenario", None) or ["frame-problem"])[0]
    spec = builtin.load(name)
    best = {"plain": [float("inf")] * 2, "plugged": [float("inf")] * 2}
    user_s = float("inf")
    with tempfile.TemporaryDirectory(prefix="vnav-bench-plugin-") as tmp:
        _timed_run(spec, Path(tmp), ())  # warm: imports, the scene's first build
        for i in range(max(1, args.rounds)):
            # ABBA: neither side always runs first (a warmer cache, a quieter moment).
            for side in ("plain", "plugged")[:: 1 if i % 2 == 0 else -1]:
                methods = (plugin_method("vnav.plugin:reference_estimate"),) * (side == "plugged")
                wall_s, cpu_s, report = _timed_run(spec, Path(tmp), methods)
                best[side] = [min(best[side][0], wall_s), min(best[side][1], cpu_s)]
                if methods:
                    own = report["estimators"][methods[0].name]["time_s"]
                    user_s = min(user_s, own["total"])
                    calls = own["calls"]
    ratio = {k: best["plugged"][i] / best["plain"][i] for i, k in enumerate(("wall", "cpu"))}
    allowed = {
        k: PLUGIN_TARGETS["plugged_over_plain"] + user_s / best["plain"][i]
        for i, k in enumerate(("wall", "cpu"))
    }
    figures = {
        "scenario": name,
        "rounds": args.rounds,
        "plain_s": dict(zip(("wall", "cpu"), best["plain"], strict=True)),
        "plugged_s": dict(zip(("wall", "cpu"), best["plugged"], strict=True)),
        "ratio": ratio,
        "allowed_ratio": allowed,
        "function_calls": calls,
        "function_total_s": user_s,
        "per_detection_us": _per_detection_us(),
        "doctor_900_s": _doctor_s(),
        "targets": PLUGIN_TARGETS,
    }
    if not args.json:
        print(f"{name}, best of {args.rounds} alternating rounds, recording as vnav-demo run does")
        for side in ("plain", "plugged"):
            label = "without" if side == "plain" else "with reference_estimate"
            print(f"  {label:<26}{best[side][0]:>8.2f} s wall {best[side][1]:>8.2f} s CPU")
        print(
            f"  ratio: wall {ratio['wall']:.3f}, CPU {ratio['cpu']:.3f} (target <= "
            f"{allowed['wall']:.3f} wall, {allowed['cpu']:.3f} CPU: 1.05 + the function's "
            f"{1e3 * user_s:.1f} ms over {calls} calls)"
        )
        per = figures["per_detection_us"]
        print(
            f"  a plug-in's cost per detection, the function aside: {per['first']:.0f} us for "
            f"an image's first detection, {per['further']:.0f} us for each further one"
        )
        doctor_ms, target_s = 1e3 * figures["doctor_900_s"], PLUGIN_TARGETS["doctor_900_s"]
        print(
            f"  the doctor on 900 observations (30 s at 30 Hz): {doctor_ms:.1f} ms "
            f"(target < {target_s:g} s)"
        )
    return figures


def _per_detection_us(repeat: int = 2000) -> dict[str, float]:
    """``PluginEstimator.estimate`` around a function that returns at once, microseconds:
    for a new image's detection, and for a further detection of the same image."""
    from types import SimpleNamespace

    import numpy as np

    from vnav import se3, so3
    from vnav.camera import PinholeCamera
    from vnav.frames import R_FLU_RDF
    from vnav.plugin import PluginEstimator

    camera = PinholeCamera.from_fovy(60.0, 640, 480)
    p_w = np.array([8.0, 1.0, 0.0])
    T_w_b = se3.make(so3.from_rpy(0.02, -0.03, 0.4), [0.0, 0.0, 1.5])
    T_b_c = se3.make(R_FLU_RDF, [0.15, 0.0, 0.05])
    p_c = se3.apply(se3.invert(T_w_b @ T_b_c), p_w)

    def observation() -> SimpleNamespace:  # what estimate reads of a vnav Observation
        exposure = SimpleNamespace(T_w_b=T_w_b, T_b_c=T_b_c, camera=camera)
        return SimpleNamespace(
            exposure=exposure, view=SimpleNamespace(camera_coordinates=lambda p: p_c)
        )

    estimator = PluginEstimator(lambda obs: p_w)
    fresh = [observation() for _ in range(repeat)]
    start = time.perf_counter()
    for obs in fresh:
        estimator.estimate(obs, p_w, 0.0)
    first = (time.perf_counter() - start) / repeat
    same = observation()
    start = time.perf_counter()
    for _ in range(repeat):
        estimator.estimate(same, p_w, 0.0)
    further = (time.perf_counter() - start) / repeat
    return {"first": 1e6 * first, "further": 1e6 * further}


def _doctor_s(n: int = 900) -> float:
    """``vnav.diagnose.diagnose`` on ``n`` observations, every hypothesis, best of 5, s."""
    import numpy as np

    from vnav import se3, so3
    from vnav.diagnose import diagnose

    rng = np.random.default_rng(0)
    poses = np.stack(
        [se3.make(so3.from_rpy(*rng.uniform(-1, 1, 3)), rng.normal(size=3)) for _ in range(2 * n)]
    )
    T_w_b, newest = poses[:n], poses[n:]
    T_b_c = se3.make(so3.from_rpy(0.1, -0.2, 0.3), [0.15, 0.0, 0.05])
    p_c = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(2, 20, n)])
    T_w_c = T_w_b @ T_b_c
    p_w = np.einsum("nij,nj->ni", T_w_c[:, :3, :3], p_c) + T_w_c[:, :3, 3]  # the correct chain
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        diagnose(p_c, T_w_b, T_b_c, p_w, T_w_b_newest=newest)
        best = min(best, time.perf_counter() - start)
    return best
