"""Cone apexes followed from image to image and triangulated: depth from motion alone.

A cone's apex is the one point of it fixed in the world that the detector sees in every view.
Each image gives, per detection, a world ray from the camera centre through the apex pixel
(the pose stream's ``T_w_c`` at the image's exposure). ``ApexTracker`` keeps, per cone, the
rays of a sliding window of images and triangulates them (``vnav.multiview.triangulate``,
midpoint) once they cross at ``min_parallax_deg`` or more; the cone's base centre is the apex
less the cone's height. No depth image, no ground plane and no apparent size are used.

Which ray belongs to which cone is decided without the truth, by bearing: a new ray joins the
track whose triangulated apex it points at most nearly (or, for a track without one yet, whose
latest ray it is most nearly parallel to: between two images a cone's bearing changes little),
within ``gate_deg``; a ray that joins none starts a track.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.estimators import NoEstimate
from vnav.multiview import MIN_RAY_COS, parallax_deg, triangulate_checked
from vnav.observation import Exposure, Observation
from vnav.sensor_noise import keypoint_std_px

__all__ = ["MIN_RANGE_M", "TRIANGULATED", "ApexTracker", "TrackedApex", "midpoint_covariance"]

MIN_RANGE_M = 2.0
"""The nearest a tracked cone is assumed to be (the accuracy contract's nearest range): it
bounds how far its bearing can turn as the camera moves."""


@dataclass(frozen=True)
class TrackedApex:
    """What the tracker says of one detection of the latest image.

    Attributes
    ----------
    track : int
        The track's id (stable from image to image).
    p_w : ndarray, shape (3,), or None
        The cone's base centre in the world, or None when the track's rays do not yet cross
        at ``min_parallax_deg``.
    apex_w : ndarray, shape (3,), or None
        The triangulated apex.
    parallax_deg : float
        The largest angle between the track's rays in the window.
    views : int
        Rays in the window.
    cov_w : ndarray, shape (3, 3), or None
        The estimate's covariance, m^2 (``midpoint_covariance``), with ``p_w``.
    """

    track: int
    p_w: np.ndarray | None
    apex_w: np.ndarray | None
    parallax_deg: float
    views: int
    cov_w: np.ndarray | None = None


_WINDOW_SHAPES: dict[str, tuple[int, ...]] = {
    "dirs": (3,),  # the association's ray (``update``'s direction)
    "d": (3,),  # the triangulation's ray (``multiview._rays_w``)
    # The pose: its centre and optical axis read as the reference reads them (strided
    # views of the stack: numpy's einsum sums a contiguous operand in another order).
    "T": (4, 4),
    "P": (3, 3),  # I - d d^T
    "PcS": (3, 3),  # -P [c]x
    "Sd": (3, 3),  # [d]x
    "D": (3, 2),  # the unit ray's change per pixel
    "cov_T": (6, 6),  # zero for an exact pose
    "cov_uv": (2, 2),  # zero for exact pixels
    "Pw": (3,),  # P (c - origin): the ray's term of the normal equations' right side
    "Q": (12, 12),  # the ray's terms of the covariance (``_ray_terms``)
    # The least cosine between the ray and itself or a later ray of the window, of each of
    # the two kinds of ray: the least of them is ``parallax_deg``'s over the window.
    "cos_dirs": (),
    "cos_d": (),
}
"""A ray's quantities a ``_Window`` keeps, with their shapes."""

_REBUILT_BY_RAY = ("Pw", "Q")
"""The quantities that depend on the window's origin, made again when it moves."""


class _Window:
    """A track's rays as stacked arrays, each ray's own quantities computed once, when it
    joins, and the window's sums over them kept as rays join and leave: what
    ``triangulate_checked`` and ``midpoint_covariance`` compute from every view of the
    window at each image (``_ray_terms``). Rows ``lo:hi`` of buffers twice ``max_views``
    long; when full, the window's rows move to the front, and the sums are made again from
    its rows about a new origin (the newest ray's centre): a ray that left took its terms
    out of the sums by a subtraction, which leaves the rounding of its terms behind, and
    the sums are never more than ``2 max_views`` joins and leaves away from a fresh sum."""

    __slots__ = ("A", "Q", "b", "beside", "buf", "hi", "lo", "origin")

    def __init__(self, capacity: int, origin: np.ndarray) -> None:
        self.buf = {k: np.zeros((capacity, *s)) for k, s in _WINDOW_SHAPES.items()}
        self.beside = np.zeros(capacity, dtype=bool)
        self.lo = self.hi = 0
        self.origin = origin.copy()
        self.A = np.zeros((3, 3))  # sum P_i
        self.b = np.zeros(3)  # sum P_i (c_i - origin)
        self.Q = np.zeros((12, 12))  # sum of the rays' covariance terms

    def append(self, rows: dict[str, np.ndarray], k: int, beside: bool) -> None:
        """Row ``k`` of ``rows`` (``ApexTracker._views``, with ``_ray_terms`` about this
        window's origin) as the window's newest ray."""
        capacity = self.beside.size
        moved = self.hi == capacity
        if moved:
            n = self.hi - self.lo
            for a in (*self.buf.values(), self.beside):
                a[:n] = a[self.lo : self.hi]
            self.lo, self.hi = 0, n
        i = self.hi
        buf = self.buf
        for key, value in rows.items():
            buf[key][i] = value[k]
        self.beside[i] = beside
        for key in ("dirs", "d"):
            ray, least = buf[key], buf["cos_" + key]
            least[i] = ray[i] @ ray[i]
            if i > self.lo:
                np.minimum(least[self.lo : i], ray[self.lo : i] @ ray[i], out=least[self.lo : i])
        self.hi += 1
        if moved:
            self.rebuild(buf["T"][i, :3, 3])
        else:
            self.A += buf["P"][i]
            self.b += buf["Pw"][i]
            self.Q += buf["Q"][i]

    def popleft(self) -> None:
        i = self.lo
        buf = self.buf
        self.A -= buf["P"][i]
        self.b -= buf["Pw"][i]
        self.Q -= buf["Q"][i]
        self.lo += 1

    def rebuild(self, origin: np.ndarray) -> None:
        """The rays' terms about ``origin`` and the sums made again from the window's rows."""
        self.origin = origin.copy()
        lo, hi = self.lo, self.hi
        w = {k: self.buf[k][lo:hi] for k in _WINDOW_SHAPES}
        origins = np.broadcast_to(self.origin, (hi - lo, 3))
        for key, value in zip(_REBUILT_BY_RAY, _ray_terms(w, origins), strict=True):
            self.buf[key][lo:hi] = value
        self.A = w["P"].sum(axis=0)
        self.b = w["Pw"].sum(axis=0)
        self.Q = w["Q"].sum(axis=0)

    def parallax_deg(self, key: str) -> float:
        """``multiview.parallax_deg`` of the window's rays ``key`` (``"dirs"`` or ``"d"``):
        the least of the rays' least cosines with themselves and the later rays, which were
        computed as each ray joined (a ray leaves from the front: the rays after one stay)."""
        least = float(self.buf["cos_" + key][self.lo : self.hi].min())
        return math.degrees(math.acos(min(1.0, max(-1.0, least))))

    def __getitem__(self, key: str) -> np.ndarray:
        return self.buf[key][self.lo : self.hi]


_EYE3 = np.eye(3)
# E[k, i, j] = delta_ij at d_k, delta_jk at d_i: ``M(w) = sum_k w_k E_k``, ``E_k = d_k I +
# d e_k^T`` (``_ray_terms``) as two broadcasts of the identity.
_E_FIRST = _EYE3[None, None, :, :]
_E_SECOND = _EYE3[:, None, :][None]


def _ray_terms(w: dict[str, np.ndarray], origins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each ray's terms of the window's sums, (K, 3) and (K, 12, 12), about ``origins``
    (K, 3): ``P_i (c_i - o)`` and the covariance's terms.

    ``midpoint_covariance`` of views about the midpoint ``p`` is ``A^-1 S A^-T`` with
    ``S = sum_i J_i C_i J_i^T``, ``J_i`` each view's Jacobian (pose ``[P, -P [c]x + M [d]x]``,
    pixel ``-M D``), whose ``M = (d . w) I + d w^T`` is linear in ``w = c - p``:
    ``M(w) = sum_k w_k E_k``, ``E_k = d_k I + d e_k^T``. With ``w = (c - o) - (p - o)`` and
    ``q = [1, -(p - o)]``, ``J_i = sum_a q_a H_ia``: ``H_i0`` the Jacobian at ``p = o``,
    ``H_ik`` ``[0, E_k [d]x]`` (pose) and ``-E_k D`` (pixel). So
    ``S = sum_ab q_a q_b sum_i H_ia C_i H_ib^T``: the sum over the rays of the (12, 12)
    ``H_i C_i H_i^T`` (``H_i`` the four ``H_ia`` stacked) holds the covariance at any ``p``.
    An origin near the rays keeps ``|p - o|`` to the range, and the quadratic form's
    cancellation to that of the reference's ``w``.
    """
    d, P = w["d"], w["P"]
    n = len(d)
    w0 = w["T"][:, :3, 3] - origins
    M0 = np.einsum("ni,ni->n", d, w0)[:, None, None] * _EYE3 + d[:, :, None] * w0[:, None, :]
    E = d[:, :, None, None] * _E_FIRST + d[:, None, :, None] * _E_SECOND
    Hp = np.zeros((n, 4, 3, 6))
    Hp[:, 0, :, :3] = P
    Hp[:, 0, :, 3:] = w["PcS"] + M0 @ w["Sd"]
    Hp[:, 1:, :, 3:] = E @ w["Sd"][:, None]
    Hu = np.empty((n, 4, 3, 2))
    Hu[:, 0] = -(M0 @ w["D"])
    Hu[:, 1:] = -(E @ w["D"][:, None])
    Hp = Hp.reshape(n, 12, 6)
    Hu = Hu.reshape(n, 12, 2)
    Q = Hp @ w["cov_T"] @ Hp.transpose(0, 2, 1) + Hu @ w["cov_uv"] @ Hu.transpose(0, 2, 1)
    return np.einsum("nij,nj->ni", P, w0), Q


@dataclass
class _Track:
    id: int
    window: _Window
    rays: deque = field(default_factory=deque)  # (t_s, centre (3,), unit direction (3,), T, uv)
    apex_w: np.ndarray | None = None


class ApexTracker:
    """Apex rays per cone over a sliding window, triangulated.

    Parameters
    ----------
    camera : PinholeCamera
    cone : ConeModel
    window_s : float
        Rays older than this (seconds before the latest image) are dropped.
    gate_deg : float
        A ray joins a track when it points within this angle of the track's apex (or latest
        ray).
    min_parallax_deg : float
        Triangulate only rays that cross at this angle or more.
    max_views : int
        At most this many rays per track (the newest).
    max_std_fraction : float
        Refuse an estimate whose covariance's largest standard deviation exceeds this
        fraction of its range: rays that cross at a few degrees cannot beat noise of a
        degree (no estimate rather than a wrong one).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        cone: ConeModel = TRAFFIC_CONE,
        *,
        window_s: float = 3.0,
        gate_deg: float = 2.0,
        min_parallax_deg: float = 3.0,
        max_views: int = 40,
        max_std_fraction: float = 0.05,
    ) -> None:
        if not (window_s > 0 and gate_deg > 0 and min_parallax_deg > 0 and max_views >= 2):
            raise ValueError(
                "window_s, gate_deg and min_parallax_deg must be > 0 and max_views >= 2, got "
                f"{window_s}, {gate_deg}, {min_parallax_deg}, {max_views}"
            )
        self.camera, self.cone = camera, cone
        self.window_s, self.gate_rad = float(window_s), math.radians(gate_deg)
        self.min_parallax_deg, self.max_views = float(min_parallax_deg), int(max_views)
        self.max_std_fraction = float(max_std_fraction)
        self._tracks: list[_Track] = []
        self._next_id = 0

    def update(
        self,
        t_s: float,
        T_w_c: np.ndarray,
        apex_uv: np.ndarray,
        *,
        cov_T_w_c: np.ndarray | None = None,
        cov_uv: np.ndarray | None = None,
    ) -> list[TrackedApex]:
        """Add one image's apex pixels (K, 2), seen from ``T_w_c`` at ``t_s``; return one
        ``TrackedApex`` per pixel, in order. ``cov_T_w_c`` (6, 6, left perturbation) and
        ``cov_uv`` (2, 2, px^2, every apex) are this view's noise, for the estimates'
        covariances (default: none).

        Raises
        ------
        ValueError
            On a malformed pose or pixels, or a time earlier than the previous image's.
        """
        T = se3.check_pose(T_w_c, "T_w_c")
        uv = np.asarray(apex_uv, dtype=np.float64).reshape(-1, 2)
        if not np.isfinite(uv).all():
            raise ValueError("apex_uv must be finite")
        latest = max((tr.rays[-1][0] for tr in self._tracks if tr.rays), default=-math.inf)
        if t_s < latest:
            raise ValueError(f"t_s must not go back in time: {t_s} after {latest}")
        self._forget(t_s)
        centre = T[:3, 3]
        directions = self.camera.rays(uv) @ T[:3, :3].T if len(uv) else np.zeros((0, 3))
        assigned = self._associate(centre, directions)
        beside, rows = self._views(T, uv)
        rows["dirs"] = directions
        n = len(uv)
        rows["cov_T"] = np.broadcast_to(
            np.zeros((6, 6)) if cov_T_w_c is None else cov_T_w_c, (n, 6, 6)
        )
        rows["cov_uv"] = np.broadcast_to(np.zeros((2, 2)) if cov_uv is None else cov_uv, (n, 2, 2))
        # Each ray's terms about its track's origin (a new track's: this camera's centre).
        origins = np.array(
            [assigned[k].window.origin if k in assigned else centre for k in range(n)]
        )
        rows.update(zip(_REBUILT_BY_RAY, _ray_terms(rows, origins.reshape(n, 3)), strict=True))
        out = []
        for k, d in enumerate(directions):
            track = assigned.get(k)
            if track is None:
                track = _Track(self._next_id, _Window(2 * self.max_views, centre))
                self._next_id += 1
                self._tracks.append(track)
            track.rays.append((float(t_s), centre.copy(), d, T, uv[k], cov_T_w_c, cov_uv))
            track.window.append(rows, k, bool(beside[k]))
            while len(track.rays) > self.max_views:
                track.rays.popleft()
                track.window.popleft()
            out.append(self._estimate(track))
        return out

    def _views(self, T: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The image's rays' quantities for the windows (``_Window``), (K, ...) each: computed
        by the same operations as ``triangulate_checked`` and ``midpoint_covariance`` compute
        them for every view of a window, so the same numbers (``_estimate_reference`` is the
        test), and whether each ray lies in the image plane (``MIN_RAY_COS``)."""
        camera = self.camera
        n = len(uv)
        rays_c = camera.rays(uv) if n else np.zeros((0, 3))
        Ts = np.broadcast_to(T, (n, 4, 4))
        R = Ts[:, :3, :3]
        d = np.einsum("nij,nj->ni", R, rays_c)
        P = np.eye(3) - np.einsum("ni,nj->nij", d, d)
        x = (uv[:, 0] - camera.cx) / camera.fx
        y = (uv[:, 1] - camera.cy) / camera.fy
        D = P @ np.stack([R[:, :, 0] / camera.fx, R[:, :, 1] / camera.fy], axis=2)
        D /= np.sqrt(x * x + y * y + 1.0)[:, None, None]
        rows = {
            "d": d,
            "T": Ts,
            "P": P,
            "PcS": -P @ so3.skew(np.ascontiguousarray(Ts[:, :3, 3])),
            "Sd": so3.skew(d),
            "D": D,
        }
        return ~(rays_c[:, 2] > MIN_RAY_COS), rows

    def _forget(self, t_s: float) -> None:
        for tr in self._tracks:
            while tr.rays and tr.rays[0][0] < t_s - self.window_s:
                tr.rays.popleft()
                tr.window.popleft()
        self._tracks = [tr for tr in self._tracks if tr.rays]

    def _associate(self, centre: np.ndarray, directions: np.ndarray) -> dict[int, _Track]:
        """Greedy: the closest (ray, track) pairs first, each used once, within the gate.

        Towards a track's apex the gate is ``gate_deg``; towards a track without one, the
        cone's bearing may also have turned by the camera's travel since that ray over the
        cone's range, at most ``baseline / MIN_RANGE_M``: the gate widens by that."""
        pairs = []
        # What depends on the track alone, once per track (``_angle_to_track_reference`` and
        # the gate, per pair, give the same numbers).
        towards = []
        for tr in self._tracks:
            gate = self.gate_rad
            if tr.apex_w is None:
                gate += float(np.linalg.norm(centre - tr.rays[-1][1])) / MIN_RANGE_M
            v = None if tr.apex_w is None else tr.apex_w - centre
            towards.append((tr, gate, v, None if v is None else float(np.linalg.norm(v))))
        for k, d in enumerate(directions):
            for tr, gate, v, n in towards:
                dist = _angle_to_track(d, tr, v, n)
                if dist <= gate:
                    pairs.append((dist, k, tr.id))
        pairs.sort()
        by_id = {tr.id: tr for tr in self._tracks}
        used_k: set[int] = set()
        used_track: set[int] = set()
        out: dict[int, _Track] = {}
        for _, k, tid in pairs:
            if k in used_k or tid in used_track:
                continue
            out[k] = by_id[tid]
            used_k.add(k)
            used_track.add(tid)
        return out

    def _estimate(self, track: _Track) -> TrackedApex:
        """The track's apex, base and covariance from its window's sums (``_Window``): the
        numbers of ``_estimate_reference`` (the triangulation and ``midpoint_covariance`` of
        every view again, at each image) but for rounding, each view's terms computed once
        (``_views``, ``_ray_terms``) and summed as views join and leave."""
        w = track.window
        n = w.hi - w.lo
        angle = w.parallax_deg("dirs") if n >= 2 else 0.0
        if angle < self.min_parallax_deg:
            return TrackedApex(track.id, None, track.apex_w, angle, n)
        # triangulate_checked: the same checks, in its order.
        T = w["T"]
        if w.beside[w.lo : w.hi].any() or not w.parallax_deg("d") >= self.min_parallax_deg:
            return TrackedApex(track.id, None, None, angle, n)
        A_inv = np.linalg.inv(w.A)
        p_o = A_inv @ w.b  # the apex less the window's origin
        apex = w.origin + p_o
        if not np.all(np.einsum("ni,ni->n", apex - T[:, :3, 3], T[:, :3, 2]) > 0.0):
            return TrackedApex(track.id, None, None, angle, n)
        track.apex_w = apex
        base = apex - np.array([0.0, 0.0, self.cone.height_m])
        q = np.concatenate(([1.0], -p_o))
        S = np.einsum("a,aibj,b->ij", q, w.Q.reshape(4, 3, 4, 3), q)
        cov = A_inv @ S @ A_inv.T
        cov = 0.5 * (cov + cov.T)
        range_m = float(np.linalg.norm(apex - track.rays[-1][1]))
        if (
            math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
            > self.max_std_fraction * range_m
        ):
            return TrackedApex(track.id, None, apex, angle, n, None)
        return TrackedApex(track.id, base, apex, angle, n, cov)

    def _estimate_reference(self, track: _Track) -> TrackedApex:
        """``_estimate`` as every view of the window computes it again at each image (kept to
        test it): ``triangulate_checked`` and ``midpoint_covariance`` on the window's poses and
        pixels. It leaves ``track`` as it was."""
        directions = np.array([r[2] for r in track.rays])
        angle = parallax_deg(directions) if len(directions) >= 2 else 0.0
        if angle < self.min_parallax_deg:
            return TrackedApex(track.id, None, track.apex_w, angle, len(track.rays))
        T = np.array([r[3] for r in track.rays])
        uv = np.array([r[4] for r in track.rays])
        try:
            # Every pose was checked (``update``) when its ray joined: not checked again.
            apex = triangulate_checked(self.camera, T, uv, min_parallax_deg=self.min_parallax_deg)
        except ValueError:
            return TrackedApex(track.id, None, None, angle, len(track.rays))
        base = apex - np.array([0.0, 0.0, self.cone.height_m])
        cov = midpoint_covariance(
            self.camera,
            T,
            uv,
            apex,
            [r[5] for r in track.rays],
            [r[6] for r in track.rays],
        )
        range_m = float(np.linalg.norm(apex - track.rays[-1][1]))
        if (
            math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
            > self.max_std_fraction * range_m
        ):
            return TrackedApex(track.id, None, apex, angle, len(track.rays), None)
        return TrackedApex(track.id, base, apex, angle, len(track.rays), cov)


def _angle_to_track(d: np.ndarray, track: _Track, v: np.ndarray | None, n: float | None) -> float:
    """``_angle_to_track_reference`` given ``v = track.apex_w - centre`` and its norm ``n``
    (None without an apex)."""
    if v is not None and n is not None:
        vd = float(v @ d)
        if n > 1e-9 and vd > 0.0:
            return math.acos(min(1.0, vd / n))
    d2 = track.rays[-1][2]
    return math.acos(min(1.0, max(-1.0, float(d @ d2))))


def _angle_to_track_reference(centre: np.ndarray, d: np.ndarray, track: _Track) -> float:
    """The angle (rad) between the ray ``centre + s d`` and the track: the direction from
    ``centre`` to the track's apex if it has one (in front), else its latest ray's."""
    if track.apex_w is not None:
        v = track.apex_w - centre
        n = float(np.linalg.norm(v))
        if n > 1e-9 and float(v @ d) > 0.0:
            return math.acos(min(1.0, float(v @ d) / n))
    d2 = track.rays[-1][2]
    return math.acos(min(1.0, max(-1.0, float(d @ d2))))


def midpoint_covariance(
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    uv: np.ndarray,
    p_w: np.ndarray,
    cov_T_w_c: list,
    cov_uv: list,
) -> np.ndarray:
    """First-order covariance of the midpoint ``p = A^-1 sum_i P_i c_i`` (``A = sum_i P_i``,
    ``P_i = I - d_i d_i^T``), the views independent, (3, 3) m^2.

    From ``sum_i P_i (c_i - p) = 0``: ``A dp = sum_i [P_i dc_i - M_i dd_i]`` with
    ``M_i = (d_i . w_i) I + d_i w_i^T``, ``w_i = c_i - p``. A left perturbation
    ``[rho, phi]`` of ``T_w_c`` moves ``c -> c + rho + phi x c`` and turns ``d -> d + phi x d``;
    a pixel moves the unit ray by ``(I - d d^T) [r_0 / fx, r_1 / fy] / |K^-1 [u, v, 1]|``.

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : ndarray, shape (N, 4, 4)
    uv : ndarray, shape (N, 2)
    p_w : ndarray, shape (3,)
        The midpoint.
    cov_T_w_c : list of N arrays (6, 6) or None
    cov_uv : list of N arrays (2, 2) or None
        None: that view's pose or pixel is exact.
    """
    # Every view at once (``_midpoint_covariance_reference`` is the same, view by view).
    rays_c = camera.rays(uv)
    R = T_w_c[:, :3, :3]
    d = np.einsum("nij,nj->ni", R, rays_c)
    c = T_w_c[:, :3, 3]
    P = np.eye(3) - d[:, :, None] * d[:, None, :]
    A_inv = np.linalg.inv(P.sum(axis=0))
    w = c - p_w
    M = np.einsum("ni,ni->n", d, w)[:, None, None] * np.eye(3) + d[:, :, None] * w[:, None, :]
    cov = np.zeros((3, 3))
    posed = [i for i, C in enumerate(cov_T_w_c) if C is not None]
    if posed:
        k = np.array(posed)
        J = np.empty((len(k), 3, 6))
        J[:, :, :3] = P[k]
        J[:, :, 3:] = -P[k] @ so3.skew(c[k]) + M[k] @ so3.skew(d[k])
        J = A_inv @ J
        cov += np.einsum("nij,njk,nlk->il", J, np.array([cov_T_w_c[i] for i in posed]), J)
    pixels = [i for i, C in enumerate(cov_uv) if C is not None]
    if pixels:
        k = np.array(pixels)
        x = (uv[k, 0] - camera.cx) / camera.fx
        y = (uv[k, 1] - camera.cy) / camera.fy
        D = P[k] @ np.stack([R[k, :, 0] / camera.fx, R[k, :, 1] / camera.fy], axis=2)
        D /= np.sqrt(x * x + y * y + 1.0)[:, None, None]
        J = -(A_inv @ M[k] @ D)
        cov += np.einsum("nij,njk,nlk->il", J, np.array([cov_uv[i] for i in pixels]), J)
    return 0.5 * (cov + cov.T)


def _midpoint_covariance_reference(
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    uv: np.ndarray,
    p_w: np.ndarray,
    cov_T_w_c: list,
    cov_uv: list,
) -> np.ndarray:
    """``midpoint_covariance`` view by view, as its docstring derives it (kept to test it)."""
    rays_c = camera.rays(uv)
    d = np.einsum("nij,nj->ni", T_w_c[:, :3, :3], rays_c)
    c = T_w_c[:, :3, 3]
    P = np.eye(3) - np.einsum("ni,nj->nij", d, d)
    A_inv = np.linalg.inv(P.sum(axis=0))
    cov = np.zeros((3, 3))
    for i in range(len(d)):
        w = c[i] - p_w
        M = float(d[i] @ w) * np.eye(3) + np.outer(d[i], w)
        if cov_T_w_c[i] is not None:
            J = np.empty((3, 6))
            J[:, :3] = P[i]
            J[:, 3:] = -P[i] @ so3.skew(c[i]) + M @ so3.skew(d[i])
            J = A_inv @ J
            cov += J @ cov_T_w_c[i] @ J.T
        if cov_uv[i] is not None:
            x = (uv[i, 0] - camera.cx) / camera.fx
            y = (uv[i, 1] - camera.cy) / camera.fy
            R = T_w_c[i, :3, :3]
            D = P[i] @ np.column_stack([R[:, 0] / camera.fx, R[:, 1] / camera.fy])
            D /= math.sqrt(x * x + y * y + 1.0)
            J = -A_inv @ M @ D
            cov += J @ cov_uv[i] @ J.T
    return 0.5 * (cov + cov.T)


class _TriangulatedTrack:
    """The ``triangulated`` method over one run: an ``ApexTracker`` fed each image's apexes."""

    def __init__(self, camera: PinholeCamera, cone: ConeModel) -> None:
        self.tracker = ApexTracker(camera, cone)

    def update(
        self, t_s: float, exposure: Exposure, observations: Sequence[Observation | None]
    ) -> dict[int, tuple[np.ndarray, np.ndarray] | NoEstimate]:
        """Each observation's apex, fitted along the image vertical the pose gives
        (``SilhouetteView.apex_keypoint``, memoised: the single-image methods fitted it), joins
        its track; its noise is the keypoint table's along-figure figure in every direction
        (``vnav.sensor_noise``), the camera pose's covariance the exposure's."""
        apexes = {
            i: uv
            for i, obs in enumerate(observations)
            if obs is not None and (uv := obs.view.apex_keypoint(exposure.cone)) is not None
        }
        std_px = keypoint_std_px("apex", exposure.noise.intensity_std_grey)[0]
        tracked = self.tracker.update(
            t_s,
            exposure.T_w_c,
            np.array(list(apexes.values())).reshape(-1, 2),
            cov_T_w_c=exposure.cov_T_w_c,
            cov_uv=std_px**2 * np.eye(2),
        )
        return {
            i: NoEstimate.PARALLAX if t.p_w is None else (t.p_w, t.cov_w)
            for i, t in zip(apexes, tracked, strict=True)
        }


class _Triangulated:
    """``triangulated`` (``vnav.methods``): the apex's rays over the last images."""

    def start(self, camera: PinholeCamera, cone: ConeModel) -> _TriangulatedTrack:
        return _TriangulatedTrack(camera, cone)


TRIANGULATED = _Triangulated()
"""The ``triangulated`` method's estimator (``vnav.methods.SeveralImageEstimator``)."""
