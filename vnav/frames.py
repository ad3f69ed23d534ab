"""Frame conventions as named rotations, and a tree of frames (lecture chapters 1, 7 and 8).

Constants are read-only (3, 3) float64 rotations ``R_A_B`` that map B-coordinates into A,
``p_A = R_A_B @ p_B`` (docs/CONVENTIONS.md), between these axis conventions:

- ``FLU``: x forward, y left, z up (body, ROS REP-103 ``base_link``);
- ``RDF``: x right, y down, z forward (camera optical frame, OpenCV; the lecture's camera);
- ``GLC``: x right, y up, looking along -z (MuJoCo / OpenGL camera);
- ``ENU``: x east, y north, z up (world); ``NED``: x north, y east, z down;
- ``FRD``: x forward, y right, z down (aerospace body).

``FrameTree`` is the lecture's chapter 8 "transform composer": register ``T_parent_child``
edges (world -> body -> camera) and look up ``T_a_b`` between any two frames.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from vnav import se3, so3
from vnav._validate import FloatArray

__all__ = [
    "R_ENU_NED",
    "R_FLU_FRD",
    "R_FLU_RDF",
    "R_FRD_FLU",
    "R_GLC_RDF",
    "R_NED_ENU",
    "R_RDF_FLU",
    "R_RDF_GLC",
    "FrameTree",
    "mount_rotation",
]


def _constant(columns: list[list[float]]) -> FloatArray:
    """A read-only rotation whose columns (given as lists) are the B axes in A."""
    R = np.array(columns, dtype=np.float64).T.copy()
    so3.check_rotation(R)
    R.flags.writeable = False
    return R


def _transpose(R: FloatArray) -> FloatArray:
    Rt = R.T.copy()
    Rt.flags.writeable = False
    return Rt


#: Optical (RDF) into body (FLU): camera z (forward) -> body x, camera x (right) -> body -y,
#: camera y (down) -> body -z. A forward-looking camera at the body origin has R_b_c = this.
R_FLU_RDF = _constant([[0, -1, 0], [0, 0, -1], [1, 0, 0]])
#: Body (FLU) into optical (RDF), the transpose of ``R_FLU_RDF``.
R_RDF_FLU = _transpose(R_FLU_RDF)
#: Optical (RDF) into the MuJoCo/OpenGL camera frame: diag(1, -1, -1) (flip y and z).
R_GLC_RDF = _constant([[1, 0, 0], [0, -1, 0], [0, 0, -1]])
#: MuJoCo/OpenGL camera into optical; diag(1, -1, -1) is its own inverse.
R_RDF_GLC = _transpose(R_GLC_RDF)
#: NED into ENU: north -> y, east -> x, down -> -z (symmetric, its own inverse).
R_ENU_NED = _constant([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
#: ENU into NED.
R_NED_ENU = _transpose(R_ENU_NED)
#: FRD into FLU: diag(1, -1, -1).
R_FLU_FRD = _constant([[1, 0, 0], [0, -1, 0], [0, 0, -1]])
#: FLU into FRD.
R_FRD_FLU = _transpose(R_FLU_FRD)


def mount_rotation(pitch_down_rad: float) -> FloatArray:
    """``R_b_c`` of a camera looking along body +x, tipped down by ``pitch_down_rad``.

    ``R_b_c = rot_y(pitch_down_rad) @ R_FLU_RDF`` (docs/CONVENTIONS.md): a positive rotation
    about the body's y axis (pointing left) tips the optical axis below the horizon.

    Parameters
    ----------
    pitch_down_rad : float
        Radians; 0 looks straight ahead, pi/2 straight down.

    Returns
    -------
    R_b_c : ndarray, shape (3, 3)

    Raises
    ------
    ValueError
        If the angle is NaN or inf.
    """
    return so3.rot_y(pitch_down_rad) @ R_FLU_RDF


class FrameTree:
    """Named frames linked by ``T_parent_child`` edges; ``lookup`` composes ``T_a_b``.

    Each frame has at most one parent, so the edges form a forest; ``lookup`` walks up from both
    frames to their lowest common ancestor ``r`` and returns
    ``T_a_b = invert(T_r_a) @ T_r_b`` (lecture chapter 7: inner letters cancel).

    Examples
    --------
    >>> tree = FrameTree()
    >>> tree.add("world", "body", se3.make(so3.rot_z(np.pi / 2), [5.0, 0.0, 0.0]))
    >>> tree.add("body", "camera", se3.make(np.eye(3), [0.3, 0.0, 0.2]))
    >>> np.round(tree.lookup("world", "camera")[:3, 3], 12)
    array([5. , 0.3, 0.2])
    """

    def __init__(self) -> None:
        self._edges: dict[str, tuple[str, FloatArray]] = {}  # child -> (parent, T_parent_child)
        self._frames: dict[str, None] = {}  # insertion-ordered set

    @property
    def frames(self) -> tuple[str, ...]:
        """Every registered frame name, in the order they were first added."""
        return tuple(self._frames)

    def __contains__(self, frame: object) -> bool:
        return frame in self._frames

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame``, or None for a root.

        Raises
        ------
        ValueError
            If ``frame`` is unknown.
        """
        self._check_known(frame)
        edge = self._edges.get(frame)
        return edge[0] if edge else None

    @staticmethod
    def _check_name(name: object, what: str) -> str:
        if not isinstance(name, str) or not name:
            raise ValueError(f"{what} frame name must be a non-empty str; got {name!r}")
        return name

    def _check_known(self, frame: str) -> None:
        if frame not in self._frames:
            known = ", ".join(repr(f) for f in self._frames) or "none"
            raise ValueError(f"unknown frame {frame!r}; known frames: {known}")

    @staticmethod
    def _frozen(T: ArrayLike, parent: str, child: str) -> FloatArray:
        T = se3.check_transform(T, f"T_{parent}_{child}")
        if T.shape != (4, 4):
            raise ValueError(f"T_{parent}_{child} must have shape (4, 4); got shape {T.shape}")
        T = T.copy()
        T.flags.writeable = False
        return T

    def add(self, parent: str, child: str, T_parent_child: ArrayLike) -> None:
        """Register the edge ``parent -> child`` with the pose of child in parent.

        Parameters
        ----------
        parent, child : str
            Frame names; either may be new.
        T_parent_child : array_like, shape (4, 4)
            Maps child coordinates into parent: ``p_parent = T_parent_child @ p_child``.

        Raises
        ------
        ValueError
            If a name is empty, ``parent == child``, ``child`` already has a parent, the edge
            would close a cycle, or ``T_parent_child`` is not a rigid transform.
        """
        self._check_name(parent, "parent")
        self._check_name(child, "child")
        if parent == child:
            raise ValueError(f"a frame cannot be its own parent: {parent!r}")
        if child in self._edges:
            raise ValueError(
                f"frame {child!r} already has parent {self._edges[child][0]!r}; a frame has one "
                f"parent (use set({self._edges[child][0]!r}, {child!r}, T) to move it)"
            )
        if child in self._frames and parent in self._frames and child in self._chain(parent):
            raise ValueError(
                f"edge {parent!r} -> {child!r} would close a cycle: {child!r} is already an "
                f"ancestor of {parent!r}"
            )
        T = self._frozen(T_parent_child, parent, child)
        self._frames.setdefault(parent)
        self._frames.setdefault(child)
        self._edges[child] = (parent, T)

    def set(self, parent: str, child: str, T_parent_child: ArrayLike) -> None:
        """Update the pose on an existing edge (a moving body, a re-calibrated camera).

        Raises
        ------
        ValueError
            If there is no edge ``parent -> child`` or ``T_parent_child`` is not a rigid
            transform.
        """
        edge = self._edges.get(child)
        if edge is None or edge[0] != parent:
            have = f"its parent is {edge[0]!r}" if edge else "it has no parent"
            raise ValueError(
                f"no edge {parent!r} -> {child!r} to set ({child!r}: "
                f"{have if child in self._frames else 'unknown frame'}); add it first"
            )
        self._edges[child] = (parent, self._frozen(T_parent_child, parent, child))

    def _chain(self, frame: str) -> list[str]:
        """``frame``, its parent, ..., up to its root."""
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]][0])
        return chain

    def _from_ancestor(self, chain: list[str], stop: int) -> FloatArray:
        """``T_anc_frame`` for ``anc = chain[stop]`` and ``frame = chain[0]``."""
        T = np.eye(4)
        for frame in reversed(chain[:stop]):  # from just below the ancestor down to the frame
            T = T @ self._edges[frame][1]
        return T

    def lookup(self, a: str, b: str) -> FloatArray:
        """``T_a_b``, the pose of frame b in frame a, composed through the tree.

        Parameters
        ----------
        a, b : str
            Registered frame names.

        Returns
        -------
        T_a_b : ndarray, shape (4, 4)
            Maps b-coordinates into a: ``p_a = T_a_b @ p_b``.

        Raises
        ------
        ValueError
            If a frame is unknown, or the two frames are in different trees (not connected).
        """
        self._check_known(a)
        self._check_known(b)
        chain_a = self._chain(a)
        chain_b = self._chain(b)
        if chain_a[-1] != chain_b[-1]:
            raise ValueError(
                f"frames {a!r} and {b!r} are not connected: {a!r} is under root "
                f"{chain_a[-1]!r}, {b!r} under root {chain_b[-1]!r}"
            )
        index_a = {f: i for i, f in enumerate(chain_a)}
        j = next(j for j, f in enumerate(chain_b) if f in index_a)  # lowest common ancestor
        T_r_a = self._from_ancestor(chain_a, index_a[chain_b[j]])
        T_r_b = self._from_ancestor(chain_b, j)
        return se3.invert(T_r_a) @ T_r_b
