"""The drone against the cones: contacts and clearance from MuJoCo's own collision geometry.

Every drone geom (hull, arms, rotor discs, legs) and both geoms of every cone (base plate and
conical body) collide, and each is the shape that is drawn (docs/CONVENTIONS.md, "What
collides with what"), so a contact here is the drone touching a cone as the recording shows it.

- ``cone_contacts`` / ``first_cone_contact`` read ``data.contact`` of the current state: the
  drone's geoms touching or penetrating a cone's, with the cone's index, the simulated time and
  the contact point in the world.
- ``cone_clearance`` measures, per cone, the smallest signed distance between any drone geom and
  the cone's geoms with ``mujoco.mj_geomDistance`` (negative: penetration), and the two closest
  points. Bounding volumes order the geom pairs and skip those that cannot be closer than the
  best so far; a cone next to the drone costs tens of microseconds, a far one a few.

Both read the state as it is: after ``World.step`` or ``World.set_pose`` (which end with
``mj_forward``) the contacts and geom poses are those of the current ``time_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.gl import mujoco
from sim.world import World

__all__ = ["ConeClearance", "ConeContact", "cone_clearance", "cone_contacts", "first_cone_contact"]


@dataclass(frozen=True, eq=False)
class ConeContact:
    """The drone touching a cone, one MuJoCo contact (compared by identity: it holds an array).

    Attributes
    ----------
    cone_index : int
        Index of the cone in ``SceneConfig.cones_w``.
    time_s : float
        Simulated time of the state in contact, seconds.
    p_w : np.ndarray, shape (3,)
        Contact point in the world, metres (MuJoCo's: midway between the two surfaces).
    depth_m : float
        Penetration depth, metres, >= 0 (MuJoCo's ``-dist``).
    drone_geom : str
        Name of the drone's geom in contact (``drone_rotor_fl``, ...).
    cone_geom : str
        Name of the cone's geom in contact (``sim.names.cone_shell_geom`` or ``cone_base_geom``).
    """

    cone_index: int
    time_s: float
    p_w: np.ndarray
    depth_m: float
    drone_geom: str
    cone_geom: str


def cone_contacts(world: World) -> list[ConeContact]:
    """Every contact between a drone geom and a cone geom in the current state, deepest first.

    Parameters
    ----------
    world : World

    Returns
    -------
    list of ConeContact
        Empty if the drone touches no cone (contacts with the ground are not listed).
    """
    d, m = world.data, world.model
    n = int(d.ncon)
    if n == 0:
        return []
    contact = d.contact
    geoms = np.asarray(contact.geom[:n])
    dist = np.asarray(contact.dist[:n])
    cone_of = world.cone_index_of_geom[geoms]  # (n, 2)
    is_drone = np.isin(geoms, world.drone_geom_ids)
    # A contact pairs a drone geom with a cone geom in either order; a positive dist is a pair
    # within its margin but not yet touching (only with a margin > 0, the model has none).
    drone_first = is_drone[:, 0] & (cone_of[:, 1] >= 0)
    cone_first = is_drone[:, 1] & (cone_of[:, 0] >= 0)
    hits = np.flatnonzero((drone_first | cone_first) & (dist <= 0.0))
    out = []
    for k in hits[np.argsort(dist[hits], kind="stable")]:
        g_drone, g_cone = (geoms[k, 0], geoms[k, 1]) if drone_first[k] else geoms[k, ::-1]
        out.append(
            ConeContact(
                cone_index=int(cone_of[k, 1] if drone_first[k] else cone_of[k, 0]),
                time_s=float(d.time),
                p_w=np.array(contact.pos[k], dtype=np.float64),
                depth_m=float(-dist[k]),
                drone_geom=m.geom(int(g_drone)).name,
                cone_geom=m.geom(int(g_cone)).name,
            )
        )
    return out


def first_cone_contact(world: World) -> ConeContact | None:
    """The deepest drone-cone contact of the current state, or ``None`` if there is none.

    Called after every physics step (``sim.flight.ReferenceFollower`` does), the first state
    for which it is not ``None`` is the first contact of the flight.
    """
    if world.data.ncon == 0:  # the common case, in the air: no work
        return None
    contacts = cone_contacts(world)
    return contacts[0] if contacts else None


@dataclass(frozen=True, eq=False)
class ConeClearance:
    """Per cone, the drone's true clearance: MuJoCo's distance between their geoms.

    Attributes
    ----------
    distance_m : np.ndarray, shape (N,)
        Smallest signed distance between any drone geom and the cone's geoms (base plate or
        body), metres; negative when they penetrate; ``inf`` for a cone further than the
        ``distmax_m`` asked for.
    p_drone_w, p_cone_w : np.ndarray, shape (N, 3)
        The closest points on the drone and on the cone, world, metres (NaN where the distance
        is ``inf``). When penetrating they are MuJoCo's penetration witness points.
    drone_geom : tuple of str, length N
        Name of the drone geom nearest each cone ("" where the distance is ``inf``).
    """

    distance_m: np.ndarray
    p_drone_w: np.ndarray
    p_cone_w: np.ndarray
    drone_geom: tuple[str, ...]

    @property
    def nearest_cone(self) -> int | None:
        """Index of the nearest cone, ``None`` with no cone within reach."""
        if self.distance_m.size == 0 or not np.isfinite(self.distance_m).any():
            return None
        return int(np.argmin(self.distance_m))

    @property
    def min_distance_m(self) -> float:
        """The smallest clearance over every cone, metres (``inf`` with none within reach)."""
        return float(self.distance_m.min()) if self.distance_m.size else math.inf


def cone_clearance(world: World, distmax_m: float = math.inf, drone_geom_ids=None) -> ConeClearance:
    """The drone's clearance to each cone in the current state (``mujoco.mj_geomDistance``).

    Parameters
    ----------
    world : World
    distmax_m : float
        Cones further than this (metres, > 0) are reported at ``inf`` without a distance
        computation; ``inf`` (default) measures every cone.
    drone_geom_ids : array_like of int, optional
        The drone geoms to measure from (default: all of ``world.drone_geom_ids``).

    Returns
    -------
    ConeClearance

    Raises
    ------
    ValueError
        If ``distmax_m`` is not positive, or a geom id is not one of the drone's.
    """
    distmax = float(distmax_m)
    if not distmax > 0.0:  # also NaN
        raise ValueError(f"distmax_m must be positive, got {distmax_m!r}")
    drone = _drone_geoms(world, drone_geom_ids)
    m, d = world.model, world.data
    cones = world.cone_geom_ids  # (N, 2)
    n_cones = cones.shape[0]
    distance = np.full(n_cones, math.inf)
    p_drone = np.full((n_cones, 3), math.nan)
    p_cone = np.full((n_cones, 3), math.nan)
    nearest = [-1] * n_cones  # geom id of the nearest drone geom
    if n_cones == 0:
        return ConeClearance(distance, p_drone, p_cone, ())
    bound = _distance_lower_bounds(world, drone, cones)
    # The pairs are measured lowest bound first; one whose bound exceeds the best distance so
    # far cannot be the closest.
    fromto = np.zeros(6)
    for i in range(n_cones):
        b = bound[i].ravel()  # (2 G,): cone geom major
        best = distmax
        for k in np.argsort(b, kind="stable"):
            if b[k] >= best:
                break
            g_cone, g_drone = int(cones[i, k // drone.size]), int(drone[k % drone.size])
            dist = mujoco.mj_geomDistance(m, d, g_drone, g_cone, best, fromto)
            if dist < best:
                best = dist
                distance[i] = dist
                p_drone[i], p_cone[i] = fromto[:3], fromto[3:]
                nearest[i] = g_drone
    names = tuple(m.geom(g).name if g >= 0 else "" for g in nearest)
    return ConeClearance(distance, p_drone, p_cone, names)


def _drone_geoms(world: World, drone_geom_ids) -> np.ndarray:
    """The drone geoms to measure from: all of the drone's by default, else those given.

    Parameters
    ----------
    world : World
    drone_geom_ids : array_like of int or None
        Geom ids, each one of ``world.drone_geom_ids``; None: all of them.

    Returns
    -------
    np.ndarray, shape (G,), int
        Geom ids.

    Raises
    ------
    ValueError
        If ``drone_geom_ids`` is empty or holds a geom id that is not one of the drone's.
    """
    if drone_geom_ids is None:
        return world.drone_geom_ids
    drone = np.asarray(drone_geom_ids, dtype=np.int64).ravel()
    if drone.size == 0 or not np.isin(drone, world.drone_geom_ids).all():
        raise ValueError(
            f"drone_geom_ids must be geom ids of the drone ({world.drone_geom_ids.tolist()}), "
            f"got {drone.tolist()}"
        )
    return drone


def _distance_lower_bounds(world: World, drone: np.ndarray, cones: np.ndarray) -> np.ndarray:
    """A lower bound of the signed distance of each drone geom to each cone geom.

    The bound is that of the drone geom's bounding sphere to the cone geom's bounding box
    (MuJoCo's ``geom_aabb``, in the geom's frame): the box's signed distance function at the
    sphere's centre minus its radius. Distance and penetration depth are monotone in the
    shapes, so the pair can be no closer (nor deeper).

    Parameters
    ----------
    world : World
        Its current state places the geoms.
    drone : np.ndarray, shape (G,), int
        The drone's geom ids.
    cones : np.ndarray, shape (N, 2), int
        Each cone's two geom ids (``world.cone_geom_ids``).

    Returns
    -------
    np.ndarray, shape (N, 2, G)
        Metres, by cone, cone geom, drone geom.
    """
    m, d = world.model, world.data
    flat = cones.ravel()
    R_w_g = d.geom_xmat[flat].reshape(-1, 3, 3)  # (2 N, 3, 3)
    aabb = m.geom_aabb[flat]  # (2 N, 6): centre, half sizes
    rel_w = d.geom_xpos[drone][None, :, :] - d.geom_xpos[flat][:, None, :]  # (2 N, G, 3)
    rel_g = np.einsum("kgi,kij->kgj", rel_w, R_w_g) - aabb[:, None, :3]
    excess = np.abs(rel_g) - aabb[:, None, 3:]
    sdf = np.linalg.norm(np.maximum(excess, 0.0), axis=-1) + np.minimum(excess.max(axis=-1), 0.0)
    return (sdf - m.geom_rbound[drone][None, :]).reshape(cones.shape[0], 2, drone.size)
