"""The pinhole camera: intrinsics, projection, back-projection and viewing rays.

Every function here works in the **optical** frame ``c`` (x right, y down, z forward) and in
OpenCV pixel coordinates (u right, v down, the centre of the top-left pixel is (0, 0));
see docs/CONVENTIONS.md. There is no lens distortion: MuJoCo renders an ideal pinhole.

The model (Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., eq. 6.1-6.5):

    [u, v, 1]^T ~ K [x, y, z]^T,   K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    u = fx x / z + cx,   v = fy y / z + cy                       (projection, z > 0)
    x = (u - cx) z / fx, y = (v - cy) z / fy                       (back-projection, z = depth)

Depth is **planar z-depth** in metres (the optical z coordinate), not the length of the ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vnav import se3

__all__ = ["PinholeCamera", "check_depth_image", "depth_to_world_points"]


def _as_points(name: str, p: np.ndarray, dim: int) -> np.ndarray:
    """Return ``p`` as a float64 (N, dim) array; accept (dim,) as one point."""
    arr = np.asarray(p, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape ({dim},) or (N, {dim}), got shape {np.shape(p)}")
    return arr


@dataclass(frozen=True)
class PinholeCamera:
    """An ideal pinhole camera with square or rectangular pixels and no distortion.

    Attributes
    ----------
    fx, fy : float
        Focal lengths in pixels (positive, finite).
    cx, cy : float
        Principal point in OpenCV pixel coordinates (top-left pixel centre is (0, 0)).
    width, height : int
        Image size in pixels (positive).

    Raises
    ------
    ValueError
        On a non-positive or non-finite focal length, a non-finite principal point, or a
        non-positive or non-integer image size.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (
                isinstance(value, int | float | np.floating | np.integer)
                and math.isfinite(value)
                and value > 0.0
            ):
                raise ValueError(
                    f"PinholeCamera.{name} must be a positive finite focal length in pixels, "
                    f"got {value!r}"
                )
            object.__setattr__(self, name, float(value))
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if not (
                isinstance(value, int | float | np.floating | np.integer) and math.isfinite(value)
            ):
                raise ValueError(f"PinholeCamera.{name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(
                    f"PinholeCamera.{name} must be a positive int (pixels), got {value!r}"
                )
            object.__setattr__(self, name, int(value))

    @classmethod
    def from_fovy(cls, fovy_deg: float, width: int, height: int) -> PinholeCamera:
        """The camera MuJoCo renders for a vertical field of view ``fovy_deg``.

        Square pixels with ``fx = fy = (H / 2) / tan(fovy / 2)`` and the principal point at the
        image centre, ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2`` in OpenCV pixel-centre coordinates
        (docs/CONVENTIONS.md, "Pixels and the pinhole camera", where the measurement is
        described).

        Parameters
        ----------
        fovy_deg : float
            Vertical field of view in degrees, in the open interval (0, 180).
        width, height : int
            Image size in pixels.

        Raises
        ------
        ValueError
            If ``fovy_deg`` is not finite or outside (0, 180), or the size is invalid.
        """
        fovy_deg = float(fovy_deg)
        if not (math.isfinite(fovy_deg) and 0.0 < fovy_deg < 180.0):
            raise ValueError(f"fovy_deg must be in the open interval (0, 180), got {fovy_deg!r}")
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"{name} must be a positive int (pixels), got {value!r}")
        f_px = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(
            fx=f_px,
            fy=f_px,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
            width=width,
            height=height,
        )

    @property
    def K(self) -> np.ndarray:
        """The (3, 3) float64 intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view in degrees, ``2 atan((H / 2) / fy)``."""
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.fy))

    @property
    def fovx_deg(self) -> float:
        """Horizontal field of view in degrees, ``2 atan((W / 2) / fx)``."""
        return math.degrees(2.0 * math.atan((self.width / 2.0) / self.fx))

    def project(self, p_c: np.ndarray) -> np.ndarray:
        """Project points in the optical frame to pixels, ``u = fx x/z + cx``, ``v = fy y/z + cy``.

        Parameters
        ----------
        p_c : array_like, shape (3,) or (N, 3)
            Points in the optical frame, metres.

        Returns
        -------
        uv : ndarray, shape (N, 2), float64
            Pixel coordinates (OpenCV). A point at or behind the camera (``z <= 0``) or with a
            non-finite coordinate gives a row of NaN. A (3,) input gives a (1, 2) result.
            Pixels outside the image are returned as they are (see ``in_image``).

        Raises
        ------
        ValueError
            If ``p_c`` does not have shape (3,) or (N, 3).
        """
        p_c = _as_points("p_c", p_c, 3)
        z = p_c[:, 2]
        valid = np.isfinite(p_c).all(axis=1) & (z > 0.0)
        uv = np.full((p_c.shape[0], 2), np.nan, dtype=np.float64)
        zv = z[valid]
        uv[valid, 0] = self.fx * p_c[valid, 0] / zv + self.cx
        uv[valid, 1] = self.fy * p_c[valid, 1] / zv + self.cy
        return uv

    def backproject(self, uv: np.ndarray, depth: float | np.ndarray) -> np.ndarray:
        """Back-project pixels with planar z-depth to points in the optical frame.

        ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``, ``z = depth``: the exact inverse of
        ``project`` for ``z > 0``.

        Parameters
        ----------
        uv : array_like, shape (2,) or (N, 2)
            Pixel coordinates (OpenCV).
        depth : float or array_like, shape (N,)
            Planar z-depth in metres (the optical z coordinate, not the ray length), one value
            for all pixels or one per pixel. Non-finite values propagate as NaN/inf.

        Returns
        -------
        p_c : ndarray, shape (N, 3), float64
            Points in the optical frame, metres.

        Raises
        ------
        ValueError
            If ``uv`` does not have shape (2,) or (N, 2), or ``depth`` is neither a scalar nor a
            length-N vector.
        """
        uv = _as_points("uv", uv, 2)
        z = np.asarray(depth, dtype=np.float64)
        if z.ndim == 0:
            z = np.full(uv.shape[0], float(z))
        elif z.shape != (uv.shape[0],):
            raise ValueError(
                f"depth must be a scalar or have shape ({uv.shape[0]},) to match uv, "
                f"got shape {z.shape}"
            )
        p_c = np.empty((uv.shape[0], 3), dtype=np.float64)
        p_c[:, 0] = (uv[:, 0] - self.cx) * z / self.fx
        p_c[:, 1] = (uv[:, 1] - self.cy) * z / self.fy
        p_c[:, 2] = z
        return p_c

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit viewing rays through pixels, in the optical frame.

        The ray through ``(u, v)`` is ``K^-1 [u, v, 1]^T`` normalised; it points forward (z > 0).

        Parameters
        ----------
        uv : array_like, shape (2,) or (N, 2)
            Pixel coordinates (OpenCV).

        Returns
        -------
        d_c : ndarray, shape (N, 3), float64
            Unit direction vectors in the optical frame, for any finite pixel (NaN where a
            pixel is not finite).

        Raises
        ------
        ValueError
            If ``uv`` does not have shape (2,) or (N, 2).
        """
        p_c = self.backproject(uv, 1.0)
        if np.abs(p_c).max(initial=0.0) > 1e150:
            # The squares of a pixel this far out overflow: an infinite norm would give a
            # zero "ray". Scaled by its largest component first, every finite pixel has one.
            p_c = p_c / np.abs(p_c).max(axis=1, keepdims=True)
        return p_c / np.linalg.norm(p_c, axis=1, keepdims=True)

    def ray_length_per_depth(self) -> np.ndarray:
        """Length of the viewing ray per unit of planar depth at every pixel centre.

        ``sqrt(1 + x^2 + y^2)`` with ``(x, y, 1) = K^-1 [u, v, 1]``: a pixel at planar depth
        ``z`` sees a point ``z * ray_length_per_depth()[v, u]`` metres from the camera.

        Returns
        -------
        scale : ndarray, shape (height, width), float64
        """
        x = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        y = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        return np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2)

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Whether pixels lie inside the image, shrunk by ``margin_px`` on every side.

        A pixel centre is inside when ``-0.5 + m <= u < W - 0.5 - m`` and likewise for v (each
        pixel covers ``[c - 0.5, c + 0.5)`` around its centre c). NaN rows are outside.

        Parameters
        ----------
        uv : array_like, shape (2,) or (N, 2)
            Pixel coordinates (OpenCV).
        margin_px : float
            Margin in pixels kept clear of the border.

        Returns
        -------
        inside : ndarray, shape (N,), bool
        """
        uv = _as_points("uv", uv, 2)
        lo = -0.5 + margin_px
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= lo)
                & (uv[:, 0] < self.width - 0.5 - margin_px)
                & (uv[:, 1] >= lo)
                & (uv[:, 1] < self.height - 0.5 - margin_px)
            )


def check_depth_image(depth: np.ndarray, camera: PinholeCamera, name: str = "depth") -> np.ndarray:
    """Validate a planar depth image for ``camera``; return it unchanged.

    Raises
    ------
    ValueError
        If ``depth`` is not a float32 or float64 numpy array of the camera's image size.
    """
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(depth).__name__}")
    if depth.dtype not in (np.float32, np.float64):
        raise ValueError(f"{name} must have dtype float32 or float64 (metres), got {depth.dtype}")
    if depth.shape != (camera.height, camera.width):
        raise ValueError(
            f"{name} must have the camera's image size (H, W) = ({camera.height}, "
            f"{camera.width}), got shape {depth.shape}"
        )
    return depth


def depth_to_world_points(
    depth: np.ndarray,
    camera: PinholeCamera,
    T_w_c: np.ndarray,
    stride: int = 1,
    far_m: float = np.inf,
) -> np.ndarray:
    """The depth image as a world-frame point cloud, ``p_w = T_w_c @ backproject(uv, z)``.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32 or float64
        Planar z-depth, metres.
    camera : PinholeCamera
        Its size must match ``depth``.
    T_w_c : ndarray, shape (4, 4)
    stride : int
        Use every ``stride``-th row and column.
    far_m : float
        Pixels with depth >= far_m (the renderer's far plane: background), <= 0 or +inf are
        dropped.

    Returns
    -------
    p_w : ndarray, shape (M, 3), float64
        One point per valid pixel, row-major pixel order.

    Raises
    ------
    ValueError
        On a wrong dtype or size, NaN depth, ``stride`` < 1, or a malformed ``T_w_c``.
    """
    check_depth_image(depth, camera)
    T_w_c = se3.check_pose(T_w_c, "T_w_c")
    if isinstance(stride, bool) or not isinstance(stride, int | np.integer) or stride < 1:
        raise ValueError(f"stride must be a positive int, got {stride!r}")
    z = depth[::stride, ::stride]
    if np.isnan(z).any():
        raise ValueError(f"depth must not contain NaN; got {int(np.isnan(z).sum())} NaN pixels")
    valid = (z > 0.0) & (z < far_m)
    # Fold K^-1 and R_w_c into one 3x3: p_w = z * (M @ [u, v, 1]) + t_w_c. M @ [u, v, 1] is a
    # column term plus a row term, so each coordinate is one broadcast over the contiguous
    # grid, then gathered at the valid pixels (row-major order); no index arrays are built.
    M = T_w_c[:3, :3] @ np.linalg.inv(camera.K)
    u = np.arange(0, depth.shape[1], stride, dtype=np.float64)
    v = np.arange(0, depth.shape[0], stride, dtype=np.float64)[:, None]
    zv = z.astype(np.float64)
    p_w = np.empty((int(np.count_nonzero(valid)), 3), dtype=np.float64)
    for i in range(3):
        plane = zv * (M[i, 0] * u + (M[i, 1] * v + M[i, 2]))
        plane += T_w_c[i, 3]
        p_w[:, i] = plane[valid]
    return p_w
