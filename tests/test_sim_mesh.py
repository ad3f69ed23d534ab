"""The meshes the recording draws, held against MuJoCo's own view of the same geoms.

Each vertex is placed through MuJoCo's computed geom pose (``geom_xpos`` / ``geom_xmat``
after a forward pass at an arbitrary drone pose) and must lie on that geom's surface as its
type and ``geom_size`` define it; each mesh's extent in its geom frame must equal MuJoCo's
``geom_aabb``; every face must point outward; the cone's shell must have the dimensions of
``vnav.cone.TRAFFIC_CONE``.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim import names
from sim.config import SceneConfig
from sim.mesh import TriangleMesh, body_mesh, geom_mesh, scenery
from sim.world import World
from vnav import quat, se3
from vnav.cone import TRAFFIC_CONE

SURFACE_ATOL_M = 1e-9
CONES_W = ((4.0, 1.0, 0.0), (6.0, -2.0, 0.0))


@pytest.fixture(scope="module")
def world() -> World:
    w = World.from_config(SceneConfig(cones_w=CONES_W))
    w.set_pose(se3.make(quat.to_matrix(quat.from_axis_angle([0.2, -0.5, 1.0], 1.1)), [1, 2, 3]))
    return w


def _drone_geoms(world: World) -> list[int]:
    return [int(g) for g in np.flatnonzero(world.model.geom_bodyid == world.body_id)]


def _in_geom_frame(world: World, g: int, mesh: TriangleMesh) -> np.ndarray:
    """The mesh's vertices (given in the geom's body frame) in the geom's own frame, through
    MuJoCo's world poses of the body and of the geom."""
    d, m = world.data, world.model
    body = m.geom_bodyid[g]
    p_w = mesh.vertices @ d.xmat[body].reshape(3, 3).T + d.xpos[body]
    return (p_w - d.geom_xpos[g]) @ d.geom_xmat[g].reshape(3, 3)


def _surface_residual(kind: int, size: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Zero where ``p`` (geom frame) is on the surface of a geom of that type and size."""
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return np.max(np.abs(p) / size, axis=1) - 1.0
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.linalg.norm(p, axis=1) - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # distance to the axis segment = radius
        on_axis = np.clip(p[:, 2], -size[1], size[1])
        return np.linalg.norm(p - np.outer(on_axis, [0, 0, 1]), axis=1) - size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return np.maximum(np.linalg.norm(p[:, :2], axis=1) / size[0], np.abs(p[:, 2]) / size[1]) - 1
    raise AssertionError(f"no surface test for geom type {kind}")


def test_drone_vertices_lie_on_mujocos_geoms(world):
    kinds = set()
    for g in _drone_geoms(world):
        mesh = geom_mesh(world.model, g)
        kind = int(world.model.geom_type[g])
        kinds.add(mujoco.mjtGeom(kind).name)
        p_g = _in_geom_frame(world, g, mesh)
        size = world.model.geom_size[g]
        residual = _surface_residual(kind, size, p_g)
        scale = 1.0 if kind != mujoco.mjtGeom.mjGEOM_BOX else 1.0 / size.min()
        assert np.max(np.abs(residual)) < SURFACE_ATOL_M * scale, world.model.geom(g).name
    # The quadrotor model uses boxes, capsules and cylinders: each surface test ran.
    assert kinds == {"mjGEOM_BOX", "mjGEOM_CAPSULE", "mjGEOM_CYLINDER"}


def test_drone_extents_equal_mujocos_bounding_boxes(world):
    for g in _drone_geoms(world):
        p_g = _in_geom_frame(world, g, geom_mesh(world.model, g))
        centre, half = world.model.geom_aabb[g][:3], world.model.geom_aabb[g][3:]
        # SEGMENTS is a multiple of 4: the facets reach each geom's extreme points exactly.
        assert np.allclose(p_g.min(axis=0), centre - half, atol=1e-9)
        assert np.allclose(p_g.max(axis=0), centre + half, atol=1e-9)


def test_every_face_points_outward_and_winds_counter_clockwise(world):
    meshes = [(g, geom_mesh(world.model, g)) for g in _drone_geoms(world)]
    cone_shell = world.model.geom(names.cone_shell_geom(0)).id
    meshes.append((cone_shell, geom_mesh(world.model, cone_shell)))
    for g, mesh in meshes:
        corners = mesh.vertices[mesh.triangles]
        face_n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        assert np.all(np.linalg.norm(face_n, axis=1) > 0.0)
        # Convex geoms: a face's normal points away from the geom's centre (MuJoCo's pose).
        centre_b = world.model.geom_pos[g]
        outward = np.einsum("ij,ij->i", face_n, corners.mean(axis=1) - centre_b)
        assert np.all(outward > 0.0), world.model.geom(g).name
        # The vertex normals agree with the winding (unit length, same side).
        normals = mesh.normals[mesh.triangles]
        assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0)
        assert np.all(np.einsum("ikj,ij->ik", normals, face_n) > 0.0), world.model.geom(g).name


def test_colours_are_mujocos(world):
    for g in _drone_geoms(world):
        mesh = geom_mesh(world.model, g)
        mat = world.model.geom_matid[g]
        rgba = world.model.mat_rgba[mat] if mat >= 0 else world.model.geom_rgba[g]
        assert np.all(np.abs(mesh.colors_rgba.astype(float) - 255 * rgba) <= 0.5)


def test_cones_have_the_traffic_cone_dimensions(world):
    scene = scenery(world.model, world.data, len(CONES_W))
    cone = TRAFFIC_CONE
    per_cone = len(scene.cones_w.vertices) // len(CONES_W)
    for i, p_w in enumerate(CONES_W):
        v = scene.cones_w.vertices[i * per_cone : (i + 1) * per_cone] - p_w
        half_base = cone.base_width_m / 2
        assert np.allclose(v.min(axis=0), [-half_base, -half_base, 0.0], atol=1e-9)
        assert np.allclose(v.max(axis=0), [half_base, half_base, cone.height_m], atol=1e-9)
        shell = v[v[:, 2] > cone.base_thickness_m + 1e-9]
        assert np.allclose(shell, [0.0, 0.0, cone.height_m], atol=1e-9)  # only the apex above
        on_plate = np.isclose(v[:, 2], cone.base_thickness_m)
        ring = v[on_plate & (np.abs(v[:, :2]).max(axis=1) < 0.9 * half_base)]
        assert np.allclose(np.linalg.norm(ring[:, :2], axis=1), cone.body_radius_m, atol=1e-9)


def test_transformed_mesh_moves_vertices_and_turns_normals(world):
    drone_b = body_mesh(world.model, world.body_id)
    moved = drone_b.transformed(world.T_w_b)
    assert np.allclose(moved.vertices, se3.apply(world.T_w_b, drone_b.vertices))
    assert np.allclose(moved.normals, drone_b.normals @ world.T_w_b[:3, :3].T)
    with pytest.raises(ValueError, match="T_a_b"):
        drone_b.transformed(np.eye(3))


def test_body_without_drawable_geom_is_refused(world):
    with pytest.raises(ValueError, match="no geom that can be drawn"):
        body_mesh(world.model, 0)  # the world body holds only the ground plane
