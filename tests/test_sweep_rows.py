"""A sweep's rows without running a sweep: a diverged episode is a row like any other (NaN
errors, zero counts, ranked worst, plotted around); the plots' curves against the per-point
summary, read back from the figures; the tables' column names, read back from Parquet."""

from __future__ import annotations

import dataclasses
import json
import keyword
import math
import re

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from scenarios import pipeline
from scenarios.scenario import schema
from scenarios.sweep import episode, plots, summary
from scenarios.sweep.plan import SweepError, plan
from scenarios.sweep.rows import (
    ESTIMATE_COLUMNS,
    NAV_COLUMNS,
    NAV_FLAGS,
    STATS,
    TABLES_VERSION,
    Episode,
    grid_column,
    method_column,
    row_columns,
)
from scenarios.sweep.store import SweepStore, estimates_table, results_table, table_metadata
from sim.world import SimulationError
from vnav import metrics
from vnav.methods import METHOD_NAMES, METHODS


def test_diverged_flight_is_a_row(monkeypatch):
    sweep = plan(
        {"scenario": "frame-problem", "seeds": 2, "grid": {"duration_s": [1.0, 1.5]}}, "s.toml"
    )
    ran = [episode.run_episode(sweep.points[0].spec, 0, s) for s in (1, 2)]

    def diverge(spec, **kwargs):
        raise SimulationError("t = 0.7000 s: the state exploded")

    monkeypatch.setattr(pipeline, "run", diverge)
    diverged = episode.run_episode(sweep.points[1].spec, 1, 1)
    assert list(diverged.row) == row_columns()
    assert diverged.row["status"] == "diverged" and diverged.row["passed"] is False
    assert "t = 0.7000 s" in diverged.row["message"]
    assert all(diverged.row[f"{m}__count"] == 0 for m in METHOD_NAMES)
    assert math.isnan(diverged.row["depth_image__median_m"])
    assert diverged.row["failed_checks"] == []
    assert diverged.estimates == {c: [] for c in diverged.estimates}

    episodes = [*ran, dataclasses.replace(diverged, seed=1)]
    table = results_table(sweep, episodes)
    assert table.num_rows == 3 and table["status"].to_pylist()[-1] == "diverged"
    assert estimates_table(episodes).num_rows == sum(len(e.estimates["error_m"]) for e in ran)
    doc = summary.build(sweep, episodes, out_dir="d", point_files=["a", "b"], complete=False)
    assert doc["worst"][0]["status"] == "diverged"
    assert doc["episodes"]["diverged"] == 1 and doc["points"][1]["pass_rate"] == 0.0
    assert doc["points"][1]["methods"]["depth_image"]["median_m"]["median"] is None
    png = plots.error_vs_key_png(sweep, episodes, "duration_s")
    assert png[:4] == b"\x89PNG"
    assert plots.error_vs_range_png(sweep, episodes)[:4] == b"\x89PNG"
    assert (
        plots.error_vs_range_png(sweep, [dataclasses.replace(diverged, seed=1)])[:4] == b"\x89PNG"
    )


# ------------------------------------------------------------------ the README's sweep, synthetic
# The README's sweep (two swept keys), its grid points parsed as the sweep command does, with
# episodes made up (nothing runs): errors that depend strongly on the noise level, as the
# README says they do (about 2 cm without noise, 16 cm with), so that a curve pooling the
# noise levels matches neither.
README_SWEEP = {
    "scenario": "approach",
    "seeds": 5,
    "rank_by": "depth_image",
    "grid": {"camera.pitch_down_deg": [8.0, 12.0, 16.0], "noise.attitude_std_deg": [0.0, 0.5]},
}


def _episodes(sweep, rng: np.random.Generator, skip=()) -> list[Episode]:
    """One made-up episode per (point, seed) of ``sweep`` but ``skip``; ``naive`` never gives
    an estimate at the first seed (NaN), as a method out of range would not."""
    out = []
    for p, s in sweep.episodes:
        if (p, s) in skip:
            continue
        values = sweep.points[p].values
        scale = 0.02 + 0.3 * values.get("noise.attitude_std_deg", 0.0)
        row: dict = dict.fromkeys(row_columns(), math.nan)
        failed = ["accuracy depth_image"] if scale > 0.1 else []
        row.update(status="failed" if failed else "passed", passed=not failed)
        row.update(failed_checks=failed, message="", wall_s=0.1, simulated_s=8.0)
        row.update(dict.fromkeys(["camera_ticks", "detections", "matched_detections"], 10))
        row.update(cones_in_view=1, cones_detected=1, detection_rate=1.0)
        estimates: dict = {c: [] for c in ESTIMATE_COLUMNS}
        for m in METHOD_NAMES:
            given = not (m == "naive" and s == sweep.seeds[0])
            errors = scale * rng.lognormal(0.0, 0.5, 8) if given else np.array([])
            ranges = rng.uniform(2.0, 12.0, errors.size)
            row[method_column(m, "count")] = int(errors.size)
            for stat, value in metrics.error_stats(errors).items():
                if stat in ("mean", "median", "rmse", "max"):
                    row[method_column(m, stat)] = math.nan if value is None else float(value)
            for tick, (r, e) in enumerate(zip(ranges, errors, strict=True)):
                for c, v in zip(ESTIMATE_COLUMNS, (tick, 0.1 * tick, 0, m, r, e), strict=True):
                    estimates[c].append(float(v) if c in ("range_m", "error_m") else v)
        out.append(Episode(p, s, row, estimates))
    return out


@pytest.fixture
def figures(monkeypatch) -> list:
    """Every matplotlib figure saved while the test runs (a plot function's PNG is one)."""
    from matplotlib.figure import Figure

    saved, savefig = [], Figure.savefig

    def keep(fig, *args, **kwargs):
        saved.append(fig)
        return savefig(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved


def _lines(ax) -> dict[str, object]:
    """An axes' lines by label (``depth_image median``, ``depth_image p90``)."""
    return {line.get_label(): line for line in ax.lines}


def _caption(fig) -> str:
    return " ".join(t.get_text() for t in fig.texts).replace("\n", " ")


@pytest.mark.parametrize("skip", [(), ((1, 2), (1, 4), (4, 5))], ids=["complete", "partial"])
def test_error_vs_key_has_a_curve_per_value_of_the_other_key(figures, rng, skip):
    """In error_vs_camera.pitch_down_deg.png, each noise level is a curve of its own (a panel
    titled with it), and each point is its grid point's median and p90 across its seeds, as
    summary.json gives them; the caption counts a point's episodes, not the sweep's."""
    sweep = plan(README_SWEEP, "my-sweep.toml")
    episodes = _episodes(sweep, rng, skip)
    doc = summary.build(
        sweep, episodes, out_dir="d", point_files=["f"] * len(sweep.points), complete=not skip
    )
    assert plots.error_vs_key_png(sweep, episodes, "camera.pitch_down_deg")[:4] == b"\x89PNG"
    (fig,) = figures
    panels = [ax for ax in fig.axes if ax.lines]
    assert sorted(ax.get_title() for ax in panels) == [
        "noise.attitude_std_deg = 0.0",
        "noise.attitude_std_deg = 0.5",
    ]
    compared = 0
    for ax in panels:
        noise = float(ax.get_title().split(" = ")[1])
        lines = _lines(ax)
        assert {label.split()[0] for label in lines} == set(METHOD_NAMES)
        for m in METHOD_NAMES:
            for stat, name in (("median", f"{m} median"), ("p90", f"{m} p90")):
                for x, y in zip(lines[name].get_xdata(), lines[name].get_ydata(), strict=True):
                    (point,) = [
                        p
                        for p in doc["points"]
                        if p["values"]
                        == {"camera.pitch_down_deg": x, "noise.attitude_std_deg": noise}
                    ]
                    expected = point["methods"][m]["median_m"][stat]
                    assert (math.isnan(y) and expected is None) or y == expected, (m, stat, x)
                    compared += 1
    assert compared == 2 * len(METHOD_NAMES) * len(sweep.points)
    for curve in plots.key_curves(sweep, episodes, "camera.pitch_down_deg"):
        for x, n in zip(curve.x, curve.episodes, strict=True):
            (point,) = [
                p
                for p in doc["points"]
                if p["values"] == {"camera.pitch_down_deg": x, **curve.others}
            ]
            assert n == point["methods"][curve.method]["episodes_with_estimates"]
    caption = _caption(fig)
    per_point = "5 episodes" if not skip else "3 to 5 episodes"
    assert f"one grid point's {per_point}" in caption
    assert f"{len(episodes)} episodes in 6 grid points" in caption


def test_one_key_sweep_has_one_panel(figures, rng):
    """A sweep with one swept key (and one fixed): one panel, each point its grid point's."""
    sweep = plan(
        {
            "scenario": "approach",
            "seeds": 4,
            "grid": {"noise.attitude_std_deg": [0.0, 0.25, 0.5], "duration_s": [6.0]},
        },
        "s.toml",
    )
    episodes = _episodes(sweep, rng)
    doc = summary.build(sweep, episodes, out_dir="d", point_files=["f"] * 3, complete=True)
    assert list(plots.plot_names(sweep)) == [
        "error_vs_noise.attitude_std_deg.png",
        "error_vs_range.png",
    ]
    plots.error_vs_key_png(sweep, episodes, "noise.attitude_std_deg")
    (fig,) = figures
    (panel,) = [ax for ax in fig.axes if ax.lines]
    assert panel.get_title() == ""
    line = _lines(panel)["depth_image median"]
    assert list(line.get_xdata()) == [0.0, 0.25, 0.5]
    assert list(line.get_ydata()) == [
        p["methods"]["depth_image"]["median_m"]["median"] for p in doc["points"]
    ]
    caption = _caption(fig)
    assert "one grid point's 4 episodes" in caption and "fixed: duration_s = 6.0" in caption.lower()


def _ink_runs(rgba: np.ndarray, row: int, x0: int, x1: int) -> int:
    """Runs of non-background pixels along ``row`` between columns ``x0`` and ``x1``."""
    ink = np.abs(rgba[row, x0:x1, :3].astype(int) - 255).sum(axis=1) > 60
    return int(np.count_nonzero(ink[1:] & ~ink[:-1]) + ink[0])


def test_legend_draws_each_statistic_as_the_lines_do(figures, rng):
    """The legend's median entry is drawn solid and its 90th percentile entry dashed, as the
    lines are: read from the rendered pixels of each entry."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    sweep = plan(README_SWEEP, "my-sweep.toml")
    plots.error_vs_key_png(sweep, _episodes(sweep, rng), "camera.pitch_down_deg")
    (fig,) = figures
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    height = rgba.shape[0]
    (legend,) = fig.legends or [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    styles = {}
    for handle, text in zip(legend.legend_handles, legend.get_texts(), strict=True):
        box = handle.get_window_extent(canvas.get_renderer())
        row = height - 1 - round(0.5 * (box.y0 + box.y1))
        styles[text.get_text()] = (
            handle.get_linestyle(),
            _ink_runs(rgba, row, int(box.x0) + 1, int(box.x1) - 1),
        )
    plotted = {
        line.get_label().split()[1]: line.get_linestyle() for ax in fig.axes for line in ax.lines
    }
    median = next(v for k, v in styles.items() if "median" in k)
    p90 = next(v for k, v in styles.items() if "p90" in k or "percentile" in k)
    assert median[0] == plotted["median"] == "-" and median[1] <= 2  # a line (and its dot)
    assert p90[0] == plotted["p90"] == "--" and p90[1] >= 4  # dashes, either side of the mark


def test_error_vs_range_has_a_panel_per_grid_point(figures, rng):
    """The range plot pools no grid points: one panel per point, its own estimates binned."""
    sweep = plan(README_SWEEP, "my-sweep.toml")
    episodes = _episodes(sweep, rng)
    plots.error_vs_range_png(sweep, episodes)
    (fig,) = figures
    panels = [ax for ax in fig.axes if ax.lines]
    assert len(panels) == len(sweep.points)
    ranges = np.array([r for e in episodes for r in e.estimates["range_m"]])
    edges = np.linspace(ranges.min(), ranges.max() + 1e-9, plots.RANGE_BINS + 1)
    for ax in panels:
        title = dict(line.split(" = ") for line in ax.get_title().split("\n"))
        (point,) = [p for p in sweep.points if {k: repr(v) for k, v in p.values.items()} == title]
        mine = [e for e in episodes if e.point == point.index]
        line = _lines(ax)["depth_image median"]
        for x, y in zip(line.get_xdata(), line.get_ydata(), strict=True):
            lo, hi = edges[edges < x].max(), edges[edges > x].min()
            errors = [
                err
                for e in mine
                for m, r, err in zip(
                    e.estimates["method"],
                    e.estimates["range_m"],
                    e.estimates["error_m"],
                    strict=True,
                )
                if m == "depth_image" and lo <= r < hi
            ]
            if len(errors) < plots.MIN_PER_BIN:
                assert math.isnan(y)
            else:
                assert y == np.median(errors)


def test_too_many_panels_are_not_drawn(figures, rng):
    """A plot that would need more than MAX_PANELS panels says so instead."""
    sweep = plan(
        {
            "scenario": "approach",
            "grid": {
                "camera.pitch_down_deg": [8.0, 12.0],
                "noise.attitude_std_deg": [0.01 * i for i in range(plots.MAX_PANELS + 1)],
            },
        },
        "s.toml",
    )
    plots.error_vs_key_png(sweep, _episodes(sweep, rng), "camera.pitch_down_deg")
    (fig,) = figures
    assert not any(ax.lines for ax in fig.axes)
    shown = " ".join(t.get_text() for ax in fig.axes for t in ax.texts).replace("\n", " ")
    assert f"{plots.MAX_PANELS + 1} combinations of noise.attitude_std_deg" in shown


# ------------------------------------------------------------------ the tables' column names
def test_tables_have_plain_column_names_and_a_list_of_failed_checks(tmp_path, rng):
    """results.parquet and estimates.parquet written and read back with pyarrow: every column
    name a plain identifier (SQL, pandas' attribute access), each grid key's column as the
    metadata maps it, and failed_checks a list column that round-trips."""
    sweep = plan(README_SWEEP, "my-sweep.toml")
    episodes = _episodes(sweep, rng)
    meta = {b"vnav.sweep": json.dumps(table_metadata(sweep)).encode()}
    pq.write_table(
        results_table(sweep, episodes).replace_schema_metadata(meta), tmp_path / "r.parquet"
    )
    pq.write_table(estimates_table(episodes), tmp_path / "e.parquet")
    results = pq.read_table(tmp_path / "r.parquet")
    estimates = pq.read_table(tmp_path / "e.parquet")
    for name in [*results.column_names, *estimates.column_names]:
        assert re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) and not keyword.iskeyword(name), name
    held = json.loads(results.schema.metadata[b"vnav.sweep"])
    assert held["grid_columns"] == {
        "camera.pitch_down_deg": "camera__pitch_down_deg",
        "noise.attitude_std_deg": "noise__attitude_std_deg",
    }
    assert held["tables_version"] == TABLES_VERSION and held["fingerprint"] == sweep.fingerprint
    got = results.to_pylist()
    for key, column in held["grid_columns"].items():
        assert [r[column] for r in got] == [sweep.points[e.point].values[key] for e in episodes]
    for m in METHOD_NAMES:
        assert [r[method_column(m, "median")] for r in got] == pytest.approx(
            [e.row[method_column(m, "median")] for e in episodes], nan_ok=True, abs=0
        )
    assert results.schema.field("failed_checks").type == pa.list_(pa.string())
    assert [r["failed_checks"] for r in got] == [e.row["failed_checks"] for e in episodes]
    assert {len(r["failed_checks"]) for r in got} == {0, 1}


def test_every_scenario_key_has_a_plain_column():
    """Every key path the scenario parser accepts (a list index as a number) maps to a plain
    identifier that splits back into the key; a key that could not is refused."""
    tables = {"": schema.TOP, "camera": schema.CAMERA, "noise": schema.NOISE}
    tables |= {"timing": schema.TIMING, "checks.0": schema.CHECK, "cones.1": schema.CONE}
    tables |= {"flight.waypoints.2": schema.WAYPOINT, "flight.keyframes.0": schema.KEYFRAME}
    tables |= {"camera.mount_error": schema.MOUNT_ERROR}
    tables |= {"imu": schema.IMU, "imu.mount_error": schema.IMU_MOUNT_ERROR}
    for prefix, keys in tables.items():
        for k in keys:
            key = f"{prefix}.{k.name}" if prefix else k.name
            column = grid_column(key)
            assert column.isidentifier() and column.split("__") == key.split("."), key
    for bad in ("a..b", "_x", "x_", "a__b", "2.x", "a-b", "é"):
        with pytest.raises(ValueError, match="no plain column name"):
            grid_column(bad)


def test_a_users_function_has_plain_columns(tmp_path, rng, figures):
    """A user's function ``user:ref`` is the part ``user_ref`` of its columns (the statistics
    and ``__failures``, a count), after the built-ins' and before ``simulated_s``; the
    metadata maps each method to its part; a name that would not read back is refused. The
    summary and the plots show it as a method (in black: its recordings' white would not
    show on the page)."""
    (tmp_path / "mine.py").write_text("def ref(obs):\n    return None\n")
    sweep = plan({**README_SWEEP, "estimator": "mine.py:ref"}, "my-sweep.toml", base_dir=tmp_path)
    columns = row_columns(sweep.methods)
    builtin = row_columns()
    users = [f"user_ref__{s}" if s == "count" else f"user_ref__{s}_m" for s in STATS]
    assert columns == [*builtin[:-2], *users, "user_ref__failures", *builtin[-2:]]
    assert method_column("user:ref", "failures") == "user_ref__failures"
    for bad in ("user:_ref", "user:ref_", "user:my__ref", "user:é"):
        with pytest.raises(ValueError, match="no plain column name"):
            method_column(bad, "count")
    episodes = _episodes(sweep, rng)
    for e in episodes:
        e.row.update({c: 1.5 for c in users}, user_ref__count=3, user_ref__failures=2)
    results = results_table(sweep, episodes)
    assert results.column_names == ["point", "seed", *map(grid_column, sweep.keys), *columns]
    assert results.schema.field("user_ref__failures").type == pa.int64()
    assert results["user_ref__failures"].to_pylist() == [2] * len(episodes)
    held = table_metadata(sweep)["method_columns"]
    assert held == {**{m: m for m in METHOD_NAMES}, "user:ref": "user_ref"}
    doc = summary.build(sweep, episodes, out_dir="d", point_files=["a"] * 6, complete=True)
    assert doc["points"][0]["methods"]["user:ref"]["failures"] == 2 * len(sweep.seeds)
    assert "failures" not in doc["points"][0]["methods"]["depth_image"]
    assert doc["estimators"] == [{"spec": "mine.py:ref", "sha256": sweep.estimators[0].sha256}]
    assert doc["worst"][0]["replay"].endswith(f"--estimator {tmp_path}/mine.py:ref")
    plots.error_vs_key_png(sweep, episodes, "camera.pitch_down_deg")
    (fig,) = figures
    lines = {line.get_label(): line for ax in fig.axes for line in ax.lines}
    assert lines["user:ref median"].get_color() == plots.USER_COLORS[0] == "#000000"
    assert list(lines["user:ref median"].get_ydata()) == [1.5, 1.5, 1.5]


# ------------------------------------------------------------------ a navigating flight
# The avoid built-in swept over whose map the drone flies on (strings in the grid) and an
# uncalibrated mount, with made-up outcomes (nothing runs): a seed's flight collides, reaches
# the goal, or neither (out of time), and one episode diverges.
NAV_SWEEP = {
    "scenario": "avoid",
    "seeds": 4,
    "grid": {
        "flight.estimate": ["depth_image", "naive"],
        "noise.extrinsic_std_deg": [0.0, 2.0, 5.0],
    },
}


def _nav_episodes(sweep, rng: np.random.Generator, diverged=(5, 3)) -> list[Episode]:
    """``_episodes`` with a made-up flight outcome in each row; the episode ``diverged``
    (point, seed) diverged, as ``run_episode`` writes such a row."""
    out = _episodes(sweep, rng)
    for e in out:
        e.row = {k: v for k, v in e.row.items() if k not in ("simulated_s", "wall_s")}
        outcome = rng.choice(["collided", "reached", "neither"], p=[0.4, 0.4, 0.2])
        e.row.update(
            nav__reached_goal=bool(outcome == "reached"),
            nav__collided=bool(outcome == "collided"),
            nav__min_clearance_m=-0.006 if outcome == "collided" else float(rng.uniform(0, 1)),
            nav__time_to_goal_s=float(rng.uniform(9, 11)) if outcome == "reached" else math.nan,
            nav__path_length_m=float(rng.uniform(5, 21)),
            simulated_s=8.0,
            wall_s=0.1,
        )
        if (e.point, e.seed) == diverged:
            e.row.update(dict.fromkeys(NAV_FLAGS), status="diverged", passed=False)
            e.row.update(dict.fromkeys(NAV_COLUMNS[2:], math.nan))
        assert list(e.row) == row_columns(navigates=True)
    return out


def test_navigate_flights_keys_sweep_with_strings_and_vectors():
    """Every key of a navigating flight sweeps as any other: a string choice, numbers and a
    vector; each grid point's scenario has the values (read back from its parsed flight),
    and the tables keep a string column as strings and a vector column as lists."""
    sweep = plan(
        {
            "scenario": "avoid",
            "grid": {
                "flight.estimate": ["depth_image", "naive"],
                "flight.clearance_m": [1.0, 1.5],
                "flight.speed_mps": [1.5],
                "flight.goal_w": [[20.0, 0.0, 0.5], [18.0, 2.0, 0.5]],
            },
        },
        "s.toml",
    )
    assert len(sweep.points) == 8 and sweep.navigates
    for p in sweep.points:
        flight = p.spec.flight
        assert flight.mode == "navigate"
        assert flight.estimate == p.values["flight.estimate"]
        assert flight.clearance_m == p.values["flight.clearance_m"]
        assert flight.speed_mps == 1.5
        assert list(flight.goal_w) == p.values["flight.goal_w"]
    assert [p.values["flight.estimate"] for p in sweep.points] == ["depth_image"] * 4 + [
        "naive"
    ] * 4
    episodes = [
        Episode(p.index, 1, dict.fromkeys(row_columns(navigates=True), 0.0)) for p in sweep.points
    ]
    for e in episodes:
        e.row.update(status="passed", passed=True, failed_checks=[], message="")
        e.row.update(nav__reached_goal=True, nav__collided=False)
        e.row.update({c: 0 for c in e.row if c.endswith("__count")})
        e.row.update(dict.fromkeys(["camera_ticks", "detections", "matched_detections"], 0))
        e.row.update(cones_in_view=0, cones_detected=0)
    table = results_table(sweep, episodes)
    assert table.schema.field("flight__estimate").type == pa.string()
    assert table["flight__estimate"].to_pylist() == [
        p.values["flight.estimate"] for p in sweep.points
    ]
    assert table["flight__goal_w"].to_pylist() == [p.values["flight.goal_w"] for p in sweep.points]
    with pytest.raises(SweepError, match=r"flight.estimate: must be one of .*'naive'"):
        plan({"scenario": "avoid", "grid": {"flight.estimate": ["nave"]}}, "s.toml")


def _assert_rates_counted_by_hand(doc: dict, got: list[dict]) -> None:
    """Each of summary.json's ``points`` (``doc``) has the collision and goal rates, counts,
    clearance and time-to-goal statistics counted by hand from the rows ``got`` (read back
    from results.parquet), over its episodes that did not diverge."""
    assert [p["index"] for p in doc["points"]] == list(range(6))
    for point in doc["points"]:
        mine = [r for r in got if r["point"] == point["index"]]
        flown = [r for r in mine if r["status"] != "diverged"]
        collided = [r for r in flown if r["nav__collided"]]
        reached = [r for r in flown if r["nav__reached_goal"]]
        assert point["collision_rate"] == len(collided) / len(flown)
        assert point["goal_rate"] == len(reached) / len(flown)
        nav = point["navigation"]
        assert (nav["flown"], nav["collided"], nav["reached_goal"]) == (
            len(flown),
            len(collided),
            len(reached),
        )
        clearances = [r["nav__min_clearance_m"] for r in flown]
        assert nav["min_clearance_m"]["min"] == min(clearances)
        assert nav["min_clearance_m"]["median"] == np.median(clearances)
        times = [r["nav__time_to_goal_s"] for r in reached]
        assert nav["time_to_goal_s"]["median"] == (np.median(times) if times else None)


def _assert_rate_lines_match_summary(fig, doc: dict, key: str) -> None:
    """navigation_vs_<key>.png's figure ``fig``: a collision and a goal panel, one line per
    ``flight.estimate`` in the method's colour, each point the rate summary.json (``doc``)
    gives its grid point; the legend titled with the other key."""
    collision, goal = [ax for ax in fig.axes if ax.lines]
    assert (collision.get_title(), goal.get_title()) == ("collision rate", "goal rate")
    colors = {m.name: tuple(np.array(m.color_rgb) / 255.0) for m in METHODS}
    for ax, rate in ((collision, "collision_rate"), (goal, "goal_rate")):
        assert sorted(line.get_label() for line in ax.lines) == ["depth_image", "naive"]
        for line in ax.lines:
            assert tuple(line.get_color()) == colors[line.get_label()]
            for x, y in zip(line.get_xdata(), line.get_ydata(), strict=True):
                (point,) = [
                    p
                    for p in doc["points"]
                    if p["values"] == {"flight.estimate": line.get_label(), key: x}
                ]
                assert y == point[rate]
    (legend,) = fig.legends
    assert legend.get_title().get_text() == "flight.estimate"


def test_navigation_columns_rates_and_plot(tmp_path, rng, figures):
    """A navigating sweep's rows carry the flight's outcome (booleans, null where the flight
    diverged); summary.json's collision and goal rates per grid point are the fractions
    counted by hand from results.parquet (read back), over the episodes that did not diverge;
    navigation_vs_<key>.png draws them, one line per value of the other key, in the methods'
    colours."""
    sweep = plan(NAV_SWEEP, "avoid-sweep.toml")
    episodes = _nav_episodes(sweep, rng)
    pq.write_table(results_table(sweep, episodes), tmp_path / "r.parquet")
    table = pq.read_table(tmp_path / "r.parquet")
    assert table.column_names[-7:] == [*NAV_COLUMNS, "simulated_s", "wall_s"]
    for flag in NAV_FLAGS:
        assert table.schema.field(flag).type == pa.bool_()
    got = table.to_pylist()
    (diverged,) = [r for r in got if r["status"] == "diverged"]
    assert diverged["nav__collided"] is None and diverged["nav__reached_goal"] is None
    assert math.isnan(diverged["nav__min_clearance_m"])

    doc = summary.build(sweep, episodes, out_dir="d", point_files=["f"] * 6, complete=True)
    _assert_rates_counted_by_hand(doc, got)
    assert doc["points"][5]["navigation"]["flown"] == 3  # its seed 3 diverged
    json.dumps(doc, allow_nan=False)  # summary.json holds no NaN

    key = "noise.extrinsic_std_deg"
    names = plots.plot_names(sweep)
    assert f"navigation_vs_{key}.png" in names and "navigation_vs_flight.estimate.png" in names
    png = plots.plot_png(sweep, episodes, f"navigation_vs_{key}.png")
    assert png[:4] == b"\x89PNG"
    (fig,) = figures
    _assert_rate_lines_match_summary(fig, doc, key)
    with pytest.raises(ValueError, match="no plot"):
        plots.plot_png(sweep, episodes, "navigation_vs_nothing.png")


def test_a_sweep_of_other_flights_has_no_navigation_columns(rng):
    """A sweep whose flight does not navigate has the columns, summary entries and plots it
    had before navigation existed."""
    sweep = plan(README_SWEEP, "my-sweep.toml")
    assert not sweep.navigates
    episodes = _episodes(sweep, rng)
    table = results_table(sweep, episodes)
    assert table.column_names == ["point", "seed", *map(grid_column, sweep.keys), *row_columns()]
    assert not any(c.startswith("nav__") for c in table.column_names)
    doc = summary.build(sweep, episodes, out_dir="d", point_files=["f"] * 6, complete=True)
    for point in doc["points"]:
        assert not {"goal_rate", "collision_rate", "navigation"} & set(point)
    assert not any(n.startswith("navigation_vs_") for n in plots.plot_names(sweep))


def test_navigating_rows_round_trip_through_the_journal(tmp_path, rng):
    """A navigating episode's row, diverged or not, is journalled and read back as it was
    (``--resume``); a flag of the wrong type sets the entry aside."""
    sweep = plan({**NAV_SWEEP, "seeds": 1, "grid": {"flight.estimate": ["naive"]}}, "s.toml")
    (flown,) = _nav_episodes(sweep, rng, diverged=())
    (diverged,) = _nav_episodes(sweep, rng, diverged=(0, 1))
    store = SweepStore.open(tmp_path, sweep, resume=False)
    store.begin()
    store.add(flown)
    again = SweepStore.open(tmp_path, sweep, resume=True)
    held = again.episodes[0, 1].row
    assert list(held) == list(flown.row)
    assert all(
        held[k] == v or (isinstance(v, float) and math.isnan(v) and math.isnan(held[k]))
        for k, v in flown.row.items()
    )
    store.add(diverged)
    again = SweepStore.open(tmp_path, sweep, resume=True)
    assert again.episodes[0, 1].row["nav__collided"] is None and not again.bad_entries
    entry = json.loads((tmp_path / "episodes" / "p0-s1.json").read_text())
    entry["row"]["nav__collided"] = "no"
    (tmp_path / "episodes" / "p0-s1.json").write_text(json.dumps(entry))
    again = SweepStore.open(tmp_path, sweep, resume=True)
    assert (
        not again.episodes
        and "row.nav__collided: str 'no', expected a boolean" in (again.bad_entries[0])
    )


def test_a_navigating_episodes_row_is_its_runs_outcome(monkeypatch):
    """run_episode of avoid-naive (its flight ends at the contact, seconds in): the row's
    outcome is the run's own navigation record (MuJoCo's contact and clearances); a flight
    that diverges has a row with the outcome unknown."""
    spec = plan({"scenario": "avoid-naive"}, "s.toml").points[0].spec
    outcomes = []
    run = pipeline.run

    def run_and_keep(*args, **kwargs):
        outcomes.append(run(*args, **kwargs))
        return outcomes[-1]

    monkeypatch.setattr(pipeline, "run", run_and_keep)
    row = episode.run_episode(spec, 0, 1).row
    nav = outcomes[0].result.navigation
    assert list(row) == row_columns(navigates=True)
    assert row["nav__collided"] is nav.collided is True
    assert row["nav__reached_goal"] is nav.reached_goal is False
    assert row["nav__min_clearance_m"] == pytest.approx(nav.min_clearance_m, abs=1e-9)
    assert row["nav__min_clearance_m"] < 0.0  # in contact
    assert row["nav__path_length_m"] == pytest.approx(nav.path_length_m, abs=1e-9)
    assert math.isnan(row["nav__time_to_goal_s"])

    def diverge(spec, **kwargs):
        raise SimulationError("t = 0.7000 s: the state exploded")

    monkeypatch.setattr(pipeline, "run", diverge)
    row = episode.run_episode(spec, 0, 1).row
    assert list(row) == row_columns(navigates=True) and row["status"] == "diverged"
    assert row["nav__collided"] is None and row["nav__reached_goal"] is None
    assert math.isnan(row["nav__min_clearance_m"])
