"""Planning a drone's way around the mapped cones, and the reference that flies it.

Everything here is in the world's horizontal plane (x east, y north, metres; the drone keeps
its altitude; docs/CONVENTIONS.md, "Navigation"). ``clearance_m`` is the distance to keep
between the drone's centre and each mapped cone's vertical axis: each obstacle is a keep-out
disc of that radius about its centre (``vnav.obstacle_map``; choose it above the cone's
footprint, ``vnav.obstacle_map.footprint_radius_m``, plus the drone's radius and the
estimates' error).

The shortest path among discs
-----------------------------
A shortest path from a point to a point that avoids the interiors of discs is taut: it is made
of straight segments tangent to the discs it touches, and arcs of their boundaries between
those tangent points; it never touches a disc elsewhere, nor a corner where two discs overlap
(a taut string there would cut across the notch). So it runs along the *tangent visibility
graph*: the start and the goal, the tangent points of the segments from each of them to each
disc and of the four common tangents of each pair of discs (two outer; two inner when the discs
are apart), kept when no disc's interior meets them, joined along each circle by the arcs
between consecutive tangent points that no other disc's interior meets. This is the visibility
graph of de Berg, Cheong, van Kreveld and Overmars, "Computational Geometry: Algorithms and
Applications", chapter 15, with discs for polygons (Chen and Wang, "Computing shortest paths
among curved obstacles in the plane", SoCG 2013); with overlapping discs the union's boundary
keeps only the arcs outside every other disc, and the outer tangents bridge the notches.
Dijkstra's algorithm (A* with the straight-line distance to the goal, which never
overestimates) finds the shortest route in that graph. When the straight line from start to
goal is clear it is the answer and no graph is built.

Arcs as polylines
-----------------
The path is returned as waypoints joined by straight segments. A chord of an arc would cut
inside the clearance circle, so each arc is replaced by the polyline *circumscribing* it: the
tangent lines to the circle at the arc's ends and at angles at most ``max_arc_step_deg`` apart,
joined at their intersections. Every segment of it touches the circle or runs outside it, so
the drone never comes closer than ``clearance_m`` to that cone's axis; the corners stand out by
at most ``clearance_m (1 / cos(step / 2) - 1)`` (0.1 % of the clearance at 5 deg), and the
polyline is longer than the arc by a factor of at most ``tan(step / 2) / (step / 2)`` (1.0006
at 5 deg). A corner could poke into a neighbouring disc that (nearly) touches the arc: the
tangent angles also include the direction of each neighbour within ``2 clearance_m`` plus the
bulge, so the tangent line there keeps the neighbour's whole distance. The finished path is
checked against every disc, and an arc that still failed would be split finer until it
cleared (down to 1/256 of the step); no layout tried needed it.

Start too close
---------------
A drone that is already inside a keep-out disc (noise, or a cone first seen close) is not an
error: the path first leaves it along the shortest way out, to the nearest point outside every
disc (straight out along the radius of the disc it is in, or to the corner where two overlapping
discs' circles cross when that is nearer), then plans from there. That first segment is the one
part of the path inside a disc.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate

__all__ = ["NoPathError", "PathReference", "follow_path", "path_length_m", "plan_path"]

_REL_EPS = 1e-9
"""Distances within this fraction of the clearance count as on the circle (rounding)."""

_MAX_REFINE = 8
"""Arc refinements (each halving the step) tried before a corner is left as it is."""

_TWO_PI = 2.0 * math.pi


class NoPathError(ValueError):
    """No path from the start to the goal keeps the clearance: overlapping keep-out discs
    enclose one of them."""


def _positive(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def _points(x: ArrayLike, name: str) -> np.ndarray:
    a = _validate.as_float(x, name)
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"{name} must have shape (M, 2); got shape {a.shape}")
    return _validate.check_finite(a, name)


def _unit(angle_rad: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle_rad), np.sin(angle_rad)], axis=-1)


def _clear(a: np.ndarray, b: np.ndarray, centres: np.ndarray, radius_m: float) -> np.ndarray:
    """Which segments ``a[k] -> b[k]`` (shape (E, 2) each) keep at least ``radius_m`` from
    every centre (shape (M, 2)): (E,) bool. Components apart: the arrays are small and many
    calls run per plan, so numpy's per-call overhead is what counts."""
    abx, aby = (b[:, 0] - a[:, 0])[:, None], (b[:, 1] - a[:, 1])[:, None]
    acx = centres[None, :, 0] - a[:, 0, None]
    acy = centres[None, :, 1] - a[:, 1, None]
    # A segment of no length has its only point at a: t = 0.
    t = np.clip((acx * abx + acy * aby) / np.maximum(abx * abx + aby * aby, 1e-300), 0.0, 1.0)
    gx, gy = acx - t * abx, acy - t * aby
    return (gx * gx + gy * gy >= radius_m * radius_m).all(axis=1)


def _in_ccw(x: np.ndarray | float, start: np.ndarray | float, span: np.ndarray | float):
    """Whether angle ``x`` lies on the counter-clockwise arc from ``start`` of ``span``."""
    return np.mod(np.subtract(x, start), _TWO_PI) <= span


def _distinct(centres: np.ndarray, eps_m: float) -> np.ndarray:
    """The centres with exact duplicates (within ``eps_m`` of an earlier one) dropped: one disc
    is enough."""
    gap = centres[None, :, :] - centres[:, None, :]  # [i, j]: from centre i to centre j
    close = np.einsum("ijd,ijd->ij", gap, gap) <= eps_m * eps_m
    return centres[~np.tril(close, -1).any(axis=1)]


def _escape(start: np.ndarray, centres: np.ndarray, r: float, eps_m: float) -> np.ndarray:
    """The nearest point to ``start`` outside every disc: on the union's boundary, so either
    ``start`` pushed out along a circle's radius or a point where two circles cross."""
    d = start - centres
    norm = np.hypot(d[:, 0], d[:, 1])
    direction = np.where(norm[:, None] > 0.0, d / np.maximum(norm, 1e-300)[:, None], [1.0, 0.0])
    candidates = [centres + r * direction]
    i, j = np.triu_indices(len(centres), 1)
    gap = centres[j] - centres[i]
    dist = np.hypot(gap[:, 0], gap[:, 1])
    crossing = dist < 2.0 * r
    if crossing.any():
        i, j, gap, dist = i[crossing], j[crossing], gap[crossing], dist[crossing]
        mid = 0.5 * (centres[i] + centres[j])
        half = np.sqrt(r * r - 0.25 * dist * dist)[:, None]
        perp = np.stack([-gap[:, 1], gap[:, 0]], axis=1) / dist[:, None]
        candidates += [mid + half * perp, mid - half * perp]
    points = np.vstack(candidates)
    to_centres = points[:, None, :] - centres[None, :, :]
    outside = (np.einsum("pmd,pmd->pm", to_centres, to_centres) >= (r - eps_m) ** 2).all(axis=1)
    if not outside.any():
        raise NoPathError("the start is inside the keep-out discs and no way out was found")
    points = points[outside]
    return points[np.argmin(np.hypot(*(points - start).T))]


@dataclass
class _Graph:
    """The tangent visibility graph, as flat lists the search reads element by element.

    Node 0 is the start, node 1 the goal, the others tangent points: ``circle`` (-1 for start
    and goal) and ``angle`` (radians) say where. Segments: node ``u``'s neighbours are
    ``seg_to[seg_from[u]:seg_from[u + 1]]`` at lengths ``seg_m``. Arcs: ``ccw_to[u]`` is the
    next tangent node counter-clockwise on u's circle, ``ccw_rad[u]`` the arc's angle, -1 when
    that arc enters another disc; ``cw_to[u]`` is the one before (its arc is ``cw_to[u]``'s
    counter-clockwise one)."""

    xy: np.ndarray
    circle: list[int]
    angle: list[float]
    seg_from: list[int]
    seg_to: list[int]
    seg_m: list[float]
    ccw_to: list[int]
    ccw_rad: list[float]
    cw_to: list[int]


def _candidate_segments(
    start: np.ndarray, goal: np.ndarray, centres: np.ndarray, r: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every tangent segment: ``(end_a_circle, end_a_angle, end_b_circle, end_b_angle)``, each
    (E,); circle -1 is the start, -2 the goal (angle unused)."""
    m = len(centres)
    ca, aa, cb, ab = [], [], [], []
    for code, point in ((-1, start), (-2, goal)):
        d = point - centres
        alpha = np.arctan2(d[:, 1], d[:, 0])
        beta = np.arccos(np.clip(r / np.hypot(d[:, 0], d[:, 1]), -1.0, 1.0))
        for sign in (1.0, -1.0):
            ca.append(np.full(m, code))
            aa.append(np.zeros(m))
            cb.append(np.arange(m))
            ab.append(alpha + sign * beta)
    i, j = np.triu_indices(m, 1)
    gap = centres[j] - centres[i]
    phi = np.arctan2(gap[:, 1], gap[:, 0])
    dist = np.hypot(gap[:, 0], gap[:, 1])
    for sign in (1.0, -1.0):  # outer tangents: the same normal on both circles
        ca.append(i)
        aa.append(phi + sign * 0.5 * math.pi)
        cb.append(j)
        ab.append(phi + sign * 0.5 * math.pi)
    apart = dist > 2.0 * r
    beta = np.arccos(2.0 * r / dist[apart])
    for sign in (1.0, -1.0):  # inner tangents: through the midpoint, opposite normals
        ca.append(i[apart])
        aa.append(phi[apart] + sign * beta)
        cb.append(j[apart])
        ab.append(phi[apart] + sign * beta + math.pi)
    return (
        np.concatenate(ca).astype(np.int64),
        np.mod(np.concatenate(aa), _TWO_PI),
        np.concatenate(cb).astype(np.int64),
        np.mod(np.concatenate(ab), _TWO_PI),
    )


def _build_graph(
    start: np.ndarray, goal: np.ndarray, centres: np.ndarray, r: float, eps_m: float
) -> _Graph:
    ca, aa, cb, ab = _candidate_segments(start, goal, centres, r)

    def ends(circle: np.ndarray, angle: np.ndarray) -> np.ndarray:
        xy = centres[np.maximum(circle, 0)] + r * _unit(angle)
        xy[circle == -1] = start
        xy[circle == -2] = goal
        return xy

    a_xy, b_xy = ends(ca, aa), ends(cb, ab)
    ok = _clear(a_xy, b_xy, centres, r - eps_m)
    ca, aa, cb, ab, a_xy, b_xy = ca[ok], aa[ok], cb[ok], ab[ok], a_xy[ok], b_xy[ok]
    # Node ids: 0 start, 1 goal, then one per segment end on a circle.
    on_a = ca >= 0
    n_a = int(np.count_nonzero(on_a))
    ida = np.where(ca == -1, 0, 1)
    ida[on_a] = 2 + np.arange(n_a)
    idb = 2 + n_a + np.arange(len(ca))
    xy = np.vstack([start, goal, a_xy[on_a], b_xy])
    circle = np.concatenate([[-1, -1], ca[on_a], cb])
    angle = np.concatenate([[0.0, 0.0], aa[on_a], ab])
    # Both directions of each segment, grouped by the node they leave.
    src, dst = np.concatenate([ida, idb]), np.concatenate([idb, ida])
    length_m = np.tile(np.hypot(*(b_xy - a_xy).T), 2)
    order = np.argsort(src, kind="stable")
    seg_from = np.searchsorted(src[order], np.arange(len(xy) + 1))
    ccw_to, ccw_rad, cw_to = _arcs(circle, angle, centres, r)
    return _Graph(
        xy,
        circle.tolist(),
        angle.tolist(),
        seg_from.tolist(),
        dst[order].tolist(),
        length_m[order].tolist(),
        ccw_to.tolist(),
        ccw_rad.tolist(),
        cw_to.tolist(),
    )


def _arcs(
    circle: np.ndarray, angle: np.ndarray, centres: np.ndarray, r: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each node's next and previous tangent node round its circle, and the angle of the arc
    to the next one (-1 where that arc enters another disc, or the node is alone on it).

    The points of circle i inside disc j (centres ``d < 2 r`` apart, direction ``phi``) are
    the open arc ``|angle - phi| < acos(d / 2r)``; an arc between tangent nodes is free when it
    meets none of them (two arcs meet when either one's start lies on the other)."""
    tiny = 1e-9
    n = len(circle)
    ccw_to, cw_to, ccw_rad = np.full(n, -1), np.full(n, -1), np.full(n, -1.0)
    nodes = np.flatnonzero(circle >= 0)
    if not len(nodes):
        return ccw_to, ccw_rad, cw_to
    nodes = nodes[np.lexsort((angle[nodes], circle[nodes]))]
    ring = circle[nodes]
    new_ring = np.ones(len(nodes), dtype=bool)
    new_ring[1:] = ring[1:] != ring[:-1]
    first = np.flatnonzero(new_ring)
    counts = np.diff(first, append=len(nodes))
    size, group_first = np.repeat(counts, counts), np.repeat(first, counts)
    following = group_first + (np.arange(len(nodes)) - group_first + 1) % size
    starts = angle[nodes]
    spans = np.mod(starts[following] - starts, _TWO_PI)
    free = size >= 2
    gap = centres[None, :, :] - centres[:, None, :]  # [i, j]: from centre i to centre j
    dist = np.hypot(gap[..., 0], gap[..., 1])
    half = np.arccos(np.clip(dist / (2.0 * r), 0.0, 1.0)) - tiny
    overlap = (dist < 2.0 * r) & (dist > 0.0) & (half > 0.0)
    if overlap.any():
        lo = np.arctan2(gap[..., 1], gap[..., 0]) - half
        lo, half, overlap = lo[ring], half[ring], overlap[ring]
        meets = _in_ccw(lo, starts[:, None], spans[:, None]) | _in_ccw(
            starts[:, None], lo, 2.0 * half
        )
        free &= ~(meets & overlap).any(axis=1)
    ccw_to[nodes] = nodes[following]
    cw_to[nodes[following]] = nodes
    ccw_rad[nodes] = np.where(free, spans, -1.0)
    return ccw_to, ccw_rad, cw_to


def _shortest(graph: _Graph, r: float) -> list[tuple[int, tuple[int, float, float] | None]]:
    """A* from node 0 to node 1: the route as ``(node, arc into it or None)``, start first,
    an arc as ``(circle, start_rad, signed_span_rad)``."""
    heuristic = np.hypot(*(graph.xy - graph.xy[1]).T).tolist()
    seg_from, seg_to, seg_m = graph.seg_from, graph.seg_to, graph.seg_m
    ccw_to, ccw_rad, cw_to = graph.ccw_to, graph.ccw_rad, graph.cw_to
    best = {0: 0.0}
    came: dict[int, tuple[int, int]] = {}  # node: (previous, +1 ccw arc, -1 cw arc, 0 segment)
    heap = [(heuristic[0], 0.0, 0)]
    done: set[int] = set()
    while heap:
        _, cost, u = heapq.heappop(heap)
        if u in done:
            continue
        if u == 1:
            break
        done.add(u)
        steps = [(seg_to[k], seg_m[k], 0) for k in range(seg_from[u], seg_from[u + 1])]
        if ccw_rad[u] >= 0.0:
            steps.append((ccw_to[u], r * ccw_rad[u], 1))
        back = cw_to[u]
        if back >= 0 and ccw_rad[back] >= 0.0:
            steps.append((back, r * ccw_rad[back], -1))
        for v, w, how in steps:
            c = cost + w
            if c < best.get(v, math.inf):
                best[v] = c
                came[v] = (u, how)
                heapq.heappush(heap, (c + heuristic[v], c, v))
    else:
        raise NoPathError(
            "no path from start to goal keeps clearance_m: keep-out discs enclose the goal "
            "(or the start)"
        )
    route: list[tuple[int, tuple[int, float, float] | None]] = []
    node = 1
    while node != 0:
        prev, how = came[node]
        arc = None
        if how == 1:
            arc = (graph.circle[prev], graph.angle[prev], ccw_rad[prev])
        elif how == -1:
            arc = (graph.circle[prev], graph.angle[prev], -ccw_rad[node])
        route.append((node, arc))
        node = prev
    route.append((0, None))
    return route[::-1]


def _arc_corners(
    centre: np.ndarray, r: float, start_rad: float, span_rad: float, steps: int, extra: np.ndarray
) -> np.ndarray:
    """The corners of the polyline circumscribing an arc (its ends excluded), shape (K, 2):
    tangent lines at ``steps + 1`` equally spaced angles and at the ``extra`` angles inside the
    arc, joined where consecutive ones cross."""
    fractions = np.linspace(0.0, 1.0, steps + 1)
    if len(extra):
        inside = np.mod((extra - start_rad) * np.sign(span_rad), _TWO_PI) / abs(span_rad)
        fractions = np.unique(np.concatenate([fractions, inside[inside < 1.0]]))
    tangents = start_rad + span_rad * fractions
    half = 0.5 * np.diff(tangents)
    return centre + (r / np.cos(half))[:, None] * _unit(tangents[:-1] + half)


def _polyline(route, graph: _Graph, centres: np.ndarray, r: float, step_rad: float, eps_m):
    """The route's waypoints, each arc replaced by its circumscribing polyline, split finer
    where a corner would enter a neighbouring disc."""
    gap = centres[None, :, :] - centres[:, None, :]  # [i, j]: from centre i to centre j
    dist = np.hypot(gap[..., 0], gap[..., 1])
    # A neighbour whose disc a corner could reach: closer than 2 r plus the corners' bulge.
    near = (dist > 0.0) & (dist < 2.0 * r / math.cos(0.5 * step_rad))
    pieces: list[np.ndarray] = [graph.xy[route[0][0]][None, :]]
    arcs: list[tuple[int, tuple[int, float, float], int, np.ndarray]] = []
    for node, arc in route[1:]:
        if arc is not None and arc[2] != 0.0:
            i = arc[0]
            extra = np.arctan2(gap[i, near[i], 1], gap[i, near[i], 0]) if near[i].any() else ()
            steps = max(1, math.ceil(abs(arc[2]) / step_rad))
            arcs.append((len(pieces), arc, steps, np.asarray(extra)))
            pieces.append(_arc_corners(centres[i], r, arc[1], arc[2], steps, arcs[-1][3]))
        pieces.append(graph.xy[node][None, :])
    for _ in range(_MAX_REFINE):
        path = np.vstack(pieces)
        bad = ~_clear(path[:-1], path[1:], centres, r - eps_m)
        if not bad.any():
            break
        piece_of_point = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
        touched = set(piece_of_point[np.flatnonzero(bad)].tolist())
        touched |= set(piece_of_point[np.flatnonzero(bad) + 1].tolist())
        for n, (k, arc, steps, extra) in enumerate(arcs):
            if k in touched:
                arcs[n] = (k, arc, 2 * steps, extra)
                pieces[k] = _arc_corners(centres[arc[0]], r, arc[1], arc[2], 2 * steps, extra)
    return np.vstack(pieces)


def _drop_repeats(path: np.ndarray) -> np.ndarray:
    """The path without zero-length segments (at least its two ends)."""
    keep = np.ones(len(path), dtype=bool)
    keep[1:] = np.any(np.diff(path, axis=0) != 0.0, axis=1)
    out = path[keep]
    return out if len(out) >= 2 else path[[0, -1]]


def plan_path(
    start_xy_w: ArrayLike,
    goal_xy_w: ArrayLike,
    centres_xy_w: ArrayLike,
    clearance_m: float,
    *,
    max_arc_step_deg: float = 5.0,
) -> np.ndarray:
    """The shortest path from start to goal that keeps ``clearance_m`` from every cone's axis.

    Parameters
    ----------
    start_xy_w : array_like, shape (2,)
        Where the drone is (its estimated position), world x and y, metres.
    goal_xy_w : array_like, shape (2,)
        Where it is going, metres.
    centres_xy_w : array_like, shape (M, 2)
        The mapped cones' axes (``ObstacleMap.centres_xy_w``), metres; M may be 0.
    clearance_m : float
        Distance to keep between the drone's centre and each cone's axis, metres (> 0).
    max_arc_step_deg : float
        Largest angle between the tangent lines that replace an arc, degrees, in (0, 45]
        (see the module: corners at most ``clearance_m (1 / cos(step / 2) - 1)`` out).

    Returns
    -------
    path_xy_w : ndarray, shape (K, 2)
        Waypoints, the start first and the goal last (K >= 2), joined by straight segments;
        no two consecutive ones equal unless start and goal are. Every segment keeps at least
        ``clearance_m`` from every centre (to rounding, ``1e-9 clearance_m``; see the module
        for two discs all but touching), except the first when the start is inside a keep-out
        disc (it leaves by the shortest way; see the module). The straight line when it is
        clear.

    Raises
    ------
    ValueError
        An input of the wrong shape, not finite, or out of range; the goal inside a keep-out
        disc (naming the obstacle's index and centre).
    NoPathError
        (a ``ValueError``) The goal enclosed by keep-out discs: no path exists.
    """
    start = _validate.vector(start_xy_w, "start_xy_w", 2, batched=False)
    goal = _validate.vector(goal_xy_w, "goal_xy_w", 2, batched=False)
    centres = _points(centres_xy_w, "centres_xy_w")
    r = _positive(clearance_m, "clearance_m")
    step_deg = _arc_step_deg(max_arc_step_deg)
    eps_m = _REL_EPS * r
    _check_goal_outside(goal, centres, r, eps_m)
    centres = _distinct(centres, eps_m)
    head: list[np.ndarray] = []
    if len(centres) and (np.hypot(*(start - centres).T) < r - eps_m).any():
        head = [start]
        start = _escape(start, centres, r, eps_m)
    if not len(centres) or _clear(start[None], goal[None], centres, r - eps_m)[0]:
        return _drop_repeats(np.vstack([*head, start, goal]))
    graph = _build_graph(start, goal, centres, r, eps_m)
    route = _shortest(graph, r)
    path = _polyline(route, graph, centres, r, math.radians(step_deg), eps_m)
    return _drop_repeats(np.vstack([*head, path]))


def _arc_step_deg(max_arc_step_deg: float) -> float:
    """``plan_path``'s largest angle between the tangents that replace an arc, checked.

    Parameters
    ----------
    max_arc_step_deg : float
        Degrees.

    Returns
    -------
    float
        Degrees, in (0, 45].

    Raises
    ------
    ValueError
        If it is not a finite number in (0, 45].
    """
    step_deg = _positive(max_arc_step_deg, "max_arc_step_deg")
    if step_deg > 45.0:
        raise ValueError(f"max_arc_step_deg must be at most 45, got {max_arc_step_deg!r}")
    return step_deg


def _check_goal_outside(goal: np.ndarray, centres: np.ndarray, r: float, eps_m: float) -> None:
    """Refuse a goal inside a keep-out disc: no path could end there.

    Parameters
    ----------
    goal : ndarray, shape (2,)
        World x and y, metres.
    centres : ndarray, shape (M, 2)
        The cones' axes, metres.
    r, eps_m : float
        The discs' radius (``clearance_m``) and the rounding allowed, metres.

    Raises
    ------
    ValueError
        Naming the nearest obstacle whose disc holds the goal, its index and centre.
    """
    to_goal = np.hypot(*(goal - centres).T) if len(centres) else np.zeros(0)
    inside = np.flatnonzero(to_goal < r - eps_m)
    if len(inside):
        k = int(inside[np.argmin(to_goal[inside])])
        raise ValueError(
            f"goal_xy_w {goal.tolist()} is inside the keep-out disc of obstacle {k} at "
            f"{centres[k].tolist()}: {to_goal[k]:.3f} m from its axis, clearance_m is {r}"
        )


def path_length_m(path_xy_w: ArrayLike) -> float:
    """Length of a polyline, metres.

    Parameters
    ----------
    path_xy_w : array_like, shape (K, 2)
        Waypoints, metres (K >= 1).

    Raises
    ------
    ValueError
        Not of shape (K, 2) with K >= 1, or not finite.
    """
    path = _points(path_xy_w, "path_xy_w")
    if not len(path):
        raise ValueError("path_xy_w must hold at least one waypoint; got none")
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


@dataclass(frozen=True)
class PathReference:
    """What the controller should track at one instant, to follow a planned path.

    Attributes
    ----------
    p_w : ndarray, shape (3,)
        Position, world ENU, metres: the carrot point on the path at the flight altitude.
    v_w : ndarray, shape (3,)
        Velocity, m/s: along the path at the carrot, slowing to 0 within one lookahead of the
        goal.
    yaw_rad : float
        Heading (body x from world x, counter-clockwise): along the path at the carrot, so the
        camera (looking along body x) faces where the drone is going and sees the cones ahead.
    remaining_m : float
        Path length from the drone's nearest point on the path to the goal, metres.
    """

    p_w: np.ndarray
    v_w: np.ndarray
    yaw_rad: float
    remaining_m: float


def follow_path(
    path_xy_w: ArrayLike,
    p_w: ArrayLike,
    *,
    altitude_m: float,
    speed_mps: float,
    lookahead_m: float,
    yaw_still_rad: float = 0.0,
) -> PathReference:
    """The carrot to chase: the point ``lookahead_m`` along the path past the drone's nearest.

    The drone's nearest point on the path is found (a replanned path starts at the drone, so
    it is usually the first waypoint); the carrot is ``lookahead_m`` further along, or the goal.
    The velocity is ``speed_mps`` along the path there, scaled down linearly over the last
    ``lookahead_m`` before the goal to stop on it; the heading is the path's direction there.

    A drone chasing the carrot cuts across the path's bends: round an arc of radius
    ``clearance_m`` the chord to a carrot ``lookahead_m`` ahead comes inside by up to
    ``lookahead_m^2 / (8 clearance_m)`` (3 cm for 0.5 m round 1 m), which the clearance's margin
    over the cone's footprint must hold.

    Parameters
    ----------
    path_xy_w : array_like, shape (K, 2)
        The path (``plan_path``), world x and y, metres.
    p_w : array_like, shape (2,) or (3,)
        The drone's (estimated) position, metres; z is not used.
    altitude_m : float
        The reference's height, metres.
    speed_mps : float
        Cruise speed, m/s (>= 0).
    lookahead_m : float
        Carrot distance along the path, metres (> 0).
    yaw_still_rad : float
        Heading returned when the path has no length (start at the goal), radians.

    Returns
    -------
    PathReference

    Raises
    ------
    ValueError
        An input of the wrong shape, not finite, or out of range.
    """
    path, p, lookahead_m = _follow_inputs(
        path_xy_w, p_w, altitude_m, speed_mps, lookahead_m, yaw_still_rad
    )
    carrot = _carrot(path, p, lookahead_m)
    if carrot is None:
        p_ref = np.array([path[-1, 0], path[-1, 1], float(altitude_m)])
        return PathReference(p_ref, np.zeros(3), float(yaw_still_rad), 0.0)
    xy, direction, remaining = carrot
    speed = speed_mps * min(1.0, remaining / lookahead_m)
    return PathReference(
        p_w=np.array([xy[0], xy[1], float(altitude_m)]),
        v_w=np.array([speed * direction[0], speed * direction[1], 0.0]),
        yaw_rad=math.atan2(direction[1], direction[0]),
        remaining_m=float(remaining),
    )


def _follow_inputs(
    path_xy_w: ArrayLike,
    p_w: ArrayLike,
    altitude_m: float,
    speed_mps: float,
    lookahead_m: float,
    yaw_still_rad: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """``follow_path``'s inputs, checked.

    Parameters
    ----------
    path_xy_w, p_w, altitude_m, speed_mps, lookahead_m, yaw_still_rad
        As ``follow_path`` takes them.

    Returns
    -------
    path : ndarray, shape (K, 2)
        Waypoints, metres, K >= 1.
    p : ndarray, shape (2,)
        The drone's x and y, metres.
    lookahead_m : float
        Metres, > 0.

    Raises
    ------
    ValueError
        An input of the wrong shape, not finite, or out of range.
    """
    path = _points(path_xy_w, "path_xy_w")
    if not len(path):
        raise ValueError("path_xy_w must hold at least one waypoint; got none")
    p = _validate.as_float(p_w, "p_w")
    if p.shape not in ((2,), (3,)):
        raise ValueError(f"p_w must have shape (2,) or (3,); got shape {p.shape}")
    p = _validate.check_finite(p, "p_w")[:2]
    for name, value in (("altitude_m", altitude_m), ("yaw_still_rad", yaw_still_rad)):
        if isinstance(value, bool) or not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
    if isinstance(speed_mps, bool) or not (math.isfinite(speed_mps) and speed_mps >= 0.0):
        raise ValueError(f"speed_mps must be a finite number >= 0, got {speed_mps!r}")
    return path, p, _positive(lookahead_m, "lookahead_m")


def _carrot(
    path: np.ndarray, p: np.ndarray, lookahead_m: float
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The point ``lookahead_m`` along the path past the drone's nearest point, or the goal.

    Parameters
    ----------
    path : ndarray, shape (K, 2)
        Waypoints, metres.
    p : ndarray, shape (2,)
        The drone's x and y, metres.
    lookahead_m : float
        Metres, > 0.

    Returns
    -------
    xy : ndarray, shape (2,)
        The carrot, metres.
    direction : ndarray, shape (2,)
        The path's unit direction there.
    remaining : float
        Path length from the drone's nearest point to the goal, metres.

    None when the path has no length.
    """
    seg = np.diff(path, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    moving = seg_len > 0.0
    if not moving.any():
        return None
    seg, seg_len, starts = seg[moving], seg_len[moving], path[:-1][moving]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    t = np.clip(np.einsum("kd,kd->k", p - starts, seg) / seg_len**2, 0.0, 1.0)
    nearest = np.argmin(np.hypot(*(starts + t[:, None] * seg - p).T))
    s_drone = cum[nearest] + t[nearest] * seg_len[nearest]
    total = cum[-1]
    s_carrot = min(s_drone + lookahead_m, total)
    k = min(int(np.searchsorted(cum, s_carrot, side="right")) - 1, len(seg) - 1)
    direction = seg[k] / seg_len[k]
    xy = starts[k] + (s_carrot - cum[k]) * direction
    return xy, direction, total - s_drone
