"""Run a scenario, judge it and, if asked, write its recording and report: the one entry point.

The command line (``vnav-demo run``), the benchmarks and the tests all call ``run``, so a
scenario is run, judged and written the same way everywhere::

    run        scenarios.run.runner.run_scenario        (MuJoCo; the recording observes every tick)
    calibrate  scenarios.judge.calibration.calibrate_run  (only if a check asks for it; then
               the run's images estimated again with the recovered mount)
    judge      scenarios.judge.checks.judge             (the spec's checks, else the default ones;
               and each user function's, ``check_kinds.user_checks``)
    finish     scenarios.record.recording.Recording.finish  (with the verdicts and calibration)
               and each exporter's finish                (scenarios.export, if asked)
    report     scenarios.judge.report.build              (JSON; with ``exports``, if asked)
    commit     scenarios.record.outputs.OutputPair.commit  (every file in place, or none)

The recording is finished only after the run is judged: what the checks found (and the mount
calibration recovered) is in the recording as well as in the report. The report's
``timing_s`` gives the run's stages, ``calibrate``, ``judge`` and its ``total`` wall and CPU
seconds (what ``vnav-demo run`` prints).

Exports (``scenarios.export``) observe the run beside the recording
(``scenarios.run.runner.FanOut``), each writing into a staging directory of its own in the
output directory, and are committed with the recording and the report: the report's
``exports`` lists every file each wrote, with its size, and why a file was not written.
"""

from __future__ import annotations

import contextlib
import resource
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from scenarios import export
from scenarios.export.base import ExportResult, listed_files
from scenarios.judge import checks, report
from scenarios.record.outputs import OutputPair, staging_dir
from scenarios.record.recording import Recording
from scenarios.run.records import RunResult
from scenarios.run.runner import FanOut, run_scenario
from scenarios.scenario import check_kinds
from scenarios.scenario.spec import ScenarioSpec
from sim.scene_cache import SceneCache
from vnav.methods import active_methods

__all__ = ["Outcome", "cpu_time_s", "judge", "output_paths", "run"]


@dataclass(frozen=True)
class Outcome:
    """A judged run.

    Attributes
    ----------
    result : RunResult
        Every camera tick's record.
    judged : list of CheckResult
        Every check's outcome.
    report : dict
        The JSON report (``scenarios.judge.report.build``).
    rrd_path, json_path : Path or None
        The files written, or None when nothing was written.
    exports : tuple of ExportResult
        What each export format asked for wrote (final names in the output directory).
    """

    result: RunResult
    judged: list[checks.CheckResult]
    report: dict[str, Any]
    rrd_path: Path | None = None
    json_path: Path | None = None
    exports: tuple[ExportResult, ...] = ()

    @property
    def passed(self) -> bool:
        """Whether every check passed."""
        return bool(self.report["passed"])


def output_paths(spec: ScenarioSpec, out_dir: Path) -> tuple[Path, Path]:
    """Where ``run`` writes the recording and the report of ``spec``: ``<name>.rrd``, ``.json``."""
    return out_dir / f"{spec.name}.rrd", out_dir / f"{spec.name}.json"


def run(
    spec: ScenarioSpec,
    *,
    seed: int = 1,
    out_dir: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    scenes: SceneCache | None = None,
    exports: Sequence[str] = (),
    render_ahead: bool = True,
) -> Outcome:
    """Run ``spec``, judge it with its checks (or ``check_kinds.default_checks()``), report it.

    Parameters
    ----------
    spec : ScenarioSpec
    seed : int
        Seeds the run (see ``scenarios.run.runner.run_scenario``).
    out_dir : Path, optional
        If given, the recording and the report are written there (``output_paths``): both or
        neither, checked complete (``scenarios.record.outputs``). The report names the recording's
        id, unique to this run.
    progress : callable(done, total), optional
        Called after every camera tick.
    scenes : sim.scene_cache.SceneCache, optional
        Worlds and renderers to reuse across runs (``scenarios.run.runner.run_scenario``).
    exports : sequence of str
        Export formats (``scenarios.export.FORMATS``) written with the recording and the
        report, committed with them; only with ``out_dir``.
    render_ahead : bool
        See ``scenarios.run.runner.run_scenario`` (False for a process with one core of
        several; the results are the same).

    Raises
    ------
    sim.world.SimulationError
        If the flight diverges; nothing is written then.
    scenarios.record.outputs.OutputError
        If the files cannot be written whole (a full disk...); the previous files stay.
    ValueError
        If ``exports`` are asked for without ``out_dir``, or name an unknown format.
    """
    started = _Clock()
    for m in active_methods():
        if m.images == "user":  # a user's function: this run's failures only
            m.estimator.reset()
    if out_dir is None:
        if exports:
            raise ValueError("exports are written beside the recording: give out_dir")
        result = run_scenario(
            spec, seed=seed, progress=progress, scenes=scenes, render_ahead=render_ahead
        )
        judged = _calibrate_and_judge(spec, result)
        started.stop(result)
        return Outcome(result, judged, report.build(result, judged))
    run_args = {"seed": seed, "progress": progress, "scenes": scenes, "render_ahead": render_ahead}
    return _run_and_write(spec, Path(out_dir), exports, run_args, started)


def _run_and_write(
    spec: ScenarioSpec,
    out_dir: Path,
    exports: Sequence[str],
    run_args: dict[str, Any],
    started: _Clock,
) -> Outcome:
    """``run`` with ``out_dir``: the recording, the exports and the report staged, then
    committed together (``OutputPair``), or none of them; an unknown format refused first."""
    unknown = [name for name in exports if name not in export.FORMATS]
    if unknown:
        raise ValueError(
            f"unknown export format {unknown[0]!r}; the formats are {', '.join(export.FORMATS)}"
        )
    recording_id = f"{spec.name}-seed{run_args['seed']}-{uuid.uuid4().hex[:12]}"
    rrd_path, json_path = output_paths(spec, out_dir)
    pair = OutputPair(rrd_path, json_path)
    try:
        with contextlib.ExitStack() as staged:
            stagings = [
                staged.enter_context(staging_dir(out_dir / f"{spec.name}.export-{name}"))
                for name in exports
            ]
            recording = Recording(pair.rrd_tmp, recording_id)
            exporters = export.ExportSet(exports, stagings) if exports else None
            result, judged, exported = _observed_run(spec, recording, exporters, run_args)
            started.stop(result)
            rep = report.build(
                result, judged, recording={"file": rrd_path.name, "id": recording_id}
            )
            if exporters:
                rep["exports"] = {
                    done.format: _export_entry(done, where)
                    for done, where in zip(exported, stagings, strict=True)
                }
            for done, where in zip(exported, stagings, strict=True):
                for name in done.written:
                    # An exporter flushes every file it writes (scenarios.export.base).
                    pair.add(out_dir / name, where / name, flushed=True)
                for name in done.not_written:
                    pair.add(out_dir / name, None)
        pair.write_json(report.dumps(rep))
        pair.commit()
    except BaseException:
        pair.discard()
        raise
    return Outcome(result, judged, rep, rrd_path, json_path, exported)


def _observed_run(
    spec: ScenarioSpec,
    recording: Recording,
    exporters: export.ExportSet | None,
    run_args: dict[str, Any],
) -> tuple[RunResult, list[checks.CheckResult], tuple[ExportResult, ...]]:
    """The run with the recording and the exporters observing it, judged, the recording and
    the exports finished (their time counted: the recording's end as set-up, the exports'
    as ``export``); every observer aborted if any of it fails."""
    observer = FanOut(recording, exporters) if exporters else recording
    try:
        result = run_scenario(spec, observer=observer, **run_args)
        judged = _calibrate_and_judge(spec, result)
        finish_start = time.perf_counter()
        recording.finish(result, judged)
        export_start = time.perf_counter()
        exported = exporters.finish(result) if exporters else ()
    except BaseException:
        # A failed run has aborted its observers already (a second abort does nothing); a
        # failure while judging or finishing must not leave a file open.
        observer.abort()
        raise
    # The recording's end (plots, layout, footer) is set-up work, as its start is.
    result.timing_s["setup"] += export_start - finish_start
    if exporters:
        result.timing_s["export"] = time.perf_counter() - export_start
    return result, judged, exported


def _export_entry(done: ExportResult, staging: Path) -> dict[str, Any]:
    """The report's entry for one format: every file written with its size, the note, the
    format's figures."""
    return {
        "files": listed_files(staging, done.written),
        "note": done.note,
        **done.figures,
    }


def _calibrate_and_judge(spec: ScenarioSpec, result: RunResult) -> list[checks.CheckResult]:
    """Recover the camera mount and clock offset from the run if a check judges them (into
    ``result.calibration``), and the camera-IMU calibration likewise (into
    ``result.imu_calibration``), then judge every check of ``spec`` (or the default ones)."""
    start = time.perf_counter()
    if spec.checks_calibration:
        from scenarios.judge.calibration import calibrate_run

        result.calibration = calibrate_run(result)
    if spec.checks_imu_calibration:
        from scenarios.judge.imu_calibration import calibrate_imu_run

        result.imu_calibration = calibrate_imu_run(result)
    judge_start = time.perf_counter()
    judged = judge(spec, result)
    result.timing_s["calibrate"] = judge_start - start
    result.timing_s["judge"] = time.perf_counter() - judge_start
    return judged


def judge(spec: ScenarioSpec, result: RunResult) -> list[checks.CheckResult]:
    """Every check of ``spec`` (or ``check_kinds.default_checks()``) on ``result``, then each
    active user function's (``check_kinds.user_checks``: its agreement with the correct chain,
    and the truth's bound where the scenario holds ``depth_image`` to it): what ``run``
    judges, for a run already calibrated if its checks ask for it."""
    own = spec.checks or check_kinds.default_checks()
    return [checks.judge(c, result) for c in (*own, *check_kinds.user_checks(spec.checks))]


def cpu_time_s() -> float:
    """CPU seconds, user and system, of this process (every thread's) and of its children
    that have ended and been waited for (the export process, ``scenarios.export.process``,
    which ``run`` waits for)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


class _Clock:
    """The wall and CPU time of a whole run, from ``run``'s start to its report."""

    def __init__(self) -> None:
        self.wall_s, self.cpu_s = time.perf_counter(), cpu_time_s()

    def stop(self, result: RunResult) -> None:
        """Put the run's ``total`` (wall) and ``total_cpu`` (``cpu_time_s``: this process's
        and its export process's) seconds in ``result.timing_s``."""
        result.timing_s["total"] = time.perf_counter() - self.wall_s
        result.timing_s["total_cpu"] = cpu_time_s() - self.cpu_s
