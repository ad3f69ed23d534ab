"""A sweep's directory: what is planned, what is done, and the tables of results.

::

    DIR/sweep.json           the sweep: its file, fingerprint, keys, seeds, grid points
    DIR/points/<name>.toml   each grid point as a scenario file (replay: vnav-demo run)
    DIR/episodes/p<i>-s<seed>.json   the journal: one file per finished episode, written whole
    DIR/results.parquet      one row per finished episode (point, seed, grid values, numbers)
    DIR/estimates.parquet    one row per estimate (episode, tick, cone, method, range, error)

The tables' column names are plain identifiers (``scenarios.sweep.rows``: a grid key's dots
become ``__``); each table's schema metadata ``vnav.sweep`` holds the sweep's fingerprint, the
tables' version, the grid key of each grid column and each method's part of its columns' names
(a user's function ``user:f`` is ``user_f``). A sweep with user estimators has their columns
too (the methods of ``SweepPlan.methods``), and a sweep of a navigating flight the flight's
outcome (``NAV_COLUMNS``: ``nav__reached_goal`` and ``nav__collided`` booleans, null where the
flight diverged; the figures NaN there); a sweep of other flights has none of them.

Every file is written whole or not at all (``scenarios.record.outputs.write_atomic``). The journal
is the record: an episode is finished once its file is there, so an interrupted sweep loses
at most the episodes that were running, and ``--resume`` runs only the missing ones. The two
tables are rebuilt from the journal as the sweep goes (every few seconds) and at its end; rows
are sorted by point and seed, so a table does not depend on which worker finished first.
Journal floats are written by ``json`` in shortest round-trip form: read back, they are the
same doubles.

Each journal entry carries the identity of its episode: the sweep's fingerprint, its grid
point's index, values and the SHA-256 of its scenario file, its seed, and (in a sweep with user
estimators) each estimator's spec and file hash. Reading the journal
back, an entry of another sweep is refused (``SweepError`` saying what differs: nothing of
another sweep is mixed into this one's tables), and an entry that does not read as an episode
(not a regular file, not JSON, a missing key, a value of the wrong type) is set aside in
``SweepStore.bad_entries`` with the reason, and its episode runs again. A file is opened
without blocking and read only if it is a regular file: a FIFO would wait for ever.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import time
from pathlib import Path
from typing import Any

from scenarios.record import outputs
from scenarios.record.outputs import OutputError, write_atomic
from scenarios.sweep.plan import SweepError, SweepPlan, estimator_identity, label, navigates
from scenarios.sweep.plots import plot_names
from scenarios.sweep.rows import (
    ESTIMATE_COLUMNS,
    NAV_COLUMNS,
    NAV_FLAGS,
    STATUSES,
    TABLES_VERSION,
    Episode,
    grid_column,
    method_part,
    row_columns,
)

__all__ = ["DERIVED", "MANIFEST", "SweepStore", "pyarrow_missing", "table_metadata"]

MANIFEST = "sweep.json"
RESULTS, ESTIMATES = "results.parquet", "estimates.parquet"
DERIVED = ("summary.json", "plots")
"""Files made from the whole journal at the end; removed when a sweep (re)starts, so that
what is there always describes the tables beside it."""
WORK_DIRS = ("points", "episodes", "worst")
"""Sub-directories a sweep writes files into one by one (``worst``: ``--record-worst``): a run
killed there leaves its temporary files, which the next run into the sweep removes."""
MANIFEST_VERSION = 2
JOURNAL_VERSION = 2
"""Version 1 entries (point, seed, row, estimates) carried no identity, and their rows the
tables' old column names: they run again."""
FLUSH_EVERY_S = 5.0
_ENTRY_NAME = re.compile(r"^p(\d+)-s(\d+)\.json$")
_IDENTITY = ("journal_version", "sweep", "point", "values", "scenario_sha256", "seed")
_ENTRY_KEYS = (*_IDENTITY, "row", "estimates")
_OPTIONAL_KEYS = ("estimators",)
"""Entry keys only a sweep with user estimators writes (a built-in sweep's entries are as
they were)."""


class _BadEntryError(ValueError):
    """A journal entry that does not read as an episode: the message says why."""


class _ForeignEntry(Exception):  # noqa: N818 (not an error: an entry of another sweep)
    """A journal entry of another sweep: what differs, and whether its point or seed does."""


def pyarrow_missing() -> str | None:
    """Why the tables cannot be written (pyarrow not installed), or None."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return "pyarrow is not installed: pip install 'vnav-sim[sweep]'"
    return None


def _episode_file(point: int, seed: int) -> str:
    return f"p{point}-s{seed}.json"


class SweepStore:
    """The directory ``out_dir`` of the sweep ``plan``.

    Use ``open``: it checks that the directory holds no other sweep (and, unless ``resume``,
    no sweep at all), writes the plan, and reads back the journal.

    Attributes
    ----------
    episodes : dict
        ``(point, seed)`` to ``Episode``: every finished episode, journal and new.
    bad_entries : list of str
        The journal entries that did not read as episodes, each ``episodes/NAME: why``; their
        episodes are pending again.
    """

    def __init__(self, out_dir: Path, plan: SweepPlan) -> None:
        self.dir = Path(out_dir)
        self.plan = plan
        self.episodes: dict[tuple[int, int], Episode] = {}
        self.bad_entries: list[str] = []
        self._seeds = frozenset(plan.seeds)
        self._flushed_at = 0.0
        self._flush_cost_s = 0.0
        self._new = True

    @classmethod
    def open(cls, out_dir: Path, plan: SweepPlan, resume: bool) -> SweepStore:
        """The store of ``plan`` in ``out_dir``, with its journal read back; nothing is
        written until ``begin``.

        Raises
        ------
        SweepError
            ``out_dir`` holds a sweep (or the journal of one) and ``resume`` is off, or holds
            a different sweep, or a journal entry of one.
        """
        store = cls(out_dir, plan)
        manifest = store.dir / MANIFEST
        store._new = not (manifest.exists() or manifest.is_symlink())
        for name in WORK_DIRS:
            if (store.dir / name).exists() and not (store.dir / name).is_dir():
                raise SweepError(f"{store.dir / name}: not a directory; choose another --out")
        if not store._new:
            store._check_manifest(manifest, resume)
        store._read_journal()
        if store._new and store.episodes and not resume:
            raise SweepError(
                f"{store.dir} holds the journal of this sweep ({len(store.episodes)} of "
                f"{len(plan.episodes)} episodes done; its {MANIFEST} is gone): add --resume to "
                "finish it, or choose another --out"
            )
        return store

    def begin(self) -> None:
        """Make the sweep's directories and the grid points' files (whatever of them is
        missing), remove the temporary files of dead runs there, write the plan (a new
        sweep), and remove the files made from a previous journal.

        Raises
        ------
        OutputError
            A file cannot be written or removed.
        """
        try:
            for name in ("points", "episodes"):
                (self.dir / name).mkdir(exist_ok=True)
        except OSError as exc:
            raise OutputError(exc.errno, f"cannot make {exc.filename}: {exc.strerror}") from None
        for name in WORK_DIRS:
            if (self.dir / name).is_dir():
                outputs.remove_stale_partials(self.dir / name)
        self._write_points()
        if self._new:
            self._write_manifest()
            self._new = False
        for name in DERIVED:
            self._remove(self.dir / name)

    # ------------------------------------------------------------------ plan and journal
    def _check_manifest(self, manifest: Path, resume: bool) -> None:
        try:
            held = json.loads(_read_regular(manifest))
            fingerprint, held_file = held["fingerprint"], held["sweep_file"]
        except (OSError, ValueError, KeyError, TypeError, RecursionError) as exc:
            raise SweepError(
                f"{manifest}: not a sweep manifest ({exc}); choose another --out"
            ) from None
        if fingerprint != self.plan.fingerprint:
            raise SweepError(
                f"{self.dir} holds another sweep (from {held_file}): "
                f"{self._manifest_difference(held)}; choose another --out"
            )
        if not resume:
            done = len(_entry_names(self.dir / "episodes"))
            raise SweepError(
                f"{self.dir} holds this sweep already ({done} of {len(self.plan.episodes)} "
                "episodes done): add --resume to finish it, or choose another --out"
            )

    def _manifest_difference(self, held: dict[str, Any]) -> str:
        """What differs between the sweep a manifest describes and this one, in words."""
        plan = self.plan
        differs = _estimator_difference(held.get("estimators", []), plan)
        if differs:
            return differs
        seeds, points = held.get("seeds"), held.get("points")
        if seeds != list(plan.seeds):
            if not isinstance(seeds, list) or len(seeds) != len(plan.seeds):
                n = len(seeds) if isinstance(seeds, list) else "no"
                return f"it has {n} seeds, this sweep {len(plan.seeds)}"
            k = next(i for i, (a, b) in enumerate(zip(seeds, plan.seeds, strict=True)) if a != b)
            return f"its seed {k + 1} of {len(seeds)} is {seeds[k]!r}, this sweep's {plan.seeds[k]}"
        if not isinstance(points, list) or len(points) != len(plan.points):
            n = len(points) if isinstance(points, list) else "no"
            return f"it has {n} grid points, this sweep {len(plan.points)}"
        for there, p in zip(points, plan.points, strict=True):
            differs = _point_difference(there, p, self.point_file(p.index))
            if differs:
                return differs
        return "its grid points' scenarios differ"

    def _write_points(self) -> None:
        """Every grid point's scenario file that is missing or differs from the plan's."""
        for p in self.plan.points:
            path = self.dir / self.point_file(p.index)
            if self._new or _text_or_none(path) != p.scenario_toml:
                _write_text(path, p.scenario_toml)

    def _write_manifest(self) -> None:
        manifest = {
            "manifest_version": MANIFEST_VERSION,
            "sweep_file": self.plan.path,
            "scenario": self.plan.scenario,
            "fingerprint": self.plan.fingerprint,
            "keys": list(self.plan.keys),
            "seeds": list(self.plan.seeds),
            **self._estimators_entry(),
            "points": [
                {
                    "index": p.index,
                    "values": p.values,
                    "scenario_file": self.point_file(p.index),
                    "scenario_sha256": p.scenario_sha256,
                }
                for p in self.plan.points
            ],
        }
        _write_text(self.dir / MANIFEST, json.dumps(manifest, indent=1) + "\n")

    def _estimators_entry(self) -> dict[str, Any]:
        """``{"estimators": [...]}`` (``estimator_identity``) for a sweep with user estimators,
        else nothing: the manifest and journal of a built-in sweep are as they were."""
        if not self.plan.estimators:
            return {}
        return {"estimators": estimator_identity(self.plan.estimators)}

    def _read_journal(self) -> None:
        """Read back every journal entry: this sweep's into ``episodes``, the ones that do not
        read into ``bad_entries``.

        Raises
        ------
        SweepError
            An entry is another sweep's; the message names one whose grid point or seed
            differs from this sweep's, where there is one.
        """
        journal = self.dir / "episodes"
        foreign: list[tuple[str, str, bool]] = []  # name, what differs, whether the point does
        for name in sorted(_entry_names(journal)):
            where = f"episodes/{name}"
            try:
                episode = self._episode(_load_entry(journal / name), name)
            except _BadEntryError as exc:
                self.bad_entries.append(f"{where}: {exc}")
                continue
            except _ForeignEntry as exc:
                foreign.append((where, *exc.args))
                continue
            self.episodes[episode.point, episode.seed] = episode
        if foreign:
            where, differs, _ = next((f for f in foreign if f[2]), foreign[0])
            raise SweepError(
                f"{journal} holds {len(foreign)} episodes of another sweep ({where}: {differs}); "
                "move it away, or choose another --out"
            )

    def _episode(self, entry: Any, name: str) -> Episode:
        """The episode a journal entry holds, checked against its file's name and the plan.

        Raises
        ------
        _BadEntryError
            The entry is not an episode as this program writes it.
        _ForeignEntry
            The entry is another sweep's.
        """
        if not isinstance(entry, dict):
            raise _BadEntryError(f"{_kind(entry)}, expected a table")
        if set(entry) == {"point", "seed", "row", "estimates"}:
            raise _BadEntryError("written by an older vnav-demo, without the sweep's identity")
        for key in _ENTRY_KEYS:
            if key not in entry:
                raise _BadEntryError(f"{key}: missing")
        unknown = sorted(set(entry) - set(_ENTRY_KEYS) - set(_OPTIONAL_KEYS))
        if unknown:
            raise _BadEntryError(f"{unknown[0]}: unknown key")
        if not isinstance(entry.get("estimators", []), list):
            raise _BadEntryError(f"estimators: {_kind(entry['estimators'])}, expected a list")
        if entry["journal_version"] != JOURNAL_VERSION:
            version = entry["journal_version"]
            raise _BadEntryError(f"journal_version: {version!r}, expected {JOURNAL_VERSION}")
        for key, kind in (("sweep", str), ("point", int), ("seed", int)):
            _expect(entry[key], kind, key)
        _expect(entry["scenario_sha256"], str, "scenario_sha256")
        _expect(entry["values"], dict, "values")
        named = _ENTRY_NAME.match(name)
        assert named is not None  # _entry_names gives entries' names only
        point, seed = entry["point"], entry["seed"]
        if (point, seed) != (int(named[1]), int(named[2])):
            raise _BadEntryError(f"holds point {point} seed {seed}, not the episode of its name")
        if entry["sweep"] != self.plan.fingerprint:
            raise _ForeignEntry(*self._difference(entry))
        if point >= len(self.plan.points) or seed not in self._seeds:
            raise _BadEntryError(f"point {point} seed {seed} is not an episode of this sweep")
        differs = _point_difference(entry, self.plan.points[point], self.point_file(point))
        if differs:
            raise _BadEntryError(differs)
        methods = self.plan.methods
        columns = row_columns(methods, navigates(self.plan.points[point].spec))
        row = _row(entry["row"], columns)
        return Episode(point, seed, row, _estimates(entry["estimates"], [m.name for m in methods]))

    def _difference(self, entry: dict[str, Any]) -> tuple[str, bool]:
        """What differs between the episode of another sweep's journal entry and this sweep's
        of the same name, in words, and whether its grid point or seed does."""
        point, seed = entry["point"], entry["seed"]
        differs = _estimator_difference(entry.get("estimators", []), self.plan)
        if differs:
            return differs, False
        if point >= len(self.plan.points):
            return f"grid point {point} there; this sweep has {len(self.plan.points)}", True
        differs = _point_difference(entry, self.plan.points[point], self.point_file(point))
        if differs:
            return differs, True
        if seed not in self._seeds:
            return f"seed {seed} there is not one of this sweep's seeds", True
        return (
            f"the same episode, of a sweep of other grid points or seeds (fingerprint "
            f"{entry['sweep']} there, {self.plan.fingerprint} here)"
        ), False

    def point_file(self, index: int) -> str:
        """Grid point ``index``'s scenario file, relative to the sweep directory."""
        return f"points/{self.plan.points[index].spec.name}.toml"

    def pending(self) -> list[tuple[int, int]]:
        """The planned episodes not yet finished, in plan order."""
        return [e for e in self.plan.episodes if e not in self.episodes]

    def add(self, episode: Episode) -> None:
        """Journal a finished episode, and now and then rebuild the tables."""
        point = self.plan.points[episode.point]
        entry = {
            "journal_version": JOURNAL_VERSION,
            "sweep": self.plan.fingerprint,
            "point": episode.point,
            "values": point.values,
            "scenario_sha256": point.scenario_sha256,
            "seed": episode.seed,
            **self._estimators_entry(),
            "row": episode.row,
            "estimates": episode.estimates,
        }
        path = self.dir / "episodes" / _episode_file(episode.point, episode.seed)
        text = json.dumps(entry, allow_nan=True)
        # The journal is the record: a stop between the entry and the dict would leave the
        # tables and summary written at the stop one episode short of it.
        with outputs.signals_held():
            _write_text(path, text)
            self.episodes[episode.point, episode.seed] = episode
        # Rebuilding costs time in proportion to the rows: at most ~5% of the sweep's.
        if time.monotonic() - self._flushed_at > max(FLUSH_EVERY_S, 20.0 * self._flush_cost_s):
            self.write_tables()

    # ------------------------------------------------------------------ tables
    def sorted_episodes(self) -> list[Episode]:
        """The finished episodes, by point and seed."""
        return [self.episodes[k] for k in sorted(self.episodes)]

    def write_tables(self) -> None:
        """Rebuild ``results.parquet`` and ``estimates.parquet`` from every finished episode."""
        import pyarrow.parquet as pq

        start = time.monotonic()
        episodes = self.sorted_episodes()
        meta = {"vnav.sweep": json.dumps(table_metadata(self.plan))}
        results = results_table(self.plan, episodes).replace_schema_metadata(meta)
        estimates = estimates_table(episodes).replace_schema_metadata(meta)
        write_atomic(self.dir / RESULTS, lambda tmp: pq.write_table(results, tmp))
        write_atomic(self.dir / ESTIMATES, lambda tmp: pq.write_table(estimates, tmp))
        self._flushed_at = time.monotonic()
        self._flush_cost_s = self._flushed_at - start

    def _remove(self, path: Path) -> None:
        """Remove a derived file, or the plots a directory holds of this sweep's (only the
        names it writes: a file of the user's there stays), then the directory if empty."""
        try:
            if path.is_dir():
                for name in plot_names(self.plan):
                    (path / name).unlink(missing_ok=True)
                if not any(path.iterdir()):
                    path.rmdir()
            else:
                path.unlink(missing_ok=True)
        except OSError as exc:
            raise OutputError(
                exc.errno, f"cannot remove the stale {path}: {exc.strerror}"
            ) from None


def _write_text(path: Path, text: str) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _read_regular(path: Path) -> bytes:
    """The bytes of ``path`` if it is a regular file; opened without blocking (a FIFO waits
    for a writer for ever), then checked before reading.

    Raises
    ------
    OSError
        It cannot be opened or read, or is not a regular file (``EINVAL``).
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise OSError(22, "not a regular file", str(path))
        return f.read()


def _text_or_none(path: Path) -> str | None:
    """``path``'s text if it is a readable regular UTF-8 file, else None."""
    try:
        return _read_regular(path).decode("utf-8")
    except (OSError, ValueError):
        return None


def _entry_names(journal: Path) -> list[str]:
    """The names in ``journal`` that are journal entries' (``p<i>-s<seed>.json``); none if
    it is missing. Other files there are not this program's and are left alone."""
    try:
        return [n for n in os.listdir(journal) if _ENTRY_NAME.match(n)]
    except FileNotFoundError:
        return []


def _load_entry(path: Path) -> Any:
    """A journal entry's parsed JSON.

    Raises
    ------
    _BadEntryError
        It cannot be read, is not a regular file, or is not JSON.
    """
    try:
        return json.loads(_read_regular(path))
    except OSError as exc:
        raise _BadEntryError(exc.strerror or type(exc).__name__) from None
    except (ValueError, RecursionError) as exc:  # not UTF-8, not JSON, nested past the stack
        raise _BadEntryError(f"not JSON ({type(exc).__name__})") from None


def _kind(value: Any) -> str:
    """How a JSON value reads, for a message: ``null``, ``list``, ``str '30'``."""
    if value is None:
        return "null"
    text = repr(value)
    return type(value).__name__ + (f" {text}" if len(text) <= 20 else "")


def _expect(value: Any, kind: type, where: str) -> None:
    """Raise ``_BadEntryError`` unless ``value`` is a ``kind`` (a bool is no number)."""
    if (isinstance(value, bool) and kind is not bool) or not isinstance(value, kind):
        names = {int: "an integer", bool: "a boolean", str: "a string", dict: "a table"}
        raise _BadEntryError(f"{where}: {_kind(value)}, expected {names.get(kind, kind.__name__)}")


def _point_difference(there: Any, point, point_file: str) -> str | None:
    """How a grid point described elsewhere (a manifest's or a journal entry's ``values``
    and ``scenario_sha256``) differs from this sweep's ``point``, or None."""
    values = there.get("values") if isinstance(there, dict) else None
    if values != point.values:
        shown = label(values) if isinstance(values, dict) else repr(values)
        return f"grid point {point.index} there is {shown}; here {point.label}"
    if there.get("scenario_sha256", point.scenario_sha256) != point.scenario_sha256:
        return (
            f"grid point {point.index} ({point.label}) there runs another scenario than "
            f"{point_file}"
        )
    return None


def _estimator_difference(there: Any, plan: SweepPlan) -> str | None:
    """How the user estimators a manifest or journal entry names (``estimator_identity``)
    differ from ``plan``'s, in words, or None."""
    here = estimator_identity(plan.estimators)
    if there == here:
        return None
    listed = there if isinstance(there, list) else [there]
    specs = [str(e.get("spec") if isinstance(e, dict) else e) for e in listed]
    if specs != [e["spec"] for e in here]:
        mine = [e["spec"] for e in here]
        return (
            f"its estimator is {', '.join(specs) or 'none'}, this sweep's "
            f"{', '.join(mine) or 'none'}"
        )
    for old, new in zip(listed, here, strict=True):
        old_sha256 = old.get("sha256") if isinstance(old, dict) else None
        if old_sha256 != new["sha256"]:
            return (
                f"estimator {new['spec']}: its function's file changed (SHA-256 "
                f"{_short(old_sha256)} there, {_short(new['sha256'])} here)"
            )
    return "its estimators differ"


def _short(sha256: Any) -> str:
    """A file hash in a message: its first 12 digits, or ``none``."""
    return sha256[:12] if isinstance(sha256, str) else "none"


def _row(row: Any, columns: list[str]) -> dict[str, Any]:
    """A journal entry's row, checked: every one of ``columns`` (``row_columns``), of its
    type.

    Raises
    ------
    _BadEntryError
        Naming the first column missing, unknown or of the wrong type.
    """
    _expect(row, dict, "row")
    for name in columns:
        if name not in row:
            raise _BadEntryError(f"row.{name}: missing")
        value = row[name]
        kind = _column_type(name)
        if kind == "float":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise _BadEntryError(f"row.{name}: {_kind(value)}, expected a number")
        elif kind == "flag":  # a navigating flight's outcome: None where it diverged
            if value is not None:
                _expect(value, bool, f"row.{name}")
        elif kind == "list":
            _expect(value, list, f"row.{name}")
            if not all(isinstance(v, str) for v in value):
                raise _BadEntryError(f"row.{name}: a value that is not a string")
        else:
            _expect(value, {"int": int, "text": str, "bool": bool}[kind], f"row.{name}")
    unknown = sorted(set(row) - set(columns))
    if unknown:
        raise _BadEntryError(f"row.{unknown[0]}: unknown column")
    if row["status"] not in STATUSES:
        raise _BadEntryError(f"row.status: {row['status']!r}, expected one of {list(STATUSES)}")
    return row


def _estimates(estimates: Any, methods: list[str]) -> dict[str, list]:
    """A journal entry's estimates, checked: a list per ``ESTIMATE_COLUMNS``, all as long,
    each value of its column's type (a method one of ``methods``).

    Raises
    ------
    _BadEntryError
        Naming the first column missing, unknown, of another length or holding a wrong value.
    """
    _expect(estimates, dict, "estimates")
    unknown = sorted(set(estimates) - set(ESTIMATE_COLUMNS))
    if unknown:
        raise _BadEntryError(f"estimates.{unknown[0]}: unknown column")
    lengths = set()
    for name in ESTIMATE_COLUMNS:
        values = estimates.get(name)
        if not isinstance(values, list):
            raise _BadEntryError(f"estimates.{name}: {_kind(values)}, expected a list")
        lengths.add(len(values))
        if name in ("tick", "cone"):
            ok = all(type(v) is int for v in values)
        elif name == "method":
            ok = all(isinstance(v, str) and v in methods for v in values)
        else:
            ok = all(type(v) is float or type(v) is int for v in values)
        if not ok:
            raise _BadEntryError(f"estimates.{name}: a value of the wrong type")
    if len(lengths) > 1:
        raise _BadEntryError("estimates: columns of different lengths")
    return estimates


def _column_type(name: str) -> str:
    """The type of a row's column: ``int``, ``text``, ``list`` (of strings), ``bool``,
    ``flag`` (a boolean or None) or ``float``: the journal's check and the table's types both
    read it."""
    if name.endswith(("__count", "__failures")) or name in _INT_COLUMNS:
        return "int"
    if name in NAV_FLAGS:
        return "flag"
    if name in _TEXT_COLUMNS:
        return "text"
    if name in _LIST_COLUMNS:
        return "list"
    return "bool" if name == "passed" else "float"


def _column(values: list[Any]):
    """A pyarrow array of grid values: typed where they agree (numbers, strings, lists),
    else their JSON text."""
    import pyarrow as pa

    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.array([json.dumps(v) for v in values])


def table_metadata(plan: SweepPlan) -> dict[str, Any]:
    """What each table's schema metadata ``vnav.sweep`` holds (as JSON): the sweep's
    ``fingerprint``, ``tables_version``, ``grid_columns``, each grid key to its column, and
    ``method_columns``, each method to its part of its columns' names (``method_part``)."""
    return {
        "fingerprint": plan.fingerprint,
        "tables_version": TABLES_VERSION,
        "grid_columns": {key: grid_column(key) for key in plan.keys},
        "method_columns": {m.name: method_part(m.name) for m in plan.methods},
    }


def results_table(plan: SweepPlan, episodes: list[Episode]):
    """One row per episode: ``point``, ``seed``, each grid key's column (``grid_column``), then
    ``row_columns`` of the plan's methods (with ``NAV_COLUMNS`` if ``plan.navigates``: null
    and NaN for an episode of a grid point that does not); ``failed_checks`` is a list of
    strings."""
    import pyarrow as pa

    columns: dict[str, Any] = {
        "point": pa.array([e.point for e in episodes], pa.int64()),
        "seed": pa.array([e.seed for e in episodes], pa.int64()),
    }
    for key in plan.keys:
        columns[grid_column(key)] = _column([plan.points[e.point].values[key] for e in episodes])
    types = {
        "int": pa.int64(),
        "text": pa.string(),
        "bool": pa.bool_(),
        "flag": pa.bool_(),
        "list": pa.list_(pa.string()),
    }
    absent = dict.fromkeys(NAV_COLUMNS, math.nan) | dict.fromkeys(NAV_FLAGS)
    for name in row_columns(plan.methods, plan.navigates):
        values = [e.row[name] if name in e.row else absent[name] for e in episodes]
        kind = _column_type(name)
        if kind == "float":
            columns[name] = pa.array([float(v) for v in values], pa.float64())
        else:
            columns[name] = pa.array(values, types[kind])
    return pa.table(columns)


_INT_COLUMNS = {"camera_ticks", "detections", "matched_detections", "cones_in_view"}
_INT_COLUMNS |= {"cones_detected"}
_TEXT_COLUMNS = {"status", "message"}
_LIST_COLUMNS = {"failed_checks"}


def estimates_table(episodes: list[Episode]):
    """One row per estimate: ``point``, ``seed``, then ``ESTIMATE_COLUMNS``."""
    import pyarrow as pa

    counts = [len(e.estimates.get("error_m", [])) for e in episodes]
    columns: dict[str, Any] = {
        "point": pa.array(
            [e.point for e, n in zip(episodes, counts, strict=True) for _ in range(n)], pa.int64()
        ),
        "seed": pa.array(
            [e.seed for e, n in zip(episodes, counts, strict=True) for _ in range(n)], pa.int64()
        ),
    }
    types = {"tick": pa.int64(), "cone": pa.int64(), "method": pa.string()}
    for name in ESTIMATE_COLUMNS:
        values = [v for e in episodes for v in e.estimates.get(name, [])]
        columns[name] = pa.array(values, types.get(name, pa.float64()))
    table = pa.table(columns)
    return table.set_column(
        table.schema.get_field_index("method"),
        "method",
        table["method"].dictionary_encode(),
    )
