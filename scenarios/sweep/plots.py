"""A sweep's plots as PNG (matplotlib): error against each swept key, and against range.

``error_vs_<key>.png``, one per grid key with more than one value: each method's per-episode
median error, summarised at each value of the key across seeds and the other keys' values
(solid: median; dashed: 90th percentile). ``error_vs_range.png``: every estimate of the sweep
binned by range (solid: median; dashed: 90th percentile; bins with fewer than
``MIN_PER_BIN`` estimates are left out). The y axis is logarithmic where the errors span more
than ``LOG_SPAN`` times. Colours are the methods' own (``vnav.methods``), as in recordings.
"""

from __future__ import annotations

import io
import math
import textwrap
from numbers import Real
from typing import Any

import numpy as np

from scenarios.sweep.plan import SweepPlan
from scenarios.sweep.rows import Episode, method_column
from vnav.methods import METHODS

__all__ = ["LOG_SPAN", "MIN_PER_BIN", "error_vs_key_png", "error_vs_range_png", "plot_names"]

MIN_PER_BIN = 3
LOG_SPAN = 30.0
RANGE_BINS = 12


def plot_names(plan: SweepPlan) -> dict[str, str | None]:
    """File name of each plot, keyed by grid key (None: the range plot)."""
    names: dict[str, str | None] = {}
    for key in plan.keys:
        if len({repr(p.values[key]) for p in plan.points}) > 1:
            names[f"error_vs_{key}.png"] = key
    names["error_vs_range.png"] = None
    return names


def _figure(title: str, xlabel: str):
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    fig = Figure(figsize=(7.5, 4.4), dpi=100)
    ax = fig.add_axes((0.1, 0.22, 0.6, 0.7))
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(xlabel, fontsize=9)
    ax.set_ylabel("position error (m)", fontsize=9)
    ax.grid(True, color="#dddddd", linewidth=0.6)
    return fig, ax


def _finish(fig, ax, lows: list[float], note: str) -> bytes:
    finite = [v for v in lows if math.isfinite(v) and v > 0.0]
    if finite and max(finite) / min(finite) > LOG_SPAN:
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0.0)
    if ax.lines:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    else:
        ax.text(0.5, 0.5, "no estimate", transform=ax.transAxes, ha="center")
    fig.text(0.1, 0.02, "\n".join(textwrap.wrap(note, 110)), fontsize=7.5, color="#555555")
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return buffer.getvalue()


def _positions(values: list[Any]) -> tuple[np.ndarray, list[str] | None]:
    """x of each distinct value: the number itself, or 0, 1, ... with labels for others."""
    if all(isinstance(v, Real) and not isinstance(v, bool) for v in values):
        return np.array(values, dtype=np.float64), None
    return np.arange(len(values), dtype=np.float64), [str(v) for v in values]


def error_vs_key_png(plan: SweepPlan, episodes: list[Episode], key: str) -> bytes:
    """The per-episode median error of each method against grid key ``key``."""
    distinct: list[Any] = []
    for p in plan.points:
        if p.values[key] not in distinct:
            distinct.append(p.values[key])
    x, labels = _positions(distinct)
    fig, ax = _figure(f"{plan.scenario}: error against {key}", key)
    if labels is not None:
        ax.set_xticks(x, labels, fontsize=8)
    elif len(x) <= 12:
        ax.set_xticks(x)
    shown: list[float] = []
    for m in METHODS:
        median, p90 = np.full(len(distinct), np.nan), np.full(len(distinct), np.nan)
        for i, value in enumerate(distinct):
            errs = [
                e.row[method_column(m.name, "median")]
                for e in episodes
                if plan.points[e.point].values[key] == value
            ]
            errs = [v for v in errs if math.isfinite(v)]
            if errs:
                median[i], p90[i] = np.median(errs), np.percentile(errs, 90.0)
        if np.isfinite(median).any():
            color = np.array(m.color_rgb) / 255.0
            ax.plot(x, median, "-o", color=color, markersize=4, label=f"{m.name} median")
            # A marker too: a single value draws no dashed line.
            ax.plot(x, p90, "--_", color=color, linewidth=1.0, markersize=9, label=f"{m.name} p90")
            shown += [*median[np.isfinite(median)], *p90[np.isfinite(p90)]]
    note = (
        f"each episode's median error; at each value of {key}: median (solid) and 90th "
        f"percentile (dashed) across {len(episodes)} episodes' seeds and other grid values"
    )
    return _finish(fig, ax, shown, note)


def error_vs_range_png(plan: SweepPlan, estimates: dict[str, np.ndarray]) -> bytes:
    """Every estimate's error against its range, binned, per method.

    ``estimates`` holds ``method`` (str array), ``range_m`` and ``error_m`` (float arrays).
    """
    fig, ax = _figure(f"{plan.scenario}: error against range", "range (m)")
    ranges = estimates["range_m"]
    shown: list[float] = []
    if ranges.size:
        edges = np.linspace(ranges.min(), ranges.max() + 1e-9, RANGE_BINS + 1)
        centres = 0.5 * (edges[:-1] + edges[1:])
        for m in METHODS:
            mine = estimates["method"] == m.name
            median, p90 = _binned(ranges[mine], estimates["error_m"][mine], edges)
            if np.isfinite(median).any():
                color = np.array(m.color_rgb) / 255.0
                ax.plot(centres, median, "-o", color=color, markersize=4, label=f"{m.name} median")
                ax.plot(centres, p90, "--", color=color, linewidth=1.0, label=f"{m.name} p90")
                shown += [*median[np.isfinite(median)], *p90[np.isfinite(p90)]]
    note = (
        f"{ranges.size} estimates in {RANGE_BINS} range bins (bins with fewer than "
        f"{MIN_PER_BIN} left out): median (solid) and 90th percentile (dashed)"
    )
    return _finish(fig, ax, shown, note)


def _binned(r: np.ndarray, e: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median and 90th percentile of ``e`` in each bin of ``r`` (NaN for sparse bins)."""
    which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, len(edges) - 2)
    median, p90 = np.full(len(edges) - 1, np.nan), np.full(len(edges) - 1, np.nan)
    for b in range(len(edges) - 1):
        sel = e[which == b]
        if sel.size >= MIN_PER_BIN:
            median[b], p90[b] = np.median(sel), np.percentile(sel, 90.0)
    return median, p90
