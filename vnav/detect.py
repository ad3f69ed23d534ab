"""Traffic-cone detection in an RGB image with OpenCV: colour thresholds, clean-up, components.

The pipeline (one pass over the image, no pose needed):

1. RGB -> HSV (OpenCV scale: H in [0, 180), S and V in [0, 255]) and a threshold box around
   the cone's orange (``vnav.cone.ConeModel.color_rgb`` = (1, 0.35, 0) has hue 21 deg, i.e.
   10.5 on OpenCV's scale); shading changes V and, with specular light, S, but hardly H.
2. A 3x3 morphological closing fills one-pixel holes and gaps (no opening: it would eat the
   cone's thin tip, on which the apex estimate depends).
3. 8-connected components; components smaller than ``min_area_px`` are dropped as noise.
   One component is one detection. Cones that overlap in the image merge into one.

Per detection the apex pixel is estimated to sub-pixel precision by intersecting two straight
lines fitted to the left and right silhouette edges of the upper half of the blob (the cone's
sides are straight lines in the image, the images of its two contour generators); when that
is ill-conditioned (a blob too small or seen from above) the top-most pixel is used. The
base-centre pixel ``base_uv`` is a pose-free estimate: the point of the blob farthest along the
image direction of the cone's axis (from apex towards the blob's centroid), i.e. the near
bottom edge of the base plate. The true base centre is hidden inside the base plate and lies
a little above that point in the image; ``vnav.localize`` refines it with the camera pose and
the cone's known dimensions.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from vnav.camera import PinholeCamera

__all__ = [
    "DEFAULT_THRESHOLDS",
    "ConeDetection",
    "HsvThresholds",
    "check_detection",
    "detect_cones",
    "detection_from_mask",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class HsvThresholds:
    """An inclusive box in OpenCV HSV space (H in [0, 179], S and V in [0, 255]).

    Attributes
    ----------
    h_min, h_max : int
        Hue range (OpenCV's scale is degrees / 2).
    s_min, v_min : int
        Lowest saturation and value accepted (the upper bounds are 255).
    """

    h_min: int = 3
    h_max: int = 22
    s_min: int = 120
    v_min: int = 50

    def __post_init__(self) -> None:
        if not 0 <= self.h_min <= self.h_max <= 179:
            raise ValueError(
                f"HsvThresholds needs 0 <= h_min <= h_max <= 179, got {self.h_min}, {self.h_max}"
            )
        for name in ("s_min", "v_min"):
            value = getattr(self, name)
            if not 0 <= value <= 255:
                raise ValueError(f"HsvThresholds.{name} must be in [0, 255], got {value}")

    @property
    def lower(self) -> np.ndarray:
        """(3,) uint8 lower corner for ``cv2.inRange``."""
        return np.array([self.h_min, self.s_min, self.v_min], dtype=np.uint8)

    @property
    def upper(self) -> np.ndarray:
        """(3,) uint8 upper corner for ``cv2.inRange``."""
        return np.array([self.h_max, 255, 255], dtype=np.uint8)


DEFAULT_THRESHOLDS = HsvThresholds()
"""Thresholds tuned on MuJoCo renders of ``vnav.cone.TRAFFIC_CONE`` (see tests/test_detect.py)."""

_KERNEL_3X3 = np.ones((3, 3), dtype=np.uint8)


@dataclass(frozen=True, eq=False)
class ConeDetection:
    """One cone seen in an image. All pixel coordinates follow OpenCV (docs/CONVENTIONS.md).

    Attributes
    ----------
    bbox : tuple of int
        ``(x, y, w, h)``: column and row of the top-left pixel, width and height in pixels.
    area_px : int
        Number of pixels in the mask.
    mask : ndarray, shape (h, w), bool
        The blob, **cropped to bbox**: ``mask[r, c]`` is image pixel
        ``(row, col) = (y + r, x + c)``. Use ``full_mask(shape)`` for an image-sized mask and
        ``pixels_uv()`` for the pixel centres.
    apex_uv : ndarray, shape (2,), float64
        Estimated image of the cone's apex (sub-pixel, see the module docstring).
    base_uv : ndarray, shape (2,), float64
        Pose-free estimate of the base: the bottom of the blob along the cone's image axis
        (the near bottom edge of the base plate, slightly below the hidden base centre).
    centroid_uv : ndarray, shape (2,), float64
        Mean pixel centre of the mask.
    touches_border : bool
        True if the mask reaches the first or last row or column: the cone may be cut off.
    apex_from_edges : bool
        True if ``apex_uv`` came from the two-edge fit, False if from the top-most pixel.
    """

    bbox: tuple[int, int, int, int]
    area_px: int
    mask: np.ndarray = field(repr=False)
    apex_uv: np.ndarray
    base_uv: np.ndarray
    centroid_uv: np.ndarray
    touches_border: bool
    apex_from_edges: bool

    @property
    def height_px(self) -> float:
        """Apparent length of the cone from apex to base estimate, pixels."""
        return float(np.linalg.norm(self.base_uv - self.apex_uv))

    def pixels_uv(self) -> np.ndarray:
        """Pixel centres ``(u, v)`` of the mask, shape (area_px, 2), float64."""
        rows, cols = np.nonzero(self.mask)
        return np.column_stack((cols + self.bbox[0], rows + self.bbox[1])).astype(np.float64)

    def full_mask(self, shape: tuple[int, int]) -> np.ndarray:
        """The mask pasted into an all-False (H, W) bool image of ``shape``."""
        out = np.zeros(shape[:2], dtype=bool)
        x, y, w, h = self.bbox
        out[y : y + h, x : x + w] = self.mask
        return out


def check_detection(detection: ConeDetection, camera: PinholeCamera) -> None:
    """Validate a detection against the camera whose image it was found in.

    Raises
    ------
    ValueError
        If ``detection`` is not a ConeDetection or its bbox does not fit the camera's image.
    """
    if not isinstance(detection, ConeDetection):
        raise ValueError(f"detection must be a ConeDetection, got {type(detection).__name__}")
    x, y, w, h = detection.bbox
    if x < 0 or y < 0 or x + w > camera.width or y + h > camera.height:
        raise ValueError(
            f"detection bbox {detection.bbox} does not fit the camera's image "
            f"{camera.width}x{camera.height}"
        )


def check_rgb(rgb: np.ndarray, name: str = "rgb") -> np.ndarray:
    """Validate an RGB image: a non-empty (H, W, 3) uint8 array. Returns it unchanged.

    Raises
    ------
    ValueError
        On another type, dtype or shape, or an empty image.
    """
    if not isinstance(rgb, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(rgb).__name__}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"{name} must have dtype uint8, got {rgb.dtype}")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"{name} must have shape (H, W, 3), got {rgb.shape}")
    if rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {rgb.shape}")
    return rgb


def cone_mask(rgb: np.ndarray, thresholds: HsvThresholds = DEFAULT_THRESHOLDS) -> np.ndarray:
    """The (H, W) uint8 mask (0 or 255) of cone-coloured pixels after the 3x3 closing."""
    check_rgb(rgb)
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    raw = cv2.inRange(hsv, thresholds.lower, thresholds.upper)
    return cv2.morphologyEx(raw, cv2.MORPH_CLOSE, _KERNEL_3X3)


def detect_cones(
    rgb: np.ndarray,
    thresholds: HsvThresholds = DEFAULT_THRESHOLDS,
    min_area_px: int = 12,
) -> list[ConeDetection]:
    """Find traffic cones in an RGB image.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        The image, channels in RGB order (as MuJoCo renders it).
    thresholds : HsvThresholds
        Colour box for the cone's orange.
    min_area_px : int
        Blobs with fewer pixels are ignored (a 12 px tall cone covers about 40 pixels).

    Returns
    -------
    list of ConeDetection
        One per blob, largest first; empty when no cone is in view.

    Raises
    ------
    ValueError
        If ``rgb`` is not a non-empty (H, W, 3) uint8 array or ``min_area_px`` < 1.
    """
    check_rgb(rgb)
    if min_area_px < 1:
        raise ValueError(f"min_area_px must be >= 1, got {min_area_px}")
    mask = cone_mask(rgb, thresholds)
    height, width = mask.shape
    # Label only the bounding box of all candidate pixels (labelling the full image costs
    # about 1 ms; the box is usually small).
    rx, ry, rw, rh = cv2.boundingRect(mask)
    detections: list[ConeDetection] = []
    if rw == 0 or rh == 0:
        logger.debug("detect_cones: no cone-coloured pixel")
        return detections
    roi = mask[ry : ry + rh, rx : rx + rw]
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(roi, connectivity=8)
    for label in range(1, n):
        x, y, w, h, area = (int(s) for s in stats[label])
        if area < min_area_px:
            continue
        crop = labels[y : y + h, x : x + w] == label
        x, y = x + rx, y + ry
        touches = x == 0 or y == 0 or x + w == width or y + h == height
        centroid_uv = centroids[label].astype(np.float64) + np.array([rx, ry])
        detections.append(_describe_blob(crop, (x, y, w, h), area, centroid_uv, touches))
    detections.sort(key=lambda d: -d.area_px)
    logger.debug("detect_cones: %d blobs, %d detections", n - 1, len(detections))
    return detections


def detection_from_mask(
    mask: np.ndarray, bbox: tuple[int, int, int, int], image_size: tuple[int, int]
) -> ConeDetection:
    """The detection ``detect_cones`` makes of one blob, from the blob alone: its apex, base,
    centroid and border flag computed from the mask as ``detect_cones`` computes them.

    What a log keeps of a detection (the blob, ``ConeDetection.mask`` and ``bbox``) is enough to
    make it again, exactly: ``vnav-demo calibrate`` re-fits the apexes of a recording's masks.

    Parameters
    ----------
    mask : ndarray, shape (h, w), bool
        The blob cropped to ``bbox`` (``ConeDetection.mask``).
    bbox : tuple of int
        ``(x, y, w, h)`` in the image.
    image_size : tuple of int
        ``(width, height)`` of the image, px.

    Returns
    -------
    ConeDetection

    Raises
    ------
    ValueError
        If ``mask`` is not (h, w) to match ``bbox``, is empty, or ``bbox`` does not fit the image.
    """
    mask = np.asarray(mask, dtype=bool)
    x, y, w, h = (int(v) for v in bbox)
    width, height = (int(v) for v in image_size)
    if mask.shape != (h, w) or not mask.any():
        raise ValueError(f"mask of shape {mask.shape} must be non-empty and (h, w) = {(h, w)}")
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise ValueError(f"bbox {bbox} does not fit the image {width}x{height}")
    rows, cols = np.nonzero(mask)
    # The mean pixel centre, as cv2.connectedComponentsWithStats's centroid.
    centroid_uv = np.array([cols.mean() + x, rows.mean() + y])
    touches = x == 0 or y == 0 or x + w == width or y + h == height
    return _describe_blob(mask, (x, y, w, h), int(rows.size), centroid_uv, touches)


def _fit_line(v: np.ndarray, u: np.ndarray) -> tuple[float, float] | None:
    """Least-squares ``u = a + b v``; None if fewer than 3 rows or no spread in v."""
    if v.size < 3 or np.ptp(v) < 2:
        return None
    # Closed-form simple regression on centred data (what np.polyfit(v, u, 1) solves, without
    # its SVD): b = cov(v, u) / var(v), a = mean(u) - b mean(v).
    v = v.astype(np.float64)
    u = u.astype(np.float64)
    v_mean, u_mean = float(v.mean()), float(u.mean())
    dv = v - v_mean
    b = float(dv @ (u - u_mean)) / float(dv @ dv)
    return u_mean - b * v_mean, b


def _apex_from_edges(crop: np.ndarray, x0: int, y0: int) -> np.ndarray | None:
    """Intersect lines fitted to the left and right edges of the upper half of a blob.

    In a row whose pixel centres ``c_min..c_max`` are inside the blob the silhouette's edges lie
    in ``(c_min - 1, c_min]`` and ``[c_max, c_max + 1)``, so ``c_min - 0.5`` and ``c_max + 0.5`` are
    unbiased edge estimates. Returns None when the fit is ill-conditioned.
    """
    rows = np.flatnonzero(crop.any(axis=1))
    h = rows[-1] - rows[0] + 1
    if h < 6:
        return None
    upper = rows[rows <= rows[0] + h // 2]
    sub = crop[upper]
    left = sub.argmax(axis=1) - 0.5
    right = sub.shape[1] - 1 - sub[:, ::-1].argmax(axis=1) + 0.5
    v = upper.astype(np.float64)
    fit_l = _fit_line(v, left)
    fit_r = _fit_line(v, right)
    if fit_l is None or fit_r is None:
        return None
    (a_l, b_l), (a_r, b_r) = fit_l, fit_r
    # The cone widens downwards (v grows down): the edges diverge, b_r - b_l > 0.
    if not b_r - b_l > 0.05:
        return None
    v_apex = (a_l - a_r) / (b_r - b_l)
    u_apex = a_l + b_l * v_apex
    # Accept only an apex near the top of the blob (the thin tip may leave the top-most
    # covered pixel centre a few pixels below the apex).
    if not rows[0] - 6.0 <= v_apex <= rows[0] + 1.0:
        return None
    return np.array([u_apex + x0, v_apex + y0])


def _describe_blob(
    crop: np.ndarray,
    bbox: tuple[int, int, int, int],
    area: int,
    centroid_uv: np.ndarray,
    touches: bool,
) -> ConeDetection:
    x0, y0, _, _ = bbox
    apex_uv = _apex_from_edges(crop, x0, y0)
    from_edges = apex_uv is not None
    if apex_uv is None:
        top = int(np.flatnonzero(crop.any(axis=1))[0])
        cols = np.flatnonzero(crop[top])
        apex_uv = np.array([cols.mean() + x0, top - 0.5 + y0])
    # Axis direction in the image: from the apex through the centroid (downwards in the scene).
    axis = centroid_uv - apex_uv
    norm = np.linalg.norm(axis)
    axis = axis / norm if norm > 1e-9 else np.array([0.0, 1.0])
    base_uv = extreme_point(crop, x0, y0, axis)
    return ConeDetection(
        bbox=bbox,
        area_px=area,
        mask=crop,
        apex_uv=apex_uv,
        base_uv=base_uv,
        centroid_uv=centroid_uv,
        touches_border=touches,
        apex_from_edges=from_edges,
    )


def extreme_point(crop: np.ndarray, x0: int, y0: int, direction_uv: np.ndarray) -> np.ndarray:
    """The blob's extreme point along a unit image direction, to sub-pixel precision.

    Along ``d``: the largest projection ``s = p . d`` of a pixel centre, moved by half a pixel's
    extent along ``d`` (``0.5 (|d_u| + |d_v|)``) from the centre to the edge (for ``d`` along an
    image axis the silhouette's edge lies within one pixel beyond the last covered centre, so
    half a pixel is its unbiased estimate). Across ``d``: the mean of the pixel centres within
    1 px of the largest projection (the middle of the extreme edge).

    Parameters
    ----------
    crop : ndarray, shape (h, w), bool
        The blob, cropped; its top-left pixel is ``(x0, y0)`` in the image.
    direction_uv : ndarray, shape (2,)
        Unit direction in the image.

    Returns
    -------
    uv : ndarray, shape (2,), float64
    """
    rows, cols = np.nonzero(crop)
    uv = np.column_stack((cols + x0, rows + y0)).astype(np.float64)
    d = np.asarray(direction_uv, dtype=np.float64)
    s = uv @ d
    s_max = float(s.max())
    near = uv[s >= s_max - 1.0]
    half = 0.5 * (abs(d[0]) + abs(d[1]))
    across = np.array([-d[1], d[0]])
    return (s_max + half) * d + float((near @ across).mean()) * across
