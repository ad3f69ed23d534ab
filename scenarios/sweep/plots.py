"""A sweep's plots as PNG (matplotlib): error against each swept key, and against range.

A swept key is a grid key with more than one value. A curve never pools grid points that
differ in a swept key: each plot has one panel per combination of the swept keys it does not
plot against, titled with their values (one panel when there are none), and the panels share
their axes.

``error_vs_<key>.png``, one per swept key: in each panel, each method's curve against the key
(``key_curves``); a point is one grid point, summarised across its seeds: the median (solid,
filled marker) and 90th percentile (dashed, open marker) of the episodes' own median errors,
as ``summary.json`` gives them per grid point. ``error_vs_range.png``: one panel per grid
point (per combination of every swept key), its estimates binned by range, the same bins in
every panel (bins with fewer than ``MIN_PER_BIN`` estimates are left out). The y axis is
logarithmic where the errors span more than ``LOG_SPAN`` times. The methods are the plan's
(``SweepPlan.methods``: the built-ins, then the user's functions of its ``estimator`` key).
Colours are the methods' own (``vnav.methods``), as in recordings, but a user's function's,
white on a recording's dark background, is one of ``USER_COLORS`` on the white page; the
legend names the colours and the two line styles, drawn with the lines' own styles. A plot
needing more than ``MAX_PANELS`` panels says so instead of drawing them (the numbers are in
``summary.json``).

A sweep of a navigating flight has ``navigation_vs_<key>.png`` too, one per swept key: two
panels, the collision rate and the goal rate (each grid point's fraction of its flown
episodes, as ``summary.json`` gives them), one line per combination of the other swept keys
(``rate_curves``), in the method's colour where that combination is a ``flight.estimate``.
``plot_png`` draws any of the plots by its file name (``plot_names``).
"""

from __future__ import annotations

import io
import math
import textwrap
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np

from scenarios.sweep.plan import SweepPlan, label
from scenarios.sweep.rows import Episode, method_column
from vnav.methods import METHODS

__all__ = [
    "LOG_SPAN",
    "MAX_LINES",
    "MAX_PANELS",
    "MIN_PER_BIN",
    "Curve",
    "RateCurve",
    "error_vs_key_figure",
    "error_vs_key_png",
    "error_vs_range_figure",
    "error_vs_range_png",
    "key_curves",
    "navigation_vs_key_figure",
    "navigation_vs_key_png",
    "plot_names",
    "plot_png",
    "rate_curves",
    "swept_keys",
]

MIN_PER_BIN = 3
LOG_SPAN = 30.0
RANGE_BINS = 12
MAX_PANELS = 16
"""Most panels one plot draws (a 4 x 4 grid): past that the panels are too small to read."""
MAX_LINES = 10
"""Most lines one panel of ``navigation_vs_<key>.png`` draws (one per combination of the other
swept keys): past that their colours cannot be told apart."""
LINE_COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
)
"""Colours of the lines of ``navigation_vs_<key>.png`` where they are not methods (matplotlib's
``tab10``)."""
_ESTIMATE_KEY = "flight.estimate"
RATE_STYLE = {"linestyle": "-", "marker": "o", "markersize": 5.0, "linewidth": 1.5}
USER_COLORS = ("#000000", "#8c564b", "#7f7f7f", "#17becf")
"""Plot colours of a sweep's user functions, in order (black, brown, grey, cyan: none a
built-in's), cycled past four."""

MEDIAN_STYLE = {"linestyle": "-", "marker": "o", "markersize": 4.0, "linewidth": 1.5}
P90_STYLE = {
    "linestyle": "--",
    "marker": "o",
    "markersize": 6.5,  # larger than the median's dot: where the two agree, a ring round it
    "markerfacecolor": "none",  # open: a point whose neighbours are missing still shows
    "linewidth": 1.0,
}
"""The two statistics' line styles; the legend's entries are drawn with these same styles."""
_STYLE_COLOR = "#444444"


@dataclass(frozen=True)
class Curve:
    """One method's error against a swept key, the other swept keys held at ``others``.

    Attributes
    ----------
    method : str
    others : dict
        Each other swept key to its value on this curve (empty if the key is the only one).
    x : list
        The key's values, in the grid's order, shape (n,).
    median_m, p90_m : np.ndarray
        Shape (n,): median and 90th percentile of the per-episode median errors of the grid
        point at each ``x`` (NaN where no episode of it has an estimate of ``method``).
    episodes : np.ndarray
        Shape (n,), int: the episodes behind each point (those with an estimate).
    """

    method: str
    others: dict[str, Any]
    x: list[Any]
    median_m: np.ndarray
    p90_m: np.ndarray
    episodes: np.ndarray


def swept_keys(plan: SweepPlan) -> list[str]:
    """The grid keys with more than one value, in the grid's order."""
    return [k for k in plan.keys if len({repr(p.values[k]) for p in plan.points}) > 1]


def plot_names(plan: SweepPlan) -> dict[str, str | None]:
    """File name of each plot, to the grid key it plots against (None: the range plot);
    ``navigation_vs_<key>.png`` only for a sweep of a navigating flight."""
    names: dict[str, str | None] = {f"error_vs_{key}.png": key for key in swept_keys(plan)}
    names["error_vs_range.png"] = None
    if plan.navigates:
        names |= {f"navigation_vs_{key}.png": key for key in swept_keys(plan)}
    return names


def plot_png(plan: SweepPlan, episodes: list[Episode], name: str) -> bytes:
    """The plot ``name`` (one of ``plot_names(plan)``) as PNG.

    Raises
    ------
    ValueError
        ``name`` is not one of ``plot_names(plan)``.
    """
    names = plot_names(plan)
    if name not in names:
        raise ValueError(f"no plot {name!r} in this sweep; its plots: {list(names)}")
    key = names[name]
    if key is None:
        return error_vs_range_png(plan, episodes)
    if name.startswith("navigation_vs_"):
        return navigation_vs_key_png(plan, episodes, key)
    return error_vs_key_png(plan, episodes, key)


def _groups(plan: SweepPlan, keys: list[str]) -> list[tuple[dict[str, Any], list[int]]]:
    """Each distinct combination of ``keys``' values (grid order) and its grid points."""
    groups: dict[str, tuple[dict[str, Any], list[int]]] = {}
    for p in plan.points:
        combo = {k: p.values[k] for k in keys}
        groups.setdefault(repr(list(combo.values())), (combo, []))[1].append(p.index)
    return list(groups.values())


def _distinct(plan: SweepPlan, key: str) -> list[Any]:
    seen: dict[str, Any] = {}
    for p in plan.points:
        seen.setdefault(repr(p.values[key]), p.values[key])
    return list(seen.values())


def _by_point(plan: SweepPlan, episodes: list[Episode]) -> dict[int, list[Episode]]:
    by_point: dict[int, list[Episode]] = {p.index: [] for p in plan.points}
    for e in episodes:
        by_point[e.point].append(e)
    return by_point


def key_curves(plan: SweepPlan, episodes: list[Episode], key: str) -> list[Curve]:
    """Every method's curve against ``key``, one per combination of the other swept keys.

    Each point summarises one grid point (the grid points with the same values, if a grid
    list repeats a value) across its finished episodes, as ``summary.json`` does: the median
    and 90th percentile of the episodes' finite median errors. Curves come combination by
    combination (grid order), method by method (``vnav.methods`` order).
    """
    others = [k for k in swept_keys(plan) if k != key]
    xs = _distinct(plan, key)
    by_point = _by_point(plan, episodes)
    curves = []
    for combo, points in _groups(plan, others):
        at_x = [
            [e for p in points if repr(plan.points[p].values[key]) == repr(x) for e in by_point[p]]
            for x in xs
        ]
        for m in plan.methods:
            median, p90 = np.full(len(xs), np.nan), np.full(len(xs), np.nan)
            count = np.zeros(len(xs), dtype=np.int64)
            for i, mine in enumerate(at_x):
                errs = [e.row[method_column(m.name, "median")] for e in mine]
                errs = [v for v in errs if math.isfinite(v)]
                count[i] = len(errs)
                if errs:
                    median[i], p90[i] = np.median(errs), np.percentile(errs, 90.0)
            curves.append(Curve(m.name, combo, xs, median, p90, count))
    return curves


# ------------------------------------------------------------------ figures
@dataclass(frozen=True)
class _Layout:
    """Panels in a grid of ``nrows`` x ``ncols``, titles of ``title_lines``; sizes in inches."""

    n: int
    ncols: int
    nrows: int
    panel_w: float
    panel_h: float
    title_lines: int
    gap_w: float = 0.25
    left: float = 0.75
    right: float = 1.9  # the legend
    top: float = 0.45

    @classmethod
    def of(cls, n: int, title_lines: int) -> _Layout:
        ncols = n if n <= 3 else 2 if n == 4 else 3 if n <= 9 else 4
        size = (4.5, 3.1) if n == 1 else (3.0, 2.1)
        return cls(n, ncols, math.ceil(n / ncols), *size, title_lines)

    @property
    def titles_h(self) -> float:
        """Height of a panel's title."""
        return 0.14 * self.title_lines + (0.08 if self.title_lines else 0.0)

    @property
    def gap_h(self) -> float:
        return 0.3 + self.titles_h if self.n > 1 else 0.0

    @property
    def width(self) -> float:
        return self.left + self.ncols * self.panel_w + (self.ncols - 1) * self.gap_w + self.right

    @property
    def note_chars(self) -> int:
        """Characters of the note per line (7.5 pt text)."""
        return int(15 * (self.width - 0.3))


def _figure(
    title: str,
    xlabel: str,
    panel_titles: list[str],
    note: list[str],
    ylabel: str = "position error (m)",
):
    """A figure with one panel per entry of ``panel_titles`` (shared axes; no title where
    it is empty), ``ylabel`` on the left column, a legend column on the right and ``note``
    (wrapped) below."""
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    title_lines = max((t.count("\n") + 1 for t in panel_titles if t), default=0)
    lay = _Layout.of(len(panel_titles), title_lines)
    lines = [line for part in note for line in textwrap.wrap(part, lay.note_chars)]
    bottom = 0.55 + 0.13 * len(lines)
    top = lay.top + lay.titles_h
    height = bottom + lay.nrows * lay.panel_h + (lay.nrows - 1) * lay.gap_h + top
    fig = Figure(figsize=(lay.width, height), dpi=100)
    grid = fig.add_gridspec(
        lay.nrows,
        lay.ncols,
        left=lay.left / lay.width,
        right=1.0 - lay.right / lay.width,
        bottom=bottom / height,
        top=1.0 - top / height,
        wspace=lay.gap_w / lay.panel_w,
        hspace=lay.gap_h / lay.panel_h,
    )
    axes: list = []
    for i, panel_title in enumerate(panel_titles):
        ax = fig.add_subplot(grid[i // lay.ncols, i % lay.ncols])
        if axes:
            ax.sharex(axes[0])
            ax.sharey(axes[0])
        if panel_title:
            ax.set_title(panel_title, fontsize=8)
        ax.grid(True, color="#dddddd", linewidth=0.6)
        ax.tick_params(labelsize=8)
        if i + lay.ncols >= lay.n:  # nothing below it: the bottom of its column
            ax.set_xlabel(xlabel, fontsize=9)
        else:
            ax.tick_params(labelbottom=False)
        if i % lay.ncols == 0:
            ax.set_ylabel(ylabel, fontsize=9)
        else:
            ax.tick_params(labelleft=False)
        axes.append(ax)
    fig.suptitle(title, fontsize=10, x=lay.left / lay.width, y=1.0 - 0.1 / height, ha="left")
    fig.text(0.1 / lay.width, 0.1 / height, "\n".join(lines), fontsize=7.5, color="#555555")
    return fig, axes


def _colors(plan: SweepPlan) -> dict[str, Any]:
    """Each of the plan's methods' plot colour: its own, ``USER_COLORS`` for user functions."""
    colors: dict[str, Any] = {}
    users = 0
    for m in plan.methods:
        if m.images == "user":
            colors[m.name] = USER_COLORS[users % len(USER_COLORS)]
            users += 1
        else:
            colors[m.name] = np.array(m.color_rgb) / 255.0
    return colors


def _finish(fig, axes: list, shown: list[float], plan: SweepPlan) -> None:
    """One scale for every panel, and the legend: the plan's methods by colour, the
    statistics by line style, each entry drawn with the lines' own style."""
    methods, colors = plan.methods, _colors(plan)
    from matplotlib.lines import Line2D

    finite = [v for v in shown if math.isfinite(v) and v > 0.0]
    log = bool(finite) and max(finite) / min(finite) > LOG_SPAN
    for ax in axes:
        if log:
            ax.set_yscale("log")
        elif finite:
            ax.set_ylim(bottom=0.0)
        if not ax.lines:
            ax.text(0.5, 0.5, "no estimate", transform=ax.transAxes, ha="center", fontsize=8)
    drawn = {line.get_label().split()[0] for ax in axes for line in ax.lines}
    handles = [
        Line2D([], [], color=colors[m.name], **MEDIAN_STYLE, label=m.name)
        for m in methods
        if m.name in drawn
    ]
    if handles:
        handles += [
            Line2D([], [], color=_STYLE_COLOR, **MEDIAN_STYLE, label="median"),
            Line2D([], [], color=_STYLE_COLOR, **P90_STYLE, label="90th percentile"),
        ]
        x1 = max(ax.get_position().x1 for ax in axes)
        y1 = max(ax.get_position().y1 for ax in axes)
        fig.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(x1 + 0.1 / fig.get_figwidth(), y1),
            fontsize=8,
            frameon=False,
            handlelength=3.5,  # long enough to show the dashes either side of the marker
        )


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return buffer.getvalue()


def _positions(values: list[Any]) -> tuple[np.ndarray, list[str] | None]:
    """x of each distinct value: the number itself, or 0, 1, ... with labels for others."""
    if all(isinstance(v, Real) and not isinstance(v, bool) for v in values):
        return np.array(values, dtype=np.float64), None
    return np.arange(len(values), dtype=np.float64), [str(v) for v in values]


def _x_axis(ax, x: np.ndarray, labels: list[str] | None) -> None:
    """Ticks at the swept values (``_positions``); values that are not numbers get half a
    step of room either side, so that the labels of panels side by side do not run into each
    other."""
    if labels is not None:
        ax.set_xticks(x, labels)
        ax.set_xlim(-0.5, len(labels) - 0.5)
    elif len(x) <= 12:
        ax.set_xticks(x)


def _per_point(plan: SweepPlan, episodes: list[Episode]) -> str:
    """How many episodes each grid point has: ``5 episodes (its seeds)``, or a range."""
    done = [len(v) for v in _by_point(plan, episodes).values()]
    lo, hi = min(done), max(done)
    if lo == hi:
        return f"{lo} episode{'' if lo == 1 else 's'} (its seeds)"
    return f"{lo} to {hi} episodes (of its {len(plan.seeds)} seeds: the sweep is not complete)"


def _panels_note(plan: SweepPlan, panels: str, episodes: list[Episode]) -> str:
    """``panels`` (what a panel is, or empty), what is fixed, how many episodes in all."""
    swept = set(swept_keys(plan))
    fixed = {k: plan.points[0].values[k] for k in plan.keys if k not in swept}
    parts = [panels] if panels else []
    parts += [f"fixed: {label(fixed)}"] if fixed else []
    parts += [f"{len(episodes)} episodes in {len(plan.points)} grid points"]
    text = "; ".join(parts)
    return text[0].upper() + text[1:] + "."


def _panel_title(values: dict[str, Any]) -> str:
    """A panel's title: ``key = value``, one line per key (none for no key)."""
    return "\n".join(label({k: v}) for k, v in values.items())


def _too_many(title: str, n: int, what: str):
    fig, (ax,) = _figure(title, "", [""], [])
    ax.set_axis_off()
    text = (
        f"{n} {what}: more than {MAX_PANELS} panels. Each grid point's statistics are in "
        "summary.json."
    )
    ax.text(
        0.5,
        0.5,
        "\n".join(textwrap.wrap(text, 50)),
        transform=ax.transAxes,
        ha="center",
        va="center",
        fontsize=9,
    )
    return fig


def error_vs_key_figure(plan: SweepPlan, episodes: list[Episode], key: str):
    """The figure of ``error_vs_key_png`` (a matplotlib ``Figure``): one panel per combination
    of the other swept keys (its title their values), each method's ``key_curves`` in it; a
    line's label is ``<method> median`` or ``<method> p90``."""
    title = f"{plan.scenario}: error against {key}"
    others = [k for k in swept_keys(plan) if k != key]
    curves = key_curves(plan, episodes, key)
    combos = list({repr(list(c.others.values())): c.others for c in curves}.values())
    if len(combos) > MAX_PANELS:
        return _too_many(title, len(combos), f"combinations of {', '.join(others)}")
    note = [
        f"Each point: one grid point's {_per_point(plan, episodes)}: the median (solid, "
        "filled) and 90th percentile (dashed, open) of the episodes' own median errors; an "
        "episode where a method gave no estimate is left out of that method's point.",
        _panels_note(
            plan, f"one panel per value of {', '.join(others)}" if others else "", episodes
        ),
    ]
    fig, axes = _figure(title, key, [_panel_title(c) for c in combos], note)
    x, labels = _positions(_distinct(plan, key))
    colors = _colors(plan)
    shown: list[float] = []
    for ax, combo in zip(axes, combos, strict=True):
        _x_axis(ax, x, labels)
        for c in curves:
            if c.others == combo and np.isfinite(c.median_m).any():
                ax.plot(
                    x,
                    c.median_m,
                    color=colors[c.method],
                    label=f"{c.method} median",
                    **MEDIAN_STYLE,
                )
                ax.plot(x, c.p90_m, color=colors[c.method], label=f"{c.method} p90", **P90_STYLE)
                shown += [*c.median_m[np.isfinite(c.median_m)], *c.p90_m[np.isfinite(c.p90_m)]]
    _finish(fig, axes, shown, plan)
    return fig


def error_vs_key_png(plan: SweepPlan, episodes: list[Episode], key: str) -> bytes:
    """``error_vs_key_figure`` as PNG."""
    return _png(error_vs_key_figure(plan, episodes, key))


def error_vs_range_figure(plan: SweepPlan, episodes: list[Episode]):
    """Every estimate's error against its range, binned, per method: one panel per
    combination of the swept keys (a grid point, its seeds' estimates pooled), the same range
    bins in each; a line's label is ``<method> median`` or ``<method> p90``."""
    title = f"{plan.scenario}: error against range"
    swept = swept_keys(plan)
    groups = _groups(plan, swept)
    if len(groups) > MAX_PANELS:
        return _too_many(title, len(groups), "grid points")
    by_point = _by_point(plan, episodes)
    ranges = np.array([r for e in episodes for r in e.estimates["range_m"]], dtype=np.float64)
    note = [
        f"{ranges.size} estimates, of {len(episodes)} episodes, in {RANGE_BINS} range bins "
        f"(the same in every panel; bins with fewer than {MIN_PER_BIN} estimates left out): "
        "the median (solid, filled) and 90th percentile (dashed, open) of the errors in each "
        "bin.",
        _panels_note(
            plan, f"one panel per grid point ({', '.join(swept)})" if swept else "", episodes
        ),
    ]
    fig, axes = _figure(title, "range (m)", [_panel_title(c) for c, _ in groups], note)
    shown: list[float] = []
    if ranges.size:
        edges = np.linspace(ranges.min(), ranges.max() + 1e-9, RANGE_BINS + 1)
        centres = 0.5 * (edges[:-1] + edges[1:])
        colors = _colors(plan)
        for ax, (_, points) in zip(axes, groups, strict=True):
            mine = [e for p in points for e in by_point[p]]
            method = np.array([m for e in mine for m in e.estimates["method"]], dtype=str)
            r = np.array([v for e in mine for v in e.estimates["range_m"]], dtype=np.float64)
            err = np.array([v for e in mine for v in e.estimates["error_m"]], dtype=np.float64)
            for m in plan.methods:
                median, p90 = _binned(r[method == m.name], err[method == m.name], edges)
                if np.isfinite(median).any():
                    color = colors[m.name]
                    ax.plot(centres, median, color=color, label=f"{m.name} median", **MEDIAN_STYLE)
                    ax.plot(centres, p90, color=color, label=f"{m.name} p90", **P90_STYLE)
                    shown += [*median[np.isfinite(median)], *p90[np.isfinite(p90)]]
    _finish(fig, axes, shown, plan)
    return fig


def error_vs_range_png(plan: SweepPlan, episodes: list[Episode]) -> bytes:
    """``error_vs_range_figure`` as PNG."""
    return _png(error_vs_range_figure(plan, episodes))


def _binned(r: np.ndarray, e: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median and 90th percentile of ``e`` in each bin of ``r`` (NaN for sparse bins)."""
    which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, len(edges) - 2)
    median, p90 = np.full(len(edges) - 1, np.nan), np.full(len(edges) - 1, np.nan)
    for b in range(len(edges) - 1):
        sel = e[which == b]
        if sel.size >= MIN_PER_BIN:
            median[b], p90[b] = np.median(sel), np.percentile(sel, 90.0)
    return median, p90


# ------------------------------------------------------------------ navigation
@dataclass(frozen=True)
class RateCurve:
    """A navigating flight's outcome against a swept key, the other swept keys held at
    ``others``.

    Attributes
    ----------
    others : dict
        Each other swept key to its value on this curve (empty if the key is the only one).
    x : list
        The key's values, in the grid's order, shape (n,).
    collision_rate, goal_rate : np.ndarray
        Shape (n,): the fraction of the flown episodes at each ``x`` that touched a cone, and
        that reached the goal (NaN where none flew).
    flown : np.ndarray
        Shape (n,), int: the flown episodes behind each point (those that did not diverge).
    """

    others: dict[str, Any]
    x: list[Any]
    collision_rate: np.ndarray
    goal_rate: np.ndarray
    flown: np.ndarray


def rate_curves(plan: SweepPlan, episodes: list[Episode], key: str) -> list[RateCurve]:
    """The collision and goal rates against ``key``, one curve per combination of the other
    swept keys (grid order); each point pools the grid points with its values (one, unless a
    grid list repeats a value), as ``summary.json``'s ``collision_rate`` and ``goal_rate``
    count them: over the episodes whose flight did not diverge. Episodes of a grid point that
    does not navigate count for nothing."""
    others = [k for k in swept_keys(plan) if k != key]
    xs = _distinct(plan, key)
    by_point = _by_point(plan, episodes)
    curves = []
    for combo, points in _groups(plan, others):
        collided, reached = np.full(len(xs), np.nan), np.full(len(xs), np.nan)
        flown = np.zeros(len(xs), dtype=np.int64)
        for i, x in enumerate(xs):
            mine = [
                e
                for p in points
                if repr(plan.points[p].values[key]) == repr(x)
                for e in by_point[p]
                if e.row.get("nav__collided") is not None
            ]
            flown[i] = len(mine)
            if mine:
                collided[i] = sum(bool(e.row["nav__collided"]) for e in mine) / len(mine)
                reached[i] = sum(bool(e.row["nav__reached_goal"]) for e in mine) / len(mine)
        curves.append(RateCurve(combo, xs, collided, reached, flown))
    return curves


def _rate_colors(curves: list[RateCurve]) -> list[Any]:
    """Each curve's colour: its method's where the curves differ in ``flight.estimate`` only
    (the colour it has everywhere else), else ``LINE_COLORS`` in order."""
    own = {m.name: np.array(m.color_rgb) / 255.0 for m in METHODS}
    if all(list(c.others) == [_ESTIMATE_KEY] and c.others[_ESTIMATE_KEY] in own for c in curves):
        return [own[c.others[_ESTIMATE_KEY]] for c in curves]
    return [LINE_COLORS[i % len(LINE_COLORS)] for i in range(len(curves))]


def _too_many_lines_figure(title: str, n_curves: int, others: list[str]):
    """The figure drawn instead of more than ``MAX_LINES`` lines: one panel saying how many
    combinations of the ``others`` keys there are, and that summary.json holds each grid
    point's rates.

    Parameters
    ----------
    title : str
        The figure's title.
    n_curves : int
        How many lines the plot would have drawn (combinations of the other swept keys).
    others : list of str
        The other swept keys.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, (ax,) = _figure(title, "", [""], [])
    ax.set_axis_off()
    text = (
        f"{n_curves} combinations of {', '.join(others)}: more than {MAX_LINES} lines. "
        "Each grid point's rates are in summary.json."
    )
    ax.text(
        0.5,
        0.5,
        "\n".join(textwrap.wrap(text, 50)),
        transform=ax.transAxes,
        ha="center",
        va="center",
        fontsize=9,
    )
    return fig


def _navigation_note(
    plan: SweepPlan, episodes: list[Episode], curves: list[RateCurve], others: list[str]
) -> list[str]:
    """The caption of ``navigation_vs_key_figure``: what each point counts (the range of the
    grid points' flown episodes) and what the panels hold (``_panels_note``).

    Returns
    -------
    list of str
        The caption's paragraphs.
    """
    flown = [int(n) for c in curves for n in c.flown]
    counts = f"{min(flown)}" if min(flown) == max(flown) else f"{min(flown)} to {max(flown)}"
    return [
        f"Each point: of one grid point's {counts} flown episodes (its seeds, less any whose "
        "flight diverged), the fraction that touched a cone (MuJoCo's contact), and the "
        "fraction that came within the goal radius of the goal.",
        _panels_note(
            plan, f"one line per value of {', '.join(others)}" if others else "", episodes
        ),
    ]


def _other_keys_legend(fig, axes, others: list[str]) -> None:
    """The legend of the lines (one per combination of the ``others`` keys, titled with
    their names), right of the panels, aligned with their top.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    axes : list of matplotlib.axes.Axes
        The panels; the first one's lines are the legend's entries.
    others : list of str
        The other swept keys.
    """
    x1 = max(ax.get_position().x1 for ax in axes)
    y1 = max(ax.get_position().y1 for ax in axes)
    fig.legend(
        handles=axes[0].lines,
        loc="upper left",
        bbox_to_anchor=(x1 + 0.1 / fig.get_figwidth(), y1),
        fontsize=8,
        title=", ".join(others),
        title_fontsize=8,
        alignment="left",
        frameon=False,
    )


def navigation_vs_key_figure(plan: SweepPlan, episodes: list[Episode], key: str):
    """The figure of ``navigation_vs_key_png`` (a matplotlib ``Figure``): two panels, the
    collision rate and the goal rate against ``key``, one line per ``rate_curves`` curve,
    labelled with the other swept keys' values (``-`` where there are none; the legend's
    title names the keys)."""
    title = f"{plan.scenario}: collisions and goals against {key}"
    others = [k for k in swept_keys(plan) if k != key]
    curves = rate_curves(plan, episodes, key)
    if len(curves) > MAX_LINES:
        return _too_many_lines_figure(title, len(curves), others)
    note = _navigation_note(plan, episodes, curves, others)
    fig, axes = _figure(
        title, key, ["collision rate", "goal rate"], note, ylabel="fraction of episodes"
    )
    x, labels = _positions(_distinct(plan, key))
    for ax, rate in zip(axes, ("collision_rate", "goal_rate"), strict=True):
        _x_axis(ax, x, labels)
        ax.set_ylim(-0.05, 1.05)
        for c, color in zip(curves, _rate_colors(curves), strict=True):
            shown = ", ".join(_show_value(v) for v in c.others.values()) or "-"
            ax.plot(x, getattr(c, rate), color=color, label=shown, **RATE_STYLE)
        if not any(np.isfinite(getattr(c, rate)).any() for c in curves):
            ax.text(0.5, 0.5, "no flown episode", transform=ax.transAxes, ha="center", fontsize=8)
    if others:
        _other_keys_legend(fig, axes, others)
    return fig


def _show_value(value: Any) -> str:
    """A grid value in a legend: a string bare, anything else as ``label`` writes it."""
    return value if isinstance(value, str) else label({"k": value}).removeprefix("k = ")


def navigation_vs_key_png(plan: SweepPlan, episodes: list[Episode], key: str) -> bytes:
    """``navigation_vs_key_figure`` as PNG."""
    return _png(navigation_vs_key_figure(plan, episodes, key))
