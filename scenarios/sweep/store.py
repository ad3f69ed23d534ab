"""A sweep's directory: what is planned, what is done, and the tables of results.

::

    DIR/sweep.json           the sweep: its file, fingerprint, keys, seeds, grid points
    DIR/points/<name>.toml   each grid point as a scenario file (replay: vnav-demo run)
    DIR/episodes/*.json      the journal: one file per finished episode, written whole
    DIR/results.parquet      one row per finished episode (point, seed, grid values, numbers)
    DIR/estimates.parquet    one row per estimate (episode, tick, cone, method, range, error)

The tables' column names are plain identifiers (``scenarios.sweep.rows``: a grid key's dots
become ``__``); each table's schema metadata ``vnav.sweep`` holds the sweep's fingerprint, the
tables' version and the grid key of each grid column.

Every file is written whole or not at all (``scenarios.record.outputs.write_atomic``). The journal
is the record: an episode is finished once its file is there, so an interrupted sweep loses
at most the episodes that were running, and ``--resume`` runs only the missing ones. The two
tables are rebuilt from the journal as the sweep goes (every few seconds) and at its end; rows
are sorted by point and seed, so a table does not depend on which worker finished first.
Journal floats are written by ``json`` in shortest round-trip form: read back, they are the
same doubles.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from scenarios.record.outputs import OutputError, write_atomic
from scenarios.sweep.plan import SweepError, SweepPlan
from scenarios.sweep.rows import (
    ESTIMATE_COLUMNS,
    TABLES_VERSION,
    Episode,
    grid_column,
    row_columns,
)

__all__ = ["DERIVED", "MANIFEST", "SweepStore", "pyarrow_missing", "table_metadata"]

MANIFEST = "sweep.json"
RESULTS, ESTIMATES = "results.parquet", "estimates.parquet"
DERIVED = ("summary.json", "plots")
"""Files made from the whole journal at the end; removed when a sweep (re)starts, so that
what is there always describes the tables beside it."""
MANIFEST_VERSION = 2  # 2: journal rows with the tables' column names (rows.TABLES_VERSION)
FLUSH_EVERY_S = 5.0


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
    """

    def __init__(self, out_dir: Path, plan: SweepPlan) -> None:
        self.dir = Path(out_dir)
        self.plan = plan
        self.episodes: dict[tuple[int, int], Episode] = {}
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
            ``out_dir`` holds a sweep and ``resume`` is off, or holds a different sweep.
        """
        store = cls(out_dir, plan)
        manifest = store.dir / MANIFEST
        store._new = not manifest.exists()
        if not store._new:
            store._check_manifest(manifest, resume)
            store._read_journal()
        return store

    def begin(self) -> None:
        """Write the plan (a new sweep) and remove the files made from a previous journal.

        Raises
        ------
        OutputError
            A file cannot be written or removed.
        """
        if self._new:
            self._write_plan()
            self._new = False
        for name in DERIVED:
            self._remove(self.dir / name)

    # ------------------------------------------------------------------ plan and journal
    def _check_manifest(self, manifest: Path, resume: bool) -> None:
        try:
            held = json.loads(manifest.read_text(encoding="utf-8"))
            fingerprint, held_file = held["fingerprint"], held["sweep_file"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise SweepError(
                f"{manifest}: not a sweep manifest ({exc}); choose another --out"
            ) from None
        if fingerprint != self.plan.fingerprint:
            raise SweepError(
                f"{self.dir} holds another sweep (from {held_file}): its grid points or seeds "
                f"differ from {self.plan.path}'s; choose another --out"
            )
        if not resume:
            done = sum(1 for _ in (self.dir / "episodes").glob("*.json"))
            raise SweepError(
                f"{self.dir} holds this sweep already ({done} of {len(self.plan.episodes)} "
                "episodes done): add --resume to finish it, or choose another --out"
            )

    def _write_plan(self) -> None:
        points_dir = self.dir / "points"
        points_dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "episodes").mkdir(exist_ok=True)
        for p in self.plan.points:
            _write_text(points_dir / f"{p.spec.name}.toml", p.scenario_toml)
        manifest = {
            "manifest_version": MANIFEST_VERSION,
            "sweep_file": self.plan.path,
            "scenario": self.plan.scenario,
            "fingerprint": self.plan.fingerprint,
            "keys": list(self.plan.keys),
            "seeds": list(self.plan.seeds),
            "points": [
                {"index": p.index, "values": p.values, "scenario_file": self.point_file(p.index)}
                for p in self.plan.points
            ],
        }
        _write_text(self.dir / MANIFEST, json.dumps(manifest, indent=1) + "\n")

    def _read_journal(self) -> None:
        planned = set(self.plan.episodes)
        for path in sorted((self.dir / "episodes").glob("*.json")):
            try:
                entry = json.loads(path.read_text(encoding="utf-8"))
                episode = Episode(entry["point"], entry["seed"], entry["row"], entry["estimates"])
            except (OSError, ValueError, KeyError, TypeError):
                # Journal files are written whole: one that does not read was not written by
                # a sweep; it is left alone and its episode runs again.
                continue
            if (episode.point, episode.seed) in planned:
                self.episodes[episode.point, episode.seed] = episode

    def point_file(self, index: int) -> str:
        """Grid point ``index``'s scenario file, relative to the sweep directory."""
        return f"points/{self.plan.points[index].spec.name}.toml"

    def pending(self) -> list[tuple[int, int]]:
        """The planned episodes not yet finished, in plan order."""
        return [e for e in self.plan.episodes if e not in self.episodes]

    def add(self, episode: Episode) -> None:
        """Journal a finished episode, and now and then rebuild the tables."""
        entry = {
            "point": episode.point,
            "seed": episode.seed,
            "row": episode.row,
            "estimates": episode.estimates,
        }
        path = self.dir / "episodes" / _episode_file(episode.point, episode.seed)
        _write_text(path, json.dumps(entry, allow_nan=True))
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
        try:
            if path.is_dir():
                for child in path.iterdir():
                    child.unlink()
                path.rmdir()
            else:
                path.unlink(missing_ok=True)
        except OSError as exc:
            raise OutputError(
                exc.errno, f"cannot remove the stale {path}: {exc.strerror}"
            ) from None


def _write_text(path: Path, text: str) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


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
    ``fingerprint``, ``tables_version`` and ``grid_columns``, each grid key to its column."""
    return {
        "fingerprint": plan.fingerprint,
        "tables_version": TABLES_VERSION,
        "grid_columns": {key: grid_column(key) for key in plan.keys},
    }


def results_table(plan: SweepPlan, episodes: list[Episode]):
    """One row per episode: ``point``, ``seed``, each grid key's column (``grid_column``), then
    ``row_columns()``; ``failed_checks`` is a list of strings."""
    import pyarrow as pa

    columns: dict[str, Any] = {
        "point": pa.array([e.point for e in episodes], pa.int64()),
        "seed": pa.array([e.seed for e in episodes], pa.int64()),
    }
    for key in plan.keys:
        columns[grid_column(key)] = _column([plan.points[e.point].values[key] for e in episodes])
    for name in row_columns():
        values = [e.row[name] for e in episodes]
        if name.endswith("__count") or name in _INT_COLUMNS:
            columns[name] = pa.array(values, pa.int64())
        elif name in _TEXT_COLUMNS:
            columns[name] = pa.array(values, pa.string())
        elif name in _LIST_COLUMNS:
            columns[name] = pa.array(values, pa.list_(pa.string()))
        elif name == "passed":
            columns[name] = pa.array(values, pa.bool_())
        else:
            columns[name] = pa.array([float(v) for v in values], pa.float64())
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
