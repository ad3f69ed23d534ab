"""One episode of a sweep: a grid point's scenario run with one seed, judged, in numbers.

An episode is a pure function of the point's scenario and the seed: every column of its row
but ``wall_s`` is the same wherever and however it runs (in the command's process, on a Ray
worker, replayed by ``vnav-demo run``); the tests compare them. The statistics are the JSON
report's (``scenarios.judge.report``), so a row and ``vnav-demo run``'s report agree to the digit.

``EpisodeRunner`` is what a worker holds: the scenes it has built (``sim.scene_cache``), so
that the next episode of the same grid point reuses the world and its OpenGL context, and the
sweep's user estimators (``vnav.plugin``), which it imports itself and runs beside the built-ins
(``vnav.methods.extended``): a row has the columns of ``active_methods()`` within it.
"""

from __future__ import annotations

import math
import time
import tomllib
from collections.abc import Sequence
from typing import Any

from scenarios import pipeline
from scenarios.judge import checks
from scenarios.run.records import RunResult
from scenarios.scenario.spec import ScenarioSpec, from_dict
from scenarios.sweep.plan import EstimatorSource, navigates
from scenarios.sweep.rows import (
    ESTIMATE_COLUMNS,
    NAV_FLAGS,
    STATS,
    Episode,
    method_column,
    row_columns,
)
from sim.scene_cache import SceneCache
from sim.world import SimulationError
from vnav.methods import Method, active_methods, extended

__all__ = ["EpisodeRunner", "run_episode"]


def _nan_if_none(value: float | int | None) -> float:
    return math.nan if value is None else float(value)


def _row(run: RunResult, report: dict[str, Any], judged: list[checks.CheckResult]) -> dict:
    detected, seen = checks.detection_counts(run)
    failed = [c.name for c in judged if c.outcome.fails_run]
    row: dict[str, Any] = {
        "status": "passed" if report["passed"] else "failed",
        "passed": bool(report["passed"]),
        "failed_checks": failed,
        "message": "",
        "camera_ticks": int(report["camera_ticks"]),
        "detections": int(report["detections"]),
        "matched_detections": int(report["matched_detections"]),
        "cones_in_view": seen,
        "cones_detected": detected,
        "detection_rate": detected / seen if seen else math.nan,
    }
    methods = active_methods()
    for m in methods:
        stats = report["methods"][m.name]["position_error_m"]
        for s in STATS:
            value = stats[s]
            row[method_column(m.name, s)] = int(value) if s == "count" else _nan_if_none(value)
    for m in methods:
        if m.images == "user":  # the detections it failed on, every kind (the report's)
            failures = report["estimators"][m.name]["failures"].values()
            row[method_column(m.name, "failures")] = sum(f["count"] for f in failures)
    if run.navigation is not None:
        nav = report["navigation"]  # the report's figures: a row agrees with `vnav-demo run`'s
        row["nav__reached_goal"] = bool(nav["reached_goal"])
        row["nav__collided"] = bool(nav["collided"])
        row["nav__min_clearance_m"] = _nan_if_none(nav["min_clearance_m"])
        row["nav__time_to_goal_s"] = _nan_if_none(nav["time_to_goal_s"])
        row["nav__path_length_m"] = _nan_if_none(nav["path_length_m"])
    row["simulated_s"] = float(report["simulated_s"])
    return row


def _estimates(run: RunResult) -> dict[str, list]:
    out: dict[str, list] = {c: [] for c in ESTIMATE_COLUMNS}
    names = [m.name for m in active_methods()]
    for t in run.ticks:
        for d in t.detections:
            if d.cone_index is None:
                continue
            for m in names:
                if m in d.errors_m:
                    for c, v in zip(
                        ESTIMATE_COLUMNS,
                        (t.tick, t.t_s, d.cone_index, m, d.range_m, d.errors_m[m]),
                        strict=True,
                    ):
                        out[c].append(v)
    return out


def _diverged(spec: ScenarioSpec, exc: SimulationError) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(row_columns(navigates=navigates(spec)), math.nan)
    row.update(
        status="diverged",
        passed=False,
        failed_checks=[],
        message=f"the simulation diverged: {exc}",
        camera_ticks=0,
        detections=0,
        matched_detections=0,
        cones_in_view=0,
        cones_detected=0,
    )
    methods = active_methods()
    row.update({method_column(m.name, "count"): 0 for m in methods})
    row.update({method_column(m.name, "failures"): 0 for m in methods if m.images == "user"})
    if navigates(spec):  # whether it would have reached the goal or touched a cone is unknown
        row.update(dict.fromkeys(NAV_FLAGS))
    return row


def run_episode(
    spec: ScenarioSpec,
    point: int,
    seed: int,
    scenes: SceneCache | None = None,
    render_ahead: bool = True,
) -> Episode:
    """Run, judge and measure ``spec`` with ``seed`` (no files written; ``render_ahead`` as
    ``scenarios.pipeline.run``'s).

    A diverging flight is a result (status ``diverged``), not an error: it is as much a
    property of the grid point and seed as an error figure.
    """
    start = time.perf_counter()
    timing_s: dict[str, float] = {}
    try:
        outcome = pipeline.run(spec, seed=seed, scenes=scenes, render_ahead=render_ahead)
    except SimulationError as exc:
        row, estimates = _diverged(spec, exc), {c: [] for c in ESTIMATE_COLUMNS}
    else:
        row = _row(outcome.result, outcome.report, outcome.judged)
        estimates = _estimates(outcome.result)
        timing_s = dict(outcome.result.timing_s)
    row["wall_s"] = time.perf_counter() - start
    return Episode(point, seed, row, estimates, timing_s)


class EpisodeRunner:
    """Runs episodes in one process, keeping the scenes it builds (``SceneCache``).

    This is the class a Ray worker holds (``scenarios.sweep.engine``): created inside the
    worker, its OpenGL contexts are made there too, and it imports the user's estimators
    itself, on its first episode.

    Parameters
    ----------
    estimators : sequence of EstimatorSource, optional
        The sweep's user estimators, run in every episode beside the built-ins.
    render_ahead : bool
        As ``scenarios.pipeline.run``'s: False in a worker given one core of several.

    Raises
    ------
    ValueError
        From ``run``, where an estimator no longer imports or its file changed
        (``EstimatorSource.load``): that episode's error; the next one tries again.
    """

    def __init__(
        self, estimators: Sequence[EstimatorSource] = (), render_ahead: bool = True
    ) -> None:
        self._scenes = SceneCache(capacity=2)
        self._render_ahead = render_ahead
        self._specs: dict[str, ScenarioSpec] = {}
        self._sources = tuple(estimators)
        self._methods: tuple[Method, ...] | None = None

    def run(self, scenario_toml: str, point: int, seed: int) -> Episode:
        """The episode of the grid point whose scenario file is ``scenario_toml``."""
        spec = self._specs.get(scenario_toml)
        if spec is None:
            spec = from_dict(tomllib.loads(scenario_toml), where=f"grid point {point}")
            self._specs = {scenario_toml: spec}  # one point at a time, mostly
        if self._methods is None:
            self._methods = tuple(source.load() for source in self._sources)
        with extended(self._methods):
            return run_episode(spec, point, seed, self._scenes, self._render_ahead)

    def scenes_built(self) -> int:
        """Scenes this runner has built (fewer than the episodes when they are reused)."""
        return self._scenes.builds

    def close(self) -> None:
        """Free the scenes' rendering contexts."""
        self._scenes.close()
