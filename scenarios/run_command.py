"""``vnav-demo run``: resolve, validate, run, judge, write, summarise.

Everything that can be checked before running is checked first (every name and file, the
duration, the output directory), so bad input exits with status 2 and writes nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
import tempfile
import time
from pathlib import Path

from scenarios import builtin, pipeline
from scenarios.spec import ScenarioError, ScenarioSpec, load_toml
from sim.world import SimulationError
from vnav.methods import METHOD_NAMES

logger = logging.getLogger(__name__)


class InputError(Exception):
    """Bad usage or bad input: one line for the user, exit status 2."""


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
        try:
            if item.endswith(".toml") or Path(item).is_file():
                specs.append(load_toml(item))
            else:
                specs.append(builtin.load(item))
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


def run_one(spec: ScenarioSpec, args: argparse.Namespace, out_dir: Path) -> bool:
    """Run one scenario, write its files, print its summary; return whether it passed."""
    start = time.perf_counter()
    try:
        outcome = pipeline.run(
            spec,
            seed=args.seed,
            out_dir=out_dir,
            progress=Progress(spec.name, enabled=not args.quiet),
        )
    except SimulationError as exc:
        print(f"{spec.name}: FAILED: the simulation diverged: {exc}", file=sys.stderr)
        return False
    if not args.quiet:
        wall_s = time.perf_counter() - start
        print(summary(outcome.report, wall_s, outcome.rrd_path, outcome.json_path), flush=True)
    return outcome.passed


def run(args: argparse.Namespace) -> int:
    """Entry point of ``vnav-demo run``; returns the exit status."""
    try:
        specs = resolve(args.scenarios, args.all)
        if args.duration is not None:
            if not (math.isfinite(args.duration) and args.duration > 0.0):
                raise InputError(
                    f"--duration must be a positive number of seconds, got {args.duration}"
                )
            specs = [dataclasses.replace(s, duration_s=min(args.duration, s.end_s)) for s in specs]
        out_dir = prepare_out_dir(args.out)
    except InputError as exc:
        print(f"vnav-demo: error: {exc}", file=sys.stderr)
        return 2
    try:
        results = [run_one(spec, args, out_dir) for spec in specs]
    except KeyboardInterrupt:
        print("vnav-demo: interrupted; no partial file was kept", file=sys.stderr)
        return 130
    return 0 if all(results) else 1
