"""A sweep file, read and expanded into grid points, each a checked scenario.

A sweep file (TOML)::

    scenario = "approach"              # a built-in name, or a scenario file (path relative
                                       # to the sweep file's directory, or absolute)
    seeds = 50                         # episodes per grid point: seeds 1..50 (or a list)
    rank_by = "depth_image"            # optional: whose median error ranks the worst seeds
    estimator = "mine.py:my_estimate"  # optional: your function beside the built-ins (a spec,
                                       # or a list of specs; a path relative to the sweep file)
    [grid]                             # dotted keys into the scenario; full product
    "camera.pitch_down_deg" = [10.0, 30.0, 50.0]
    "noise.attitude_std_deg" = [0.0, 0.5, 1.0]

A grid key is a path into the scenario's tables (``camera.pitch_down_deg``); a number
indexes a list (``flight.waypoints.2.position_w``); a table the scenario leaves out is made
(``noise.attitude_std_deg`` on a scenario without ``[noise]``). A key with one value fixes it
for the whole sweep. Grid points are numbered in row-major order of the keys as written.

Every grid point is written out as a scenario file (``toml_out.dumps(exact=True)``) and parsed
back by the scenario parser before anything runs: a bad value stops the sweep with a message
naming the grid point and the key, and each point's file is what ``vnav-demo run FILE --seed S``
replays, number for number. That takes a few milliseconds a point, so a sweep holds at most
``MAX_POINTS`` grid points (planned in seconds); statistics come from seeds, which cost nothing
to plan (``MAX_EPISODES`` episodes in all).

``estimator`` runs a user's function in every episode as ``vnav-demo run --estimator`` does
(``vnav.plugin``): each spec is imported once here, so that one that does not import stops the
sweep before anything is written, and its file's SHA-256 is part of the sweep's identity
(``SweepPlan.fingerprint``): ``--resume`` after the function changed refuses to mix its rows
with the old function's. Each worker imports the function again itself (``EstimatorSource``:
plain strings, an absolute path, whatever the worker's directory) and checks the file's hash.
"""

from __future__ import annotations

import copy
import functools
import hashlib
import itertools
import json
import math
import os
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenarios.scenario import builtin, schema, toml_out
from scenarios.scenario.spec import (
    MAX_NESTING,
    MAX_SEED,
    ScenarioError,
    ScenarioSpec,
    from_dict,
    read_toml,
)
from scenarios.sweep.rows import method_column
from vnav.methods import METHODS, PREFERENCE, Method
from vnav.noise_model import SENSORS

__all__ = [
    "MAX_EPISODES",
    "MAX_POINTS",
    "EstimatorSource",
    "GridPoint",
    "SweepError",
    "SweepPlan",
    "draws_from_seed",
    "label",
    "load",
    "navigates",
    "plan",
]

MAX_EPISODES = 1_000_000
"""Most episodes one sweep may hold (grid points x seeds)."""
MAX_POINTS = 1_000
"""Most grid points one sweep may hold. Each is written out, parsed back and checked before
anything runs, 2-5 ms a point: a thousand take seconds, a million would take an hour (and
write a million scenario files) before the first episode."""
_TOP_KEYS = ("scenario", "seeds", "grid", "rank_by", "estimator")
_INDEX = re.compile(r"[0-9]+")
"""A part of a grid key that indexes a list."""


class SweepError(ValueError):
    """A sweep file that cannot be run: the message names the file, and the key or grid point."""


@dataclass(frozen=True)
class GridPoint:
    """One combination of the grid's values, and the scenario it makes.

    Attributes
    ----------
    index : int
        Position in the grid (row-major in the keys' order), from 0.
    values : dict
        Each grid key (dotted) to its value here.
    scenario_toml : str
        The scenario as a file, floats in full: parsed, it gives ``spec`` exactly.
    spec : ScenarioSpec
    scenario_sha256 : str
        The SHA-256 of ``scenario_toml`` (hex): what the journal holds to tell this point's
        episodes from another sweep's.
    """

    index: int
    values: dict[str, Any]
    scenario_toml: str
    spec: ScenarioSpec
    scenario_sha256: str = field(init=False)

    def __post_init__(self) -> None:
        digest = hashlib.sha256(self.scenario_toml.encode()).hexdigest()
        object.__setattr__(self, "scenario_sha256", digest)

    @property
    def label(self) -> str:
        """``key = value, ...`` in the grid's order (``-`` for a grid with no keys)."""
        return label(self.values)


@dataclass(frozen=True)
class EstimatorSource:
    """A user's estimator of the sweep (``estimator = "SPEC"``), as plain strings: what a
    worker needs to import it itself (``load``), sent to Ray workers as it is.

    Attributes
    ----------
    spec : str
        As the sweep file writes it (``mine.py:my_estimate``, ``package.module:function``).
    shown : str
        As the command's directory reaches it: a relative file path joined to the sweep file's
        directory (what ``vnav-demo run --estimator`` is given to replay an episode).
    absolute : str
        The spec with its file's absolute path (a module spec as written): what workers
        import, whatever their current directory.
    sha256 : str or None
        The SHA-256 (hex) of the file the function was imported from (the ``.py`` file, or the
        module's file); None for a module without one.
    search_dir : str
        The command's directory, absolute: where a module spec is looked up as well as on
        ``sys.path`` (as ``vnav-demo run`` does in its own directory).
    """

    spec: str
    shown: str
    absolute: str
    sha256: str | None
    search_dir: str

    def load(self) -> Method:
        """Import the function and make it a method (``vnav.plugin.plugin_method``), checking
        that its file is still the one the sweep hashed.

        Raises
        ------
        ValueError
            The spec does not import (``plugin_method``'s message), or the file changed.
        """
        m = _import_method(self.absolute, self.search_dir)
        digest = _source_sha256(self.absolute)
        if digest != self.sha256:
            raise ValueError(
                f"estimator {self.spec}: its file changed since the sweep started (SHA-256 "
                f"{_short(self.sha256)} then, {_short(digest)} now)"
            )
        return m


@dataclass(frozen=True)
class SweepPlan:
    """A sweep: a scenario, the grid points made from it, the seeds run at each.

    Attributes
    ----------
    path : str
        The sweep file, as given.
    scenario : str
        The scenario as the file names it (a built-in name or a path).
    keys : tuple of str
        The grid's dotted keys, in the file's order.
    seeds : tuple of int
    points : tuple of GridPoint
    rank_by : str
        The method whose median error ranks episodes (``worst`` first).
    estimators : tuple of EstimatorSource
        The user's functions every episode runs beside the built-ins (none by default).
    user_methods : tuple of vnav.methods.Method
        Those functions as methods, imported by ``plan`` (in this process, for the tables and
        the recordings of the worst episodes; workers import their own).
    """

    path: str
    scenario: str
    keys: tuple[str, ...]
    seeds: tuple[int, ...]
    points: tuple[GridPoint, ...]
    rank_by: str
    estimators: tuple[EstimatorSource, ...] = ()
    user_methods: tuple[Method, ...] = field(default=(), compare=False, repr=False)

    @property
    def methods(self) -> tuple[Method, ...]:
        """Every method an episode runs: the built-ins, then the user's functions (what
        ``vnav.methods.active_methods()`` is within an episode)."""
        return (*METHODS, *self.user_methods)

    @property
    def episodes(self) -> list[tuple[int, int]]:
        """Every ``(point index, seed)``, point by point (a worker then mostly keeps its scene)."""
        return [(p.index, s) for p in self.points for s in self.seeds]

    @property
    def navigates(self) -> bool:
        """Whether a grid point's flight navigates (``navigates``): the tables then have the
        flight's outcome (``scenarios.sweep.rows.NAV_COLUMNS``), summary.json its rates."""
        return any(navigates(p.spec) for p in self.points)

    @functools.cached_property
    def fingerprint(self) -> str:
        """A hash of what the sweep runs (every point's scenario, the seeds, and each user
        estimator's spec and file hash): ``--resume`` refuses a directory, or a journal entry,
        whose sweep has another."""
        parts: list[Any] = [[p.scenario_toml for p in self.points], list(self.seeds)]
        if self.estimators:  # a sweep of built-ins only keeps the fingerprint it always had
            parts.append(estimator_identity(self.estimators))
        text = json.dumps(parts)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def estimator_identity(estimators: tuple[EstimatorSource, ...]) -> list[dict[str, Any]]:
    """Each estimator's ``spec`` (as written) and ``sha256``: what the fingerprint, the
    manifest and the journal hold of them."""
    return [{"spec": e.spec, "sha256": e.sha256} for e in estimators]


def draws_from_seed(spec: ScenarioSpec) -> bool:
    """Whether a run of ``spec`` draws anything from its seed.

    The seed feeds every random draw of a run (``scenarios.run.runner``): the pose, image,
    depth and mount noise (``sim.noise``: each drawn only where a figure of that sensor is
    above zero), the arrival jitter (``scenarios.run.streams``: only where ``jitter_s`` is
    above zero) and an ``[imu]``'s noise (``vnav.imu.ImuNoiseProcess``: only where one of its
    four figures is above zero). Where none is, every seed gives the same run, number for
    number.
    """
    imu = spec.scene.imu
    imu_noisy = imu is not None and not imu.noise.is_zero
    return any(spec.noise.noisy(s) for s in SENSORS) or spec.timing.jitter_s > 0.0 or imu_noisy


def navigates(spec: ScenarioSpec) -> bool:
    """Whether ``spec``'s flight is closed loop (``flight.mode = "navigate"``): its run has a
    navigation outcome (``scenarios.run.records.NavigationRecord``)."""
    return spec.flight.mode == "navigate"


def label(values: dict[str, Any]) -> str:
    """Grid values as ``key = value, ...`` (``-`` for none): how messages and tables name a
    grid point."""
    return ", ".join(f"{k} = {_show(v)}" for k, v in values.items()) or "-"


def _show(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, float) else repr(v)


def load(path: str | Path) -> SweepPlan:
    """Read and expand a sweep file; ``SweepError`` names what is wrong."""
    try:
        data = read_toml(path, what="sweep file")
    except ScenarioError as exc:
        raise SweepError(str(exc)) from None
    return plan(data, str(path), base_dir=Path(path).parent)


def plan(data: dict[str, Any], where: str, base_dir: Path = Path()) -> SweepPlan:
    """Expand parsed sweep-file ``data`` into checked grid points.

    Raises
    ------
    SweepError
        An unknown or missing key, bad seeds, an empty grid list, a grid key that is not a
        path into the scenario, or a grid point the scenario parser refuses.
    """
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise SweepError(f"{where}: {unknown[0]}: unknown key; expected one of {list(_TOP_KEYS)}")
    if "scenario" not in data or not isinstance(data["scenario"], str):
        raise SweepError(f"{where}: scenario: required: a built-in name or a scenario file path")
    base = _base_scenario(data["scenario"], where, base_dir)
    seeds = _seeds(data.get("seeds", 1), where)
    estimators, user_methods = _estimators(data.get("estimator", []), where, base_dir)
    names = [m.name for m in (*METHODS, *user_methods)]
    rank_by = data.get("rank_by", PREFERENCE[0])
    if rank_by not in names:
        raise SweepError(f"{where}: rank_by: must be one of {names}, got {rank_by!r}")
    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise SweepError(f"{where}: grid: must be a table of key = [values]")
    _check_grid(grid, where)
    n_points = math.prod(len(v) for v in grid.values())
    if n_points > MAX_POINTS:
        raise SweepError(
            f"{where}: grid: {n_points} grid points is more than {MAX_POINTS} (each is checked "
            "and written as a scenario file before anything runs); sweep fewer values, in "
            "several sweeps, and raise seeds for statistics"
        )
    if n_points * len(seeds) > MAX_EPISODES:
        raise SweepError(
            f"{where}: {n_points} grid points x {len(seeds)} seeds is more than "
            f"{MAX_EPISODES} episodes"
        )
    name = _point_name(base["name"], n_points)
    points = tuple(
        _point(base, dict(zip(grid, combo, strict=True)), i, name(i), where)
        for i, combo in enumerate(itertools.product(*grid.values()))
    )
    return SweepPlan(
        where, data["scenario"], tuple(grid), seeds, points, rank_by, estimators, user_methods
    )


def _estimators(
    raw: Any, where: str, base_dir: Path
) -> tuple[tuple[EstimatorSource, ...], tuple[Method, ...]]:
    """The ``estimator`` key (a spec or a list of them), each imported now; ``SweepError``
    naming the key for one that does not import, names no callable, shares another's name,
    or whose name makes no plain column (``scenarios.sweep.rows.method_column``)."""
    specs = [raw] if isinstance(raw, str) else raw
    if not isinstance(specs, list) or not all(isinstance(s, str) for s in specs):
        raise SweepError(
            f"{where}: estimator: must be a spec (package.module:function or "
            f"path/to/file.py:function) or a list of them, got {raw!r}"
        )
    sources, methods = [], []
    for spec in specs:
        module, sep, function = spec.rpartition(":")
        shown = spec
        if sep and module.endswith(".py") and not Path(module).is_absolute():
            shown = f"{base_dir / module}:{function}"  # relative to the sweep file
        absolute = shown
        if sep and module.endswith(".py"):
            absolute = f"{Path(shown.rpartition(':')[0]).resolve()}:{function}"
        try:
            m = _import_method(absolute, os.getcwd())
            method_column(m.name, "count")
        except ValueError as exc:
            raise SweepError(f"{where}: estimator: {exc}") from None
        if m.name in [n.name for n in methods]:
            raise SweepError(f"{where}: estimator: {spec} is {m.name}, as another one is")
        sha256 = _source_sha256(absolute)
        sources.append(EstimatorSource(spec, shown, absolute, sha256, os.getcwd()))
        methods.append(m)
    return tuple(sources), tuple(methods)


def _import_method(spec: str, search_dir: str) -> Method:
    """``vnav.plugin.plugin_method(spec)``, a module spec looked up in ``search_dir`` as
    well as on ``sys.path``."""
    from vnav.plugin import plugin_method

    if not spec.rpartition(":")[0].endswith(".py") and search_dir not in sys.path:
        sys.path.insert(0, search_dir)
    return plugin_method(spec)


def _source_sha256(spec: str) -> str | None:
    """The SHA-256 (hex) of the file a spec's function comes from (its ``.py`` file, or its
    module's file once imported); None where there is none."""
    module = spec.rpartition(":")[0]
    if module.endswith(".py"):
        path: str | None = module
    else:
        path = getattr(sys.modules.get(module), "__file__", None)
    if path is None:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _short(sha256: str | None) -> str:
    """A file hash in a message: its first 12 digits, or ``none``."""
    return sha256[:12] if sha256 else "none"


def _check_grid(grid: dict[str, Any], where: str) -> None:
    """Each grid key a dotted path (at most ``MAX_NESTING`` parts, none empty, list indices in
    ASCII digits), each value list non-empty and of values a scenario file can hold (no TOML
    date or time: no scenario key takes one, and the tables could not write it)."""
    for key, values in grid.items():
        parts = key.split(".")
        if len(parts) > MAX_NESTING:
            raise SweepError(
                f"{where}: grid.{key[:60]}...: a path of {len(parts)} parts; a scenario nests "
                f"at most {MAX_NESTING} deep"
            )
        if not all(parts):
            raise SweepError(
                f"{where}: grid.{key}: an empty part; write a dotted path such as "
                f'"camera.pitch_down_deg"'
            )
        if not isinstance(values, list) or not values:
            raise SweepError(f"{where}: grid.{key}: must be a non-empty list of values")
        stack = [(v, f"grid.{key}[{i}]") for i, v in enumerate(values)]
        while stack:  # the values nest at most MAX_NESTING deep (read_toml)
            value, path = stack.pop()
            if isinstance(value, dict):
                stack.extend((v, f"{path}.{k}") for k, v in value.items())
            elif isinstance(value, list):
                stack.extend((v, f"{path}[{i}]") for i, v in enumerate(value))
            elif not isinstance(value, str | int | float):  # a date, time or date-time
                raise SweepError(
                    f"{where}: {path}: a TOML {type(value).__name__} is not a scenario value, "
                    f"got {value}"
                )


def _base_scenario(source: str, where: str, base_dir: Path) -> dict[str, Any]:
    """The scenario's tables: a built-in's, or a file's (relative to the sweep file)."""
    is_file = source.endswith(".toml") or "/" in source
    try:
        if not is_file:
            if source not in builtin.REGISTRY:
                raise ScenarioError(
                    f"unknown built-in {source!r}; valid names: {', '.join(builtin.names())}"
                )
            return builtin.REGISTRY[source]()
        path = Path(source)
        data = read_toml(path if path.is_absolute() else base_dir / path)
        from_dict(copy.deepcopy(data), where=str(path))  # its own errors, named as its own
        return data
    except ScenarioError as exc:
        raise SweepError(f"{where}: scenario: {exc}") from None


def _seeds(raw: Any, where: str) -> tuple[int, ...]:
    """``n`` means seeds 1..n; a list is taken as written (distinct, in [0, 2**63 - 1])."""
    if isinstance(raw, int) and not isinstance(raw, bool):
        if not 1 <= raw <= MAX_EPISODES:
            raise SweepError(f"{where}: seeds: must be in [1, {MAX_EPISODES}], got {raw}")
        return tuple(range(1, raw + 1))
    ok = isinstance(raw, list) and raw and all(type(s) is int and 0 <= s <= MAX_SEED for s in raw)
    if not ok or len(set(raw)) != len(raw):
        raise SweepError(
            f"{where}: seeds: must be a count (seeds 1..n) or a list of distinct seeds in "
            f"[0, 2**63 - 1], got {raw!r}"
        )
    return tuple(raw)


def _point_name(base_name: str, n_points: int):
    """Grid point ``i``'s scenario name, ``<base>-p<i>`` (zero-padded), within the name limit."""
    digits = len(str(max(n_points - 1, 0)))
    stem = base_name[: schema.MAX_NAME_CHARS - digits - 2]
    return lambda i: f"{stem}-p{i:0{digits}d}"


def _point(
    base: dict[str, Any], values: dict[str, Any], index: int, name: str, where: str
) -> GridPoint:
    """Grid point ``index``: the base scenario with ``values`` set, written out and parsed."""
    here = f"{where}: grid point {index} ({label(values)})"
    scenario = copy.deepcopy(base)
    for key, value in values.items():
        _set(scenario, key, value, here)
    scenario["name"] = name
    try:
        text = toml_out.dumps(scenario, exact=True)
        spec = from_dict(tomllib.loads(text), where=here)
    except ScenarioError as exc:
        raise SweepError(str(exc)) from None
    except (ValueError, TypeError) as exc:  # a value TOML cannot hold where it was put
        raise SweepError(f"{here}: {exc}") from None
    return GridPoint(index, values, text, spec)


def _set(scenario: dict[str, Any], key: str, value: Any, here: str) -> None:
    """Set the dotted ``key`` in ``scenario`` to ``value``, making missing tables."""
    parts = key.split(".")
    if parts[0] == "name":
        raise SweepError(f"{here}: {key}: the sweep names each grid point; sweep another key")
    node: Any = scenario
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            # ASCII digits only: str.isdigit also takes "²", which int() refuses.
            if not _INDEX.fullmatch(part) or int(part) >= len(node):
                raise SweepError(
                    f"{here}: {key}: {'.'.join(parts[:depth])} is a list of {len(node)}; "
                    f"index it with a number below {len(node)}"
                )
            part = int(part)  # type: ignore[assignment]
        elif not isinstance(node, dict):
            raise SweepError(f"{here}: {key}: {'.'.join(parts[:depth])} is not a table")
        if last:
            node[part] = value
        else:
            if isinstance(node, dict) and node.get(part) is None:
                node[part] = {}
            node = node[part]
            if not isinstance(node, dict | list):
                raise SweepError(f"{here}: {key}: {where} is a value, not a table")
