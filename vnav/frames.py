"""Frame conventions as named rotations, and a tree of frames (lecture chapters 1, 7 and 8).

Constants are read-only (3, 3) float64 rotations ``R_A_B`` that map B-coordinates into A,
``p_A = R_A_B @ p_B`` (docs/CONVENTIONS.md), between these axis conventions:

- ``FLU``: x forward, y left, z up (body, ROS REP-103 ``base_link``);
- ``RDF``: x right, y down, z forward (camera optical frame, OpenCV; the lecture's camera);
- ``GLC``: x right, y up, looking along -z (MuJoCo / OpenGL camera);
- ``ENU``: x east, y north, z up (world); ``NED``: x north, y east, z down;
- ``FRD``: x forward, y right, z down (aerospace body).

``FrameTree`` is the lecture's chapter 8 "transform composer": register ``T_parent_child``
edges (world -> body -> camera) and look up ``T_a_b`` between any two frames, as they are now.

``FrameBuffer`` adds time, in the spirit of ROS tf2's ``BufferCore`` and pytransform3d's
``TemporalTransformManager``: each edge keeps a stamped history (or is static), and
``lookup(target, source, t_s)`` interpolates every edge on the path at ``t_s`` (translation
linearly, rotation by slerp along the shorter arc), refusing to extrapolate
(``ExtrapolationError``). Use ``FrameTree`` for a snapshot (one pose per edge, the lecture's
exercises, a camera mount); use ``FrameBuffer`` when poses arrive as a stream with stamps and
must be looked up at a sensor's stamp, which is what a real pipeline does.
"""

from __future__ import annotations

import bisect
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from vnav import quat, se3, so3
from vnav._validate import FloatArray
from vnav.se3 import compose_xyzw_xyz, invert_xyzw_xyz

__all__ = [
    "R_ENU_NED",
    "R_FLU_FRD",
    "R_FLU_RDF",
    "R_FRD_FLU",
    "R_GLC_RDF",
    "R_NED_ENU",
    "R_RDF_FLU",
    "R_RDF_GLC",
    "ExtrapolationError",
    "FrameBuffer",
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


class _Graph:
    """Named frames, each with at most one parent: the bookkeeping ``FrameTree`` and
    ``FrameBuffer`` share (names, cycles, paths)."""

    def __init__(self) -> None:
        self._parents: dict[str, str] = {}  # child -> parent
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
        return self._parents.get(frame)

    @staticmethod
    def _check_name(name: object, what: str) -> str:
        if not isinstance(name, str) or not name:
            raise ValueError(f"{what} frame name must be a non-empty str; got {name!r}")
        return name

    def _check_known(self, frame: str) -> None:
        if frame not in self._frames:
            known = ", ".join(repr(f) for f in self._frames) or "none"
            raise ValueError(f"unknown frame {frame!r}; known frames: {known}")

    def _check_new_edge(self, parent: str, child: str, how: str) -> None:
        """Refuse an edge that would give ``child`` a second parent or close a cycle."""
        self._check_name(parent, "parent")
        self._check_name(child, "child")
        if parent == child:
            raise ValueError(f"a frame cannot be its own parent: {parent!r}")
        if child in self._parents:
            raise ValueError(
                f"frame {child!r} already has parent {self._parents[child]!r}; a frame has one "
                f"parent ({how})"
            )
        if child in self._frames and parent in self._frames and child in self._chain(parent):
            raise ValueError(
                f"edge {parent!r} -> {child!r} would close a cycle: {child!r} is already an "
                f"ancestor of {parent!r}"
            )

    def _link(self, parent: str, child: str) -> None:
        self._frames.setdefault(parent)
        self._frames.setdefault(child)
        self._parents[child] = parent

    def _chain(self, frame: str) -> list[str]:
        """``frame``, its parent, ..., up to its root."""
        chain = [frame]
        while chain[-1] in self._parents:
            chain.append(self._parents[chain[-1]])
        return chain

    def _paths(self, a: str, b: str) -> tuple[list[str], list[str]]:
        """The frames below the lowest common ancestor r on the way up from a and from b
        (``[a, ..., child of r]``, likewise for b; empty when a or b is r itself).

        Raises
        ------
        ValueError
            If a frame is unknown or the two are not connected.
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
        return chain_a[: index_a[chain_b[j]]], chain_b[:j]


def _frozen(T: ArrayLike, parent: str, child: str) -> FloatArray:
    T = se3.check_transform(T, f"T_{parent}_{child}")
    if T.shape != (4, 4):
        raise ValueError(f"T_{parent}_{child} must have shape (4, 4); got shape {T.shape}")
    T = T.copy()
    T.flags.writeable = False
    return T


class FrameTree(_Graph):
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
        super().__init__()
        self._poses: dict[str, FloatArray] = {}  # child -> T_parent_child

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
        self._check_new_edge(
            parent, child, f"use set({self._parents.get(child)!r}, {child!r}, T) to move it"
        )
        T = _frozen(T_parent_child, parent, child)
        self._link(parent, child)
        self._poses[child] = T

    def set(self, parent: str, child: str, T_parent_child: ArrayLike) -> None:
        """Update the pose on an existing edge (a moving body, a re-calibrated camera).

        Raises
        ------
        ValueError
            If there is no edge ``parent -> child`` or ``T_parent_child`` is not a rigid
            transform.
        """
        if self._parents.get(child) != parent:
            have = (
                f"its parent is {self._parents[child]!r}"
                if child in self._parents
                else "it has no parent"
            )
            raise ValueError(
                f"no edge {parent!r} -> {child!r} to set ({child!r}: "
                f"{have if child in self._frames else 'unknown frame'}); add it first"
            )
        self._poses[child] = _frozen(T_parent_child, parent, child)

    def _from_ancestor(self, path: list[str]) -> FloatArray:
        """``T_r_x`` for ``path = [x, ..., child of r]``."""
        T = np.eye(4)
        for frame in reversed(path):  # from just below the ancestor down to the frame
            T = T @ self._poses[frame]
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
        path_a, path_b = self._paths(a, b)
        return se3.invert(self._from_ancestor(path_a)) @ self._from_ancestor(path_b)


class ExtrapolationError(ValueError):
    """A lookup at a time outside the stored interval of a time-stamped edge.

    ``FrameBuffer`` never extrapolates a pose (tf2 refuses it on purpose: a pose guessed past
    the last sample is the silent error this class exists to prevent). The message names the
    edge, the time asked for and the interval available.
    """


DEFAULT_CACHE_S = 10.0
"""History kept per time-stamped edge, seconds (tf2's default cache time)."""


# A pose as components (qx, qy, qz, qw, px, py, pz): floats for one time, (N,) arrays for many.
# The same arithmetic serves both, so one lookup (pure Python, a few microseconds) and 1e5
# lookups (numpy, columns not (N, 4, 4) stacks) run the same formulas: se3.compose_xyzw_xyz
# and se3.invert_xyzw_xyz, bound here by name (a module attribute lookup per call would cost
# the single lookup's hot path).
_IDENTITY = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


def _matrix(a, shape: tuple[int, ...]) -> FloatArray:
    """The 4x4 homogeneous matrix of a pose given as components (unit quaternion)."""
    x, y, z, w, px, py, pz = a
    T = np.zeros((*shape, 4, 4))
    T[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    T[..., 0, 1] = 2.0 * (x * y - z * w)
    T[..., 0, 2] = 2.0 * (x * z + y * w)
    T[..., 1, 0] = 2.0 * (x * y + z * w)
    T[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    T[..., 1, 2] = 2.0 * (y * z - x * w)
    T[..., 2, 0] = 2.0 * (x * z - y * w)
    T[..., 2, 1] = 2.0 * (y * z + x * w)
    T[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    T[..., 0, 3] = px
    T[..., 1, 3] = py
    T[..., 2, 3] = pz
    T[..., 3, 3] = 1.0
    return T


def _components(T: FloatArray) -> FloatArray:
    """(7, N) components of a stack of transforms already validated (quaternion from
    ``vnav.quat``)."""
    q = quat.from_matrix(T[:, :3, :3], assume_valid=True)
    return np.concatenate([q.T, T[:, :3, 3].T])


def _segments(q: FloatArray) -> FloatArray:
    """Slerp constants of each pair of consecutive quaternions (columns of ``q``, (4, K)):
    rows ``omega`` (the angle between the two 4-vectors), ``1 / sin(omega)`` (0 where the
    weights are linear to rounding, below 1e-12) and the sign that takes the second to the
    shorter arc (q and -q are one rotation). (3, K - 1).

    The angle is ``2 atan2(|q1 - q0|, |q1 + q0|)``, accurate when the two are close (unlike
    ``arccos(q0 . q1)``); computed once per sample, so lookups need no inverse trigonometry.
    """
    q0, q1 = q[:, :-1], q[:, 1:]
    sign = np.where(np.sum(q0 * q1, axis=0) < 0.0, -1.0, 1.0)
    q1 = sign * q1
    omega = 2.0 * np.arctan2(
        np.sqrt(np.sum((q1 - q0) ** 2, axis=0)), np.sqrt(np.sum((q1 + q0) ** 2, axis=0))
    )
    sin_omega = np.sin(omega)
    inv_sin = np.divide(1.0, sin_omega, out=np.zeros_like(omega), where=sin_omega >= 1e-12)
    return np.stack([omega, inv_sin, sign])


def _interpolate(a, b, segment, alpha):
    """Translation linearly and rotation by slerp along the shorter arc (Shoemake 1985),
    ``alpha`` of the way from pose ``a`` to pose ``b`` (components; floats, or (N,) columns),
    with the pair's ``segment`` constants (``_segments``). At ``alpha = 0`` it is ``a``
    exactly: the weights are then ``sin(omega) / sin(omega) = 1`` and ``sin(0) = 0``."""
    x0, y0, z0, w0, px0, py0, pz0 = a
    x1, y1, z1, w1, px1, py1, pz1 = b
    omega, inv_sin, sign = segment
    if isinstance(alpha, float):
        if inv_sin == 0.0:
            k0, k1 = 1.0 - alpha, sign * alpha
        else:
            k0 = math.sin((1.0 - alpha) * omega) * inv_sin
            k1 = sign * math.sin(alpha * omega) * inv_sin
    else:
        k0 = np.sin((1.0 - alpha) * omega) * inv_sin
        k1 = sign * np.sin(alpha * omega) * inv_sin
        linear = inv_sin == 0.0
        if np.any(linear):
            k0[linear] = 1.0 - alpha[linear]
            k1[linear] = sign[linear] * alpha[linear]
    return (
        k0 * x0 + k1 * x1,
        k0 * y0 + k1 * y1,
        k0 * z0 + k1 * z1,
        k0 * w0 + k1 * w1,
        px0 + alpha * (px1 - px0),
        py0 + alpha * (py1 - py0),
        pz0 + alpha * (pz1 - pz0),
    )


class _Samples(NamedTuple):
    """One edge's samples as a reader sees them: ``[lo, hi)`` of the arrays and lists is the
    live part, indexed alike (sample ``i`` is ``stamps[i]``, ``times[i]``, ``rows[i]``; the
    pair ``(i, i + 1)`` is ``segments[:, i]``, ``steps[i]``).

    Published whole by the writer (``_Track.view``): a reader that takes one never sees
    another's ``lo`` or ``hi``, and the writer never changes what lies in ``[lo, hi)`` of a
    published one (it appends beyond ``hi``, or copies into new containers).
    """

    lo: int
    hi: int
    times: list[float]
    rows: list[tuple[float, ...]]
    steps: list[tuple[float, ...]]
    stamps: FloatArray
    components: FloatArray
    segments: FloatArray


class _Track:
    """One time-stamped edge's samples, kept by its writer and read through ``view``.

    Components are stored column-wise, (7, capacity), with each pair's slerp constants
    (``_segments``, (3, capacity), column i for samples i and i + 1), so a vectorised lookup
    gathers contiguous rows; a Python mirror (stamps, component and constant tuples) serves
    single lookups without numpy's per-call cost. Appending is amortised O(1): samples go
    after the live part, and once the arrays are full the live part is copied into new ones
    (twice as large if it fills half of them) and the lists likewise; trimming only moves
    ``lo``. Every change ends by publishing a new ``_Samples`` (one reference assignment, atomic
    in CPython): readers on other threads see the edge before or after it, never between.
    """

    __slots__ = ("view",)

    def __init__(self) -> None:
        self.view = _Samples(0, 0, [], [], [], np.empty(16), np.empty((7, 16)), np.empty((3, 16)))

    def __len__(self) -> int:
        view = self.view
        return view.hi - view.lo

    def append(self, t: FloatArray, components: FloatArray, oldest_s: float) -> None:
        """Add samples after the newest, then drop those before ``oldest_s`` (the newest
        always stays); publish the result once."""
        lo, hi, times, rows, steps, stamps, comps, segments = self.view
        n, live = len(t), hi - lo
        if hi + n > len(stamps):
            capacity = len(stamps)
            while live + n > capacity // 2:
                capacity *= 2
            new_stamps, new_comps = np.empty(capacity), np.empty((7, capacity))
            new_segments = np.empty((3, capacity))
            new_stamps[:live] = stamps[lo:hi]
            new_comps[:, :live] = comps[:, lo:hi]
            new_segments[:, :live] = segments[:, lo:hi]
            stamps, comps, segments = new_stamps, new_comps, new_segments
            times, rows, steps = times[lo:hi], rows[lo:hi], steps[lo : max(hi - 1, lo)]
            lo, hi = 0, live
        first = hi - 1 if live else hi  # the pair across the old last sample
        stamps[hi : hi + n] = t
        comps[:, hi : hi + n] = components
        hi += n
        pairs = _segments(comps[:4, first:hi])
        segments[:, first : hi - 1] = pairs
        times.extend(t.tolist())
        rows.extend(map(tuple, components.T.tolist()))
        steps.extend(map(tuple, pairs.T.tolist()))
        lo = min(bisect.bisect_left(times, oldest_s, lo, hi), hi - 1)
        self.view = _Samples(lo, hi, times, rows, steps, stamps, comps, segments)


def _stamped_samples(
    parent: str, child: str, t_s: ArrayLike, T_parent_child: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """``FrameBuffer.set_transform``'s samples, checked: stamps and their transforms.

    Parameters
    ----------
    parent, child : str
        The edge's frame names (for the messages).
    t_s : float or array_like, shape (N,)
        Stamps, seconds.
    T_parent_child : array_like, shape (4, 4) or (N, 4, 4)
        One transform per stamp.

    Returns
    -------
    t : ndarray, shape (N,)
        The stamps, seconds (one for a float).
    T : ndarray, shape (4, 4) or (N, 4, 4)
        The transforms, as given.

    Raises
    ------
    ValueError
        If ``t_s`` has more than one dimension, a stamp is not finite or not increasing, the
        shapes do not match, or a transform is not rigid.
    """
    t = np.asarray(t_s, dtype=np.float64)
    scalar = t.ndim == 0
    if t.ndim > 1:
        raise ValueError(f"t_s must be a float or a 1-D array; got shape {t.shape}")
    t = t.reshape(-1)
    T = se3.check_transform(T_parent_child, f"T_{parent}_{child}")
    expected = (4, 4) if scalar else (len(t), 4, 4)
    if T.shape != expected:
        raise ValueError(
            f"T_{parent}_{child} must have shape {expected} for "
            f"{'one stamp' if scalar else f'{len(t)} stamps'}; got shape {T.shape}"
        )
    if not np.all(np.isfinite(t)):
        raise ValueError(f"stamps of edge {parent!r} -> {child!r} must be finite; got {t}")
    if len(t) > 1 and np.any(np.diff(t) <= 0.0):
        k = int(np.argmax(np.diff(t) <= 0.0))
        raise ValueError(
            f"stamps of edge {parent!r} -> {child!r} must increase; got "
            f"{float(t[k])!r} then {float(t[k + 1])!r} s"
        )
    return t, T


class FrameBuffer(_Graph):
    """A time-stamped frame graph: static edges and edges with a history of stamped poses.

    ``lookup(target, source, t_s)`` returns ``T_target_source`` at time ``t_s`` through any
    path of the graph, each time-stamped edge interpolated between its two samples around
    ``t_s``: translation linearly, rotation by slerp along the shorter arc (Shoemake 1985, as
    tf2). Exactly at a stored stamp it is the stored transform (to rounding: the rotation
    goes through its quaternion). Outside an edge's stored interval it raises
    ``ExtrapolationError``. Each edge keeps the samples of its last ``cache_s`` seconds
    (counted back from its newest stamp), as tf2's cache does.

    With only static edges it behaves like ``FrameTree`` (``t_s`` may then be omitted).

    Threads: one writer (``set_transform``, ``set_static``) and any number of readers
    (``lookup``, ``can_lookup``, ``interval``) may run at once on different threads, without
    a lock. Each write publishes the edge's samples whole (``_Track``), and a lookup reads one
    snapshot per edge: it sees the edge before or after a write, never between, and a pose
    inside an edge's interval never changes (new samples come after the newest). A time
    trimmed from the cache meanwhile raises ``ExtrapolationError``. Two writers at once are
    not supported: serialise them with a lock (docs/CONVENTIONS.md, "Performance and
    threads").

    Parameters
    ----------
    cache_s : float
        History kept per edge, seconds (> 0, finite); default ``DEFAULT_CACHE_S``.

    Raises
    ------
    ValueError
        If ``cache_s`` is not a finite number > 0.

    Examples
    --------
    >>> buf = FrameBuffer()
    >>> buf.set_static("body", "camera", se3.make(np.eye(3), [0.2, 0.0, 0.0]))
    >>> buf.set_transform("world", "body", [0.0, 1.0],
    ...                   [se3.make(np.eye(3), [0.0, 0, 0]), se3.make(np.eye(3), [1.0, 0, 0])])
    >>> buf.lookup("world", "camera", 0.25)[:3, 3]
    array([0.45, 0.  , 0.  ])
    """

    def __init__(self, cache_s: float = DEFAULT_CACHE_S) -> None:
        super().__init__()
        if isinstance(cache_s, bool) or not isinstance(cache_s, int | float):
            raise ValueError(f"cache_s must be a number of seconds; got {cache_s!r}")
        if not 0.0 < cache_s < math.inf:
            raise ValueError(f"cache_s must be finite and > 0 seconds; got {cache_s!r}")
        self.cache_s = float(cache_s)
        self._static: dict[str, tuple[float, ...]] = {}  # child -> components of T_parent_child
        self._tracks: dict[str, _Track] = {}  # child -> stamped history

    # ------------------------------------------------------------------ writing
    def set_static(self, parent: str, child: str, T_parent_child: ArrayLike) -> None:
        """Register (or replace) a static edge: ``T_parent_child`` at every time.

        Raises
        ------
        ValueError
            If a name is empty, ``parent == child``, ``child`` has another parent or a
            time-stamped edge, the edge would close a cycle, or the transform is not rigid.
        """
        if child in self._tracks:
            raise ValueError(
                f"edge {self._parents[child]!r} -> {child!r} is time-stamped; it cannot "
                "become static"
            )
        if self._parents.get(child) != parent or child not in self._static:
            self._check_new_edge(parent, child, "build a new FrameBuffer to re-parent it")
        T = _frozen(T_parent_child, parent, child)
        # Stored before it is linked: a reader that finds the edge finds its transform.
        self._static[child] = tuple(_components(T[None])[:, 0].tolist())
        self._link(parent, child)

    def set_transform(
        self, parent: str, child: str, t_s: ArrayLike, T_parent_child: ArrayLike
    ) -> None:
        """Add stamped samples of ``T_parent_child`` to the edge ``parent -> child``.

        Parameters
        ----------
        parent, child : str
            Frame names; either may be new. The first call creates the edge.
        t_s : float or array_like, shape (N,)
            Stamps, seconds; strictly increasing, and after the edge's newest stamp.
        T_parent_child : array_like, shape (4, 4) or (N, 4, 4)
            The pose of child in parent at each stamp.

        Raises
        ------
        ValueError
            If a name is empty, ``parent == child``, ``child`` has another parent or a static
            edge, the edge would close a cycle, a stamp is not finite or not increasing, the
            shapes do not match, or a transform is not rigid.
        """
        if child in self._static:
            raise ValueError(
                f"edge {parent!r} -> {child!r} is static; it cannot take stamped samples"
            )
        if child not in self._tracks or self._parents.get(child) != parent:
            self._check_new_edge(parent, child, "build a new FrameBuffer to re-parent it")
        t, T = _stamped_samples(parent, child, t_s, T_parent_child)
        track = self._tracks.get(child)
        newest = None if track is None or not len(track) else track.view.times[track.view.hi - 1]
        if newest is not None and len(t) and t[0] <= newest:
            raise ValueError(
                f"stamps of edge {parent!r} -> {child!r} must increase; got {float(t[0])!r} s "
                f"after the newest stored stamp {newest!r} s"
            )
        if not len(t):
            return
        components = _components(T.reshape(-1, 4, 4))
        if track is None:  # filled before it is linked: a reader never finds it empty
            track = _Track()
            track.append(t, components, float(t[-1]) - self.cache_s)
            self._tracks[child] = track
            self._link(parent, child)
        else:
            track.append(t, components, float(t[-1]) - self.cache_s)

    # ------------------------------------------------------------------ reading
    def interval(self, parent: str, child: str) -> tuple[float, float]:
        """The stored interval ``(first, last)`` of an edge, seconds; ``(-inf, inf)`` for a
        static edge.

        Raises
        ------
        ValueError
            If there is no edge ``parent -> child``.
        """
        if child not in self._frames or self._parents.get(child) != parent:
            raise ValueError(f"no edge {parent!r} -> {child!r}")
        if child in self._static:
            return (-math.inf, math.inf)
        view = self._tracks[child].view
        return (view.times[view.lo], view.times[view.hi - 1])

    def lookup(
        self,
        target: str,
        source: str,
        t_s: ArrayLike | None = None,
        *,
        source_time_s: ArrayLike | None = None,
        fixed: str | None = None,
    ) -> FloatArray:
        """``T_target_source`` at time ``t_s``: maps source coordinates into target.

        With ``source_time_s`` and ``fixed`` (tf2's "time travel"): the source as it was at
        ``source_time_s``, the target as it is at ``t_s``, joined through ``fixed``, a frame
        assumed not to move between the two times (usually the world):
        ``T_target(t_s)_source(source_time_s) = T_target_fixed(t_s) T_fixed_source(source_time_s)``.
        A point seen in the camera at exposure, expressed in the body at arrival, is
        ``lookup("body", "camera", t_arrival, source_time_s=t_exposure, fixed="world")``.

        Parameters
        ----------
        target, source : str
            Registered frame names.
        t_s : float or array_like, shape (N,), optional
            Seconds. May be omitted only if every edge on the path is static.
        source_time_s : float or array_like, shape (N,), optional
            The source's time, with ``fixed``; broadcast against ``t_s``.
        fixed : str, optional
            The frame fixed in time, with ``source_time_s``.

        Returns
        -------
        ndarray, shape (4, 4), or (N, 4, 4) for an array of times

        Raises
        ------
        ExtrapolationError
            If a time falls outside the stored interval of an edge on the path.
        ValueError
            If a frame is unknown, the frames are not connected, a time is not finite, or only
            one of ``source_time_s`` and ``fixed`` is given.
        """
        if (source_time_s is None) != (fixed is None):
            raise ValueError("time travel needs both source_time_s and fixed (or neither)")
        if fixed is None:
            return self._lookup_at(target, source, t_s)
        if t_s is None:
            raise ValueError("time travel needs t_s, the target's time")
        return self._lookup_time_travel(target, source, t_s, source_time_s, fixed)

    def _lookup_at(self, target: str, source: str, t_s: ArrayLike | None) -> FloatArray:
        """``T_target_source`` with both frames at ``t_s`` (``lookup`` without time travel).

        Parameters
        ----------
        target, source : str
            Registered frame names.
        t_s : float or array_like, shape (N,), or None
            Seconds, in any order; None only if every edge on the path is static.

        Returns
        -------
        ndarray, shape (4, 4), or (N, 4, 4) for an array of times
            In the order of ``t_s``.
        """
        t = None if t_s is None else self._times(t_s, "t_s")
        if isinstance(t, np.ndarray) and t.size > 1 and np.any(t[1:] < t[:-1]):
            # Sorted times search faster (see _at); the result is put back in order.
            order = np.argsort(t)
            back = np.empty_like(order)
            back[order] = np.arange(len(order))
            pose = self._pose(target, source, t[order])
            return _matrix(tuple(np.take(np.broadcast_to(c, t.shape), back) for c in pose), t.shape)
        return _matrix(self._pose(target, source, t), () if t is None else np.shape(t))

    def _lookup_time_travel(
        self, target: str, source: str, t_s: ArrayLike, source_time_s: ArrayLike, fixed: str
    ) -> FloatArray:
        """``T_target_fixed(t_s) T_fixed_source(source_time_s)`` (``lookup``'s time travel).

        Parameters
        ----------
        target, source, fixed : str
            Registered frame names; ``fixed`` is assumed not to move between the two times.
        t_s, source_time_s : float or array_like, shape (N,)
            The target's and the source's times, seconds; broadcast against each other.

        Returns
        -------
        ndarray, shape (4, 4), or (N, 4, 4) for an array of times
        """
        t_target, t_source = np.broadcast_arrays(
            self._times(t_s, "t_s"), self._times(source_time_s, "source_time_s")
        )
        if t_target.ndim == 0:
            t_target, t_source = float(t_target), float(t_source)
        pose = compose_xyzw_xyz(
            self._pose(target, fixed, t_target), self._pose(fixed, source, t_source)
        )
        return _matrix(pose, np.shape(t_target))

    def can_lookup(
        self,
        target: str,
        source: str,
        t_s: ArrayLike | None = None,
        *,
        source_time_s: ArrayLike | None = None,
        fixed: str | None = None,
    ) -> bool:
        """Whether ``lookup`` with the same arguments would succeed (tf2's ``canTransform``)."""
        try:
            self.lookup(target, source, t_s, source_time_s=source_time_s, fixed=fixed)
        except ValueError:
            return False
        return True

    @staticmethod
    def _times(t_s: ArrayLike, name: str) -> float | FloatArray:
        """A finite float, or a finite 1-D float64 array."""
        if type(t_s) is float and math.isfinite(t_s):  # the single lookup's fast path
            return t_s
        t = np.asarray(t_s, dtype=np.float64)
        if t.ndim > 1:
            raise ValueError(f"{name} must be a float or a 1-D array; got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"{name} must be finite; got {t_s!r}")
        return float(t) if t.ndim == 0 else t

    def _pose(self, target: str, source: str, t: float | FloatArray | None):
        """``T_target_source`` at ``t`` as components."""
        path_target, path_source = self._paths(target, source)
        if t is None:
            stamped = [f for f in path_target + path_source if f in self._tracks]
            if stamped:
                raise ValueError(
                    f"lookup({target!r}, {source!r}) needs t_s: edge "
                    f"{self._parents[stamped[0]]!r} -> {stamped[0]!r} is time-stamped"
                )
        return compose_xyzw_xyz(
            invert_xyzw_xyz(self._from_ancestor(path_target, t)),
            self._from_ancestor(path_source, t),
        )

    def _from_ancestor(self, path: list[str], t: float | FloatArray | None):
        """``T_r_x`` at ``t`` as components, for ``path = [x, ..., child of r]``."""
        pose = _IDENTITY
        for frame in reversed(path):
            edge = self._static.get(frame)
            if edge is None:
                edge = self._at(frame, t)
            pose = edge if pose is _IDENTITY else compose_xyzw_xyz(pose, edge)
        return pose

    def _at(self, child: str, t: float | FloatArray):
        """``T_parent_child`` of a time-stamped edge at ``t`` as components."""
        # One snapshot of the edge for the whole lookup: the writer may publish another.
        lo, hi, times, rows, steps, stamps, components, segments = self._tracks[child].view
        first, last = times[lo], times[hi - 1]
        if isinstance(t, float):
            if not first <= t <= last:
                self._refuse(child, np.array([t]), 1, first, last, hi - lo)
            i = bisect.bisect_right(times, t, lo, hi) - 1
            if times[i] == t:  # at a stamp (the last one included): the sample itself
                return rows[i]
            t0, t1 = times[i], times[i + 1]
            alpha = (t - t0) / (t1 - t0)
            return _interpolate(rows[i], rows[i + 1], steps[i], alpha)
        outside = (t < first) | (t > last)
        if np.any(outside):
            self._refuse(child, t[outside], t.size, first, last, hi - lo)
        stamps = stamps[lo:hi]
        if len(stamps) == 1:  # every t equals the one stamp
            return tuple(np.full(t.shape, c) for c in rows[lo])
        # t arrives sorted (see lookup): numpy's binary search then starts from the last
        # result, several times faster than for scattered times.
        i0 = np.searchsorted(stamps, t, side="right") - 1
        np.minimum(i0, len(stamps) - 2, out=i0)  # t at the last stamp: alpha = 1
        i1 = i0 + 1
        t0 = stamps[i0]
        alpha = (t - t0) / (stamps[i1] - t0)
        live = components[:, lo:hi]
        a = tuple(np.take(live, i0, axis=1))
        b = tuple(np.take(live, i1, axis=1))
        segment = tuple(np.take(segments[:, lo:hi], i0, axis=1))
        return _interpolate(a, b, segment, alpha)

    def _refuse(
        self, child: str, bad: FloatArray, asked: int, first: float, last: float, n: int
    ) -> None:
        many = f" ({len(bad)} of {asked} times asked)" if asked > 1 else ""
        raise ExtrapolationError(
            f"edge {self._parents[child]!r} -> {child!r} has no pose at t = {float(bad[0])!r} s"
            f"{many}: it holds [{first!r}, {last!r}] s ({n} samples); "
            "a pose outside that interval would be extrapolated, which is refused"
        )
