"""``summary.json``: a sweep's statistics per grid point, and its worst episodes to replay.

Per grid point, across its seeds: the pass rate, the detection rate, and per method the
median, 90th percentile and maximum of the episodes' own median and RMS errors, plus the
statistics of every estimate pooled (``vnav.metrics.error_stats``); a user's function
(``estimator`` in the sweep file) is a method like the others, with its ``failures``: the
detections it failed on, summed over the episodes. A sweep of a navigating flight has, per
grid point, ``goal_rate`` and ``collision_rate``: the fractions of its flown episodes (those
whose flight did not diverge) that reached the goal and that touched a cone, and
``navigation``: those counts, and the spread across seeds of the smallest true clearance, of
the time to the goal and of the path flown (``navigation_entry``). Episodes are ranked worst
first: a diverged flight, then a failed check, then a pass; within each, the largest median
error of ``rank_by`` (an episode where it gave no estimate counts as worst); then the seed.
Every number here is computed from the rows of ``results.parquet`` and ``estimates.parquet``
beside it (the tests recompute them from the files).
"""

from __future__ import annotations

import math
import shlex
from typing import Any

import numpy as np

from scenarios.sweep.plan import SweepPlan, estimator_identity, navigates
from scenarios.sweep.rows import Episode, method_column
from vnav import metrics
from vnav.methods import Method

__all__ = [
    "SUMMARY_VERSION",
    "build",
    "navigation_entry",
    "rank_key",
    "replay_command",
    "replay_specs",
    "worst",
]

SUMMARY_VERSION = 2
"""2: ``failed_checks`` a list, the rank figure named as its column (``depth_image__median_m``)."""
_STATUS_ORDER = {"diverged": 0, "failed": 1, "passed": 2}


def _num(x: float | None) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    return None if x is None or not math.isfinite(x) else float(x)


def rank_key(episode: Episode, rank_by: str) -> tuple[int, float, int]:
    """Sort key putting the worst episode first (see the module doc)."""
    median = episode.row[method_column(rank_by, "median")]
    return (
        _STATUS_ORDER[episode.row["status"]],
        -math.inf if math.isnan(median) else -median,
        episode.seed,
    )


def worst(episodes: list[Episode], rank_by: str, k: int) -> list[Episode]:
    """The ``k`` worst ``episodes``, worst first."""
    return sorted(episodes, key=lambda e: rank_key(e, rank_by))[:k]


def replay_command(
    out_dir: str, point_file: str, seed: int, estimators: tuple[str, ...] = ()
) -> str:
    """The command that runs an episode again, with its recording: shell words, each quoted
    where it needs to be (a space in the directory's name), with ``--estimator SPEC`` for each
    of the sweep's user estimators (``EstimatorSource.shown``)."""
    path = f"{out_dir.rstrip('/')}/{point_file}"
    words = ["vnav-demo", "run", path, "--seed", str(seed)]
    for spec in estimators:
        words += ["--estimator", spec]
    return shlex.join(words)


def replay_specs(plan: SweepPlan) -> tuple[str, ...]:
    """The ``--estimator`` specs that replay an episode of ``plan`` from the command's
    directory."""
    return tuple(e.shown for e in plan.estimators)


def _spread(values: list[float]) -> dict[str, float | None]:
    """Median, 90th percentile and maximum of the finite ``values`` (None if there are none)."""
    a = np.array([v for v in values if math.isfinite(v)], dtype=np.float64)
    if not a.size:
        return {"median": None, "p90": None, "max": None}
    return {
        "median": float(np.median(a)),
        "p90": float(np.percentile(a, 90.0)),
        "max": float(a.max()),
    }


def _finite(values: list[float]) -> np.ndarray:
    return np.array([v for v in values if math.isfinite(v)], dtype=np.float64)


def navigation_entry(episodes: list[Episode]) -> dict[str, Any]:
    """A navigating grid point's outcome across ``episodes`` (its seeds).

    ``flown``: the episodes whose flight has an outcome (not diverged); ``reached_goal`` and
    ``collided``: how many of them reached the goal and touched a cone, and ``goal_rate`` and
    ``collision_rate`` those counts over ``flown`` (None if none flew); ``min_clearance_m``:
    the minimum, 10th percentile and median across the flown episodes of each one's smallest
    true clearance (metres; negative in contact); ``time_to_goal_s`` (of those that reached
    it) and ``path_length_m``: median and maximum. A statistic with no episode is None.
    """
    flown = [e for e in episodes if e.row["nav__collided"] is not None]
    reached = sum(bool(e.row["nav__reached_goal"]) for e in flown)
    collided = sum(bool(e.row["nav__collided"]) for e in flown)
    clearance = _finite([e.row["nav__min_clearance_m"] for e in flown])
    times = _finite([e.row["nav__time_to_goal_s"] for e in flown])
    paths = _finite([e.row["nav__path_length_m"] for e in flown])
    return {
        "flown": len(flown),
        "reached_goal": reached,
        "collided": collided,
        "goal_rate": reached / len(flown) if flown else None,
        "collision_rate": collided / len(flown) if flown else None,
        "min_clearance_m": {
            "min": float(clearance.min()) if clearance.size else None,
            "p10": float(np.percentile(clearance, 10.0)) if clearance.size else None,
            "median": float(np.median(clearance)) if clearance.size else None,
        },
        "time_to_goal_s": {
            "median": float(np.median(times)) if times.size else None,
            "max": float(times.max()) if times.size else None,
        },
        "path_length_m": {
            "median": float(np.median(paths)) if paths.size else None,
            "max": float(paths.max()) if paths.size else None,
        },
    }


def _method(episodes: list[Episode], m: Method) -> dict[str, Any]:
    method = m.name
    errors = np.array(
        [
            err
            for e in episodes
            for m, err in zip(e.estimates["method"], e.estimates["error_m"], strict=True)
            if m == method
        ],
        dtype=np.float64,
    )
    out = {
        "episodes_with_estimates": sum(e.row[method_column(method, "count")] > 0 for e in episodes),
        "median_m": _spread([e.row[method_column(method, "median")] for e in episodes]),
        "rmse_m": _spread([e.row[method_column(method, "rmse")] for e in episodes]),
        "pooled": {
            k: int(v) if k == "count" else _num(v) for k, v in metrics.error_stats(errors).items()
        },
    }
    if m.images == "user":
        out["failures"] = sum(e.row[method_column(method, "failures")] for e in episodes)
    return out


def _point(
    plan: SweepPlan, index: int, episodes: list[Episode], out_dir: str, point_file: str
) -> dict[str, Any]:
    rates = [e.row["detection_rate"] for e in episodes]
    finite_rates = [r for r in rates if math.isfinite(r)]
    flight: dict[str, Any] = {}  # a sweep of other flights: the entries it always had
    if plan.navigates:
        nav = navigation_entry(episodes) if navigates(plan.points[index].spec) else None
        flight = {
            "goal_rate": nav["goal_rate"] if nav else None,
            "collision_rate": nav["collision_rate"] if nav else None,
            "navigation": nav,
        }
    entry: dict[str, Any] = {
        "index": index,
        "values": plan.points[index].values,
        "scenario_file": point_file,
        "episodes": len(episodes),
        "passed": sum(e.row["passed"] for e in episodes),
        "diverged": sum(e.row["status"] == "diverged" for e in episodes),
        "pass_rate": (sum(e.row["passed"] for e in episodes) / len(episodes)) if episodes else None,
        **flight,
        "detection_rate": {
            "mean": float(np.mean(finite_rates)) if finite_rates else None,
            "min": float(np.min(finite_rates)) if finite_rates else None,
        },
        "methods": {m.name: _method(episodes, m) for m in plan.methods},
        "worst": None,
    }
    if episodes:
        (w,) = worst(episodes, plan.rank_by, 1)
        entry["worst"] = _worst_entry(plan, w, out_dir, point_file)
    return entry


def _worst_entry(plan: SweepPlan, e: Episode, out_dir: str, point_file: str) -> dict[str, Any]:
    return {
        "point": e.point,
        "seed": e.seed,
        "status": e.row["status"],
        "failed_checks": e.row["failed_checks"],
        method_column(plan.rank_by, "median"): _num(e.row[method_column(plan.rank_by, "median")]),
        "replay": replay_command(out_dir, point_file, e.seed, replay_specs(plan)),
    }


def build(
    plan: SweepPlan,
    episodes: list[Episode],
    *,
    out_dir: str,
    point_files: list[str],
    complete: bool,
    recordings: dict[tuple[int, int], str] | None = None,
    n_worst: int = 10,
) -> dict[str, Any]:
    """The summary as a JSON-ready dict.

    ``episodes`` are the finished ones; ``complete`` says whether that is every planned one.
    ``recordings`` maps ``(point, seed)`` to a recording written for it (``--record-worst``).
    """
    by_point: dict[int, list[Episode]] = {p.index: [] for p in plan.points}
    for e in episodes:
        by_point[e.point].append(e)
    statuses = [e.row["status"] for e in episodes]
    ranked = worst(episodes, plan.rank_by, n_worst)
    recordings = recordings or {}
    return {
        "summary_version": SUMMARY_VERSION,
        "sweep_file": plan.path,
        "scenario": plan.scenario,
        "fingerprint": plan.fingerprint,
        "complete": complete,
        "episodes": {
            "planned": len(plan.episodes),
            "done": len(episodes),
            **{s: statuses.count(s) for s in _STATUS_ORDER},
        },
        "keys": list(plan.keys),
        "seeds": list(plan.seeds),
        "rank_by": plan.rank_by,
        **({"estimators": estimator_identity(plan.estimators)} if plan.estimators else {}),
        "points": [_point(plan, i, eps, out_dir, point_files[i]) for i, eps in by_point.items()],
        "worst": [
            {
                **_worst_entry(plan, e, out_dir, point_files[e.point]),
                "recording": recordings.get((e.point, e.seed)),
            }
            for e in ranked
        ],
    }
