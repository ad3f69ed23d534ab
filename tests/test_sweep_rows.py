"""A diverged episode is a row like any other: NaN errors, zero counts, ranked worst, plotted
around; the tables and the summary take it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from scenarios import pipeline
from scenarios.sweep import episode, plots, summary
from scenarios.sweep.plan import plan
from scenarios.sweep.rows import row_columns
from scenarios.sweep.store import estimates_table, results_table
from sim.world import SimulationError
from vnav.methods import METHOD_NAMES


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
    assert all(diverged.row[f"{m}.count"] == 0 for m in METHOD_NAMES)
    assert math.isnan(diverged.row["depth_image.median_m"])
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
    empty = {"method": np.array([], str), "range_m": np.array([]), "error_m": np.array([])}
    assert plots.error_vs_range_png(sweep, empty)[:4] == b"\x89PNG"
