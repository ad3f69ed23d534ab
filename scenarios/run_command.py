"""``vnav-demo run``: resolve, validate, run, judge, write, summarise.

Everything that can be checked before running is checked first (every name and file, the
seed, the duration, the run's length, the output directory and paths), so bad input exits
with status 2 and writes nothing. Exit statuses (``EXIT_*``): 0 every check passed, 1 a check
failed, 2 bad input, 3 a run could not complete (I/O error such as a full disk, a diverging
simulation, out of memory, an internal error), 128 + N on signal N (SIGINT, SIGTERM, SIGHUP).
Each scenario's ``.rrd`` and ``.json`` are written together or not at all
(``scenarios.outputs``); whatever ends a run, the previous pair stays as it was.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

from scenarios import builtin, outputs, pipeline
from scenarios.console import error as _error
from scenarios.console import say
from scenarios.spec import ScenarioError, ScenarioSpec, load_toml
from sim.world import SimulationError
from vnav.methods import METHOD_NAMES

logger = logging.getLogger(__name__)

EXIT_PASSED, EXIT_CHECK_FAILED, EXIT_BAD_INPUT, EXIT_INCOMPLETE = 0, 1, 2, 3
MAX_SEED = 2**63 - 1


class InputError(Exception):
    """Bad usage or bad input: one line for the user, exit status 2."""


class Signalled(BaseException):
    """SIGTERM or SIGHUP, raised in the main thread so that a run ends as on Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_signalled(signum: int, frame: object) -> None:
    raise Signalled(signum)


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


def check_outputs(specs: list[ScenarioSpec], out_dir: Path) -> None:
    """Refuse outputs that could not be written: an existing directory under a file's name."""
    for spec in specs:
        for path in pipeline.output_paths(spec, out_dir):
            if path.is_dir():
                raise InputError(f"{path} is a directory; the run would write a file there")


def check_lengths(specs: list[ScenarioSpec], max_ticks: int) -> None:
    """Refuse runs longer than ``max_ticks`` camera ticks (``--max-ticks``)."""
    for spec in specs:
        if spec.n_ticks > max_ticks:
            raise InputError(
                f"{spec.name}: {spec.n_ticks} camera ticks ({spec.end_s:g} s at "
                f"{spec.camera_rate_hz:g} Hz) is more than --max-ticks {max_ticks}; raise it to "
                f"run this long (about 35 KB of recording per tick)"
            )


def prepare_out_dir(out: str) -> Path:
    """Create ``out`` if needed and prove it can be written."""
    path = Path(out)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".vnav-write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise InputError(f"output directory {out!r} cannot be written: {reason}") from None
    return path


class Progress:
    """A one-line progress bar on stderr, only when stderr is a terminal."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled = label, enabled and sys.stderr.isatty()

    def __call__(self, done: int, total: int) -> None:
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


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def summary(rep: dict, wall_s: float, rrd: Path, json_path: Path) -> str:
    """The table printed after each scenario."""
    status = "PASSED" if rep["passed"] else "FAILED"
    lines = [
        f"{rep['scenario']}: {status}  ({rep['camera_ticks']} camera ticks, "
        f"{rep['detections']} detections, "
        f"{rep['matched_detections']} matched, {wall_s:.1f} s)",
        f"  {'method':<13} {'count':>5} {'mean':>8} {'median':>8} {'rmse':>8} {'max':>8}  "
        "position error (m)",
    ]
    for method in METHOD_NAMES:
        s = rep["methods"][method]["position_error_m"]
        lines.append(
            f"  {method:<13} {s['count']:>5} {_fmt(s['mean']):>8} "
            f"{_fmt(s['median']):>8} {_fmt(s['rmse']):>8} {_fmt(s['max']):>8}"
        )
    for c in rep["checks"]:
        mark = "ok  " if c["passed"] else "FAIL"
        lines.append(f"  [{mark}] {c['name']}: {_fmt(c['value'])} (limit {c['limit']:g})")
    lines.append(f"  wrote {rrd} and {json_path}")
    return "\n".join(lines)


def run_one(spec: ScenarioSpec, args: argparse.Namespace, out_dir: Path) -> int:
    """Run one scenario, write its files, print its summary; return its exit status."""
    start = time.perf_counter()
    try:
        outcome = pipeline.run(
            spec,
            seed=args.seed,
            out_dir=out_dir,
            progress=Progress(spec.name, enabled=not args.quiet),
        )
    except SimulationError as exc:
        _error(f"{spec.name}: could not complete: the simulation diverged: {exc}")
        return EXIT_INCOMPLETE
    except OSError as exc:
        _error(
            f"{spec.name}: could not complete: cannot write its files: {exc}; "
            "the previous files were kept"
        )
        return EXIT_INCOMPLETE
    except MemoryError:
        _error(f"{spec.name}: could not complete: out of memory")
        return EXIT_INCOMPLETE
    except Exception as exc:  # an internal error: say it in one line, keep the others going
        logger.debug("internal error", exc_info=True)
        _error(f"{spec.name}: could not complete: internal error: {type(exc).__name__}: {exc}")
        return EXIT_INCOMPLETE
    if not args.quiet:
        wall_s = time.perf_counter() - start
        say(summary(outcome.report, wall_s, outcome.rrd_path, outcome.json_path))
    return EXIT_PASSED if outcome.passed else EXIT_CHECK_FAILED


def _validate(args: argparse.Namespace) -> tuple[list[ScenarioSpec], Path]:
    """Every check that can be made before running; InputError on the first failure."""
    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed must be in [0, 2**63 - 1], got {args.seed}")
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
    out_dir = prepare_out_dir(args.out)
    check_outputs(specs, out_dir)
    return specs, out_dir


def run(args: argparse.Namespace) -> int:
    """Entry point of ``vnav-demo run``; returns the exit status."""
    try:
        specs, out_dir = _validate(args)
    except InputError as exc:
        _error(str(exc))
        return EXIT_BAD_INPUT
    previous = {s: signal.signal(s, _raise_signalled) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        with outputs.directory_lock(out_dir):
            statuses = [run_one(spec, args, out_dir) for spec in specs]
    except BlockingIOError:
        _error(f"another vnav-demo run is writing into {out_dir}; wait for it to finish")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        _error("interrupted; no partial file was kept")
        return 128 + signal.SIGINT
    except Signalled as exc:
        _error(f"stopped by {signal.Signals(exc.signum).name}; no partial file was kept")
        return 128 + exc.signum
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return max(statuses, default=EXIT_PASSED)
