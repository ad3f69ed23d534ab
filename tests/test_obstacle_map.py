"""vnav.obstacle_map: estimates matched to obstacles within the gate and averaged, new cones
added, estimates outside the flight band (the naive chain's sky cone) left out; against means
computed with numpy and a camera view built with vnav's frame chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vnav import frames, se3, so3
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.estimators import naive
from vnav.navigate import plan_path
from vnav.obstacle_map import ObstacleMap, footprint_radius_m


def _map() -> ObstacleMap:
    return ObstacleMap(flight_altitude_m=1.0, vertical_margin_m=0.5, gate_m=1.0)


def test_unseen_cones_are_not_in_the_map_and_new_ones_are_added():
    m = _map()
    assert len(m) == 0 and m.centres_xy_w().shape == (0, 2)
    update = m.update(np.zeros((0, 3)), "depth_image")
    assert (update.fused, update.added, update.rejected) == (0, 0, 0)
    update = m.update([[5.0, 0.0, 0.01], [5.0, 3.0, -0.02]], "depth_image")
    assert (update.fused, update.added, update.rejected) == (0, 2, 0)
    np.testing.assert_array_equal(m.centres_xy_w(), [[5.0, 0.0], [5.0, 3.0]])
    assert [(o.method, o.n_seen) for o in m.obstacles] == [("depth_image", 1)] * 2


def test_estimates_within_the_gate_are_averaged_into_their_obstacle():
    m = _map()
    ticks = [
        [[5.0, 0.0, 0.0], [5.0, 3.0, 0.0]],
        [[5.3, 3.2, 0.1], [5.1, -0.2, 0.02]],  # the other order: matched by distance
        [[4.8, 0.1, -0.05]],
    ]
    for tick in ticks:
        m.update(tick, "ground_plane")
    first = np.array([ticks[0][0], ticks[1][1], ticks[2][0]])
    second = np.array([ticks[0][1], ticks[1][0]])
    obstacles = m.obstacles
    np.testing.assert_allclose(obstacles[0].p_xy_w, first[:, :2].mean(axis=0), atol=1e-15)
    np.testing.assert_allclose(obstacles[1].p_xy_w, second[:, :2].mean(axis=0), atol=1e-15)
    assert obstacles[0].base_z_m == pytest.approx(first[:, 2].mean(), abs=1e-15)
    assert [o.n_seen for o in obstacles] == [3, 2]


def test_an_estimate_beyond_the_gate_is_another_cone():
    m = _map()
    m.update([[5.0, 0.0, 0.0]], "depth_image")
    update = m.update([[6.2, 0.0, 0.0]], "depth_image")  # 1.2 m away, gate 1 m
    assert (update.fused, update.added) == (0, 1) and len(m) == 2


def test_one_tick_gives_an_obstacle_at_most_one_estimate_the_closest():
    m = _map()
    m.update([[5.0, 0.0, 0.0]], "depth_image")
    update = m.update([[5.6, 0.0, 0.0], [5.2, 0.0, 0.0]], "depth_image")
    assert (update.fused, update.added) == (1, 1)
    np.testing.assert_allclose(m.centres_xy_w(), [[5.1, 0.0], [5.6, 0.0]])


def test_an_obstacle_keeps_the_method_that_put_it_there():
    m = _map()
    m.update([[5.0, 0.0, 0.0]], "depth_image")
    m.update([[5.1, 0.0, 0.0], [9.0, 0.0, 0.0]], "user:mine")
    assert [(o.method, o.n_seen) for o in m.obstacles] == [("depth_image", 2), ("user:mine", 1)]


def test_the_naive_chain_puts_the_cone_in_the_sky_and_out_of_the_map():
    # A drone at 1 m, yawed 30 deg, its camera pitched 20 deg down, sees a cone 6 m away. The
    # lecture's chain p_w = T_w_b T_b_c p_c gives the cone back on the ground; the naive
    # t_w_b + p_c puts it at 1 m + its depth (z forward in the optical frame): in the sky,
    # above the flight band, so that map holds no obstacle and a plan through the cone stays
    # straight, while the right map bends the plan round it.
    p_cone_w = np.array([6.0, 2.0, 0.0])
    T_w_b = se3.make(so3.rot_z(math.radians(30.0)), [0.0, 0.0, 1.0])
    T_b_c = se3.make(frames.mount_rotation(math.radians(20.0)), [0.1, 0.0, 0.0])
    p_c = se3.apply(se3.invert(T_w_b @ T_b_c), p_cone_w)
    assert p_c[2] > 5.0  # in front of the camera
    chained = se3.apply(T_w_b @ T_b_c, p_c)
    sky = naive(p_c, T_w_b[:3, 3])
    assert sky[2] == pytest.approx(1.0 + p_c[2])

    right, wrong = _map(), _map()
    assert right.update([chained], "depth_image").added == 1
    assert wrong.update([sky], "naive").rejected == 1 and len(wrong) == 0
    goal = 2.0 * p_cone_w[:2]  # the straight line runs through the cone
    assert len(plan_path([0.0, 0.0], goal, wrong.centres_xy_w(), 1.0)) == 2
    bent = plan_path([0.0, 0.0], goal, right.centres_xy_w(), 1.0)
    assert len(bent) > 2


@pytest.mark.parametrize(
    ("z_m", "kept"),
    [(-0.5, True), (-0.51, False), (1.5, True), (1.51, False), (0.7, True), (40.0, False)],
)
def test_the_flight_band_is_from_the_ground_tolerance_to_altitude_plus_margin(z_m, kept):
    m = _map()
    assert m.z_band_m == (-0.5, 1.5)
    update = m.update([[3.0, 0.0, z_m]], "depth_image")
    assert (update.added, update.rejected) == ((1, 0) if kept else (0, 1))


def test_the_footprint_is_the_widest_corner_of_the_cone():
    for cone in (TRAFFIC_CONE, ConeModel(base_width_m=0.5, body_radius_m=0.2)):
        corners_w = cone.extreme_points([0.0, 0.0, 0.0])
        widest = np.hypot(corners_w[:, 0], corners_w[:, 1]).max()
        assert footprint_radius_m(cone) == pytest.approx(widest, rel=1e-15)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda m: m.update([[1.0, 2.0]], "depth_image"), "p_w"),
        (lambda m: m.update([[1.0, 2.0, math.nan]], "depth_image"), "p_w"),
        (lambda m: m.update([[1.0, 2.0, 0.0]], ""), "method"),
        (lambda m: ObstacleMap(flight_altitude_m=0.0), "flight_altitude_m"),
        (lambda m: ObstacleMap(flight_altitude_m=1.0, gate_m=-1.0), "gate_m"),
        (lambda m: ObstacleMap(flight_altitude_m=1.0, vertical_margin_m=math.inf), "vertical"),
    ],
)
def test_bad_input_is_refused_naming_it(call, match):
    with pytest.raises(ValueError, match=match):
        call(_map())
