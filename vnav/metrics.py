"""Error statistics of position estimates against ground truth, in the style of evo.

evo (``evo/core/metrics.py``) reports every error series with the same statistics: rmse, mean,
median, std, min, max. The same here, plus the count. Reference (ground truth) comes first in
every argument list. Errors are Euclidean distances in metres.

An empty series is not an error: ``error_stats`` returns count 0 and NaN for every statistic,
so a table of several methods keeps its rows when one method never produced an estimate.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = [
    "STATS",
    "error_stats",
    "horizontal_error",
    "match_nearest",
    "position_error",
]

STATS = ("rmse", "mean", "median", "std", "min", "max", "count")
"""The keys of ``error_stats``, in display order."""


def _points(x: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape (3,), (N, 3), (2,) or (N, 2); got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite; got {int((~np.isfinite(a)).sum())} NaN/inf")
    return a


def error_stats(errors: np.ndarray) -> dict[str, float]:
    """Statistics of a series of non-negative errors (evo's set, plus ``count``).

    ``rmse = sqrt(mean(e^2))``; ``std`` is the population standard deviation (ddof = 0, as evo).

    Parameters
    ----------
    errors : array_like, shape (N,)
        Errors, e.g. metres. Must be finite.

    Returns
    -------
    dict
        Keys ``STATS``; ``count`` is an int. For N = 0 every other value is NaN.

    Raises
    ------
    ValueError
        If ``errors`` is not one-dimensional, holds NaN/inf or a negative value.
    """
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1:
        raise ValueError(f"errors must be one-dimensional, got shape {e.shape}")
    if not np.isfinite(e).all():
        raise ValueError(f"errors must be finite; got {int((~np.isfinite(e)).sum())} NaN/inf")
    if (e < 0.0).any():
        raise ValueError(
            f"errors are distances and must be >= 0; got {int((e < 0.0).sum())} negative "
            f"(smallest {float(e.min()):g})"
        )
    if e.size == 0:
        stats: dict[str, float] = {key: math.nan for key in STATS}
        stats["count"] = 0
        return stats
    return {
        "rmse": float(np.sqrt(np.mean(e**2))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "count": int(e.size),
    }


def position_error(p_ref: np.ndarray, p_est: np.ndarray) -> np.ndarray:
    """Euclidean (3-D) distance per row, ``|p_est - p_ref|``, shape (N,), metres.

    Raises
    ------
    ValueError
        If the shapes differ or are not (3,) / (N, 3), or a point holds NaN or inf (the
        message names the argument).
    """
    a, b = _points(p_ref, "p_ref"), _points(p_est, "p_est")
    if a.shape != b.shape or a.shape[1] != 3:
        raise ValueError(f"p_ref and p_est must both be (N, 3); got {a.shape} and {b.shape}")
    return np.linalg.norm(b - a, axis=1)


def horizontal_error(p_ref: np.ndarray, p_est: np.ndarray) -> np.ndarray:
    """Distance in the ground plane (world x, y; z ignored) per row, shape (N,), metres.

    Raises
    ------
    ValueError
        If the shapes differ or are not (3,) / (N, 3), or a point holds NaN or inf (the
        message names the argument).
    """
    a, b = _points(p_ref, "p_ref"), _points(p_est, "p_est")
    if a.shape != b.shape or a.shape[1] != 3:
        raise ValueError(f"p_ref and p_est must both be (N, 3); got {a.shape} and {b.shape}")
    return np.linalg.norm(b[:, :2] - a[:, :2], axis=1)


def match_nearest(
    p_ref: np.ndarray, p_est: np.ndarray, max_distance: float = math.inf
) -> list[tuple[int, int]]:
    """Pair estimates with true positions one-to-one: as many pairs as possible within
    ``max_distance``, and of those the least total distance.

    Exact for any number of points: the Hungarian algorithm (``_assignment``), O(N^2 M) for
    N <= M points. Pairs farther apart than ``max_distance`` are left unmatched. 2-D or 3-D
    points (pass ``[:, :2]`` to match in the ground plane).

    Parameters
    ----------
    p_ref : array_like, shape (N, D)
        True positions.
    p_est : array_like, shape (M, D)
        Estimates.
    max_distance : float
        Largest distance of a pair, same unit as the points: a number >= 0 or ``inf``.

    Returns
    -------
    list of (i_ref, i_est)
        Sorted by ``i_ref``.

    Raises
    ------
    ValueError
        On mismatched dimensions, non-finite points (even when the other set is empty), or a
        ``max_distance`` that is NaN or negative (a NaN would silently match nothing).
    """
    real = isinstance(max_distance, int | float | np.floating | np.integer)
    if isinstance(max_distance, bool) or not real or not max_distance >= 0.0:
        raise ValueError(f"max_distance must be a number >= 0 or inf; got {max_distance!r}")
    if np.size(p_ref) == 0 or np.size(p_est) == 0:
        for x, name in ((p_ref, "p_ref"), (p_est, "p_est")):
            if np.size(x) != 0:
                _points(x, name)
        return []
    a, b = _points(p_ref, "p_ref"), _points(p_est, "p_est")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"p_ref and p_est must have the same dimension; got {a.shape}, {b.shape}")
    dist = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    allowed = dist <= max_distance
    if not allowed.any():
        return []
    # A pair beyond the gate costs more than any set of pairs within it: the cheapest full
    # assignment then has the most pairs within the gate, and of those the least distance.
    beyond = 1.0 + min(dist.shape) * (float(dist[allowed].max()) + 1.0)
    cost = np.where(allowed, dist, beyond)
    transpose = cost.shape[0] > cost.shape[1]
    col_of_row = _assignment(cost.T if transpose else cost)
    pairs = [(j, i) if transpose else (i, j) for i, j in enumerate(col_of_row)]
    return sorted((i, j) for i, j in pairs if allowed[i, j])


def _assignment(cost: np.ndarray) -> list[int]:
    """The column of each row in the cheapest assignment of every row of ``cost`` (N, M),
    N <= M, to a distinct column.

    The Hungarian algorithm (Kuhn 1955, Munkres 1957) in its shortest-augmenting-path form
    with row and column potentials (Jonker and Volgenant 1987): one row added at a time,
    reached by a Dijkstra search over reduced costs; O(N^2 M). Plain floats: the sets matched
    here are a handful of cones.
    """
    n, m = cost.shape
    c = cost.tolist()
    u = [0.0] * (n + 1)  # row potentials (1-based; 0 is the search's virtual start)
    v = [0.0] * (m + 1)  # column potentials
    row_of = [0] * (m + 1)  # the row assigned to each column, 0 for none
    for i in range(1, n + 1):
        row_of[0] = i
        j0 = 0
        min_to = [math.inf] * (m + 1)  # shortest reduced distance to each column so far
        prev = [0] * (m + 1)  # the column before each one on that shortest path
        done = [False] * (m + 1)
        while True:
            done[j0] = True
            i0 = row_of[j0]
            row, u_i0 = c[i0 - 1], u[i0]
            delta, j1 = math.inf, 0
            for j in range(1, m + 1):
                if not done[j]:
                    reduced = row[j - 1] - u_i0 - v[j]
                    if reduced < min_to[j]:
                        min_to[j], prev[j] = reduced, j0
                    if min_to[j] < delta:
                        delta, j1 = min_to[j], j
            for j in range(m + 1):
                if done[j]:
                    u[row_of[j]] += delta
                    v[j] -= delta
                else:
                    min_to[j] -= delta
            j0 = j1
            if row_of[j0] == 0:  # a free column: augment along the path back to the start
                break
        while j0:
            j1 = prev[j0]
            row_of[j0] = row_of[j1]
            j0 = j1
    col_of = [0] * n
    for j in range(1, m + 1):
        if row_of[j]:
            col_of[row_of[j] - 1] = j - 1
    return col_of


def _match_brute_force(dist: np.ndarray, allowed: np.ndarray) -> list[tuple[int, int]]:
    """The definition ``match_nearest`` solves, by trying every assignment (small sets only;
    kept to test it): most pairs within the gate first, then least total distance."""
    n, m = dist.shape
    transpose = n > m
    if transpose:
        dist, allowed = dist.T, allowed.T
        n, m = m, n
    best: tuple[int, float, list[tuple[int, int]]] = (0, 0.0, [])
    for perm in itertools.permutations(range(m), n):
        pairs = [(i, j) for i, j in enumerate(perm) if allowed[i, j]]
        total = float(sum(dist[i, j] for i, j in pairs))
        if len(pairs) > best[0] or (len(pairs) == best[0] and total < best[1]):
            best = (len(pairs), total, pairs)
    pairs = best[2]
    return [(j, i) for i, j in pairs] if transpose else pairs
