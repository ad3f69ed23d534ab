"""Several views: a point triangulated from N cameras, a camera's pose from known points (PnP).

Triangulation (Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., ch. 12):

- **midpoint** (default): the point nearest to every viewing ray in the least-squares sense,
  ``p = (sum_i P_i)^-1 sum_i P_i c_i`` with ``P_i = I - d_i d_i^T`` the projection across ray
  ``i`` (centre ``c_i``, unit direction ``d_i``). With noisy camera poses it is the better N-view
  estimate (Nasiri et al., "A critical review of N-view triangulation", 2021).
- **dlt**: the homogeneous linear system ``x_i P_i^3 - P_i^1 = 0`` (H&Z eq. 12.2) solved by SVD,
  in normalised image coordinates ``K^-1 [u, v, 1]`` for conditioning.

Both refuse degenerate views: a point is only fixed by rays that cross at an angle, and the
largest angle between any two rays (the parallax) must reach ``min_parallax_deg``.

The pose of a camera from world points and their pixels is OpenCV's ``solvePnP`` with SQPnP
(Terzakis & Lourakis 2020; globally optimal, any number of points >= 3, planar or not) or
IPPE (Collins & Bartoli 2014; planar points), then ``solvePnPRefineLM``. OpenCV's own notes
mark DLS and UPnP as broken and ``SOLVEPNP_ITERATIVE`` can report success with absurd
reprojection errors: neither is offered. The residual reprojection error comes with the pose,
so that a caller can tell a good fit from a bad one.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from vnav import se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection

__all__ = [
    "MIN_PARALLAX_DEG",
    "PnPResult",
    "camera_pose_from_apexes",
    "camera_pose_from_cones",
    "camera_pose_from_points",
    "parallax_deg",
    "triangulate",
    "unambiguous_pose",
]

MIN_PARALLAX_DEG = 1.0
"""The smallest angle between two viewing rays that ``triangulate`` accepts by default: at 1 deg
a 0.5 px error on a 415 px focal length (the default camera) moves the point by about 7% of
its range along the rays."""


def _check_views(camera: PinholeCamera, T_w_c: object, uv: object) -> tuple[np.ndarray, np.ndarray]:
    T = se3.check_transform(T_w_c, "T_w_c")
    if T.ndim != 3:
        raise ValueError(f"T_w_c must be a stack of poses, shape (N, 4, 4), got {T.shape}")
    px = np.asarray(uv, dtype=np.float64)
    if px.shape != (T.shape[0], 2):
        raise ValueError(
            f"uv must have shape (N, 2) with N = {T.shape[0]} (one pixel per pose), got {px.shape}"
        )
    if not np.isfinite(px).all():
        raise ValueError("uv must be finite; it holds NaN or inf")
    if T.shape[0] < 2:
        raise ValueError(f"triangulation needs at least 2 views, got {T.shape[0]}")
    return T, px


MIN_RAY_COS = 1e-9
"""``triangulate`` refuses a pixel whose ray is within 1e-9 rad of the image plane (90 deg
off the optical axis, to rounding: 4e11 px out for the default camera): it sees nothing in
front of the camera, and a point on it has no depth."""


def _rays_w(camera: PinholeCamera, T: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Unit world rays through the pixels, (N, 3).

    Raises
    ------
    ValueError
        If a pixel's ray lies in the image plane (``MIN_RAY_COS``), naming it.
    """
    rays_c = camera.rays(px)
    beside = np.flatnonzero(~(rays_c[:, 2] > MIN_RAY_COS))
    if beside.size:
        i = int(beside[0])
        raise ValueError(
            f"uv[{i}] = ({px[i, 0]:.3g}, {px[i, 1]:.3g}) px is 90 deg off the optical axis (to "
            f"rounding): its ray sees nothing in front of the camera"
        )
    return np.einsum("nij,nj->ni", T[:, :3, :3], rays_c)


def parallax_deg(rays_w: np.ndarray) -> float:
    """The largest angle between any two of the unit rays ``rays_w`` (N, 3), degrees."""
    cos = np.clip(rays_w @ rays_w.T, -1.0, 1.0)
    return math.degrees(float(np.arccos(cos.min())))


def triangulate(
    camera: PinholeCamera,
    T_w_c: object,
    uv: object,
    method: str = "midpoint",
    *,
    min_parallax_deg: float = MIN_PARALLAX_DEG,
) -> np.ndarray:
    """The world point seen at pixel ``uv[i]`` by the camera at pose ``T_w_c[i]``.

    Parameters
    ----------
    camera : PinholeCamera
    T_w_c : array_like, shape (N, 4, 4)
        The camera (optical frame) poses, N >= 2.
    uv : array_like, shape (N, 2)
        The point's pixel in each view.
    method : {"midpoint", "dlt"}
    min_parallax_deg : float
        Refuse views whose rays are all closer than this.

    Returns
    -------
    p_w : ndarray, shape (3,)

    Raises
    ------
    ValueError
        On malformed input (``uv`` not finite, or a pixel so far out that its ray lies in the
        image plane), an unknown method, views with too little parallax (the message gives
        the angle), or a point that comes out behind a camera.
    """
    if method not in ("midpoint", "dlt"):
        raise ValueError(f"method must be 'midpoint' or 'dlt', got {method!r}")
    T, px = _check_views(camera, T_w_c, uv)
    return triangulate_checked(camera, T, px, method, min_parallax_deg)


def triangulate_checked(
    camera: PinholeCamera,
    T: np.ndarray,
    px: np.ndarray,
    method: str = "midpoint",
    min_parallax_deg: float = MIN_PARALLAX_DEG,
) -> np.ndarray:
    """``triangulate`` of views already checked: ``T`` a float64 (N, 4, 4) stack of rigid
    transforms (``vnav.se3.check_pose`` each), ``px`` finite float64 (N, 2), N >= 2, and
    ``method`` a valid one. For a caller that keeps checked views and triangulates them again
    as more arrive (``vnav.tracking.ApexTracker``): the poses are not checked every time.

    Raises
    ------
    ValueError
        As ``triangulate``, but for malformed input.
    """
    rays = _rays_w(camera, T, px)
    angle = parallax_deg(rays)
    if not angle >= min_parallax_deg:
        raise ValueError(
            f"degenerate views: the rays meet at {angle:.3g} deg at most, below "
            f"{min_parallax_deg:g} deg; the baseline is too short for the range (move across "
            "the line of sight)"
        )
    centres = T[:, :3, 3]
    p_w = _midpoint(centres, rays) if method == "midpoint" else _dlt(camera, T, px)
    depths = np.einsum("ni,ni->n", p_w - centres, T[:, :3, 2])
    if not np.all(depths > 0.0):
        i = int(np.argmin(depths))
        raise ValueError(
            f"the triangulated point lies behind camera {i} (depth {depths[i]:.3g} m): the rays "
            "through uv do not meet in front of the cameras"
        )
    return p_w


def _midpoint(centres: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """``(sum P_i)^-1 sum P_i c_i``, ``P_i = I - d_i d_i^T``."""
    P = np.eye(3) - np.einsum("ni,nj->nij", rays, rays)
    return np.linalg.solve(P.sum(axis=0), np.einsum("nij,nj->i", P, centres))


def _dlt(camera: PinholeCamera, T: np.ndarray, px: np.ndarray) -> np.ndarray:
    """H&Z eq. 12.2 in normalised coordinates: rows ``x P^3 - P^1``, ``y P^3 - P^2``."""
    T_c_w = se3.invert(T)
    P = T_c_w[:, :3, :]  # (N, 3, 4): [R_c_w | t_c_w]
    x = (px[:, 0] - camera.cx) / camera.fx
    y = (px[:, 1] - camera.cy) / camera.fy
    A = np.concatenate([x[:, None] * P[:, 2] - P[:, 0], y[:, None] * P[:, 2] - P[:, 1]])
    _, _, Vt = np.linalg.svd(A)
    X = Vt[-1]
    if abs(X[3]) < 1e-12 * np.abs(X).max():
        raise ValueError("the DLT solution is a point at infinity: the rays are parallel")
    return X[:3] / X[3]


@dataclass(frozen=True)
class PnPResult:
    """A camera pose from points, with how well it explains them.

    Attributes
    ----------
    T_w_c : ndarray, shape (4, 4)
    rms_px : float
        Root-mean-square reprojection error over the points, pixels.
    residuals_px : ndarray, shape (N,)
        Each point's reprojection error, pixels.
    """

    T_w_c: np.ndarray
    rms_px: float
    residuals_px: np.ndarray


def camera_pose_from_points(
    camera: PinholeCamera, p_w: object, uv: object, method: str = "sqpnp"
) -> PnPResult:
    """The camera pose that projects the world points ``p_w`` onto the pixels ``uv``.

    SQPnP (or IPPE for coplanar points) for the global solution, then Levenberg-Marquardt on
    the reprojection error (``cv2.solvePnPRefineLM``).

    Parameters
    ----------
    camera : PinholeCamera
    p_w : array_like, shape (N, 3)
        World points, N >= 4 (three points admit up to four poses).
    uv : array_like, shape (N, 2)
        Their pixels.
    method : {"sqpnp", "ippe"}

    Returns
    -------
    PnPResult

    Raises
    ------
    ValueError
        On malformed input, fewer than 4 points, points on one line (the rotation about it is
        free), ``"ippe"`` with points off a plane, a solver failure, or a pose that puts a
        point behind the camera.
    """
    flags = {"sqpnp": cv2.SOLVEPNP_SQPNP, "ippe": cv2.SOLVEPNP_IPPE}
    if method not in flags:
        raise ValueError(f"method must be one of {sorted(flags)}, got {method!r}")
    P = np.asarray(p_w, dtype=np.float64)
    px = np.asarray(uv, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"p_w must have shape (N, 3), got {P.shape}")
    if px.shape != (P.shape[0], 2):
        raise ValueError(f"uv must have shape ({P.shape[0]}, 2), got {px.shape}")
    if not (np.isfinite(P).all() and np.isfinite(px).all()):
        raise ValueError("p_w and uv must be finite")
    if P.shape[0] < 4:
        raise ValueError(
            f"a camera pose needs at least 4 points, got {P.shape[0]} "
            "(three admit up to four poses)"
        )
    singular = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    scale = max(float(singular[0]), 1e-12)
    if singular[1] < 1e-6 * scale:
        raise ValueError("the points lie on one line: the rotation about it is undetermined")
    if method == "ippe" and singular[2] > 1e-6 * scale:
        raise ValueError("method 'ippe' needs coplanar points; use 'sqpnp'")
    result = _pnp(camera, P, px, flags[method], refine=True)
    if result is None:
        raise ValueError(f"solvePnP ({method}) found no pose with every point in front")
    return result


def _pnp(
    camera: PinholeCamera, P: np.ndarray, px: np.ndarray, flag: int, *, refine: bool
) -> PnPResult | None:
    """``cv2.solvePnP`` (then ``solvePnPRefineLM`` if ``refine``) on validated input; None if
    it fails or puts a point behind the camera."""
    try:
        ok, rvec, tvec = cv2.solvePnP(P, px, camera.K, None, flags=flag)
        if ok and refine:
            rvec, tvec = cv2.solvePnPRefineLM(P, px, camera.K, None, rvec, tvec, _LM_CRITERIA)
    except cv2.error:  # SQPnP asserts on degenerate sets (repeated points or pixels)
        return None
    if not ok:
        return None
    R_c_w, _ = cv2.Rodrigues(rvec)
    T_c_w = se3.make(R_c_w, tvec.reshape(3))
    p_c = P @ R_c_w.T + T_c_w[:3, 3]
    if not np.all(p_c[:, 2] > 0.0):
        return None
    residuals = np.linalg.norm(camera.project(p_c) - px, axis=1)
    return PnPResult(se3.invert(T_c_w), float(np.sqrt(np.mean(residuals**2))), residuals)


_LM_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-14)
"""Levenberg-Marquardt's stop: OpenCV's default (20 steps, float32 epsilon) leaves ~1e-6 px."""

GUESS_GATE_PX = 30.0
"""``camera_pose_from_cones`` with a guessed pose: the gate of its matching, px (a few degrees
of attitude or mount error)."""

MATCH_GATE_PX = 8.0
"""``camera_pose_from_cones``: a cone's apex matches a detection within this many pixels of
its projection under the candidate pose."""

REPROJECTION_GATE_PX = 3.0
"""``camera_pose_from_cones`` with a guessed pose keeps a pose only if every apex it is fitted
to reprojects within this many pixels: a detector's apex is off by under a pixel, a cone
matched to its neighbour's detection leaves several (the ``calibration`` built-in, its mount
2.4 deg off: 34 of 361 poses matched one cone wrong, 4-6 px RMS, up to 0.49 m and 8 deg
off)."""


def camera_pose_from_cones(
    camera: PinholeCamera,
    cones_w: object,
    detections: Sequence[ConeDetection],
    cone: ConeModel = TRAFFIC_CONE,
    *,
    T_w_c_guess: np.ndarray | None = None,
) -> tuple[PnPResult, dict[int, int]]:
    """The camera pose from detected cones of a known map, with the matches it found.

    Each cone gives one sharp world point, its apex ``cone_w + (0, 0, H)``, seen at the
    detection's ``apex_uv`` (the detector's pose-free apex). Which detection is which cone is
    not known: every ordered choice of 4 cones for 4 detections is solved (SQPnP) and scored by
    how many apexes it then projects within ``MATCH_GATE_PX`` of a detection; the best is
    refined on all its matches. A cone layout that two poses explain equally well (a symmetric
    map seen from where the symmetry holds) is refused rather than guessed.

    With exactly 3 cones seen (three apexes admit up to four poses), each also gives its base
    plate's near bottom edge (``_pose_from_three_cones``); they must not stand on one line.

    Parameters
    ----------
    camera : PinholeCamera
    cones_w : array_like, shape (M, 3)
        Base centres of the map's cones, M >= 3.
    detections : sequence of ConeDetection
        At least 3, clear of the image border.
    cone : ConeModel
    T_w_c_guess : ndarray, shape (4, 4), optional
        A rough pose (the pose stream's, say): the apexes are matched by projecting the map
        with it (mutual nearest within ``GUESS_GATE_PX``), a single solve; the search over
        every choice runs only when fewer than 4 match.

    Returns
    -------
    PnPResult
        The pose refined on every matched cone.
    matches : dict of int to int
        Detection index -> cone index.

    Raises
    ------
    ValueError
        Fewer than 3 usable detections or cones, 3 cones on one line, no pose that explains
        the detections, or an ambiguous match.
    """
    C = _cone_map(cones_w)
    apex_w = C + np.array([0.0, 0.0, cone.height_m])
    usable = _usable_detections(detections)
    if len(usable) == 3 and len(C) >= 3:
        return _pose_from_three_cones(camera, C, detections, usable, cone)
    if len(usable) < 4 or len(C) < 4:
        raise ValueError(
            f"a pose from cones needs at least 3 cones seen whole, got {len(usable)} detections "
            f"clear of the border and {len(C)} cones in the map"
        )
    uv = np.array([detections[i].apex_uv for i in usable])
    areas_px = [detections[i].area_px for i in usable]
    result, found = _pose_from_apexes(camera, apex_w, uv, areas_px, T_w_c_guess)
    return result, {usable[k]: c for k, c in found.items()}


def _pose_from_apexes(
    camera: PinholeCamera,
    apex_w: np.ndarray,
    uv: np.ndarray,
    areas_px: list[int],
    T_w_c_guess: np.ndarray | None,
) -> tuple[PnPResult, dict[int, int]]:
    """``camera_pose_from_cones`` for 4 or more apexes: matched by a rough pose, else searched.

    Parameters
    ----------
    camera : PinholeCamera
    apex_w : ndarray, shape (M, 3)
        The map's cone apexes, world frame, metres, M >= 4.
    uv : ndarray, shape (N, 2)
        The usable detections' apexes, pixels, N >= 4.
    areas_px : list of int
        Their detections' areas, pixels: the 4 largest (nearest, best measured) seed the
        search.
    T_w_c_guess : ndarray, shape (4, 4), optional
        A rough pose (``_pose_from_guess``); the search runs only when it matches too few.

    Returns
    -------
    PnPResult
        The pose refined on every matched apex.
    matches : dict of int to int
        Index into ``uv`` -> cone index.

    Raises
    ------
    ValueError
        No pose that explains the detections, or an ambiguous match.
    """
    if T_w_c_guess is not None:
        posed = _pose_from_guess(camera, apex_w, uv, T_w_c_guess)
        if posed is not None:
            return posed
    # Seed with the 4 largest detections (nearest, best measured).
    seeds = sorted(range(len(uv)), key=lambda k: -areas_px[k])[:4]
    result, found = camera_pose_from_apexes(camera, apex_w, uv, seeds)
    return unambiguous_pose(camera, apex_w, uv, result, found, T_w_c_guess)


def _cone_map(cones_w: object) -> np.ndarray:
    """The map's cone base centres, checked.

    Parameters
    ----------
    cones_w : array_like, shape (M, 3)
        Metres, world frame.

    Returns
    -------
    ndarray, shape (M, 3), float64

    Raises
    ------
    ValueError
        If the shape is not (M, 3), or a coordinate is NaN or inf.
    """
    C = np.asarray(cones_w, dtype=np.float64)
    if C.ndim != 2 or C.shape[1] != 3:
        raise ValueError(f"cones_w must have shape (M, 3), got {C.shape}")
    if not np.isfinite(C).all():
        raise ValueError("cones_w must be finite; it holds NaN or inf")
    return C


def _usable_detections(detections: Sequence[ConeDetection]) -> list[int]:
    """The indices of the detections clear of the image border, their keypoints checked.

    Parameters
    ----------
    detections : sequence of ConeDetection

    Returns
    -------
    list of int
        In order.

    Raises
    ------
    ValueError
        If a usable detection's ``apex_uv`` or ``base_uv`` is not finite.
    """
    usable = [i for i, d in enumerate(detections) if not d.touches_border]
    for i in usable:
        if not np.isfinite([*detections[i].apex_uv, *detections[i].base_uv]).all():
            raise ValueError(f"detections[{i}]: apex_uv and base_uv must be finite")
    return usable


def _pose_from_guess(
    camera: PinholeCamera, apex_w: np.ndarray, uv: np.ndarray, T_w_c_guess: np.ndarray
) -> tuple[PnPResult, dict[int, int]] | None:
    """The pose from the apexes a rough pose matches (mutual nearest within ``GUESS_GATE_PX``).

    Parameters
    ----------
    camera : PinholeCamera
    apex_w : ndarray, shape (M, 3)
        The map's cone apexes, world frame, metres.
    uv : ndarray, shape (N, 2)
        The usable detections' apexes, pixels.
    T_w_c_guess : ndarray, shape (4, 4)
        The rough pose.

    Returns
    -------
    (PnPResult, dict of int to int) or None
        The pose and its matches (index into ``uv`` -> cone index); None when fewer than 4
        apexes match or their fit fails the gate (``_gated_fit``).

    Raises
    ------
    ValueError
        If ``T_w_c_guess`` is not a pose, or the match is ambiguous (``unambiguous_pose``).
    """
    guess = se3.check_pose(T_w_c_guess, "T_w_c_guess")
    guessed = _match(camera, guess, apex_w, uv, GUESS_GATE_PX)
    gated = _gated_fit(camera, apex_w, uv, {k: c for k, (_, c) in guessed.items()})
    if gated is None:
        return None
    return unambiguous_pose(camera, apex_w, uv, *gated, guess)


def _gated_fit(
    camera: PinholeCamera, apex_w: np.ndarray, uv: np.ndarray, matches: dict[int, int]
) -> tuple[PnPResult, dict[int, int]] | None:
    """The pose of ``matches`` (pixel index -> map index) with every apex within
    ``REPROJECTION_GATE_PX``, or None.

    A wrong match among them is not found by its own residual (a 4-point fit absorbs it):
    the matches are fitted whole and with each one or two of them left out; under each pose
    the map is matched again (mutual nearest within ``MATCH_GATE_PX``) and fitted once more
    (``_fit_within_gate``: a detection beyond the gate, two cones' blobs merged say, left
    out); the pose that keeps the most apexes wins, then the lower RMS."""
    ks = sorted(matches)
    best: tuple[int, float, PnPResult, dict[int, int]] | None = None
    for drop in (0, 1, 2):
        if len(ks) - drop < 4:
            break
        for subset in itertools.combinations(ks, len(ks) - drop):
            gated = _fit_within_gate(camera, apex_w, uv, {k: matches[k] for k in subset})
            if gated is None:
                continue
            found = _match(camera, gated[0].T_w_c, apex_w, uv, MATCH_GATE_PX)
            again = {k: c for k, (_, c) in found.items()}
            if again != gated[1] and len(again) >= 4:
                gated = _fit_within_gate(camera, apex_w, uv, again) or gated
            fit, kept = gated
            if best is None or (len(kept), -fit.rms_px) > best[:2]:
                best = (len(kept), -fit.rms_px, fit, kept)
        # Fewer left out first: a pose that keeps every match (all but one) needs no search
        # further (the subsets' costs grow as the binomial coefficients).
        if best is not None and best[0] >= len(ks) - drop:
            break
    return None if best is None else (best[2], best[3])


def _fit_within_gate(
    camera: PinholeCamera, apex_w: np.ndarray, uv: np.ndarray, matches: dict[int, int]
) -> tuple[PnPResult, dict[int, int]] | None:
    """``camera_pose_from_points`` on ``matches``, the worst apex left out while one lies
    beyond ``REPROJECTION_GATE_PX`` and more than 4 remain: the pose and the matches kept,
    or None."""
    ks = sorted(matches)
    while len(ks) >= 4:
        try:
            fit = camera_pose_from_points(camera, apex_w[[matches[k] for k in ks]], uv[ks])
        except ValueError:
            return None
        worst = int(np.argmax(fit.residuals_px))
        if fit.residuals_px[worst] <= REPROJECTION_GATE_PX:
            return fit, {k: matches[k] for k in ks}
        if len(ks) == 4:
            return None
        del ks[worst]
    return None


def unambiguous_pose(
    camera: PinholeCamera,
    apex_w: np.ndarray,
    uv: np.ndarray,
    fit: PnPResult,
    matches: dict[int, int],
    T_w_c_guess: np.ndarray | None,
) -> tuple[PnPResult, dict[int, int]]:
    """``fit`` of the pixels ``uv`` matched to the map ``apex_w`` as ``matches`` (pixel index
    -> map index), unless those apexes, all in one plane (cones of one height on flat ground),
    admit a second pose (IPPE's other solution, Collins & Bartoli 2014) that explains them
    nearly as well (RMS below ``2 rms + 0.5`` px, the ambiguity rule of
    ``camera_pose_from_apexes``): then the one nearer the guess ``T_w_c_guess`` if the other
    is at least twice as far from it.

    Returns
    -------
    PnPResult, dict of int to int
        The pose kept and ``matches``.

    Raises
    ------
    ValueError
        Ambiguous: the second pose fits as well and no guess (or one as near both) chooses.
    """
    ks = sorted(matches)
    P, px = apex_w[[matches[k] for k in ks]], uv[ks]
    other = _ippe_other(camera, P, px, fit)
    if other is None or other.rms_px >= 2.0 * fit.rms_px + 0.5:
        return fit, matches
    if T_w_c_guess is not None:
        d_fit, d_other = (
            _pose_distance(fit.T_w_c, T_w_c_guess),
            _pose_distance(other.T_w_c, T_w_c_guess),
        )
        if d_fit * 2.0 <= d_other:
            return fit, matches
        if d_other * 2.0 <= d_fit:
            return other, matches
    raise ValueError(
        "ambiguous: the apexes, in one plane, fit two poses equally well (IPPE's two "
        f"solutions, {fit.rms_px:.2g} and {other.rms_px:.2g} px RMS)"
    )


def _ippe_other(
    camera: PinholeCamera, P: np.ndarray, px: np.ndarray, fit: PnPResult
) -> PnPResult | None:
    """For coplanar ``P``: IPPE's solution that is not ``fit`` (more than 1 cm or 0.1 deg
    from it), refined, with every point in front; None for points off a plane or no such
    solution."""
    singular = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    if singular[2] > 1e-6 * max(float(singular[0]), 1e-12):
        return None
    try:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(P, px, camera.K, None, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return None
    for rvec, tvec in zip(rvecs, tvecs, strict=True):
        rvec, tvec = cv2.solvePnPRefineLM(P, px, camera.K, None, rvec, tvec, _LM_CRITERIA)
        R_c_w, _ = cv2.Rodrigues(rvec)
        p_c = P @ R_c_w.T + tvec.reshape(3)
        if not np.all(p_c[:, 2] > 0.0):
            continue
        T_w_c = se3.invert(se3.make(R_c_w, tvec.reshape(3)))
        if _pose_distance(T_w_c, fit.T_w_c) < 0.01:
            continue
        residuals = np.linalg.norm(camera.project(p_c) - px, axis=1)
        return PnPResult(T_w_c, float(np.sqrt(np.mean(residuals**2))), residuals)
    return None


def _pose_distance(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Position difference (m) plus rotation angle over 0.1 deg per centimetre (rad * 5.7)."""
    R = T_a[:3, :3].T @ T_b[:3, :3]
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0)))
    return float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])) + angle * 0.01 / math.radians(0.1)


def _pose_from_three_cones(
    camera: PinholeCamera,
    C: np.ndarray,
    detections: Sequence[ConeDetection],
    usable: list[int],
    cone: ConeModel,
) -> tuple[PnPResult, dict[int, int]]:
    """``camera_pose_from_cones`` for exactly 3 detections: apexes and base edges.

    Three apexes admit up to four poses: each cone also gives its base plate's near bottom
    edge on the line of sight, seen at ``base_uv``: ``cone_w - s b`` with
    ``s = ConeModel.base_axis_distance_m`` and ``b`` the horizontal bearing from the camera,
    which the pose sets; solved from the cones' centres first, then once more with the edges
    the first pose gives. The 3 cones must not stand on one line.
    """
    apex_uv = np.array([detections[i].apex_uv for i in usable])
    base_uv = np.array([detections[i].base_uv for i in usable])
    px = np.concatenate([apex_uv, base_uv])
    up = np.array([0.0, 0.0, cone.height_m])
    scored: list[tuple[float, tuple[int, ...], PnPResult]] = []
    for chosen in itertools.permutations(range(len(C)), 3):
        centres = C[list(chosen)]
        if np.linalg.matrix_rank(centres[1:] - centres[0], tol=1e-6) < 2:
            continue  # three cones on one line leave the rotation about it free
        result = _pnp(
            camera, np.concatenate([centres + up, centres]), px, cv2.SOLVEPNP_SQPNP, refine=True
        )
        if result is None:
            continue
        edges = _edges(centres, result.T_w_c, cone)
        refined = _pnp(
            camera, np.concatenate([centres + up, edges]), px, cv2.SOLVEPNP_SQPNP, refine=True
        )
        if refined is not None and refined.rms_px <= MATCH_GATE_PX:
            scored.append((refined.rms_px, chosen, refined))
    if not scored:
        raise ValueError("no pose puts 3 of the map's cones (not on one line) on the detections")
    scored.sort(key=lambda s: s[0])
    best = scored[0]
    if len(scored) > 1 and set(scored[1][1]) != set(best[1]) and scored[1][0] < 2.0 * best[0] + 0.5:
        raise ValueError(
            "ambiguous: two different matches of detections to cones fit equally well "
            "(the map looks the same from two poses)"
        )
    return best[2], {usable[k]: c for k, c in enumerate(best[1])}


def _edges(centres: np.ndarray, T_w_c: np.ndarray, cone: ConeModel) -> np.ndarray:
    """Each base plate's near bottom edge on the line of sight from the camera at ``T_w_c``."""
    b = centres - T_w_c[:3, 3]
    b[:, 2] = 0.0
    b /= np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-9)
    return centres - cone.base_axis_distance_m * b


def camera_pose_from_apexes(
    camera: PinholeCamera,
    apex_w: object,
    uv: object,
    seeds: Sequence[int] | None = None,
    *,
    T_w_c_prior: np.ndarray | None = None,
) -> tuple[PnPResult, dict[int, int]]:
    """``camera_pose_from_cones`` on bare points: a map's points ``apex_w`` (M, 3) seen at some
    of the pixels ``uv`` (K, 2), which is which unknown, K >= 4, M >= 4.

    ``seeds``: the 4 pixels to try every ordered choice of 4 map points on (default: the first
    4). ``T_w_c_prior``: a rough pose that narrows the choices: a seed pixel is tried only with
    the map points it projects within ``GUESS_GATE_PX`` of (each choice is solved and scored
    as without it); if none of those gives a pose, every choice is tried. Returns the refined
    pose and the matches (pixel index -> map index).

    Raises
    ------
    ValueError
        As ``camera_pose_from_cones``.
    """
    P = np.asarray(apex_w, dtype=np.float64).reshape(-1, 3)
    px = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if len(px) < 4 or len(P) < 4:
        raise ValueError(f"a pose needs at least 4 points and 4 pixels, got {len(P)} and {len(px)}")
    for name, values in (("apex_w", P), ("uv", px)):
        if not np.isfinite(values).all():
            raise ValueError(f"{name} must be finite; it holds NaN or inf")
    seeds = list(range(4)) if seeds is None else list(seeds)
    valid = all(isinstance(k, int | np.integer) and 0 <= k < len(px) for k in seeds)
    if not valid or len(set(seeds)) != 4:
        raise ValueError(f"seeds must be 4 distinct pixel indices in [0, {len(px)}), got {seeds}")
    everything = itertools.permutations(range(len(P)), 4)
    if T_w_c_prior is None:
        return _best_choice(camera, P, px, seeds, everything)
    near = _near_projections(camera, se3.check_pose(T_w_c_prior, "T_w_c_prior"), P, px[seeds])
    narrowed = (c for c in itertools.product(*near) if len(set(c)) == 4)
    try:
        return _best_choice(camera, P, px, seeds, narrowed)
    except ValueError:
        return _best_choice(camera, P, px, seeds, everything)


def _near_projections(
    camera: PinholeCamera, T_w_c: np.ndarray, P: np.ndarray, px: np.ndarray
) -> list[list[int]]:
    """For each pixel, the map points that ``T_w_c`` projects within ``GUESS_GATE_PX`` of it."""
    dist = _pixel_distances(camera, T_w_c, P, px)
    return [np.flatnonzero(row <= GUESS_GATE_PX).tolist() for row in dist]


def _best_choice(
    camera: PinholeCamera,
    P: np.ndarray,
    px: np.ndarray,
    seeds: list[int],
    choices: Iterable[tuple[int, ...]],
) -> tuple[PnPResult, dict[int, int]]:
    """``camera_pose_from_apexes``' search over ``choices`` (ordered map points for the seeds)."""
    scored: list[tuple[int, float, dict[int, int]]] = []
    for chosen in choices:
        trial = _pnp(camera, P[list(chosen)], px[seeds], cv2.SOLVEPNP_SQPNP, refine=False)
        if trial is None or trial.rms_px > MATCH_GATE_PX:
            continue
        found = _match(camera, trial.T_w_c, P, px)
        if len(found) >= 4:
            residual = float(np.mean([r for r, _ in found.values()]))
            scored.append((len(found), residual, {k: c for k, (_, c) in found.items()}))
    if not scored:
        raise ValueError("no pose projects 4 or more of the map's cones onto the detections")
    scored.sort(key=lambda s: (-s[0], s[1]))
    best = scored[0]
    for other in scored[1:]:
        if other[0] == best[0] and other[2] != best[2] and other[1] < 2.0 * best[1] + 0.5:
            raise ValueError(
                "ambiguous: two different matches of detections to cones fit equally well "
                "(the map looks the same from two poses)"
            )
    ks = list(best[2])
    result = camera_pose_from_points(camera, P[[best[2][k] for k in ks]], px[ks])
    return result, best[2]


def _pixel_distances(
    camera: PinholeCamera, T_w_c: np.ndarray, p_w: np.ndarray, uv: np.ndarray
) -> np.ndarray:
    """``(len(uv), len(p_w))`` distances, px, from each pixel to each map point as the camera
    at ``T_w_c`` sees it; inf for a point behind the camera."""
    T_c_w = se3.invert(T_w_c)
    p_c = p_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    front = p_c[:, 2] > 0.0
    proj = np.full((len(p_w), 2), np.inf)
    proj[front] = camera.project(p_c[front])
    return np.linalg.norm(uv[:, None, :] - proj[None, :, :], axis=2)


def _match(
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    apex_w: np.ndarray,
    uv: np.ndarray,
    gate_px: float = MATCH_GATE_PX,
) -> dict[int, tuple[float, int]]:
    """Detection index -> (pixel distance, cone index): mutual nearest within the gate."""
    dist = _pixel_distances(camera, T_w_c, apex_w, uv)  # (detections, cones)
    out = {}
    for k in range(len(uv)):
        c = int(np.argmin(dist[k]))
        if dist[k, c] <= gate_px and int(np.argmin(dist[:, c])) == k:
            out[k] = (float(dist[k, c]), c)
    return out
