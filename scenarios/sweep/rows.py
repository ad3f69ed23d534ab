"""What an episode of a sweep gives: one row of numbers, and its estimates.

The columns are declared here, apart from running (``scenarios.sweep.episode``), so that the
tables, the summary and the plots are made without MuJoCo.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from vnav.methods import METHOD_NAMES

__all__ = ["ESTIMATE_COLUMNS", "STATS", "STATUSES", "Episode", "method_column", "row_columns"]

STATUSES = ("passed", "failed", "diverged")
"""An episode's ``status``: every check passed, one failed or had no data, the flight diverged."""

STATS = ("count", "mean", "median", "rmse", "max")
"""Per-method error statistics in each row (``scenarios.judge.report``'s, metres but ``count``)."""

ESTIMATE_COLUMNS = ("tick", "t_s", "cone", "method", "range_m", "error_m")
"""Columns of an episode's estimates: one row per matched detection and method."""


def method_column(method: str, stat: str) -> str:
    """A row's column for ``method``'s statistic: ``depth_image.median_m``, ``naive.count``."""
    return f"{method}.{stat}" if stat == "count" else f"{method}.{stat}_m"


def row_columns() -> list[str]:
    """An episode row's columns, in order (the sweep adds the point, the seed, the grid)."""
    head = ["status", "passed", "failed_checks", "message", "camera_ticks", "detections"]
    head += ["matched_detections", "cones_in_view", "cones_detected", "detection_rate"]
    per_method = [method_column(m, s) for m in METHOD_NAMES for s in STATS]
    return [*head, *per_method, "simulated_s", "wall_s"]


@dataclass
class Episode:
    """What one episode gives back.

    Attributes
    ----------
    point, seed : int
    row : dict
        One value per ``row_columns()``: ``status`` is ``passed``, ``failed`` (a check failed
        or had no data; ``failed_checks`` names them) or ``diverged`` (the flight diverged;
        ``message`` says when); errors are NaN where a method gave none.
    estimates : dict of str to list
        ``ESTIMATE_COLUMNS``, one entry per matched detection and method with an estimate.
    """

    point: int
    seed: int
    row: dict[str, Any]
    estimates: dict[str, list] = field(default_factory=dict)
