"""``vnav-demo run``: resolve, validate, run, judge, write, summarise.

Everything that can be checked before running is checked first (every name and file, the
seed, the duration, the run's length, the output directory and paths), so bad input exits
with status 2 and writes nothing. Exit statuses (``EXIT_*``): 0 every check passed, 1 a check
failed, 2 bad input, 3 a run could not complete (I/O error such as a full disk, a diverging
simulation, out of memory, an internal error), 128 + N on signal N (SIGINT, SIGTERM, SIGHUP).
Each scenario's ``.rrd`` and ``.json`` are written together or not at all
(``scenarios.record.outputs``); whatever ends a run, the previous pair stays as it was.
Several scenarios run two at a time where there are two cores, on worker processes
(``--jobs N``, ``scenarios.commands.workers``), with the files, reports, output (in the
scenarios' order) and exit status of ``--jobs 1``, which runs them one after the other here.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import os
import re
import shutil
import sys
import textwrap
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from scenarios import pipeline
from scenarios.commands.common import (
    EXIT_CHECK_FAILED,
    EXIT_INCOMPLETE,
    EXIT_PASSED,
    InputError,
    Signalled,
    guarded,
    prepare_out_dir,
    signal_caught,
)
from scenarios.commands.console import WIDTH, say
from scenarios.commands.console import error as _error
from scenarios.commands.workers import RunOne, default_jobs, run_parallel
from scenarios.export.base import ExportResult
from scenarios.run.evaluate import MATCH_GATE_M
from scenarios.scenario import builtin
from scenarios.scenario.spec import MAX_SEED, ScenarioError, ScenarioSpec, load_toml
from sim.scene_cache import SceneCache
from sim.world import SimulationError
from vnav.estimators import NoEstimate
from vnav.methods import Method, extended

logger = logging.getLogger(__name__)


def resolve(targets: list[str], run_all: bool) -> list[ScenarioSpec]:
    """Scenario specs for names and files, in order, without duplicates."""
    items = list(builtin.names()) if run_all else []
    items += [t for t in targets if t not in items]
    if not items:
        raise InputError(
            "no scenario given: name one (see `vnav-demo list`), a FILE.toml, or --all"
        )
    specs = []
    for item in items:
        # A bare name is a built-in; a path (a "/" or a .toml suffix) is a file, even if a
        # file named like a built-in lies in the current directory.
        is_file = item.endswith(".toml") or "/" in item or os.sep in item
        try:
            specs.append(load_toml(item) if is_file else builtin.load(item))
        except ScenarioError as exc:
            raise InputError(str(exc)) from None
    seen: dict[str, str] = {}
    for spec, item in zip(specs, items, strict=True):
        if spec.name in seen:
            raise InputError(
                f"two scenarios are named {spec.name!r} ({seen[spec.name]} and "
                f"{item}): their output files would collide"
            )
        seen[spec.name] = item
    return specs


def check_outputs(specs: list[ScenarioSpec], out_dir: Path, exports: tuple[str, ...] = ()) -> None:
    """Refuse outputs that could not be written: an existing directory under a file's name
    (the recording, the report, an export's file), a file under an export directory's name,
    or a directory there that is not such an export (its previous one is replaced whole)."""
    from scenarios import export

    for spec in specs:
        for path in pipeline.output_paths(spec, out_dir):
            if path.is_dir():
                raise InputError(f"{path} is a directory; the run would write a file there")
        for name in exports:
            fmt = export.FORMATS[name]
            for final in fmt.final_names(spec.name):
                path = out_dir / final
                if not fmt.directory and path.is_dir():
                    raise InputError(f"{path} is a directory; the run would write a file there")
                if fmt.directory and (path.exists() or path.is_symlink()):
                    if path.is_symlink() or not path.is_dir():
                        raise InputError(
                            f"{path} is not a directory; --export {name} writes a directory there"
                        )
                    if sorted(p.name for p in path.iterdir()) not in ([], ["mav0"]):
                        raise InputError(
                            f"{path} holds more than an --export {name} directory (mav0/); "
                            "the run would replace it whole: move it or choose another --out"
                        )


def check_lengths(specs: list[ScenarioSpec], max_ticks: int) -> None:
    """Refuse runs longer than ``max_ticks`` camera ticks (``--max-ticks``)."""
    for spec in specs:
        if spec.n_ticks > max_ticks:
            raise InputError(
                f"{spec.name}: {spec.n_ticks} camera ticks ({spec.end_s:g} s at "
                f"{spec.camera_rate_hz:g} Hz) is more than --max-ticks {max_ticks}; raise it to "
                f"run this long (about 35 KB of recording per tick)"
            )


class Progress:
    """A one-line progress bar on stderr, only when stderr is a terminal."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled = label, enabled and sys.stderr.isatty()

    def __call__(self, done: int, total: int) -> None:
        if (signum := signal_caught()) is not None:  # its exception was swallowed: stop now
            raise Signalled(signum)
        if not self.enabled:
            return
        width = 30
        filled = int(width * done / total)
        sys.stderr.write(
            f"\r{self.label:<20} [{'#' * filled}{'.' * (width - filled)}] {done}/{total}"
        )
        if done == total:
            sys.stderr.write("\r" + " " * (width + 40) + "\r")
        sys.stderr.flush()


_MARK = {"passed": "ok", "failed": "FAILED", "no data": "NO DATA", "skipped": "skipped"}
"""How the table marks each check outcome (``scenarios.judge.checks.Outcome``)."""


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def _wrap(text: str, indent: int = 0, first: str | None = None) -> list[str]:
    """``text`` wrapped to ``WIDTH`` columns; ``first`` prefixes the first line (default:
    ``indent`` spaces), later lines are indented by ``indent``. Paths are never broken."""
    pad = " " * indent
    # A number keeps its unit, a bound its number, on its line: joined by a no-break space.
    glued = re.sub(r"(\d (?=(m|deg|px|s)\b)|[<>]= )", lambda m: m[0][:-1] + "\u00a0", text)
    lines = textwrap.wrap(
        glued,
        WIDTH,
        initial_indent=pad if first is None else first,
        subsequent_indent=pad,
        break_long_words=False,
        break_on_hyphens=False,
    )
    return [line.replace("\u00a0", " ") for line in lines]


def _no_estimate_text(reasons: dict[str, int]) -> str:
    """Why a method gave no estimate, from the report's ``no_estimate`` counts."""
    if not reasons:
        return "no estimate"
    parts = [f"{n} {NoEstimate(r).text}" for r, n in reasons.items()]
    if len(parts) == 1 and next(iter(reasons.values())) > 1:
        parts = [f"all {parts[0]}"]
    return "no estimate: " + "; ".join(parts)


def _check_lines(check: dict) -> list[str]:
    """One check: its mark and name, then the figure next to its limit (or why it has none);
    on one line where it fits."""
    first = f"  {_MARK[check['outcome']]:<8}"
    line = f"{first}{check['name']}: {check['shown']}"
    if len(line) <= WIDTH:
        return [line]
    return _wrap(check["name"], len(first), first) + _wrap(check["shown"], len(first))


def duration_text(wall_s: float, cpu_s: float) -> str:
    """A duration as ``run`` prints it: wall seconds, then the CPU seconds (user and system)
    this process spent meanwhile, which other processes on the machine do not inflate."""
    # A no-break space keeps "s CPU" on one line (``_wrap`` prints it as a space).
    return f"{wall_s:.1f} s, {cpu_s:.1f} s\u00a0CPU"


def summary(rep: dict, rrd: Path, json_path: Path) -> str:
    """The table printed after each scenario, ``WIDTH`` columns wide; its first line ends with
    the run's duration, the report's ``timing_s`` ``total`` and ``total_cpu``."""
    status = "PASSED" if rep["passed"] else "FAILED"
    timing = rep["timing_s"]
    lines = _wrap(
        f"{rep['scenario']}: {status}  ({rep['camera_ticks']} camera ticks, "
        f"{rep['detections']} detections, {rep['matched_detections']} matched, "
        f"{duration_text(timing['total'], timing['total_cpu'])})",
        2,
        "",
    )
    width = max(13, *map(len, rep["methods"]))  # a user's function may have a long name
    lines.append(
        f"  {'method':<{width}} {'count':>5} {'mean':>8} {'median':>8} {'rmse':>8} {'max':>8}"
        "  error, m"
    )
    lines += _method_rows(rep["methods"], width)
    lines += _estimator_lines(rep.get("estimators", {}), timing["total"])
    lines += _latest_pose_lines(rep)
    lines += _recovered_mount_lines(rep)
    lines += _navigation_lines(rep.get("navigation"))
    lines.append("  checks:")
    for c in rep["checks"]:
        lines += _check_lines(c)
    lines += _wrap(f"wrote {rrd} and {json_path}", 2)
    return "\n".join(lines)


def _method_rows(methods: dict, width: int = 13) -> list[str]:
    """One row per method, its name ``width`` wide: its error statistics, or why it gave no
    estimate."""
    lines = []
    for method, entry in methods.items():
        s = entry["position_error_m"]
        row = f"  {method:<{width}} {s['count']:>5}"
        if s["count"]:
            lines.append(
                f"{row} {_fmt(s['mean']):>8} {_fmt(s['median']):>8} {_fmt(s['rmse']):>8} "
                f"{_fmt(s['max']):>8}"
            )
        else:  # the row says why it is empty
            lines += _wrap(
                _no_estimate_text(entry.get("no_estimate", {})), len(row) + 2, row + "  "
            )
    return lines


SLOW_CALL_S = 0.010
"""A user's function whose mean call takes longer than this is said to be slow (seconds)."""

SLOW_SHARE = 0.10
"""... as is one whose calls take more than this share of the run's wall time."""


def _estimator_lines(estimators: dict, run_wall_s: float) -> list[str]:
    """Under the methods' rows, each user's function's diagnosis, how it failed (the report's
    ``estimators``: each kind's count, first camera tick and first message), how many
    detections it was skipped on after timing out, and its time when slow (a mean call over
    ``SLOW_CALL_S``, or its calls over ``SLOW_SHARE`` of the run's wall time ``run_wall_s``)."""
    lines = []
    for name, entry in estimators.items():
        diagnosis = entry.get("diagnosis")
        if diagnosis is not None and diagnosis["verdict"] != "correct":
            lines += _wrap(f"{name}: {diagnosis['message']}", 4, "    ")
        for kind, f in entry["failures"].items():
            ticks = f["ticks"]
            where = f"tick {ticks[0]}" + (f" and {len(ticks) - 1} more" if len(ticks) > 1 else "")
            lines += _wrap(
                f"{name} failed {f['count']}x ({kind.replace('_', ' ')}), first at {where}: "
                f"{f['first_message']}",
                4,
                "    ",
            )
        if entry["skipped"]:
            lines += _wrap(
                f"{name} was not called on the {entry['skipped']} later detections (stopped "
                f"after exceeding its {entry['timeout_s']:g} s limit)",
                4,
                "    ",
            )
        t = entry["time_s"]
        if t["calls"] and (t["mean"] > SLOW_CALL_S or t["total"] > SLOW_SHARE * run_wall_s):
            lines += _wrap(
                f"{name} took {_seconds(t['mean'])} per call ({t['calls']} "
                f"call{'s' if t['calls'] != 1 else ''}, "
                f"{_seconds(t['total'])}, longest {_seconds(t['max'])})",
                4,
                "    ",
            )
    return lines


def _navigation_lines(nav: dict | None) -> list[str]:
    """A navigating flight's outcome (the report's ``navigation``): the goal reached or not,
    the collision, the smallest true clearance and the length flown."""
    if nav is None:
        return []
    if nav["collided"]:
        outcome = (
            f"collision with cone {nav['first_contact_cone']} at t = {nav['first_contact_s']:.2f} s"
        )
    elif nav["reached_goal"]:
        outcome = f"reached the goal at t = {nav['time_to_goal_s']:.2f} s, no collision"
    else:
        outcome = (
            f"did not reach the goal ({nav['final_distance_to_goal_m']:.2f} m from it at the "
            "end), no collision"
        )
    return _wrap(
        f"navigation on {nav['estimate']}'s map: {outcome}; smallest true clearance "
        f"{nav['min_clearance_m']:.3f} m, flew {nav['path_length_m']:.2f} m",
        2,
    )


def _seconds(value_s: float) -> str:
    """A duration in words: ``1.00 s``, ``12.3 ms``."""
    return f"{value_s:.2f} s" if value_s >= 1.0 else f"{1e3 * value_s:.1f} ms"


def _recovered_mount_lines(rep: dict) -> list[str]:
    """In a calibrated run, the methods' rows again with the mount calibration recovered in
    place of the declared one (the report's ``calibration.position_error_m``)."""
    calibration = rep.get("calibration") or {}
    recovered = calibration.get("position_error_m", {}).get("recovered_mount")
    if not recovered or any(s is None for s in recovered.values()):
        return []
    lines = _wrap(
        "the same images estimated again with the camera mount calibration recovered "
        "(above: with the declared mount, which the scenario's mount error puts off):",
        2,
    )
    width = max(13, *map(len, recovered))
    return lines + _method_rows({m: {"position_error_m": s} for m, s in recovered.items()}, width)


def _latest_pose_lines(rep: dict) -> list[str]:
    """Where images arrive late: the row of ``depth_image`` with the newest pose at arrival,
    and what it is (nothing for a synchronous run, where it is ``depth_image``'s row)."""
    lookup = rep["pose_lookup"]
    s = lookup["latest_at_arrival"]["position_error_m"]
    lead = lookup["latest_minus_exposure_s"]
    if not s["count"] or not lead["max"] or lead["max"] == lead["min"] == 0.0:
        return []
    row = (
        f"  {'newest pose':<13} {s['count']:>5} {_fmt(s['mean']):>8} {_fmt(s['median']):>8} "
        f"{_fmt(s['rmse']):>8} {_fmt(s['max']):>8}"
    )
    latency_ms = 1000.0 * lookup["image_latency_s"]["mean"]
    predicted = lookup["latest_at_arrival"]["predicted_error_m"]["mean"]
    text = (
        f"newest pose: depth_image with the newest pose received when the image arrived "
        f"({latency_ms:.0f} ms after exposure), not the pose at its stamp; predicted mean "
        f"{_fmt(predicted)} m"
    )
    return [row, *_wrap(text, 4, "    ")]


def legend() -> str:
    """One line: what the detection counts of ``summary`` mean."""
    return (
        "detections: cones found in the images; "
        f"matched: estimated within {MATCH_GATE_M:g} m of a cone"
    )


def rerun_command() -> str:
    """How to call the Rerun viewer installed beside this Python (``.venv/bin/rerun``)."""
    beside = Path(sys.executable).parent / "rerun"
    if not beside.exists():
        return "rerun"
    found = shutil.which("rerun")
    if found and Path(found).resolve() == beside.resolve():
        return "rerun"
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def final_summary(
    outcomes: list[tuple[ScenarioSpec, int, Path | None]],
    out_dir: Path,
    duration: tuple[float, float] | None = None,
) -> str:
    """The lines after every scenario: the legend; with several scenarios, how many passed
    and failed, how long they took together and where their files are; the command to open a
    recording.

    ``outcomes`` holds each scenario's spec, exit status and recording (None if none);
    ``duration`` the wall and CPU seconds of them all.
    """
    lines = [legend()]
    if len(outcomes) > 1:
        by_status: dict[int, list[str]] = {}
        for spec, status, _ in outcomes:
            by_status.setdefault(status, []).append(spec.name)
        counts = [f"{len(by_status.get(EXIT_PASSED, []))} passed"]
        for status, word in ((EXIT_CHECK_FAILED, "failed"), (EXIT_INCOMPLETE, "incomplete")):
            if by_status.get(status):
                counts.append(f"{len(by_status[status])} {word} ({', '.join(by_status[status])})")
        took = f" in {duration_text(*duration)}" if duration is not None else ""
        lines += _wrap(f"{len(outcomes)} scenarios: {', '.join(counts)}{took}")
        lines += _wrap(f"files: {out_dir}/<name>.rrd (recording), {out_dir}/<name>.json (report)")
    written = [(status, rrd) for _, status, rrd in outcomes if rrd is not None]
    if written:
        # The first failure is the one worth a look; else the first recording.
        _, rrd = min(written, key=lambda item: item[0] != EXIT_CHECK_FAILED)
        lines += _wrap(f"open: {rerun_command()} {rrd}")
        lines.append("  (no display? add --serve-web and browse http://localhost:9090)")
    return "\n".join(lines)


def _print(stream: str, text: str) -> None:
    """``run_one``'s default ``emit``: ``text`` to stdout (``"out"``) or as an error line."""
    if stream == "out":
        say(text)
    else:
        _error(text)


def run_one(
    spec: ScenarioSpec,
    args: argparse.Namespace,
    out_dir: Path,
    scenes: SceneCache | None = None,
    emit: Callable[[str, str], None] = _print,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[int, Path | None]:
    """Run one scenario, write its files, print its summary; return its exit status and its
    recording (None when nothing was written). ``scenes``: the command's scenes and their
    OpenGL context, shared by its runs (``sim.scene_cache``). ``emit(stream, text)`` prints
    each text, ``stream`` ``"out"`` (the summary) or ``"err"`` (an error line); a worker
    process (``scenarios.commands.workers``) collects them instead. ``progress`` is called
    after every camera tick (default: ``Progress``'s bar)."""
    if progress is None:
        progress = Progress(spec.name, enabled=not args.quiet)
    try:
        try:
            outcome = pipeline.run(
                spec,
                seed=args.seed,
                out_dir=out_dir,
                progress=progress,
                exports=getattr(args, "exports", ()),
                scenes=scenes,
            )
        except Exception as exc:
            # A signal whose exception landed inside a library that turned it into another
            # error (or swallowed it, and something then failed): the signal is the cause.
            if (signum := signal_caught()) is not None:
                raise Signalled(signum) from exc
            raise
    except SimulationError as exc:
        emit("err", f"{spec.name}: could not complete: the simulation diverged: {exc}")
        return EXIT_INCOMPLETE, None
    except OSError as exc:
        emit(
            "err",
            f"{spec.name}: could not complete: cannot write its files: {exc}; "
            "the previous files were kept",
        )
        return EXIT_INCOMPLETE, None
    except MemoryError:
        emit("err", f"{spec.name}: could not complete: out of memory")
        return EXIT_INCOMPLETE, None
    except Exception as exc:  # an internal error: say it in one line, keep the others going
        logger.debug("internal error", exc_info=True)
        emit("err", f"{spec.name}: could not complete: internal error: {type(exc).__name__}: {exc}")
        return EXIT_INCOMPLETE, None
    if not args.quiet:
        emit("out", summary(outcome.report, outcome.rrd_path, outcome.json_path))
    if not args.quiet:
        for done in outcome.exports:
            emit("out", "\n".join(export_lines(done, out_dir)))
    return (EXIT_PASSED if outcome.passed else EXIT_CHECK_FAILED), outcome.rrd_path


@contextlib.contextmanager
def worker_session(options: dict[str, Any]) -> Iterator[RunOne]:
    """A worker process's set-up for its runs (``scenarios.commands.workers``): the user's
    functions and one ``SceneCache`` (its OpenGL context), as the serial command's. Yields
    ``run(spec, out_dir, emit, progress)``: ``run_one`` with the command's ``options``
    (``seed``, ``quiet``, ``exports``, ``estimator``, ``estimator_timeout_s``)."""
    args = argparse.Namespace(
        seed=options["seed"], quiet=options["quiet"], exports=options["exports"]
    )
    methods = user_methods(options["estimator"], options["estimator_timeout_s"])
    with extended(methods), SceneCache(capacity=2) as scenes:

        def run(spec: ScenarioSpec, out_dir: Path, emit, progress) -> tuple[int, Path | None]:
            return run_one(spec, args, out_dir, scenes, emit, progress)

        yield run


def export_lines(done: ExportResult, out_dir: Path) -> list[str]:
    """What one export format wrote (``scenarios.export.base.ExportResult``), and its note."""
    wrote = " and ".join(str(out_dir / n) for n in done.written) or "nothing"
    note = f"; {done.note}" if done.note else ""
    return _wrap(f"{done.format}: wrote {wrote}{note}", 2)


def _validate(args: argparse.Namespace) -> tuple[list[ScenarioSpec], Path]:
    """Every check that can be made before running; InputError on the first failure."""
    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed must be in [0, 2**63 - 1], got {args.seed}")
    if getattr(args, "jobs", None) is not None and args.jobs < 1:
        raise InputError(f"--jobs must be a positive number of processes, got {args.jobs}")
    if args.max_ticks < 1:
        raise InputError(f"--max-ticks must be a positive number of ticks, got {args.max_ticks}")
    specs = resolve(args.scenarios, args.all)
    if args.duration is not None:
        if not (math.isfinite(args.duration) and args.duration > 0.0):
            raise InputError(
                f"--duration must be a positive number of seconds, got {args.duration}"
            )
        specs = [dataclasses.replace(s, duration_s=min(args.duration, s.end_s)) for s in specs]
    check_lengths(specs, args.max_ticks)
    timeout_s = getattr(args, "estimator_timeout_s", None)
    if timeout_s is not None:
        if not (math.isfinite(timeout_s) and timeout_s > 0.0):
            raise InputError(
                f"--estimator-timeout-s must be a positive number of seconds, got {timeout_s}"
            )
        if not getattr(args, "estimator", None):
            raise InputError("--estimator-timeout-s limits an --estimator function: give one")
    args.user_methods = user_methods(getattr(args, "estimator", None) or [], timeout_s)
    args.exports = ()
    if getattr(args, "export", None) is not None:
        from scenarios import export

        try:
            args.exports = export.parse(args.export)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    out_dir = prepare_out_dir(args.out)
    check_outputs(specs, out_dir, args.exports)
    return specs, out_dir


def user_methods(specs: list[str], timeout_s: float | None = None) -> tuple[Method, ...]:
    """The methods of ``--estimator SPEC`` (``vnav.plugin``), each function imported now and
    held to ``timeout_s`` seconds a call (``--estimator-timeout-s``); InputError for a spec
    that does not import or names no callable, or two of one name."""
    from vnav.plugin import plugin_method

    found: dict[str, Method] = {}
    for spec in specs:
        try:
            m = plugin_method(spec, timeout_s)
        except ValueError as exc:
            raise InputError(f"--estimator: {exc}") from None
        if m.name in found:
            raise InputError(
                f"--estimator: {found[m.name].implementation} and {spec} are both {m.name}"
            )
        found[m.name] = m
    return tuple(found.values())


def command(args: argparse.Namespace) -> int:
    """Entry point of ``vnav-demo run``; returns the exit status."""
    return guarded(lambda: _validate(args), _body(args), kept="no partial file was kept")


def _body(args: argparse.Namespace):
    def run_all(specs: list[ScenarioSpec], out_dir: Path) -> int:
        wall_s, cpu_s = time.perf_counter(), pipeline.cpu_time_s()
        workers_cpu_s = 0.0
        jobs = min(args.jobs, len(specs)) if args.jobs is not None else default_jobs(len(specs))
        if jobs > 1:  # each worker process has its own OpenGL context and scenes
            statuses, workers_cpu_s = run_parallel(
                specs,
                args,
                out_dir,
                jobs,
                session=worker_session,
                emit=_print,
                progress_bar=lambda name: Progress(name, enabled=True),
            )
            results = [(spec, *outcome) for spec, outcome in zip(specs, statuses, strict=True)]
        else:
            # One OpenGL context for every run: a new one costs 0.2 s of set-up per scenario.
            with extended(getattr(args, "user_methods", ())), SceneCache(capacity=2) as scenes:
                results = [(spec, *run_one(spec, args, out_dir, scenes)) for spec in specs]
        cpu_s = pipeline.cpu_time_s() - cpu_s + workers_cpu_s
        duration = (time.perf_counter() - wall_s, cpu_s)
        if not args.quiet:
            say(final_summary(results, out_dir, duration))
        return max((status for _, status, _ in results), default=EXIT_PASSED)

    return run_all
