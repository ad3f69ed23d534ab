"""``vnav-demo sweep FILE.toml``: plan, run every episode, write the tables, summary and plots.

Everything that can be checked before running is checked first (the extra is installed, the
sweep file and every grid point parse, the options, the output directory and what it holds),
so bad input exits with status 2 and runs nothing. Exit statuses: 0 every episode passed its
checks, 1 some failed or diverged, 2 bad input, 3 some episode could not run (an internal
error, or its worker lost on every try: ``--resume`` runs it again), 128 + N on signal N
(what finished is kept: ``--resume`` goes on from there).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import shlex
import signal
import statistics
import sys
import time
from pathlib import Path

from scenarios import pipeline
from scenarios.commands.common import (
    EXIT_BAD_INPUT,
    EXIT_CHECK_FAILED,
    EXIT_INCOMPLETE,
    EXIT_PASSED,
    InputError,
    Signalled,
    guarded,
    prepare_out_dir,
)
from scenarios.commands.console import WIDTH, say
from scenarios.commands.console import error as _error
from scenarios.record import outputs
from scenarios.sweep import engine as engines
from scenarios.sweep import plots, summary
from scenarios.sweep.plan import SweepError, SweepPlan, draws_from_seed, load, navigates
from scenarios.sweep.rows import method_column
from scenarios.sweep.store import SweepStore, pyarrow_missing
from vnav.methods import extended

__all__ = ["command"]

SHOWN_POINTS = 20
"""Grid points listed in the printed summary (all are in summary.json)."""


@dataclasses.dataclass
class _Run:
    """What the loop over episodes leaves: failures, the signal that stopped it, the time."""

    failures: list[engines.Failure] = dataclasses.field(default_factory=list)
    stopped_by: int | None = None
    wall_s: float = 0.0
    ran: int = 0


def _validate(args: argparse.Namespace) -> tuple[SweepPlan, Path]:
    missing = pyarrow_missing() or (engines.ray_missing() if args.workers != 0 else None)
    if missing:
        hint = " (or --workers 0 to run without Ray)" if "Ray" in missing else ""
        raise InputError(f"vnav-demo sweep needs its extra: {missing}{hint}")
    if args.workers is not None and args.workers < 0:
        raise InputError(f"--workers must be 0 (this process) or more, got {args.workers}")
    if args.workers == 0 and args.address:
        raise InputError("--workers 0 runs in this process; it cannot go with --address")
    if args.workers and not args.address:
        cpus, source = engines.usable_cpus()
        if args.workers > cpus:  # each worker takes a CPU: more would wait, holding memory
            raise InputError(
                f"--workers {args.workers}: this process may use {cpus} CPUs ({source}) and "
                f"a worker takes one: ask for at most {cpus}"
            )
    if args.address:
        try:
            engines.check_address(args.address)
        except engines.EngineError as exc:
            raise InputError(str(exc)) from None
    if args.record_worst < 0:
        raise InputError(f"--record-worst must be 0 or more, got {args.record_worst}")
    try:
        plan = load(args.file)
    except SweepError as exc:
        raise InputError(str(exc)) from None
    if args.address:  # reached before anything is written (the engine keeps the connection)
        try:
            engines.join_cluster(args.address, args.workers)
        except engines.EngineError as exc:
            raise InputError(str(exc)) from None
    out = args.out if args.out is not None else str(Path("sweeps") / Path(args.file).stem)
    return plan, prepare_out_dir(out)


def command(args: argparse.Namespace) -> int:
    """Entry point of ``vnav-demo sweep``; returns the exit status."""
    started_s = time.perf_counter()
    return guarded(
        lambda: _validate(args),
        lambda plan, out_dir: _sweep_or_say(plan, out_dir, args, started_s),
        kept="finished episodes are kept",
    )


def _sweep_or_say(
    plan: SweepPlan, out_dir: Path, args: argparse.Namespace, started_s: float
) -> int:
    try:
        return _sweep(plan, out_dir, args, started_s)
    except SweepError as exc:
        raise InputError(str(exc)) from None
    except OSError as exc:
        _error(f"cannot write the sweep's files: {exc}; finished episodes are kept in {out_dir}")
        return EXIT_INCOMPLETE


def _sweep(plan: SweepPlan, out_dir: Path, args: argparse.Namespace, started_s: float) -> int:
    """The sweep; ``started_s`` is when the command started (``time.perf_counter``), for the
    total duration printed at the end."""
    store = SweepStore.open(out_dir, plan, args.resume)
    pending = store.pending()
    if not args.quiet:
        say(_header(plan, store, pending, args))
        for line in (_bad_entries(store), _seedless(plan)):
            if line:
                say(line)
    engine = _start_engine(args, plan) if pending else None
    if engine is None and pending:
        return EXIT_BAD_INPUT  # said by _start_engine; nothing was written
    try:
        store.begin()
        outcome = _run_pending(store, pending, engine, args)
    finally:
        if engine is not None:
            engine.close()
    store.write_tables()
    complete = not store.pending()
    recordings = _record_worst(store, out_dir, args) if complete and args.record_worst else {}
    _write_summary(store, out_dir, complete, recordings)
    if not args.quiet:
        say(_final(store, out_dir, outcome, args, recordings))
        say(_took(time.perf_counter() - started_s, engine, outcome))
    if outcome.stopped_by is not None:
        name = signal.Signals(outcome.stopped_by).name
        finish = shlex.join(["vnav-demo", "sweep", args.file, "--out", str(out_dir), "--resume"])
        _error(
            f"stopped by {name}: {len(store.episodes)} of {len(plan.episodes)} episodes done; "
            f"finish with: {finish}"
        )
        return 128 + outcome.stopped_by
    if outcome.failures:
        first = outcome.failures[0]
        _error(
            f"{len(outcome.failures)} episodes could not run (point {first.point} seed "
            f"{first.seed}: {first.error}); --resume runs them again"
        )
        return EXIT_INCOMPLETE
    passed = all(e.row["passed"] for e in store.episodes.values())
    return EXIT_PASSED if passed else EXIT_CHECK_FAILED


def _header(plan: SweepPlan, store: SweepStore, pending: list, args: argparse.Namespace) -> str:
    if args.workers == 0:
        where = "in this process"
    elif args.address:
        workers = f"{args.workers} workers" if args.workers else "a worker per CPU"
        where = f"on the Ray cluster at {args.address} ({workers})"
    else:
        where = f"on Ray ({args.workers or engines.default_workers()} local workers)"
    done = len(plan.episodes) - len(pending)
    resumed = f", {done} done before" if done else ""
    return (
        f"sweep {plan.scenario}: {len(plan.points)} grid points x {len(plan.seeds)} seeds = "
        f"{len(plan.episodes)} episodes{resumed}; {len(pending)} to run {where}"
    )


def _bad_entries(store: SweepStore) -> str | None:
    """One line on the journal entries set aside (they run again), or None."""
    bad = store.bad_entries
    if not bad:
        return None
    return (
        f"{len(bad)} journal entries do not read as this sweep's episodes and run again "
        f"(first: {bad[0]})"
    )


def _seedless(plan: SweepPlan) -> str | None:
    """One line where some grid points' seeds all give the same result, or None."""
    if len(plan.seeds) < 2:
        return None
    idle = [p.index for p in plan.points if not draws_from_seed(p.spec)]
    n = len(plan.seeds)
    if len(idle) == len(plan.points):
        return (
            f"no draw depends on the seed: {n} seeds give one result (every [noise] figure, "
            "every [imu] noise figure and timing.jitter_s are zero)"
        )
    if not idle:
        return None
    shown = ", ".join(f"p{i}" for i in idle[:5]) + (", ..." if len(idle) > 5 else "")
    return (
        f"no draw depends on the seed at {len(idle)} of {len(plan.points)} grid points "
        f"({shown}): {n} seeds give one result there"
    )


def _took(total_s: float, engine, run: _Run) -> str:
    """The sweep's whole duration, wall clock, from the command's start, and its parts: the
    engine's start (Ray's), the episodes, and the rest (planning, tables, plots, recordings)."""
    parts = []
    startup_s = getattr(engine, "startup_s", None)
    if startup_s:
        parts.append(f"Ray start {startup_s:.1f} s")
    parts.append(f"episodes {run.wall_s:.1f} s")
    rest_s = total_s - run.wall_s - (startup_s or 0.0)
    parts.append(f"planning, tables, plots and recordings {max(rest_s, 0.0):.1f} s")
    return f"took {total_s:.1f} s in all, wall clock ({', '.join(parts)})"


def _start_engine(args: argparse.Namespace, plan: SweepPlan):
    """The engine the options ask for, running ``plan``'s user estimators in every episode,
    or None (said in one line) if Ray cannot be joined."""
    if args.workers == 0:
        return engines.SerialEngine(plan.estimators)
    try:
        engine = engines.RayEngine(args.workers, args.address, estimators=plan.estimators)
    except engines.EngineError as exc:
        _error(str(exc))
        return None
    if not args.quiet:
        say(f"  Ray ready in {engine.startup_s:.1f} s ({engine.workers} workers)")
    return engine


def _run_pending(store: SweepStore, pending: list, engine, args: argparse.Namespace) -> _Run:
    """Run the pending episodes, journalling each as it finishes, until done or stopped."""
    out = _Run()
    if not pending:
        return out
    # Made as the engine takes them: a million tasks made up front take seconds.
    tasks = (engines.Task(p, s, store.plan.points[p].scenario_toml) for p, s in pending)
    bar = _Progress(len(pending), enabled=not args.quiet)
    start = time.perf_counter()
    bar(0, 0.0)
    try:
        for result in engine.run(tasks):
            if isinstance(result, engines.Failure):
                out.failures.append(result)
            else:
                store.add(result)
                out.ran += 1
            bar(out.ran + len(out.failures), time.perf_counter() - start)
    except KeyboardInterrupt:
        out.stopped_by = signal.SIGINT
    except Signalled as exc:
        out.stopped_by = exc.signum
    finally:
        bar.clear()
        out.wall_s = time.perf_counter() - start
    return out


class _Progress:
    """A one-line bar on stderr (a terminal only): episodes done, rate, time left."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total, self.enabled = total, enabled and sys.stderr.isatty()

    def __call__(self, done: int, elapsed_s: float) -> None:
        if not self.enabled:
            return
        rate = done / elapsed_s if elapsed_s > 0 else 0.0
        left = (self.total - done) / rate if rate > 0 else math.inf
        filled = int(30 * done / self.total)
        sys.stderr.write(
            f"\r[{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total} episodes  "
            f"{rate:.2f}/s  {_duration(left)} left "
        )
        sys.stderr.flush()

    def clear(self) -> None:
        if self.enabled:
            sys.stderr.write("\r" + " " * (WIDTH - 1) + "\r")
            sys.stderr.flush()


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"


def _record_worst(store: SweepStore, out_dir: Path, args) -> dict[tuple[int, int], str]:
    """Run the K worst episodes again, writing their recordings into ``DIR/worst/``."""
    worst_dir = out_dir / "worst"
    worst_dir.mkdir(exist_ok=True)
    written = {}
    for e in summary.worst(store.sorted_episodes(), store.plan.rank_by, args.record_worst):
        if e.row["status"] == "diverged":
            continue  # its flight diverges again: a run that diverges writes no recording
        point = store.plan.points[e.point]
        spec = dataclasses.replace(point.spec, name=f"{point.spec.name}-s{e.seed}")
        with extended(store.plan.user_methods):  # as the episode ran, with the user's functions
            outcome = pipeline.run(spec, seed=e.seed, out_dir=worst_dir)
        written[e.point, e.seed] = str(outcome.rrd_path.relative_to(out_dir))
    return written


def _write_summary(
    store: SweepStore, out_dir: Path, complete: bool, recordings: dict[tuple[int, int], str]
) -> None:
    """``plots/*.png`` and then ``summary.json``, from every finished episode."""
    import json

    episodes = store.sorted_episodes()
    plots_dir = out_dir / "plots"
    plots_dir.mkdir(exist_ok=True)
    for name in plots.plot_names(store.plan):
        png = plots.plot_png(store.plan, episodes, name)
        outputs.write_atomic(plots_dir / name, lambda tmp, png=png: tmp.write_bytes(png))
    doc = summary.build(
        store.plan,
        episodes,
        out_dir=str(out_dir),
        point_files=[store.point_file(p.index) for p in store.plan.points],
        complete=complete,
        recordings=recordings,
    )
    text = json.dumps(doc, indent=1, allow_nan=False) + "\n"
    outputs.write_atomic(out_dir / "summary.json", lambda tmp: tmp.write_text(text))


def _user_figure(name: str, episodes: list) -> str:
    """A user's function at one grid point, as the rank method's figure is given: the median
    of its episodes' median errors, and the detections it failed on."""
    medians = [e.row[method_column(name, "median")] for e in episodes]
    finite = [m for m in medians if math.isfinite(m)]
    figure = f"median {statistics.median(finite):.3f} m" if finite else "no estimate"
    failed = sum(e.row[method_column(name, "failures")] for e in episodes)
    return f"{name} {figure}, failed on {failed} detections"


def _navigation_figure(episodes: list) -> str:
    """A navigating grid point's outcome across its episodes (``summary.navigation_entry``):
    the collision and goal rates and the smallest true clearance of any."""
    nav = summary.navigation_entry(episodes)
    flown = nav["flown"]
    if not flown:
        return "navigation: every flight diverged"
    smallest = nav["min_clearance_m"]["min"]
    clearance = f", smallest clearance {smallest:.3f} m" if smallest is not None else ""
    return (
        f"collided {nav['collided']}/{flown} (rate {nav['collision_rate']:.2f}), reached the "
        f"goal {nav['reached_goal']}/{flown} (rate {nav['goal_rate']:.2f}){clearance}"
    )


def _final(
    store: SweepStore, out_dir: Path, run: _Run, args, recordings: dict[tuple[int, int], str]
) -> str:
    """The printed summary: counts, a few lines per grid point, the files, the worst seed and
    the worst episodes' recordings (``--record-worst``)."""
    plan = store.plan
    episodes = store.sorted_episodes()
    statuses = [e.row["status"] for e in episodes]
    rate = f", {run.ran / run.wall_s:.2f} episodes/s" if run.ran and run.wall_s > 0 else ""
    lines = [
        f"{len(episodes)} of {len(plan.episodes)} episodes: {statuses.count('passed')} passed, "
        f"{statuses.count('failed')} failed, {statuses.count('diverged')} diverged "
        f"({run.ran} run in {run.wall_s:.1f} s{rate})"
    ]
    rank = plan.rank_by
    for p in plan.points[:SHOWN_POINTS]:
        mine = [e for e in episodes if e.point == p.index]
        if not mine:
            continue
        medians = [e.row[method_column(rank, "median")] for e in mine]
        finite = [m for m in medians if math.isfinite(m)]
        figure = (
            f"{rank} median {statistics.median(finite):.3f} m" if finite else f"no {rank} estimate"
        )
        (w,) = summary.worst(mine, rank, 1)
        lines.append(f"  p{p.index}: {p.label}")
        lines.append(
            f"      passed {sum(e.row['passed'] for e in mine)}/{len(mine)}, {figure}, "
            f"worst seed {w.seed}"
        )
        lines += [f"      {_user_figure(m.name, mine)}" for m in plan.user_methods]
        if navigates(p.spec):
            lines.append(f"      {_navigation_figure(mine)}")
    if len(plan.points) > SHOWN_POINTS:
        lines.append(f"  ... {len(plan.points) - SHOWN_POINTS} more grid points in summary.json")
    lines.append(f"wrote {out_dir}/results.parquet, estimates.parquet, summary.json, plots/")
    if episodes:
        (w,) = summary.worst(episodes, rank, 1)
        replay = summary.replay_command(
            str(out_dir), store.point_file(w.point), w.seed, summary.replay_specs(plan)
        )
        lines.append(f"worst: {replay}")
    if recordings:
        first = shlex.join(["rerun", f"{out_dir}/{next(iter(recordings.values()))}"])
        lines.append(
            f"recorded the {len(recordings)} worst episodes in {out_dir}/worst/ "
            f"(open one with: {first})"
        )
    elif args.record_worst and store.pending():
        lines.append("--record-worst waits for a complete sweep: finish it with --resume")
    return "\n".join(lines)
