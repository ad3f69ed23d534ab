"""Error statistics and estimate-to-truth matching."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from vnav.metrics import (
    STATS,
    error_stats,
    horizontal_error,
    match_nearest,
    position_error,
)


def test_error_stats_known_values() -> None:
    s = error_stats(np.array([3.0, 4.0, 0.0, 5.0]))
    assert set(s) == set(STATS)
    assert s["count"] == 4
    assert s["mean"] == 3.0 and s["median"] == 3.5 and s["min"] == 0.0 and s["max"] == 5.0
    assert s["rmse"] == pytest.approx(math.sqrt(50.0 / 4.0))
    assert s["std"] == pytest.approx(np.std([3.0, 4.0, 0.0, 5.0]))


def test_error_stats_empty() -> None:
    s = error_stats(np.array([]))
    assert s["count"] == 0
    assert all(math.isnan(s[k]) for k in STATS if k != "count")


def test_error_stats_bad_input() -> None:
    with pytest.raises(ValueError, match="errors must be finite"):
        error_stats(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="errors must be one-dimensional"):
        error_stats(np.zeros((2, 2)))


def test_position_and_horizontal_error() -> None:
    ref = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    est = np.array([[3.0, 4.0, 12.0], [1.0, 1.0, 1.0]])
    np.testing.assert_allclose(position_error(ref, est), [13.0, 0.0])
    np.testing.assert_allclose(horizontal_error(ref, est), [5.0, 0.0])
    np.testing.assert_allclose(horizontal_error(ref[0], est[0]), [5.0])
    with pytest.raises(ValueError, match="must both be"):
        position_error(ref, est[:1])


def test_match_nearest_exact_assignment() -> None:
    # Greedy takes the closest pair (0, 0) at 0.9 and is left with (1, 1) at 3.0 (total 3.9);
    # the optimum is (0, 1) + (1, 0) = 1.1 + 1.0.
    ref = np.array([[1.1, 0.0], [3.0, 0.0]])
    est = np.array([[2.0, 0.0], [0.0, 0.0]])
    assert match_nearest(ref, est) == [(0, 1), (1, 0)]


def test_match_nearest_unequal_sizes_and_gate() -> None:
    ref = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [9.0, 9.0, 0.0]])
    est = np.array([[5.1, 0.0, 0.0], [0.2, 0.0, 0.0]])
    assert match_nearest(ref, est) == [(0, 1), (1, 0)]
    assert match_nearest(ref, est, max_distance=0.15) == [(1, 0)]
    assert match_nearest(ref, np.zeros((0, 3))) == []


def test_match_nearest_brute_force_is_optimal() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        ref = rng.uniform(0, 10, size=(5, 2))
        est = ref[rng.permutation(5)] + rng.normal(0, 1.5, size=(5, 2))
        pairs = match_nearest(ref, est)
        total = sum(np.linalg.norm(ref[i] - est[j]) for i, j in pairs)
        best = min(
            sum(np.linalg.norm(ref[i] - est[p[i]]) for i in range(5))
            for p in itertools.permutations(range(5))
        )
        assert total == pytest.approx(best)


def test_match_nearest_for_many() -> None:
    ref = np.column_stack((np.arange(20.0), np.zeros(20)))
    est = ref[::-1] + 0.1
    pairs = match_nearest(ref, est)
    assert len(pairs) == 20
    assert all(abs(ref[i, 0] + 0.1 - est[j, 0]) < 1e-9 for i, j in pairs)


def test_match_nearest_is_scipys_optimal_assignment() -> None:
    """The Hungarian algorithm against SciPy's linear_sum_assignment (test-only oracle) on
    square and rectangular sets up to 30 points, in both orientations: the same total."""
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(3)
    for n, m in [(1, 1), (3, 8), (8, 3), (8, 8), (12, 30), (30, 12), (25, 25)]:
        for _ in range(5):
            ref = rng.uniform(0, 10, size=(n, 2))
            est = rng.uniform(0, 10, size=(m, 2))
            pairs = match_nearest(ref, est)
            assert len(pairs) == min(n, m)
            assert len({i for i, _ in pairs}) == len({j for _, j in pairs}) == len(pairs)
            dist = np.linalg.norm(ref[:, None] - est[None], axis=2)
            rows, cols = linear_sum_assignment(dist)
            total = sum(dist[i, j] for i, j in pairs)
            assert total == pytest.approx(dist[rows, cols].sum(), rel=1e-12, abs=1e-12)


def test_match_nearest_with_a_gate_is_its_definition() -> None:
    """Against ``_match_brute_force``, every assignment tried: the most pairs within the gate
    first, then the least total distance; cones in clusters, so that the gate decides."""
    from vnav.metrics import _match_brute_force

    rng = np.random.default_rng(4)
    for n, m in [(2, 5), (5, 2), (4, 4), (6, 6), (3, 7)]:
        for _ in range(20):
            ref = rng.uniform(0, 4, size=(n, 2))
            est = rng.uniform(0, 4, size=(m, 2))
            gate = rng.uniform(0.3, 2.0)
            dist = np.linalg.norm(ref[:, None] - est[None], axis=2)
            expected = _match_brute_force(dist, dist <= gate)
            pairs = match_nearest(ref, est, max_distance=gate)
            assert len(pairs) == len(expected)
            total = sum(dist[i, j] for i, j in pairs)
            assert total == pytest.approx(sum(dist[i, j] for i, j in expected), abs=1e-12)
            assert all(dist[i, j] <= gate for i, j in pairs)


def test_negative_errors_and_non_finite_points_are_refused() -> None:
    with pytest.raises(ValueError, match="errors are distances and must be >= 0; got 1 negative"):
        error_stats([-1.0])
    for fn in (position_error, horizontal_error):
        with pytest.raises(ValueError, match="p_est must be finite; got 1 NaN/inf"):
            fn([0.0, 0.0, 0.0], [np.nan, 0.0, 0.0])


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: error_stats([0.5, -1e-12]), r"errors are distances .*got 1 negative"),
        (lambda: error_stats([0.5, np.nan]), r"errors must be finite"),
        (lambda: position_error([np.inf, 0.0, 0.0], [0.0, 0.0, 0.0]), r"^p_ref must be finite"),
        (lambda: horizontal_error([[0.0, 0.0, 0.0]], [[0.0, 0.0, np.nan]]), r"^p_est must be"),
        (lambda: match_nearest([[0.0, 0.0]], [[np.nan, 0.0]]), r"^p_est must be finite"),
        (lambda: match_nearest(np.zeros((0, 2)), [[np.nan, 0.0]]), r"^p_est must be finite"),
        (lambda: match_nearest([[0.0, 0.0]], [[1.0, 0.0]], max_distance=np.nan), "max_distance"),
        (lambda: match_nearest([[0.0, 0.0]], [[1.0, 0.0]], max_distance=-1.0), "max_distance"),
    ],
)
def test_garbage_in_raises_naming_the_argument(call, match) -> None:
    with pytest.raises(ValueError, match=match):
        call()


def test_zero_errors_and_an_infinite_gate_are_fine() -> None:
    stats = error_stats([0.0, 0.0, 3.0, 4.0])
    assert stats["min"] == 0.0 and stats["mean"] == 1.75 and stats["count"] == 4
    assert stats["rmse"] == 2.5  # sqrt((9 + 16) / 4), by hand
    assert match_nearest([[0.0, 0.0]], [[1e6, 0.0]], max_distance=math.inf) == [(0, 0)]
    assert match_nearest([[0.0, 0.0]], [[1.0, 0.0]], max_distance=0) == []
