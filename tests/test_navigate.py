"""vnav.navigate: shortest paths around keep-out discs against lengths computed by hand from
the tangent geometry, the clearance checked segment by segment, and the path follower's
reference on paths whose carrot can be read off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from vnav.navigate import NoPathError, follow_path, path_length_m, plan_path

STEP_DEG = 5.0
"""``plan_path``'s default ``max_arc_step_deg``."""


def _stretch(step_deg: float) -> float:
    """How much longer than its arc the circumscribing polyline may be: tan(x) / x at half the
    step (each piece of at most ``step_deg`` is two tangent half-lengths ``r tan(step / 2)``)."""
    half = math.radians(step_deg) / 2.0
    return math.tan(half) / half


def _distances(path: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Distance from ``centre`` to each segment of ``path``, shape (K - 1,)."""
    a, b = path[:-1], path[1:]
    ab = b - a
    length2 = np.maximum((ab * ab).sum(axis=1), 1e-300)
    t = np.clip(((centre - a) * ab).sum(axis=1) / length2, 0.0, 1.0)
    return np.hypot(*(a + t[:, None] * ab - centre).T)


def _tangent_length(p: np.ndarray, c: np.ndarray, r: float) -> float:
    return math.sqrt(float(np.sum((p - c) ** 2)) - r * r)


def _one_disc_length(s: np.ndarray, g: np.ndarray, c: np.ndarray, r: float) -> float:
    """The shortest path around one disc whose interior the straight line crosses: the two
    tangents and the arc between their touching points, ``theta - acos(r/ds) - acos(r/dg)``
    radians, ``theta`` the angle s-c-g."""
    ds, dg = float(np.hypot(*(s - c))), float(np.hypot(*(g - c)))
    cos_theta = float(np.dot(s - c, g - c)) / (ds * dg)
    theta = math.acos(min(1.0, max(-1.0, cos_theta)))
    arc = theta - math.acos(r / ds) - math.acos(r / dg)
    return _tangent_length(s, c, r) + _tangent_length(g, c, r) + r * arc, arc


@pytest.mark.parametrize("step_deg", [1.0, STEP_DEG, 20.0, 45.0])
def test_a_cone_on_the_line_is_passed_at_the_clearance(step_deg):
    # Cone at (10, 0), clearance 1: tangents of sqrt(10^2 - 1) from start and goal, and the arc
    # between their touching points, pi - 2 acos(1/10) = 2 asin(1/10) radians.
    start, goal, cone, r = np.array([0.0, 0.0]), np.array([20.0, 0.0]), np.array([10.0, 0]), 1.0
    path = plan_path(start, goal, [cone], r, max_arc_step_deg=step_deg)
    arc_rad = 2.0 * math.asin(0.1)
    exact = 2.0 * math.sqrt(10.0**2 - 1.0) + r * arc_rad
    length = path_length_m(path)
    assert exact - 1e-9 <= length <= exact + r * arc_rad * (_stretch(step_deg) - 1.0) + 1e-9
    np.testing.assert_array_equal(path[0], start)
    np.testing.assert_array_equal(path[-1], goal)
    d = _distances(path, cone)
    assert d.min() == pytest.approx(r, rel=1e-9)  # touches the circle, never inside
    # The corners stand out at most r (1 / cos(step / 2) - 1).
    assert np.hypot(*(path - cone).T)[1:-1].max() <= r / math.cos(math.radians(step_deg) / 2)
    # The tangent points are where the hand geometry puts them: r from the cone, seen from the
    # start at asin(r / 10) above the line.
    np.testing.assert_allclose(path[1], [10.0 - 0.1, math.sqrt(1.0 - 0.01)], atol=1e-12)


def test_two_cones_in_a_row_are_passed_over_their_outer_tangent():
    # Cones at (10, 0) and (20, 0): tangent from the start to the first, the outer common
    # tangent (10 m, y = 1) and the tangent from the second to the goal; each arc asin(1/10).
    cones = np.array([[10.0, 0.0], [20.0, 0.0]])
    path = plan_path([0.0, 0.0], [30.0, 0.0], cones, 1.0)
    arc_rad = 2.0 * math.asin(0.1)
    exact = 2.0 * math.sqrt(99.0) + 10.0 + arc_rad
    assert exact - 1e-9 <= path_length_m(path) <= exact + arc_rad * (_stretch(STEP_DEG) - 1)
    for cone in cones:
        assert _distances(path, cone).min() == pytest.approx(1.0, rel=1e-9)


def test_two_overlapping_cones_are_passed_round_their_union():
    # Discs at (10, +-0.5), radius 1, overlap: the path goes round the upper (or, by symmetry,
    # the lower) one. From its centre the start is at angle pi + e (e = atan(0.5/10)) and the
    # goal at -e, at distance d = sqrt(100.25); the upper touching points are at pi + e - b
    # and b - e (b = acos(1/d)), so the arc is pi + 2e - 2b.
    d = math.sqrt(100.25)
    e, b = math.atan(0.05), math.acos(1.0 / d)
    arc_rad = math.pi + 2.0 * e - 2.0 * b
    exact = 2.0 * math.sqrt(d * d - 1.0) + arc_rad
    cones = np.array([[10.0, 0.5], [10.0, -0.5]])
    path = plan_path([0.0, 0.0], [20.0, 0.0], cones, 1.0)
    assert exact - 1e-9 <= path_length_m(path) <= exact + arc_rad * (_stretch(STEP_DEG) - 1)
    assert min(_distances(path, c).min() for c in cones) >= 1.0 - 1e-9


def test_the_arc_through_a_neighbours_disc_is_no_way_through():
    # Discs at (0, 0) and (0, 1.9) overlap in a thin lens over the first one's top. From
    # (-1.5, 0.3) to (1.5, 0.3) round the first disc, the short way is over its top, 59 deg of
    # arc, whose middle lies inside the second disc; the path must take the long way under
    # it: 360 deg - theta - 2 acos(r / d) of arc (theta the angle start-centre-goal).
    s, g, c = np.array([-1.5, 0.3]), np.array([1.5, 0.3]), np.array([0.0, 0.0])
    cones = np.array([c, [0.0, 1.9]])
    path = plan_path(s, g, cones, 1.0)
    _, short_arc_rad = _one_disc_length(s, g, c, 1.0)
    d = float(np.hypot(*s))
    long_arc_rad = 2.0 * math.pi - short_arc_rad - 4.0 * math.acos(1.0 / d)
    exact = 2.0 * _tangent_length(s, c, 1.0) + long_arc_rad
    assert exact - 1e-9 <= path_length_m(path) <= exact + long_arc_rad * (_stretch(STEP_DEG) - 1)
    assert path[:, 1].max() == 0.3
    assert min(_distances(path, cone).min() for cone in cones) >= 1.0 - 1e-9


@pytest.mark.parametrize("goal_x_m", [0.2, 0.35, 0.5, 0.8])
def test_past_a_touching_disc_the_corners_keep_the_clearance(goal_x_m):
    # Discs at (0, 0) and (2, 0) touch at (1, 0). From (0.2, -5) to (goal_x_m, 5) the path
    # wraps the first disc's right side through the touching point; a corner of the
    # circumscribing polyline there (standing out r (1 / cos(2.5 deg) - 1) = 9.5e-4 m) would
    # enter the second disc unless a tangent line touches the circle at the point itself.
    cones = np.array([[0.0, 0.0], [2.0, 0.0]])
    path = plan_path([0.2, -5.0], [goal_x_m, 5.0], cones, 1.0)
    assert (path[:, 0] > 0.9).sum() >= 3
    assert min(_distances(path, c).min() for c in cones) >= 1.0 - 1e-9


def test_a_goal_inside_a_keep_out_disc_is_refused_naming_the_obstacle():
    with pytest.raises(ValueError, match=r"goal_xy_w .* inside .* obstacle 1 at \[20.0, 0.5\]"):
        plan_path([0.0, 0.0], [20.0, 0.0], [[10.0, 0.0], [20.0, 0.5]], 1.0)


def test_an_enclosed_goal_has_no_path():
    # Eight discs of radius 1 on a circle of radius 2 round the goal: neighbours 1.53 m apart
    # overlap, and the goal is 2 m from each, outside them.
    angles = np.arange(8) * math.pi / 4
    ring = np.array([20.0, 0.0]) + 2.0 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    with pytest.raises(NoPathError, match="enclose the goal"):
        plan_path([0.0, 0.0], [20.0, 0.0], ring, 1.0)
    assert issubclass(NoPathError, ValueError)


@pytest.mark.parametrize("cone", [[-3.0, 0.5], [5.0, 1.5], [25.0, -0.2], [10.0, -1.0]])
def test_a_cone_off_the_line_does_not_bend_it(cone):
    # Behind the start, beside the line farther than the clearance, past the goal, and
    # exactly the clearance away (the line touches the circle).
    path = plan_path([0.0, 0.0], [20.0, 0.0], [cone], 1.0)
    np.testing.assert_array_equal(path, [[0.0, 0.0], [20.0, 0.0]])


def test_no_cone_and_start_at_the_goal():
    np.testing.assert_array_equal(
        plan_path([1.0, 2.0], [4.0, 6.0], np.zeros((0, 2)), 1.0)[-1], [4, 6]
    )
    path = plan_path([1.0, 2.0], [1.0, 2.0], [[5.0, 5.0]], 1.0)
    np.testing.assert_array_equal(path, [[1.0, 2.0], [1.0, 2.0]])
    assert path_length_m(path) == 0.0


def test_a_start_inside_a_disc_leaves_along_the_radius():
    # Start 0.2 m from the cone's axis, in direction u: the nearest point outside is the cone
    # plus 1 m along u.
    start, cone = np.array([10.2, 0.1]), np.array([10.0, 0.0])
    path = plan_path(start, [20.0, 0.0], [cone], 1.0)
    u = (start - cone) / np.hypot(*(start - cone))
    np.testing.assert_array_equal(path[0], start)
    np.testing.assert_allclose(path[1], cone + u, atol=1e-12)
    assert _distances(path[1:], cone).min() >= 1.0 - 1e-9
    # At the axis itself there is no radius: it still leaves, 1 m out, and reaches the goal.
    path = plan_path(cone, [20.0, 0.0], [cone], 1.0)
    assert np.hypot(*(path[1] - cone)) == pytest.approx(1.0)
    np.testing.assert_array_equal(path[-1], [20.0, 0.0])


def test_a_start_inside_two_discs_leaves_by_the_corner_where_their_circles_cross():
    # (10, 0) is inside both discs at (10, +-0.5); each one's radial exit lies inside the
    # other, and the circles cross at (10 +- sqrt(0.75), 0), sqrt(0.75) m away.
    cones = np.array([[10.0, 0.5], [10.0, -0.5]])
    path = plan_path([10.0, 0.0], [20.0, 0.0], cones, 1.0)
    assert abs(path[1, 0] - 10.0) == pytest.approx(math.sqrt(0.75), rel=1e-12)
    assert path[1, 1] == pytest.approx(0.0, abs=1e-12)
    assert min(_distances(path[1:], c).min() for c in cones) >= 1.0 - 1e-9


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"clearance_m": 0.0}, "clearance_m"),
        ({"clearance_m": math.nan}, "clearance_m"),
        ({"centres_xy_w": [[1.0, 2.0, 3.0]]}, "centres_xy_w"),
        ({"centres_xy_w": [[1.0, math.inf]]}, "centres_xy_w"),
        ({"start_xy_w": [0.0, math.nan]}, "start_xy_w"),
        ({"goal_xy_w": [1.0]}, "goal_xy_w"),
        ({"max_arc_step_deg": 60.0}, "max_arc_step_deg"),
    ],
)
def test_bad_input_is_refused_naming_it(kwargs, match):
    args = {
        "start_xy_w": [0.0, 0.0],
        "goal_xy_w": [20.0, 0.0],
        "centres_xy_w": [[10.0, 0.0]],
        "clearance_m": 1.0,
    } | kwargs
    step = {"max_arc_step_deg": args.pop("max_arc_step_deg")} if "max_arc_step_deg" in args else {}
    with pytest.raises(ValueError, match=match):
        plan_path(**args, **step)


def test_path_length_is_the_sum_of_the_segments():
    assert path_length_m([[0.0, 0.0], [3.0, 4.0], [3.0, 0.0]]) == 9.0
    assert path_length_m([[1.0, 1.0]]) == 0.0
    with pytest.raises(ValueError, match="path_xy_w"):
        path_length_m(np.zeros((0, 2)))


# ----------------------------------------------------------------------------- properties

COORD = st.floats(-12.0, 12.0, allow_nan=False)
POINT = st.tuples(COORD, COORD)


def _connected_on_a_grid(s, g, centres, r) -> bool:
    """Whether start and goal are joined through grid squares lying wholly outside every disc
    (4-neighbours, 0.05 m squares): true means a path exists; false proves nothing."""
    h = 0.05
    lo = np.minimum(np.min(centres, axis=0), np.minimum(s, g)) - r - 1.0
    hi = np.maximum(np.max(centres, axis=0), np.maximum(s, g)) + r + 1.0
    xs, ys = np.arange(lo[0], hi[0], h) + h / 2, np.arange(lo[1], hi[1], h) + h / 2
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    free = np.ones(gx.shape, dtype=bool)
    for c in centres:
        free &= np.hypot(gx - c[0], gy - c[1]) >= r + h / math.sqrt(2.0)
    labels, _ = ndimage.label(free)
    cell = [tuple(((p - lo) // h).astype(int)) for p in (s, g)]
    return bool(labels[cell[0]] and labels[cell[0]] == labels[cell[1]])


@settings(max_examples=300, deadline=None)
@given(
    start=POINT,
    goal=POINT,
    centres=st.lists(POINT, min_size=0, max_size=7),
    r=st.floats(0.2, 3.0),
    step_deg=st.sampled_from([1.0, STEP_DEG, 20.0, 45.0]),
)
def test_any_plan_keeps_the_clearance_and_joins_start_to_goal(start, goal, centres, r, step_deg):
    s, g = np.array(start), np.array(goal)
    c = np.array(centres).reshape(-1, 2)
    to_goal = np.hypot(*(g - c).T) if len(c) else np.zeros(0)
    if (to_goal < r * (1.0 - 1e-6)).any():
        with pytest.raises(ValueError, match="goal_xy_w"):
            plan_path(s, g, c, r, max_arc_step_deg=step_deg)
        return
    assume((to_goal > r * (1.0 + 1e-6)).all())  # not the ambiguous rounding band
    try:
        path = plan_path(s, g, c, r, max_arc_step_deg=step_deg)
    except NoPathError:
        assert not _connected_on_a_grid(s, g, c, r)
        return
    np.testing.assert_array_equal(path[0], s)
    np.testing.assert_array_equal(path[-1], g)
    tail = path
    if len(c) and (np.hypot(*(s - c).T) < r).any():
        tail = path[1:]  # the way out, then outside every disc
        assert np.hypot(*(tail[0] - c).T).min() == pytest.approx(r, rel=1e-9)
    for centre in c:
        assert _distances(tail, centre).min() >= r * (1.0 - 1e-6)


@settings(max_examples=300, deadline=None)
@given(
    start=POINT, goal=POINT, centres=st.lists(POINT, min_size=1, max_size=6), r=st.floats(0.2, 2.0)
)
def test_around_disjoint_discs_the_detour_is_at_most_half_of_each_circle(start, goal, centres, r):
    # Disjoint discs leave one free region; following the straight line and going round each
    # disc it meets by the shorter half-circle is a path, so the shortest is no longer than
    # |s - g| + sum(pi r) (arcs stretched by the polyline at most tan(x) / x).
    s, g = np.array(start), np.array(goal)
    kept: list[np.ndarray] = []
    for p in map(np.array, centres):
        if all(np.hypot(*(p - q)) > 2.0 * r for q in kept):
            kept.append(p)
    c = np.array(kept)
    assume((np.hypot(*(s - c).T) > r).all() and (np.hypot(*(g - c).T) > r).all())
    path = plan_path(s, g, c, r)
    bound = np.hypot(*(g - s)) + len(c) * math.pi * r * _stretch(STEP_DEG)
    assert path_length_m(path) <= bound + 1e-9


@settings(max_examples=300, deadline=None)
@given(start=POINT, goal=POINT, centre=POINT, r=st.floats(0.2, 3.0))
def test_around_one_disc_the_length_is_the_tangents_and_the_arc(start, goal, centre, r):
    s, g, c = np.array(start), np.array(goal), np.array(centre)
    assume(np.hypot(*(s - c)) > r * 1.001 and np.hypot(*(g - c)) > r * 1.001)
    path = plan_path(s, g, [c], r)
    length = path_length_m(path)
    exact, arc_rad = _one_disc_length(s, g, c, r)
    if arc_rad <= 0.0:  # the tangents' touching points pass each other: the line is clear
        assert length == pytest.approx(np.hypot(*(g - s)), rel=1e-12)
    else:
        assert exact - 1e-9 <= length <= exact + r * arc_rad * (_stretch(STEP_DEG) - 1) + 1e-9


# ------------------------------------------------------------------------------- follower


def test_the_carrot_is_one_lookahead_along_the_path():
    ref = follow_path(
        [[0.0, 0.0], [10.0, 0.0]], [2.0, 0.3, 0.9], altitude_m=1.5, speed_mps=2.0, lookahead_m=1.0
    )
    np.testing.assert_allclose(ref.p_w, [3.0, 0.0, 1.5])
    np.testing.assert_allclose(ref.v_w, [2.0, 0.0, 0.0])
    assert ref.yaw_rad == 0.0 and ref.remaining_m == pytest.approx(8.0)


def test_round_a_corner_the_carrot_and_heading_turn_first():
    # Nearest point (4, 0), 2 m on: 1 m to the corner, then 1 m up the second leg.
    ref = follow_path(
        [[0.0, 0.0], [5.0, 0.0], [5.0, 5.0]],
        [4.0, 0.0],
        altitude_m=1.0,
        speed_mps=3.0,
        lookahead_m=2.0,
    )
    np.testing.assert_allclose(ref.p_w, [5.0, 1.0, 1.0])
    np.testing.assert_allclose(ref.v_w, [0.0, 3.0, 0.0], atol=1e-15)
    assert ref.yaw_rad == pytest.approx(math.pi / 2)


def test_near_the_goal_the_reference_slows_to_a_stop_on_it():
    path = [[0.0, 0.0], [0.0, -10.0]]
    ref = follow_path(path, [0.0, -9.5], altitude_m=2.0, speed_mps=2.0, lookahead_m=1.0)
    np.testing.assert_allclose(ref.p_w, [0.0, -10.0, 2.0])
    np.testing.assert_allclose(ref.v_w, [0.0, -1.0, 0.0], atol=1e-15)  # half a lookahead left
    assert ref.yaw_rad == pytest.approx(-math.pi / 2)
    ref = follow_path(path, [0.0, -10.0], altitude_m=2.0, speed_mps=2.0, lookahead_m=1.0)
    np.testing.assert_allclose(ref.v_w, 0.0, atol=1e-15)
    still = follow_path(
        [[1.0, 1.0], [1.0, 1.0]],
        [1.0, 1.0],
        altitude_m=2.0,
        speed_mps=2.0,
        lookahead_m=1.0,
        yaw_still_rad=0.7,
    )
    assert still.yaw_rad == 0.7 and not still.v_w.any() and still.remaining_m == 0.0


@pytest.mark.parametrize("lookahead_m", [0.3, 0.5, 1.0])
def test_the_follower_flies_a_plan_to_its_goal(lookahead_m):
    # Stepping the drone onto each carrot in turn walks the planned path to the goal; each
    # carrot is on the path, outside the clearance, and the straight flight to it cuts inside
    # by at most lookahead^2 / (8 r) (a chord of that length on a circle of radius r).
    cone, r = np.array([10.0, 0.0]), 1.0
    path = plan_path([0.0, 0.0], [20.0, 0.0], [cone], r, max_arc_step_deg=1.0)
    p = np.array([0.0, 0.0])
    for _ in range(200):
        ref = follow_path(path, p, altitude_m=1.0, speed_mps=1.0, lookahead_m=lookahead_m)
        chord = np.array([p, ref.p_w[:2]])
        p = ref.p_w[:2]
        assert np.hypot(*(p - cone)) >= r * (1.0 - 1e-9)
        assert _distances(chord, cone).min() >= r - lookahead_m**2 / (8.0 * r) - 1e-9
    np.testing.assert_allclose(p, [20.0, 0.0])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"lookahead_m": 0.0}, "lookahead_m"),
        ({"speed_mps": -1.0}, "speed_mps"),
        ({"altitude_m": math.nan}, "altitude_m"),
        ({"p_w": [1.0, 2.0, 3.0, 4.0]}, "p_w"),
        ({"path_xy_w": [[0.0, 0.0, 0.0]]}, "path_xy_w"),
    ],
)
def test_follower_bad_input_is_refused_naming_it(kwargs, match):
    args = {
        "path_xy_w": [[0.0, 0.0], [1.0, 0.0]],
        "p_w": [0.0, 0.0],
        "altitude_m": 1.0,
        "speed_mps": 1.0,
        "lookahead_m": 1.0,
    } | kwargs
    path, p = args.pop("path_xy_w"), args.pop("p_w")
    with pytest.raises(ValueError, match=match):
        follow_path(path, p, **args)
