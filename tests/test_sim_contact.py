"""The drone against the cones: contacts, clearance and a flight that ends at the first contact.

Distances are checked against the cone's shape computed by hand (vnav.cone.TRAFFIC_CONE's
numbers, the quadrotor's geom sizes of models/quadrotor.xml), not against MuJoCo itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim import names
from sim.config import SceneConfig
from sim.contact import cone_clearance, cone_contacts, first_cone_contact
from sim.flight import Reference, ReferenceFollower
from sim.gl import mujoco
from sim.world import World
from vnav.cone import TRAFFIC_CONE

H_M = TRAFFIC_CONE.height_m
T_M = TRAFFIC_CONE.base_thickness_m
R_M = TRAFFIC_CONE.body_radius_m
SLANT_M = math.hypot(H_M - T_M, R_M)

HULL_HALF_M = (0.09, 0.05, 0.035)
HULL_Z_B_M = 0.01
"""The hull box of models/quadrotor.xml: half sizes and its centre's height in the body."""
ROTOR_FL_B_M = (0.14, 0.18, 0.055)
ROTOR_RADIUS_M, ROTOR_HALF_M = 0.09, 0.004
"""The front-left rotor disc of models/quadrotor.xml: centre in the body, radius, half height."""

DIST_TOL_M = 1e-5
"""MuJoCo's distance is exact for these convex pairs up to its GJK tolerance (``opt.ccd_tolerance``,
1e-6) and the mesh's float32 vertices (~1e-7 m over a 1 m cone); ten times the first."""


def _pose(p_w, yaw_rad: float = 0.0) -> np.ndarray:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = p_w
    return T


def _ridge_distance(x0: float, z0: float) -> tuple[float, np.ndarray]:
    """Distance from the point (x0, 0, z0) of a cone's frame to the ridge of its mesh at angle 0.

    The mesh (``sim.world.cone_mesh_vertices``) has a vertex of its ring at (R, 0, T): the edge
    from there to the apex (0, 0, H) is a line of the true cone. In the xz plane its outward
    normal is n = (H - T, R) / slant; the distance is n . ((x0, z0) - (0, H)) when the foot of
    the perpendicular lies between the apex and the ring. Returns the distance and the foot.
    """
    n = np.array([H_M - T_M, R_M]) / SLANT_M
    u = np.array([R_M, -(H_M - T_M)]) / SLANT_M  # down the ridge from the apex
    rel = np.array([x0, z0 - H_M])
    along = float(rel @ u)
    assert 0.0 < along < SLANT_M, "test set-up: the foot must lie on the ridge"
    foot = np.array([0.0, H_M]) + along * u
    return float(rel @ n), np.array([foot[0], 0.0, foot[1]])


# ------------------------------------------------------------------------------- geometry
def test_cone_collision_hull_is_the_rendered_mesh() -> None:
    world = World.from_config(SceneConfig())
    m = world.model
    mesh = m.mesh(names.CONE_MESH)
    graph = m.mesh_graph[int(mesh.graphadr[0]) :]
    # MuJoCo collides with the convex hull (mesh_graph: number of vertices, then faces); the
    # drawn mesh has the same vertices and faces: the hull is what is drawn.
    assert int(graph[0]) == int(mesh.vertnum[0])
    assert int(graph[1]) == int(mesh.facenum[0])
    geom = m.geom(names.cone_shell_geom(0))
    assert geom.contype[0] and geom.conaffinity[0]
    assert m.geom(names.cone_base_geom(0)).contype[0]


def test_every_drawn_drone_geom_collides() -> None:
    world = World.from_config(SceneConfig())
    m = world.model
    drone = world.drone_geom_ids
    assert {m.geom(int(g)).name for g in drone} >= {
        "drone_hull",
        "drone_rotor_fl",
        "drone_rotor_rl",
        "drone_rotor_rr",
        "drone_rotor_fr",
    }
    for g in drone:
        # Collides with the cones (contype & conaffinity nonzero both ways).
        cone = world.cone_geom_ids[0, 1]
        assert m.geom_contype[g] & m.geom_conaffinity[cone], m.geom(int(g)).name
        assert m.geom_conaffinity[g] & m.geom_contype[cone], m.geom(int(g)).name


# ------------------------------------------------------------------------------- contacts
CONES_W = ((6.0, 1.0, 0.0), (0.0, 5.0, 0.0), (-3.0, -2.0, 0.0))


def test_rotor_disc_inside_a_cone_is_a_contact_with_that_cone() -> None:
    world = World.from_config(SceneConfig(cones_w=CONES_W))
    # The front-left rotor's centre 3 cm inside cone 2's body at 0.4 m; the hull 0.2 m away.
    cone = np.array(CONES_W[2])
    radius_at = R_M * (H_M - 0.4) / (H_M - T_M)
    alpha = math.atan2(ROTOR_FL_B_M[1], ROTOR_FL_B_M[0])
    yaw = math.pi - alpha  # the rotor's arm points along world -x
    rotor_w = cone + np.array([radius_at + ROTOR_RADIUS_M - 0.03, 0.0, 0.4])
    T = _pose([0.0, 0.0, 0.0], yaw)
    T[:3, 3] = rotor_w - T[:3, :3] @ ROTOR_FL_B_M
    world.set_time(2.5)
    world.set_pose(T)
    contacts = cone_contacts(world)
    assert contacts, "a rotor disc inside a cone must touch it"
    assert {c.cone_index for c in contacts} == {2}
    first = first_cone_contact(world)
    assert (first.drone_geom, first.depth_m) == (contacts[0].drone_geom, contacts[0].depth_m)
    assert first.drone_geom == "drone_rotor_fl"
    assert first.cone_geom == names.cone_shell_geom(2)
    assert first.time_s == 2.5
    # Penetration: minus the distance from the disc's lower rim to the ridge (negative inside).
    overlap, _ = _ridge_distance(radius_at - 0.03, 0.4 - ROTOR_HALF_M)
    assert first.depth_m == pytest.approx(-overlap, abs=DIST_TOL_M)
    # The point lies where the two overlap: at the rotor's height, by the cone's surface.
    assert first.p_w[2] == pytest.approx(0.4, abs=ROTOR_HALF_M + 1e-9)
    horizontal_m = np.linalg.norm(first.p_w[:2] - cone[:2])
    assert abs(horizontal_m - radius_at) <= first.depth_m + 1e-6
    clearance = cone_clearance(world)
    assert clearance.distance_m[2] < 0.0
    assert clearance.nearest_cone == 2
    assert np.all(clearance.distance_m[:2] > 1.0)


def test_hull_inside_a_cone_gives_that_cone_and_no_contact_when_clear() -> None:
    world = World.from_config(SceneConfig(cones_w=CONES_W))
    world.set_pose(_pose(np.add(CONES_W[1], [0.1, 0.0, 0.3])))
    contacts = cone_contacts(world)
    assert contacts and {c.cone_index for c in contacts} == {1}
    assert "drone_hull" in {c.drone_geom for c in contacts}
    world.set_pose(_pose([2.0, 2.0, 5.0]))
    assert first_cone_contact(world) is None
    # Standing on the ground: ground contacts, no cone contact.
    world.set_pose(_pose([2.0, 2.0, 0.09]))  # the legs reach 0.098 m below the centre
    assert world.data.ncon > 0
    assert cone_contacts(world) == []


# ------------------------------------------------------------------------------- clearance
@pytest.mark.parametrize(("x0", "z0"), [(0.15, 0.35), (0.30, 0.2), (0.05, 0.5)])
def test_hull_clearance_equals_the_distance_to_the_cone_ridge(x0: float, z0: float) -> None:
    cone = np.array([6.0, 1.0, 0.0])
    world = World.from_config(SceneConfig(cones_w=(tuple(cone),)))
    # Level, yaw 0: the hull's bottom edge nearest the cone at (x0, ., z0) in the cone's frame.
    p_w = cone + np.array([x0 + HULL_HALF_M[0], 0.0, z0 + HULL_HALF_M[2] - HULL_Z_B_M])
    world.set_pose(_pose(p_w))
    expected, foot = _ridge_distance(x0, z0)
    hull = [world.model.geom("drone_hull").id]
    got = cone_clearance(world, drone_geom_ids=hull)
    assert got.distance_m[0] == pytest.approx(expected, abs=DIST_TOL_M)
    np.testing.assert_allclose(got.p_cone_w[0], cone + foot, atol=1e-4)
    np.testing.assert_allclose(got.p_drone_w[0], cone + np.array([x0, 0.0, z0]), atol=1e-4)
    assert got.drone_geom == ("drone_hull",)


def test_drone_clearance_is_its_rotor_rim_to_the_cone_ridge() -> None:
    cone = np.array([0.0, 5.0, 0.0])
    world = World.from_config(SceneConfig(cones_w=((6.0, 1.0, 0.0), tuple(cone))))
    alpha = math.atan2(ROTOR_FL_B_M[1], ROTOR_FL_B_M[0])
    T = _pose([0.0, 0.0, 0.0], math.pi - alpha)  # the front-left rotor towards world -x
    rotor_w = cone + np.array([0.12 + ROTOR_RADIUS_M, 0.0, 0.4])
    T[:3, 3] = rotor_w - T[:3, :3] @ ROTOR_FL_B_M
    world.set_pose(T)
    # The disc's nearest point: its rim towards the cone, on its lower face.
    x0, z0 = 0.12, 0.4 - ROTOR_HALF_M
    expected, foot = _ridge_distance(x0, z0)
    got = cone_clearance(world)
    assert got.drone_geom[1] == "drone_rotor_fl"
    assert got.distance_m[1] == pytest.approx(expected, abs=DIST_TOL_M)
    np.testing.assert_allclose(got.p_cone_w[1], cone + foot, atol=1e-4)
    assert got.nearest_cone == 1
    assert got.min_distance_m == got.distance_m[1]
    # Beyond distmax_m a cone is not measured.
    near = cone_clearance(world, distmax_m=1.0)
    assert near.distance_m[1] == got.distance_m[1]
    assert near.distance_m[0] == math.inf and np.all(np.isnan(near.p_drone_w[0]))


def test_clearance_rejects_bad_input() -> None:
    world = World.from_config(SceneConfig())
    with pytest.raises(ValueError, match="distmax_m"):
        cone_clearance(world, distmax_m=0.0)
    with pytest.raises(ValueError, match="drone_geom_ids"):
        cone_clearance(world, drone_geom_ids=[int(world.cone_geom_ids[0, 0])])


# ------------------------------------------------------------------------------- flight
def _fly_line(world: World, goal_w, speed_m_s: float, duration_s: float, tick_hz: float = 20.0):
    """A stand-in for the navigate mode: at each camera tick, a reference moving at
    ``speed_m_s`` on the straight line from the start to ``goal_w``, then holding the goal."""
    start = world.position_w.copy()
    goal = np.asarray(goal_w, dtype=np.float64)
    length = float(np.linalg.norm(goal - start))
    direction = (goal - start) / length
    follower = ReferenceFollower(world)
    steps_per_tick = round(1.0 / (tick_hz * world.model.opt.timestep))
    while world.time_s < duration_s - 1e-9:
        s = speed_m_s * world.time_s
        if s < length:
            ref = Reference(p_w=start + s * direction, v_w=speed_m_s * direction)
        else:
            ref = Reference(p_w=goal)
        follower.set_reference(ref)
        if follower.step(steps_per_tick) is not None:
            break
    return follower


def test_follower_flies_a_straight_reference_to_its_goal() -> None:
    world = World.from_config(
        SceneConfig(cones_w=((20.0, 5.0, 0.0),), start_position_w=(0.0, 0.0, 1.0))
    )
    goal = np.array([8.0, 0.0, 1.0])
    follower = _fly_line(world, goal, speed_m_s=2.0, duration_s=7.0)
    assert follower.contact is None
    assert np.linalg.norm(world.position_w - goal) < 0.3
    assert cone_clearance(world).min_distance_m > 1.0


def test_follower_flies_into_a_cone_on_its_line_and_stops_there() -> None:
    cones = ((20.0, 5.0, 0.0), (4.0, 0.0, 0.0))
    world = World.from_config(SceneConfig(cones_w=cones, start_position_w=(0.0, 0.0, 0.5)))
    follower = _fly_line(world, [8.0, 0.0, 0.5], speed_m_s=2.0, duration_s=7.0)
    hit = follower.contact
    assert hit is not None, "the drone flew through a cone without touching it"
    assert hit.cone_index == 1
    assert world.time_s == hit.time_s  # stopped in the state of first contact
    assert 1.0 < hit.time_s < 3.0  # the line reaches the cone at about 2 s
    assert world.position_w[0] < 4.0  # before the cone's axis
    assert cone_clearance(world).distance_m[1] <= 1e-6
    assert np.linalg.norm(hit.p_w[:2] - [4.0, 0.0]) <= R_M + hit.depth_m
    with pytest.raises(RuntimeError, match="cone 1"):
        follower.step()


def test_hitting_a_cone_at_speed_does_not_diverge() -> None:
    # Plain physics, no follower to stop it: 15 m/s into a cone, then 1 s of bouncing around.
    world = World.from_config(SceneConfig(cones_w=((1.0, 0.0, 0.0),), start_position_w=(0, 0, 0.4)))
    world.set_velocity(np.array([15.0, 0.0, 0.0]), np.zeros(3))
    touched = False
    for _ in range(round(1.0 / world.model.opt.timestep)):
        world.step()
        touched |= first_cone_contact(world) is not None
    assert touched
    assert np.all(np.isfinite(world.data.qpos))


def test_follower_rejects_a_bad_reference() -> None:
    world = World.from_config(SceneConfig())
    follower = ReferenceFollower(world)
    np.testing.assert_allclose(follower.reference.p_w, world.position_w)
    with pytest.raises(ValueError, match="p_w"):
        follower.set_reference(Reference(p_w=np.array([0.0, math.nan, 1.0])))
    with pytest.raises(ValueError, match="v_w"):
        follower.set_reference(Reference(p_w=np.zeros(3), v_w=np.zeros(2)))
    with pytest.raises(ValueError, match="Reference"):
        follower.set_reference(np.zeros(3))


def test_follower_carries_the_reference_forward_between_ticks() -> None:
    world = World.from_config(SceneConfig())
    follower = ReferenceFollower(world)
    follower.set_reference(
        Reference(p_w=np.array([1.0, 2.0, 3.0]), v_w=np.array([1.0, 0.0, 0.0]), a_w=np.ones(3)),
        t_s=1.0,
    )
    ref = follower.reference_at(1.5)
    np.testing.assert_allclose(ref.p_w, [1.0 + 0.5 + 0.125, 2.125, 3.125])
    np.testing.assert_allclose(ref.v_w, [1.5, 0.5, 0.5])


def test_follower_placed_in_a_cone_ends_before_stepping() -> None:
    world = World.from_config(SceneConfig(cones_w=CONES_W))
    world.set_pose(_pose(np.add(CONES_W[0], [0.1, 0.0, 0.3])))
    follower = ReferenceFollower(world)
    t0_s, T0_w_b = world.time_s, world.T_w_b
    hit = follower.step(10)
    assert hit is not None and hit.cone_index == 0
    assert world.time_s == t0_s  # no physics step, no contact force
    np.testing.assert_array_equal(world.T_w_b, T0_w_b)


def test_clearance_is_the_minimum_over_every_geom_pair() -> None:
    # The pruning by bounding volumes must never skip the closest pair: compare with every
    # drone-cone pair measured, over random poses around and inside the cone.
    cone = np.array([0.0, 0.0, 0.0])
    world = World.from_config(SceneConfig(cones_w=(tuple(cone), (3.0, 0.0, 0.0))))
    m, d = world.model, world.data
    rng = np.random.default_rng(7)
    fromto = np.zeros(6)
    for _ in range(300):
        p_w = cone + rng.uniform([-0.6, -0.6, 0.05], [0.6, 0.6, 1.0])
        q = rng.normal(size=4)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
        T[:3, 3] = p_w
        world.set_pose(T)
        got = cone_clearance(world)
        for i, ids in enumerate(world.cone_geom_ids):
            every = [
                mujoco.mj_geomDistance(m, d, int(g), int(c), math.inf, fromto)
                for g in world.drone_geom_ids
                for c in ids
            ]
            assert got.distance_m[i] == pytest.approx(min(every), abs=1e-9)
