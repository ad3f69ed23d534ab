"""Triangle meshes of a compiled model's geoms: the drone and the cones as the recording draws them.

The meshes are built from the MuJoCo model itself (each geom's type, size, pose in its body
and colour), so what the viewer shows is what the simulator simulates, not a drawing of it.
Boxes and mesh geoms are exact; spheres, ellipsoids, cylinders and capsules are tessellated
with ``SEGMENTS`` facets around their axis. Boxes and meshes are shaded flat (vertices not
shared, each triangle with its own normal: crisp edges); round shapes share their vertices
with averaged normals (smooth, and three times fewer vertices in the recording).

This module only reads the model; the recording (``scenarios.record.recording``) gets plain arrays
(``TriangleMesh``) and needs no MuJoCo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sim import names
from vnav import quat, se3

__all__ = ["SEGMENTS", "Scenery", "TriangleMesh", "body_mesh", "geom_mesh", "scenery"]

SEGMENTS = 16
"""Facets around the axis of a tessellated sphere, cylinder or capsule."""


@dataclass(frozen=True)
class TriangleMesh:
    """An indexed triangle mesh with flat normals and per-vertex colours.

    Attributes
    ----------
    vertices : ndarray, shape (N, 3), float64
        Metres, in the frame the producer names (a body frame, or the world).
    triangles : ndarray, shape (M, 3), uint32
        Vertex indices, counter-clockwise seen from outside.
    normals : ndarray, shape (N, 3), float64
        Unit outward normal of each vertex's face.
    colors_rgba : ndarray, shape (N, 4), uint8
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    colors_rgba: np.ndarray

    def transformed(self, T_a_b: np.ndarray) -> TriangleMesh:
        """The mesh given in frame b, expressed in frame a (``p_a = T_a_b p_b``)."""
        T_a_b = se3.check_pose(T_a_b, "T_a_b")
        return TriangleMesh(
            se3.apply(T_a_b, self.vertices),
            self.triangles,
            self.normals @ T_a_b[:3, :3].T,
            self.colors_rgba,
        )

    @staticmethod
    def concatenate(meshes: list[TriangleMesh]) -> TriangleMesh:
        """One mesh holding all of ``meshes`` (indices shifted)."""
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return TriangleMesh(
            np.concatenate([m.vertices for m in meshes]).reshape(-1, 3),
            np.concatenate(
                [m.triangles + np.uint32(o) for m, o in zip(meshes, offsets, strict=True)]
            ).reshape(-1, 3),
            np.concatenate([m.normals for m in meshes]).reshape(-1, 3),
            np.concatenate([m.colors_rgba for m in meshes]).reshape(-1, 4),
        )


@dataclass(frozen=True)
class Scenery:
    """What of the scene is drawn as meshes.

    Attributes
    ----------
    drone_b : TriangleMesh
        The quadrotor's geoms in its body frame (FLU, origin at the centre of mass).
    cones_w : TriangleMesh
        Every cone (base plate and shell) in the world frame.
    """

    drone_b: TriangleMesh
    cones_w: TriangleMesh


def scenery(model: mujoco.MjModel, data: mujoco.MjData, n_cones: int) -> Scenery:
    """The drone in its body frame and cones 0 .. n_cones - 1 where ``data`` has them.

    ``data`` must have been through a forward pass (its body poses are read).
    """
    drone_b = body_mesh(model, model.body(names.DRONE_BODY).id)
    cones = []
    for i in range(n_cones):
        body = model.body(names.cone_body(i)).id
        T_w_cone = se3.make(data.xmat[body].reshape(3, 3), data.xpos[body])
        cones.append(body_mesh(model, body).transformed(T_w_cone))
    return Scenery(drone_b, TriangleMesh.concatenate(cones))


def body_mesh(model: mujoco.MjModel, body_id: int) -> TriangleMesh:
    """Every geom of one body (not of its children), in the body's frame.

    Parameters
    ----------
    model : mujoco.MjModel
    body_id : int

    Raises
    ------
    ValueError
        If the body has no geom that can be drawn (planes, height fields and SDFs are not).
    """
    parts = [geom_mesh(model, int(g)) for g in np.flatnonzero(model.geom_bodyid == body_id)]
    parts = [p for p in parts if p is not None]
    if not parts:
        raise ValueError(f"body {model.body(body_id).name!r} has no geom that can be drawn")
    return TriangleMesh.concatenate(parts)


def geom_mesh(model: mujoco.MjModel, geom_id: int) -> TriangleMesh | None:
    """One geom in its body's frame (placed by ``geom_pos`` / ``geom_quat``), coloured by its
    material or its ``rgba``; None for a geom type that cannot be drawn (plane, height field,
    SDF)."""
    local = _geom_local(model, geom_id)
    if local is None:
        return None
    vertices, triangles, smooth = local
    T_b_g = se3.make(
        quat.to_matrix(quat.wxyz_to_xyzw(model.geom_quat[geom_id]), normalize=True),
        model.geom_pos[geom_id],
    )
    mat = model.geom_matid[geom_id]
    rgba = model.mat_rgba[mat] if mat >= 0 else model.geom_rgba[geom_id]
    shade = _smooth if smooth else _flat
    return shade(se3.apply(T_b_g, vertices), triangles, rgba)


def _flat(vertices: np.ndarray, triangles: np.ndarray, rgba: np.ndarray) -> TriangleMesh:
    """Unshare vertices so that each triangle has its own face normal; one colour."""
    corners = vertices[triangles]  # (M, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    keep = lengths[:, 0] > 1e-12  # degenerate facets (at a pole) have no normal
    corners, normals = corners[keep], normals[keep] / lengths[keep]
    n = len(corners)
    color = np.clip(np.rint(np.asarray(rgba) * 255.0), 0, 255).astype(np.uint8)
    return TriangleMesh(
        corners.reshape(-1, 3),
        np.arange(3 * n, dtype=np.uint32).reshape(n, 3),
        np.repeat(normals, 3, axis=0),
        np.tile(color, (3 * n, 1)),
    )


def _smooth(vertices: np.ndarray, triangles: np.ndarray, rgba: np.ndarray) -> TriangleMesh:
    """Shared vertices, each normal the area-weighted mean of its faces' normals; one colour."""
    corners = vertices[triangles]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    keep = np.linalg.norm(face_normals, axis=1) > 1e-12  # degenerate facets (at a pole)
    triangles, face_normals = triangles[keep], face_normals[keep]
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face_normals)
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0.0)
    color = np.clip(np.rint(np.asarray(rgba) * 255.0), 0, 255).astype(np.uint8)
    return TriangleMesh(
        vertices, triangles.astype(np.uint32), normals, np.tile(color, (len(vertices), 1))
    )


def _geom_local(model: mujoco.MjModel, g: int) -> tuple[np.ndarray, np.ndarray, bool] | None:
    """(vertices, triangles, smooth) of geom ``g`` in its own frame, or None if it is not
    drawable."""
    kind = mujoco.mjtGeom(model.geom_type[g])
    size = model.geom_size[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return *_box(size), False
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return *_round(size[0], size[0], 0.0), True
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        vertices, triangles = _round(1.0, 1.0, 0.0)
        return vertices * size, triangles, True
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # size: radius, half-length of the cylinder
        return *_round(size[0], size[0], size[1]), True
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:  # size: radius, half-height
        return *_cylinder(size[0], size[1]), True
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        f0, nf = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
        return (
            np.asarray(model.mesh_vert[v0 : v0 + nv], dtype=np.float64),
            np.asarray(model.mesh_face[f0 : f0 + nf], dtype=np.int64),
            False,
        )
    return None


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box of half sizes ``half`` centred at the origin."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    # Corner index = 4 * (x > 0) + 2 * (y > 0) + (z > 0); two triangles per face, outward.
    faces = [
        (0, 1, 3), (0, 3, 2),  # -x
        (4, 6, 7), (4, 7, 5),  # +x
        (0, 4, 5), (0, 5, 1),  # -y
        (2, 3, 7), (2, 7, 6),  # +y
        (0, 2, 6), (0, 6, 4),  # -z
        (1, 5, 7), (1, 7, 3),  # +z
    ]  # fmt: skip
    return signs * np.asarray(half[:3]), np.array(faces, dtype=np.int64)


def _round(radius_xy: float, radius_z: float, half_length: float) -> tuple[np.ndarray, np.ndarray]:
    """A sphere, or a capsule when ``half_length`` > 0 (hemispheres moved apart along z)."""
    n_lon, n_lat = SEGMENTS, SEGMENTS // 2
    lat = np.linspace(-math.pi / 2, math.pi / 2, n_lat + 1)
    if half_length > 0.0:  # duplicate the equator: one ring per hemisphere
        lat = np.concatenate([lat[: n_lat // 2 + 1], lat[n_lat // 2 :]])
    lon = np.linspace(0.0, 2.0 * math.pi, n_lon, endpoint=False)
    rings = []
    for i, phi in enumerate(lat):
        shift = (-half_length if i <= n_lat // 2 else half_length) if half_length > 0.0 else 0.0
        rings.append(
            np.column_stack(
                [
                    radius_xy * math.cos(phi) * np.cos(lon),
                    radius_xy * math.cos(phi) * np.sin(lon),
                    np.full(n_lon, radius_z * math.sin(phi) + shift),
                ]
            )
        )
    return np.concatenate(rings), _grid_triangles(len(lat), n_lon)


def _cylinder(radius: float, half_height: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder along z."""
    lon = np.linspace(0.0, 2.0 * math.pi, SEGMENTS, endpoint=False)
    ring = np.column_stack([radius * np.cos(lon), radius * np.sin(lon)])
    # Rings: bottom centre (collapsed), bottom rim, top rim, top centre (collapsed).
    rings = [
        np.column_stack([np.zeros_like(ring), np.full(SEGMENTS, z)])
        if collapsed
        else np.column_stack([ring, np.full(SEGMENTS, z)])
        for collapsed, z in (
            (True, -half_height),
            (False, -half_height),
            (False, half_height),
            (True, half_height),
        )
    ]
    return np.concatenate(rings), _grid_triangles(4, SEGMENTS)


def _grid_triangles(n_rings: int, n_lon: int) -> np.ndarray:
    """Triangles joining consecutive rings of ``n_lon`` vertices each, outward for rings
    ordered bottom to top and counter-clockwise seen from +z."""
    tris = []
    for i in range(n_rings - 1):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            tris += [(a, b, d), (a, d, c)]
    return np.array(tris, dtype=np.int64)
