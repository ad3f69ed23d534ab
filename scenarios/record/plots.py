"""Static plots as PNG (matplotlib): error against range, the depth image's colour scale and
the legend of the 3D views' colours.

Rerun's time-series views plot against time only; "how does each method's error grow with
range" needs range on the x axis, so it is drawn here once per run and logged as an image.
matplotlib is imported on first use (it costs about half a second), with the Agg backend so
no display is needed. The depth scale and the legend depend on a few values only: a process
that writes several recordings (``vnav-demo run --all``) draws each once (about 50 and 80 ms)
and hands out the same bytes after.
"""

from __future__ import annotations

import functools
import io
from typing import TYPE_CHECKING

import numpy as np

from scenarios.run.records import RunResult
from vnav.methods import CONTRACT_DOMAIN, Method, active_methods

if TYPE_CHECKING:  # the viewer imports Rerun; a plot needs only the entries' fields
    from matplotlib.figure import Figure

    from scenarios.record.viewer import LegendEntry

__all__ = ["depth_scale_png", "error_against_range_png", "legend_png"]

_BACKGROUND = "#1b1b1f"
_FOREGROUND = "#d0d0d0"


def _figure(width_in: float, height_in: float):
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    fig = Figure(figsize=(width_in, height_in), dpi=100, facecolor=_BACKGROUND)
    return fig


def _style(ax) -> None:
    ax.set_facecolor(_BACKGROUND)
    ax.tick_params(colors=_FOREGROUND, labelsize=8)
    for spine in ax.spines.values():
        spine.set_color("#555555")
    ax.grid(True, color="#3a3a3a", linewidth=0.6)
    ax.xaxis.label.set_color(_FOREGROUND)
    ax.yaxis.label.set_color(_FOREGROUND)
    ax.title.set_color(_FOREGROUND)


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", facecolor=fig.get_facecolor())
    return buffer.getvalue()


RECOVERED_MOUNT_COLOR = (0.0, 225 / 255, 225 / 255)
"""Cyan, as the recovered mount is drawn in the recording (``viewer.RECOVERED_MOUNT_COLOR``)."""


def error_against_range_png(result: RunResult, recovered: RunResult | None = None) -> bytes:
    """One panel per method: each matched detection's error against its range, own y scale.

    Filled dots are detections inside the accuracy contract's domain, hollow ones outside it;
    the grey line is the method's bound ``max(floor, fraction * range)`` and the shaded band
    the contract's range domain. ``recovered``, the same run estimated again with the mount
    calibration recovered (``RunResult.with_recovered_mount``), adds its errors as cyan
    crosses.
    """
    methods = active_methods()  # a user's function too (vnav.plugin)
    fig, axes = _range_figure(len(methods))
    for ax, m in zip(axes, methods, strict=False):
        _range_panel(ax, m, result, recovered)
    title = "error against range (filled: inside the contract's domain; grey: the bound)"
    if recovered is not None:
        title = title[:-1] + "; cyan crosses: with the recovered mount)"
    fig.suptitle(
        title,
        color=_FOREGROUND,
        fontsize=9.5,
        y=1.0 - 0.12 / fig.get_figheight(),
        va="top",
    )
    return _png(fig)


_range_figures: dict[int, tuple[Figure, np.ndarray]] = {}
"""``error_against_range_png``'s figure and panels for each number of methods, drawn again
for each run: a new figure costs a third of the plot (its axes' ticks, made anew)."""


def _range_figure(n_methods: int) -> tuple[Figure, np.ndarray]:
    """The figure of ``n_methods`` panels, two a row, each empty of data (a new one, or this
    process's last one, cleared of the previous run's artists: the same pixels either way,
    ``tests/test_recording_views.py``)."""
    if n_methods in _range_figures:
        fig, axes = _range_figures[n_methods]
        for ax in axes[:n_methods]:
            for artist in (*ax.collections, *ax.lines, *ax.patches, *ax.texts):
                artist.remove()
            ax.relim()  # no data: the next run's artists set the limits as on a new figure
            ax.set_autoscale_on(True)
        return fig, axes
    columns = 2
    rows = -(-n_methods // columns)
    width_in, height_in = 7.2, 2.8 * rows
    fig = _figure(width_in, height_in)
    # Fixed margins in inches, not tight_layout: measuring every label costs an extra draw,
    # a third of the plot's time, paid by every run.
    margins = {
        "left": 0.7 / width_in,
        "right": 1.0 - 0.45 / width_in,
        "bottom": 0.5 / height_in,
        "top": 1.0 - 0.62 / height_in,
        "wspace": 0.45,
        "hspace": 0.5,
    }
    axes = fig.subplots(rows, columns, gridspec_kw=margins).ravel()
    for ax in axes[n_methods:]:
        ax.set_visible(False)
    for ax in axes[:n_methods]:
        _style(ax)
    _range_figures[n_methods] = fig, axes
    return fig, axes


def _range_panel(ax, m: Method, result: RunResult, recovered: RunResult | None) -> None:
    """``error_against_range_png``'s panel of method ``m``, on an empty styled panel."""
    color = np.array(m.color_rgb) / 255.0
    inside_r = result.ranges_for(m.name, contract_only=True)
    inside_e = result.errors(m.name, contract_only=True)
    all_r, all_e = result.ranges_for(m.name), result.errors(m.name)
    ax.scatter(all_r, all_e, s=10, facecolors="none", edgecolors=[color], linewidths=0.7)
    ax.scatter(inside_r, inside_e, s=10, color=[color])
    if recovered is not None:
        ax.scatter(
            recovered.ranges_for(m.name),
            recovered.errors(m.name),
            s=9,
            marker="x",
            color=[RECOVERED_MOUNT_COLOR],
            linewidths=0.6,
        )
    domain = (CONTRACT_DOMAIN.min_range_m, CONTRACT_DOMAIN.max_range_m)
    ax.axvspan(*domain, color="#ffffff", alpha=0.04, linewidth=0)
    top_r = max(float(all_r.max()) if all_r.size else 0.0, 1.0) * 1.1
    if m.bound is not None:
        r = np.linspace(0.0, top_r, 200)
        ax.plot(r, m.bound.allowed_m(r), color="#9a9a9a", linewidth=1.0)
    ax.set_xlim(0.0, top_r)
    ax.set_ylim(bottom=0.0)
    promise = m.bound.text if m.bound is not None else "never checked"
    ax.set_title(f"{m.name}: {promise}", fontsize=8.5)
    ax.set_xlabel("range (m)", fontsize=8)
    ax.set_ylabel("error (m)", fontsize=8)
    if not all_e.size:
        ax.text(
            0.5,
            0.5,
            "no matched estimate",
            transform=ax.transAxes,
            ha="center",
            color=_FOREGROUND,
            fontsize=9,
        )


@functools.lru_cache(maxsize=32)
def depth_scale_png(depth_max_m: float, colormap: str = "viridis") -> bytes:
    """A vertical colour bar from 0 (bottom) to ``depth_max_m`` metres (top) (drawn once per
    process for each pair of arguments)."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    fig = _figure(0.9, 4.0)
    ax = fig.add_axes((0.15, 0.05, 0.25, 0.9))
    bar = fig.colorbar(ScalarMappable(Normalize(0.0, depth_max_m), colormaps[colormap]), cax=ax)
    bar.set_label("planar depth z (m)", color=_FOREGROUND, fontsize=8)
    bar.ax.tick_params(colors=_FOREGROUND, labelsize=8)
    return _png(fig)


LEGEND_SIZE_IN = (8.4, 0.42)
"""The legend strip, inches at 100 dpi: as wide as the viewer's two 3D views side by side in
a 1400-point window, two lines high."""


def legend_png(rows: list[list[LegendEntry]], note: str, dpi: float = 200.0) -> bytes:
    """A strip naming each colour of the 3D views: one line per row of entries, each a dot or
    a line of its colour before its text, and ``note`` closing the last line; drawn at
    ``dpi`` so that the viewer's scaling keeps the text sharp (once per process for each
    legend)."""
    key = tuple(tuple((e.text, tuple(e.color_rgb), e.mark) for e in row) for row in rows)
    return _legend_png(key, note, float(dpi))


@functools.lru_cache(maxsize=32)
def _legend_png(
    rows: tuple[tuple[tuple[str, tuple[int, ...], str], ...], ...], note: str, dpi: float
) -> bytes:
    """``legend_png`` of rows of ``(text, color_rgb, mark)``."""
    from matplotlib.lines import Line2D

    fig = _figure(*LEGEND_SIZE_IN)
    fig.set_dpi(dpi)
    for i, row in enumerate(rows):
        handles = [
            Line2D(
                [],
                [],
                color=np.array(color_rgb) / 255.0,
                marker="o" if mark == "dot" else None,
                markersize=5.5,
                linestyle="-" if mark == "line" else "none",
                linewidth=2.0,
            )
            for _, color_rgb, mark in row
        ]
        labels = [text for text, _, _ in row]
        if i == len(rows) - 1:
            handles.append(Line2D([], [], linestyle="none"))
            labels.append(note)
        fig.legend(
            handles,
            labels,
            loc="upper left",
            bbox_to_anchor=(0.0, 1.0 - i / len(rows)),
            ncol=len(labels),
            frameon=False,
            fontsize=8.0,
            labelcolor=_FOREGROUND,
            handlelength=1.3,
            handletextpad=0.4,
            columnspacing=1.1,
            borderaxespad=0.1,
        )
    return _png(fig)
