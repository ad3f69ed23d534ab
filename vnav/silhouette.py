"""The cone's silhouette seen from a known camera pose: the image of the vertical, the apex,
the lower boundary and where the cone's image axis leaves it.

The image of the vertical direction at a pixel points at the vertical vanishing point
``n = K R_c_w (0, 0, -1)^T`` (Hartley & Zisserman, 2nd ed., sec. 8.6): for a pixel ``(u, v)``
the downward direction is ``(n_x - u n_z, n_y - v n_z)`` (the derivative of the projection of
``X + t e_down`` at t = 0, up to a positive factor). The camera's nadir ground point projects
to that same vanishing point, so "down the image axis" is also "towards the camera on the
ground".

``SilhouetteView`` holds one detection with one camera pose and computes each of these
once, in plain Python floats (a 3-vector in scalar arithmetic costs a fraction of a numpy
call). Next to each rewritten kernel is its lecture form (``_ray_reference``,
``_vertical_reference``, ``_boundary_reference``); the tests check that the two agree.
"""

from __future__ import annotations

import math

import numpy as np

from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE, ConeModel
from vnav.detect import ConeDetection

__all__ = [
    "SilhouetteView",
    "apex_pixel",
    "boundary_from_mask",
    "exit_on_boundary",
    "triangle_fraction",
]


class SilhouetteView:
    """One detection seen from one validated camera pose: the geometry every method shares.

    The pose and the intrinsics are held as Python floats (3-vectors and 3x3 products in plain
    arithmetic cost a fraction of numpy's per-call overhead); the pixel list, the image
    vertical, the apex fits and the blob's lower boundary are computed once, on first use.
    """

    __slots__ = (
        "R",
        "_apex",
        "_boundary",
        "_exit",
        "_uv",
        "_vertical_at_blob",
        "cx",
        "cy",
        "detection",
        "fx",
        "fy",
        "t",
    )

    def __init__(self, detection: ConeDetection, camera: PinholeCamera, T_w_c: np.ndarray):
        self.detection = detection
        self.fx, self.fy, self.cx, self.cy = camera.fx, camera.fy, camera.cx, camera.cy
        rows = T_w_c.tolist()
        self.R = (rows[0][:3], rows[1][:3], rows[2][:3])
        self.t = (rows[0][3], rows[1][3], rows[2][3])
        self._uv: np.ndarray | None = None
        self._vertical_at_blob: tuple[np.ndarray, float] | bool | None = False
        self._apex: dict[float, np.ndarray | None] = {}
        self._boundary: np.ndarray | None = None
        self._exit: dict[tuple[float, float], np.ndarray] = {}

    def uv(self) -> np.ndarray:
        """``detection.pixels_uv()``, computed once."""
        if self._uv is None:
            self._uv = self.detection.pixels_uv()
        return self._uv

    def ray(self, u: float, v: float) -> tuple[float, float, float]:
        """Unit ray through pixel ``(u, v)`` in world coordinates, ``R_w_c K^-1 [u, v, 1]``
        normalised (lecture form: ``_ray_reference``)."""
        x = (u - self.cx) / self.fx
        y = (v - self.cy) / self.fy
        norm = math.sqrt(x * x + y * y + 1.0)
        x, y, z = x / norm, y / norm, 1.0 / norm
        r0, r1, r2 = self.R
        return (
            r0[0] * x + r0[1] * y + r0[2] * z,
            r1[0] * x + r1[1] * y + r1[2] * z,
            r2[0] * x + r2[1] * y + r2[2] * z,
        )

    def camera_coordinates(self, p_w: np.ndarray) -> tuple[float, float, float]:
        """``p_c = R_w_c^T (p_w - t_w_c)``: a world point in the optical frame, three floats."""
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R
        bx, by, bz = p_w[0] - self.t[0], p_w[1] - self.t[1], p_w[2] - self.t[2]
        return (
            r00 * bx + r10 * by + r20 * bz,
            r01 * bx + r11 * by + r21 * bz,
            r02 * bx + r12 * by + r22 * bz,
        )

    def vertical(self, u: float, v: float) -> tuple[float, float] | None:
        """Unit image direction of the world's downward vertical at pixel ``(u, v)``, or None.

        Two floats (lecture form: ``_vertical_reference``); None at the nadir's image,
        where the camera looks straight down through the pixel.
        """
        m0, m1, m2 = -self.R[2][0], -self.R[2][1], -self.R[2][2]
        n0 = self.fx * m0 + self.cx * m2
        n1 = self.fy * m1 + self.cy * m2
        d0, d1 = n0 - u * m2, n1 - v * m2
        norm = math.hypot(d0, d1)
        scale = math.sqrt(n0 * n0 + n1 * n1 + m2 * m2)
        if norm < 1e-9 * max(scale, 1.0):
            return None
        return d0 / norm, d1 / norm

    def vertical_at_blob(self) -> tuple[np.ndarray, float] | None:
        """``(d, elevation)`` at the blob's centroid, or None at the nadir; computed once.

        ``d`` is the image of the downward vertical (2,), ``elevation`` the angle of the line
        of sight through the centroid below the horizontal, radians.
        """
        if self._vertical_at_blob is False:
            u, v = (float(x) for x in self.detection.centroid_uv[:2])
            d = self.vertical(u, v)
            if d is None:
                self._vertical_at_blob = None
            else:
                ray_z = self.ray(u, v)[2]
                self._vertical_at_blob = (np.array(d), math.asin(min(max(-ray_z, -1.0), 1.0)))
        return self._vertical_at_blob  # type: ignore[return-value]

    def apex(self, d: np.ndarray, fraction: float) -> np.ndarray | None:
        """``apex_pixel(detection, d, fraction)``, memoised on ``fraction``."""
        if fraction not in self._apex:
            self._apex[fraction] = _apex_pixel(self.uv(), d, fraction)
        return self._apex[fraction]

    def axis_exit(self, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
        """Where the line ``apex_uv + lambda d`` leaves the blob at the bottom, (2,).

        The blob's lower boundary is computed once, the exit memoised on the apex.
        """
        key = (float(apex_uv[0]), float(apex_uv[1]))
        if key not in self._exit:
            if self._boundary is None:
                self._boundary = boundary_from_mask(self.detection, float(d[0]), float(d[1]))
            self._exit[key] = exit_on_boundary(self._boundary, d, apex_uv)
        return self._exit[key]

    def apex_keypoint(self, cone: ConeModel) -> np.ndarray | None:
        """The apex ``bottom`` draws its axis from: ``apex_pixel`` with the triangle fraction
        at least 0.5, (2,), or None (no image vertical, or no fit). Unlike the detector's
        pose-free ``apex_uv`` (about 0.25 px above the true apex, two edges fitted to a
        rounded tip), it is unbiased (``vnav.sensor_noise.KEYPOINT_STD_PX``)."""
        vertical = self.vertical_at_blob()
        if vertical is None:
            return None
        d, elevation = vertical
        return self.apex(d, max(triangle_fraction(elevation, cone), 0.5))

    def bottom(self, cone: ConeModel) -> np.ndarray:
        """Where the image of the cone's axis leaves the blob at the bottom, (2,) float64.

        The image of the vertical through the apex (the line through ``apex_pixel``, else
        the detector's apex, along the image of the downward vertical) meets the blob's lower
        boundary (interpolated linearly between columns) at the image of the base plate's near
        bottom edge, in the vertical plane through the camera and the cone's axis:
        ``cone.base_axis_distance_m`` from the base centre towards the camera. Falls back to
        ``detection.base_uv`` when the vertical is undefined at the blob (camera looking
        straight down at it).
        """
        vertical = self.vertical_at_blob()
        if vertical is None:
            return np.asarray(self.detection.base_uv, dtype=np.float64)
        d, _ = vertical
        apex_uv = self.apex_keypoint(cone)
        if apex_uv is None:
            apex_uv = np.asarray(self.detection.apex_uv, dtype=np.float64)
        return self.axis_exit(d, apex_uv)


def _ray_reference(camera: PinholeCamera, T_w_c: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Lecture form of ``SilhouetteView.ray``: ``R_w_c @ camera.rays(uv)``, (3,)."""
    return T_w_c[:3, :3] @ camera.rays(uv)[0]


def _vertical_reference(
    camera: PinholeCamera, T_w_c: np.ndarray, uv: np.ndarray
) -> np.ndarray | None:
    """Lecture form of ``SilhouetteView.vertical``: the vanishing point, with numpy.

    ``n = K R_c_w (0, 0, -1)^T`` is the vertical vanishing point (homogeneous); the direction
    at ``(u, v)`` is ``(n_x - u n_z, n_y - v n_z)``, normalised; None at the nadir's image.
    """
    n = camera.K @ (T_w_c[:3, :3].T @ np.array([0.0, 0.0, -1.0]))
    d = np.array([n[0] - uv[0] * n[2], n[1] - uv[1] * n[2]])
    norm = float(np.hypot(d[0], d[1]))
    if norm < 1e-9 * max(float(np.linalg.norm(n)), 1.0):
        return None
    return d / norm


def triangle_fraction(elevation_rad: float, cone: ConeModel = TRAFFIC_CONE) -> float:
    """Fraction of the silhouette's length, from the apex down, that is the body's triangle.

    Seen at elevation ``e`` (line of sight below the horizontal; orthographic approximation),
    the apex lies ``(H - t) cos e`` above the image of the body's base circle's centre and the
    plate's far top corners at most ``a sin e`` above it (``a`` the plate's half-width), the
    plate's near bottom edge ``a sin e + t cos e`` below it. Down to the plate's far corners the
    silhouette is the triangle between the apex and the two tangents to the body's base, so
    ``f(e) = ((H - t) cos e - a sin e) / ((H - t) cos e + 2 a sin e + t cos e)`` when positive,
    else 0: at about 74 deg (standard cone) and steeper the apex projects onto the base plate
    and the cone's height cannot be read off the image.
    """
    H, t, a = cone.height_m, cone.base_thickness_m, 0.5 * cone.base_width_m
    c, s = math.cos(elevation_rad), math.sin(elevation_rad)
    top = (H - t) * c - a * s
    return max(top, 0.0) / ((H - t) * c + 2.0 * a * s + t * c)


def apex_pixel(detection: ConeDetection, d: np.ndarray, fraction: float) -> np.ndarray | None:
    """The apex's image from the area of the silhouette's top triangle, (2,) float64, or None.

    With ``t`` the pixel coordinate along the image vertical ``d`` (down), the triangle between
    the apex (at ``t0``) and the two tangents to the body's base has cross-section width
    ``k (t - t0)``, so its area above ``tau`` is ``N(tau) = (k / 2) (tau - t0)^2``: ``sqrt N`` is a
    straight line in ``tau`` that crosses zero at the apex. ``N`` is counted from the mask, each
    pixel spread uniformly over ``[t_i - 1/2, t_i + 1/2]`` (a unit square's extent along ``d``,
    matching its variance), and the line is fitted on ``tau`` from where ``N`` reaches 3 px down to
    ``0.85 fraction`` of the blob's length (``fraction`` from ``triangle_fraction``). Counting
    pixels measures area without bias, where the top-most pixel is several pixels below the
    apex of a thin tip and edge lines fitted to the top rows are biased by the rows whose
    width rounds up to one pixel. The apex's coordinate across ``d`` is the mean of the
    triangle's pixels in the upper half of that range (the triangle is symmetric about the
    image of the cone's axis).

    None when fewer than three samples are usable or the fit is not a widening triangle.
    """
    return _apex_pixel(detection.pixels_uv(), np.asarray(d, dtype=np.float64), fraction)


def _apex_pixel(uv: np.ndarray, d: np.ndarray, fraction: float) -> np.ndarray | None:
    """``apex_pixel`` on the pixel centres ``uv`` (N, 2)."""
    d0, d1 = float(d[0]), float(d[1])
    t, s = uv @ d, uv @ np.array([-d1, d0])
    n = t.size
    ts = np.sort(t)
    t_top = float(ts[0]) - 0.5
    length = float(ts[-1]) + 0.5 - t_top
    t_end = t_top + 0.85 * fraction * length
    tau = np.arange(t_top + 0.5, t_end + 1e-9, 0.5)
    if tau.size < 3:
        return None
    # N(tau) = sum_i clip(tau - t_i + 1/2, 0, 1): of the sorted t_i, those at or above
    # tau - 1/2 count 1 each, those within (tau - 1/2, tau + 1/2) count tau + 1/2 - t_i
    # (cumulative sums of t_i - t_top: small, and exact for pixel-aligned t).
    ts -= t_top
    csum = np.empty(n + 1)
    csum[0] = 0.0
    np.cumsum(ts, out=csum[1:])
    rel = tau - t_top
    lo = np.searchsorted(ts, rel - 0.5, side="right")
    hi = np.searchsorted(ts, rel + 0.5, side="left")
    area = lo + (hi - lo) * (rel + 0.5) - (csum[hi] - csum[lo])
    use = area >= 3.0  # the first pixels of a thin tip are the least reliable
    n_use = int(np.count_nonzero(use))
    if n_use < 3:
        return None
    # Least-squares line sqrt(N) = slope tau + offset (centred normal equations).
    x, y = tau[use], np.sqrt(area[use])
    x_mean, y_mean = float(np.add.reduce(x)) / n_use, float(np.add.reduce(y)) / n_use
    x -= x_mean
    y -= y_mean
    slope = float(x @ y) / float(x @ x)
    offset = y_mean - slope * x_mean
    if not slope > 0.0:
        return None
    t0 = -offset / slope
    upper = t <= t0 + 0.5 * (t_end - t0) + 0.5
    n_upper = int(np.count_nonzero(upper))
    s0 = float(np.add.reduce(s[upper])) / n_upper if n_upper else float(np.add.reduce(s)) / n
    return np.array([t0 * d0 + s0 * -d1, t0 * d1 + s0 * d0])


def _boundary_reference(uv: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Lecture form of ``boundary_from_mask``: from the pixel list, with numpy.

    The blob's boundary points farthest along ``d``, one per image column (or row).

    Columns when ``d`` is closer to the image's v axis, else rows; in each, the extreme pixel
    centre moved half a pixel outwards along that axis (the silhouette's edge lies within half
    a pixel of it and this is its unbiased estimate over the unknown sub-pixel phase).
    Returns (M, 2) ``(u, v)`` points sorted along the other axis.
    """
    along = 1 if abs(d[1]) >= abs(d[0]) else 0
    lat = 1 - along
    sign = 1.0 if d[along] >= 0.0 else -1.0
    keys, inverse = np.unique(uv[:, lat], return_inverse=True)
    extreme = np.full(keys.size, -np.inf)
    np.maximum.at(extreme, inverse, sign * uv[:, along])
    out = np.empty((keys.size, 2))
    out[:, lat] = keys
    out[:, along] = sign * (extreme + 0.5)
    return out


def boundary_from_mask(detection: ConeDetection, d0: float, d1: float) -> np.ndarray:
    """The blob's boundary points farthest along ``(d0, d1)``, one per column (or row), (M, 2).

    Columns when ``d`` is closer to the image's v axis, else rows; in each, the extreme pixel
    centre moved half a pixel outwards along that axis (the silhouette's edge lies within half
    a pixel of it, and this is its unbiased estimate over the unknown sub-pixel phase); sorted
    along the other axis. Read off the cropped mask directly (first or last set pixel of each
    column or row); ``_boundary_reference`` computes the same from the pixel list.
    """
    mask = detection.mask
    x0, y0 = detection.bbox[0], detection.bbox[1]
    if abs(d1) >= abs(d0):  # one point per column, extreme in v
        keys = np.flatnonzero(mask.any(axis=0))
        if d1 >= 0.0:
            along = (mask.shape[0] - 1 + y0 + 0.5) - np.argmax(mask[::-1], axis=0)[keys]
        else:
            along = np.argmax(mask, axis=0)[keys] + (y0 - 0.5)
        out = np.empty((keys.size, 2))
        out[:, 0] = keys + x0
        out[:, 1] = along
    else:  # one point per row, extreme in u
        keys = np.flatnonzero(mask.any(axis=1))
        if d0 >= 0.0:
            along = (mask.shape[1] - 1 + x0 + 0.5) - np.argmax(mask[:, ::-1], axis=1)[keys]
        else:
            along = np.argmax(mask, axis=1)[keys] + (x0 - 0.5)
        out = np.empty((keys.size, 2))
        out[:, 0] = along
        out[:, 1] = keys + y0
    return out


def exit_on_boundary(pts: np.ndarray, d: np.ndarray, apex_uv: np.ndarray) -> np.ndarray:
    """Intersection of the line ``apex_uv + lambda d`` with the boundary polyline ``pts``.

    ``pts`` as from ``boundary_from_mask``; in plain floats.

    Where the boundary polyline crosses the axis line (or touches it at a vertex) the crossing
    farthest along ``d`` wins (the first of equals); without a crossing, the vertex nearest the
    line. The result is put back onto the axis line exactly.
    """
    a0, a1 = float(apex_uv[0]), float(apex_uv[1])
    d0, d1 = float(d[0]), float(d[1])
    xy = pts.tolist()
    off = [(x - a0) * -d1 + (y - a1) * d0 for x, y in xy]
    best = None
    if len(xy) == 1 or all(o > 0 for o in off) or all(o < 0 for o in off):
        best = xy[min(range(len(off)), key=lambda j: abs(off[j]))]
    else:
        best_along = 0.0
        for j in range(len(xy) - 1):
            o0, o1 = off[j], off[j + 1]
            if o0 == 0.0 or o0 * o1 < 0.0:
                (x0, y0), (x1, y1) = xy[j], xy[j + 1]
                f = o0 / (o0 - o1)
                p = (x0 + (x1 - x0) * f, y0 + (y1 - y0) * f)
                along = p[0] * d0 + p[1] * d1
                if best is None or along > best_along:
                    best, best_along = p, along
        if off[-1] == 0.0 and (best is None or xy[-1][0] * d0 + xy[-1][1] * d1 > best_along):
            best = xy[-1]
    assert best is not None
    # Back onto the axis line exactly (the interpolation is along the boundary).
    lam = (best[0] - a0) * d0 + (best[1] - a1) * d1
    return np.array([a0 + lam * d0, a1 + lam * d1])
