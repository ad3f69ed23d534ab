"""The ``vnav-demo`` command line.

- ``vnav-demo list``: the built-in scenarios, one line each.
- ``vnav-demo show NAME``: a built-in scenario as a TOML file named ``my-NAME``, to start your
  own from.
- ``vnav-demo run NAME|FILE.toml [...] [--all] [--out DIR] [--seed N] [--duration S] [--quiet]
  [--jobs N] [--estimator SPEC] [--estimator-timeout-s S]``:
  runs scenarios headless (two at a time where there are two cores), writes
  ``DIR/<name>.rrd`` and ``DIR/<name>.json``, prints a summary.
- ``vnav-demo lecture``: the lecture's worked examples next to vnav's results.
- ``vnav-demo sweep FILE.toml [--out DIR] [--workers N] [--address ADDR] [--resume]``: a
  scenario over a grid of values and many seeds, on Ray (``scenarios.sweep``).
- ``vnav-demo calibrate FILE.rrd [--out FILE.yaml] [--imu]``: the camera mount and clock
  offset recovered from a recording (``scenarios.commands.calibrate``), written as Kalibr's
  camchain; with ``--imu``, the camera against the IMU (``T_i_c``, ``timeshift_cam_imu``).

Output fits 80 columns (``scenarios.commands.console.WIDTH``). Exit status: 0 when every check
passed (or was skipped), 1 when a check failed or had no data, 2 for bad usage or bad input
(one line on stderr, no traceback; nothing is written), 3 when a run could not complete (I/O
error, diverging simulation, out of memory, internal error), 128 + N on signal N.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence

__all__ = ["main"]

PROG = "vnav-demo"
MAX_TICKS_DEFAULT = 20_000
"""Longest run ``vnav-demo run`` accepts without ``--max-ticks`` (about 0.7 GB of recording)."""


class _UsageError(Exception):
    """Raised instead of argparse's print-usage-and-exit, so ``main`` can say it in one line."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{self.prog}: error: {message} (see {PROG} --help)")


def _verb(name: str) -> Callable[[argparse.Namespace], int]:
    """The ``command(args)`` of ``scenarios.commands.<name>``, imported when it runs (so that
    ``vnav-demo list`` does not load MuJoCo, nor ``vnav-demo run`` Ray)."""

    def command(args: argparse.Namespace) -> int:
        return importlib.import_module(f"scenarios.commands.{name}").command(args)

    return command


def build_parser() -> argparse.ArgumentParser:
    """The argument parser, one sub-parser per command."""
    parser = _Parser(prog=PROG, description="vnav-sim demonstrations.")
    sub = parser.add_subparsers(
        dest="command", metavar="COMMAND", required=True, parser_class=_Parser
    )
    p = sub.add_parser(
        "lecture",
        help="print every worked example of VNAV lecture 1 next to vnav's result",
        description="Print every worked example and quiz answer of MIT 16.485 VNAV lecture 1, "
        "the lecture's answer next to vnav's. Exit status 1 if any disagrees.",
    )
    p.set_defaults(func=_verb("lecture"))

    p = sub.add_parser(
        "list",
        help="list the built-in scenarios",
        description="List the built-in scenarios with a one-line description.",
    )
    p.set_defaults(func=_verb("list"))

    p = sub.add_parser(
        "show",
        help="print a built-in scenario as a TOML file to start your own from",
        description="Print the built-in scenario NAME in the scenario-file format (TOML), every "
        "key commented, named my-NAME so that running it leaves the built-in's files alone.",
    )
    p.add_argument("name", metavar="NAME", help="a built-in scenario (see `vnav-demo list`)")
    p.set_defaults(func=_verb("show"))

    _add_run_parser(sub)
    _add_sweep_parser(sub)

    p = sub.add_parser(
        "calibrate",
        help="recover the camera mount and clock offset from a recording",
        description="Recover the camera mount T_b_c and the camera clock's offset "
        "(t_pose = t_cam + offset) from a recording written by `vnav-demo run`: least squares "
        "on the cone apexes' reprojection error over the whole flight. Prints the answer, its "
        "standard errors and, as the recording holds the truth, its errors. Exit status 2 if "
        "the file is not such a recording or the flight does not determine the answer (too "
        "few cones seen, no rotation to reveal the offset): the message says which. With "
        "--imu, the camera-IMU calibration (T_i_c and Kalibr's timeshift_cam_imu) instead.",
    )
    p.add_argument("recording", metavar="FILE.rrd", help="a recording from vnav-demo run")
    p.add_argument(
        "--out",
        default=None,
        metavar="FILE.yaml",
        help="also write the answer as Kalibr camchain YAML",
    )
    p.add_argument(
        "--imu",
        action="store_true",
        help="calibrate the camera against the IMU instead (a run with an [imu]): T_i_c and "
        "Kalibr's timeshift_cam_imu (t_imu = t_cam + offset), from the images and the IMU's "
        "readings alone",
    )
    p.set_defaults(func=_verb("calibrate"))
    return parser


def _add_run_parser(sub) -> None:
    """``vnav-demo run`` and its options."""
    p = sub.add_parser(
        "run",
        help="run scenarios headless; write DIR/<name>.rrd and DIR/<name>.json",
        description="Run built-in scenarios (by name) or scenario files (a path: FILE.toml or "
        "DIR/FILE) headless. Each writes DIR/<name>.rrd (open it with `rerun`) and "
        "DIR/<name>.json (error statistics and checks), both or neither. Exit status 0 if every "
        "check passed, 1 if one failed or had no data, 2 for bad input, 3 if a run could not "
        "complete (I/O error, diverging simulation, out of memory, internal error), 128+N on "
        "signal N.",
    )
    p.add_argument(
        "scenarios",
        nargs="*",
        metavar="NAME|FILE.toml",
        help="built-in scenario names (see `vnav-demo list`) or TOML files",
    )
    p.add_argument("--all", action="store_true", help="run every built-in scenario")
    p.add_argument(
        "--out", default="recordings", metavar="DIR", help="output directory (default: recordings/)"
    )
    p.add_argument("--seed", type=int, default=1, metavar="N", help="random seed (default: 1)")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop each scenario after S simulated seconds",
    )
    p.add_argument(
        "--max-ticks",
        type=int,
        default=MAX_TICKS_DEFAULT,
        metavar="N",
        help=f"refuse runs of more than N camera ticks (default: {MAX_TICKS_DEFAULT})",
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="run N scenarios at a time, each in a process of its own (default: 2 where "
        "there are two cores and two scenarios, else 1; 1 runs them one after the other in "
        "this process)",
    )
    _add_estimator_and_export_options(p)
    p.set_defaults(func=_verb("run"))


def _add_estimator_and_export_options(p) -> None:
    """``run``'s options for the user's own code and for other tools: ``--estimator``,
    ``--estimator-timeout-s`` and ``--export``."""
    p.add_argument(
        "--estimator",
        action="append",
        default=None,
        metavar="SPEC",
        help="also run your function fn(obs) -> p_w at every detection, as method "
        "user:<function>, judged within depth_image's bound of the correct chain (and of the "
        "truth where depth_image is held to it); SPEC is package.module:function or "
        "path/to/file.py:function (repeatable; docs/CONVENTIONS.md, 'Your own estimator')",
    )
    p.add_argument(
        "--estimator-timeout-s",
        type=float,
        default=None,
        metavar="S",
        help="stop a call of an --estimator function that takes longer than S seconds: a "
        "failure of that function, which is then not called again that run (default: no limit)",
    )
    from scenarios import export

    p.add_argument(
        "--export",
        default=None,
        metavar="FORMAT[,FORMAT]",
        help="also write the run's data for other tools into DIR, committed with the "
        "recording and the report: "
        + "; ".join(f"{n}: {export.FORMATS[n].help}" for n in export.available())
        + " (README: Use the data elsewhere)",
    )


def _add_sweep_parser(sub) -> None:
    """``vnav-demo sweep`` and its options."""
    p = sub.add_parser(
        "sweep",
        help="run a scenario over a grid of values and many seeds (Ray); tables and plots",
        description="Run a scenario over every combination of the sweep file's grid values, "
        "each with every seed, on Ray workers (or in this process with --workers 0). Writes "
        "DIR/results.parquet (one row per episode), DIR/estimates.parquet (one row per "
        "estimate), DIR/summary.json (per grid point: statistics across seeds, pass rate, a "
        "navigating flight's collision and goal rates, the worst seed and the command that "
        "replays it) and DIR/plots/*.png. An interrupted sweep "
        "keeps its finished episodes; --resume runs the rest. Needs the sweep extra: "
        "pip install 'vnav-sim[sweep]'. Exit status 0 if every episode passed, 1 if one "
        "failed or diverged, 2 for bad input, 3 if one could not run, 128+N on signal N.",
    )
    p.add_argument("file", metavar="FILE.toml", help="the sweep file (see README: Sweeps)")
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="output directory (default: sweeps/<FILE's name>)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="Ray workers, one CPU each (default: one per CPU this process may use, or per "
        "CPU of the cluster; more are refused); 0 runs every episode in this process, one "
        "after another",
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="join an existing Ray cluster (auto, host:port or ray://host:port) instead of "
        "starting a local one; its nodes need vnav-sim installed",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="finish the sweep already in DIR: run only its missing episodes",
    )
    p.add_argument(
        "--record-worst",
        type=int,
        default=0,
        metavar="K",
        help="write the K worst episodes' recordings and reports into DIR/worst/",
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_verb("sweep"))


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``vnav-demo`` with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    # Rerun's writer logs its own errors (a full disk) in several lines; the command reports
    # every failure itself, in one line.
    os.environ.setdefault("RUST_LOG", "off")
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
