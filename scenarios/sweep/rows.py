"""What an episode of a sweep gives: one row of numbers, and its estimates.

The columns are declared here, apart from running (``scenarios.sweep.episode``), so that the
tables, the summary and the plots are made without MuJoCo.

Every column name is a plain identifier (letters, digits, ``_``), so that SQL (DuckDB),
Polars and pandas (``df.camera__pitch_down_deg``) read it without quoting. A name made of
parts joins them with ``__``, as dlt and Django do for nested names: a grid key's dots become
``__`` (``camera.pitch_down_deg`` -> ``camera__pitch_down_deg``, ``grid_column``), and a
method's statistic is ``<method>__<stat>`` (``depth_image__median_m``, ``method_column``); a
user's function ``user:my_estimate`` (``vnav.plugin``) is the part ``user_my_estimate``
(``user_my_estimate__median_m``), with one more column, ``user_my_estimate__failures``, the
detections it failed on. A sweep of a navigating flight (``flight.mode = "navigate"``) has
the flight's outcome too, under the part ``nav`` (``NAV_COLUMNS``: ``nav__reached_goal``,
``nav__collided``, ``nav__min_clearance_m``, ...); a sweep of other flights has no such column.
The parts themselves contain single ``_`` only, so the name reads back into its parts. The
columns are flat scalars rather than struct columns: a struct reaches pandas as one dict per
cell and needs unnesting in Polars, while scalar columns group, filter and plot the same in
every tool.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from vnav.methods import Method, active_methods

__all__ = [
    "ESTIMATE_COLUMNS",
    "NAV_COLUMNS",
    "NAV_FLAGS",
    "STATS",
    "STATUSES",
    "TABLES_VERSION",
    "Episode",
    "grid_column",
    "method_column",
    "method_part",
    "row_columns",
]

TABLES_VERSION = 2
"""Version of the tables' columns (2: names with ``__``, ``failed_checks`` a list; 1 had dots
and one joined string)."""

STATUSES = ("passed", "failed", "diverged")
"""An episode's ``status``: every check passed, one failed or had no data, the flight diverged."""

STATS = ("count", "mean", "median", "rmse", "max")
"""Per-method error statistics in each row (``scenarios.judge.report``'s, metres but ``count``)."""

ESTIMATE_COLUMNS = ("tick", "t_s", "cone", "method", "range_m", "error_m")
"""Columns of an episode's estimates: one row per matched detection and method."""


NAV_FLAGS = ("nav__reached_goal", "nav__collided")
"""A navigating episode's yes-or-no outcome (``scenarios.run.records.NavigationRecord``): a
boolean, or None where the flight diverged (what it would have done is unknown)."""

NAV_COLUMNS = (*NAV_FLAGS, "nav__min_clearance_m", "nav__time_to_goal_s", "nav__path_length_m")
"""A navigating episode's outcome: whether it reached the goal, whether it touched a cone, the
smallest true clearance to a cone (m, negative in contact), when it reached the goal (s; NaN:
never) and the length it flew (m); NaN figures where the flight diverged."""

_KEY_PART = re.compile(r"[A-Za-z0-9]+(?:_[A-Za-z0-9]+)*")
"""A grid key's part that joins with ``__`` into an identifier and splits back."""


_USER_PREFIX = "user:"
"""A user's function's method name starts so (``vnav.plugin``)."""

_UNITLESS = ("count", "failures")
"""Per-method columns that are counts, not metres."""


def method_part(method: str) -> str:
    """A method's part of its columns' names: its name, ``user_<function>`` for a user's
    function ``user:<function>``.

    Raises
    ------
    ValueError
        A user's function whose name would not read back from the column (a name with
        characters other than ASCII letters, digits and single inner ``_``).
    """
    if not method.startswith(_USER_PREFIX):
        return method
    function = method.removeprefix(_USER_PREFIX)
    if not _KEY_PART.fullmatch(function):
        raise ValueError(
            f"{method}: no plain column name for it; name the function with ASCII letters, "
            "digits and single inner _"
        )
    return f"user_{function}"


def method_column(method: str, stat: str) -> str:
    """A row's column for ``method``'s statistic: ``depth_image__median_m``, ``naive__count``,
    ``user_my_estimate__failures`` (``method_part``).

    Raises
    ------
    ValueError
        As ``method_part``.
    """
    part = method_part(method)
    return f"{part}__{stat}" if stat in _UNITLESS else f"{part}__{stat}_m"


def grid_column(key: str) -> str:
    """The tables' column for the grid key ``key``: its dots become ``__``.

    ``camera.pitch_down_deg`` -> ``camera__pitch_down_deg``, ``flight.waypoints.2.position_w``
    -> ``flight__waypoints__2__position_w``, ``duration_s`` -> ``duration_s``.

    Raises
    ------
    ValueError
        The column would not be a plain identifier, or would not read back into ``key`` (a
        part with characters other than ASCII letters, digits and single inner ``_``, or a
        key not starting with a letter): the scenario parser accepts no such key.
    """
    parts = key.split(".")
    if not (key[:1].isalpha() and all(_KEY_PART.fullmatch(p) for p in parts)):
        raise ValueError(f"grid key {key!r}: no plain column name for it")
    column = "__".join(parts)
    return column


def row_columns(methods: Sequence[Method] | None = None, navigates: bool = False) -> list[str]:
    """An episode row's columns, in order (the sweep adds the point, the seed, the grid): the
    statistics of each of ``methods`` (default: ``vnav.methods.active_methods()``, the run's),
    the failures of each user's function among them, and ``NAV_COLUMNS`` if the flight
    ``navigates``."""
    methods = active_methods() if methods is None else methods
    head = ["status", "passed", "failed_checks", "message", "camera_ticks", "detections"]
    head += ["matched_detections", "cones_in_view", "cones_detected", "detection_rate"]
    per_method = [method_column(m.name, s) for m in methods for s in STATS]
    failures = [method_column(m.name, "failures") for m in methods if m.images == "user"]
    nav = list(NAV_COLUMNS) if navigates else []
    return [*head, *per_method, *failures, *nav, "simulated_s", "wall_s"]


@dataclass
class Episode:
    """What one episode gives back.

    Attributes
    ----------
    point, seed : int
    row : dict
        One value per ``row_columns()``: ``status`` is ``passed``, ``failed`` (a check failed
        or had no data; ``failed_checks``, a list, names them) or ``diverged`` (the flight diverged;
        ``message`` says when); errors are NaN where a method gave none. A navigating flight's
        row has ``NAV_COLUMNS`` too.
    estimates : dict of str to list
        ``ESTIMATE_COLUMNS``, one entry per matched detection and method with an estimate.
    timing_s : dict of str to float
        The run's seconds per stage (``RunResult.timing_s``; empty for a diverged flight or
        an episode read back from a journal): not a column, a figure for the benchmarks.
    """

    point: int
    seed: int
    row: dict[str, Any]
    estimates: dict[str, list] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
