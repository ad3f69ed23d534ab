"""What the estimator makes of its sensors' noise: the covariances it propagates into each
estimate (``vnav.localize``), from the figures it is told (``vnav.noise_model.NoiseModel``).

A real estimator is told its sensors' data sheets; here they are the scenario's ``[noise]``
table, the same ``NoiseModel`` the simulator draws from. What each figure becomes:

- **the image**: Gaussian noise on each 8-bit colour value (``intensity_std_grey``, grey
  levels) moves the detector's keypoints (the apex and the bottom pixel of a cone's
  silhouette) away from the true projections, ``keypoint_cov``, pixels. Both keypoints are
  measured from the silhouette, so they carry its quantisation even without noise; the figures
  are measured against the simulator's truth (``KEYPOINT_STD_PX``, and
  ``tests/test_sensor_noise.py`` checks them on fresh renders).
- **the depth image**: ``NoiseModel.depth_std_at``, used by ``vnav.covariance``.
- **the poses**: the body pose stream and the declared camera mount, as 6x6 covariances of a
  left perturbation ``xi = [rho, phi]`` (docs/CONVENTIONS.md, "Uncertainty"):
  ``body_pose_covariance``, ``mount_covariance``.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from vnav import se3
from vnav.noise_model import NoiseModel

__all__ = [
    "KEYPOINT_STD_PX",
    "MAX_CALIBRATED_INTENSITY_STD_GREY",
    "body_pose_covariance",
    "keypoint_cov",
    "keypoint_std_px",
    "mount_covariance",
]

KEYPOINT_STD_PX: dict[str, tuple[tuple[float, float, float], ...]] = {
    # image noise std (grey levels), along the image vertical (px), across it (px)
    "apex": ((0.0, 0.37, 0.08), (8.0, 0.41, 0.09), (10.0, 0.46, 0.11), (12.0, 0.73, 0.20)),
    "bottom": ((0.0, 0.25, 0.08), (8.0, 0.25, 0.09), (10.0, 0.26, 0.11), (12.0, 0.38, 0.20)),
}
"""Root-mean-square error of each keypoint from the true projection, pixels, along and across
the image of the vertical at the cone, against the image noise (``intensity_std_grey``).

Measured on about 390 views per noise level (``tests/test_sensor_noise.py`` draws them the
same way and checks the figures: the default camera on a level drone, range 3-20 m, 1.5-8 m
high, any bearing, the cone within 17 deg of the heading) with the default detector
thresholds: the apex (``vnav.silhouette.apex_pixel``) against the projection of the true apex,
the bottom pixel (``SilhouetteView.bottom``) against the projection of the plate's true bottom
edge in the vertical plane through the camera and the cone's axis. Without noise the error is
the silhouette's quantisation; noise up to about 8 levels flips few pixels across the
detector's colour thresholds; beyond it the thin tip loses pixels first. The errors are
heavy-tailed (the apex's worst is about 2 px at 0-8 levels). A tilted drone sees the cone's
vertical across the pixel grid and its staircase edges: with roll and pitch uniform within
14 deg the apex's figure along is 0.51 px at 0-8 levels (the bottom's and the across figures
change little); the covariance does not model the tilt. Between the rows the figures are
interpolated linearly."""

MAX_CALIBRATED_INTENSITY_STD_GREY = 12.0
"""The highest image noise (8-bit grey levels) at which the keypoint figures were measured; at 15
levels the default detector already splits or loses most cones."""


def keypoint_std_px(kind: str, intensity_std_grey: float) -> tuple[float, float]:
    """``(along, across)`` standard deviations of a keypoint, pixels (``KEYPOINT_STD_PX``).

    Parameters
    ----------
    kind : {"apex", "bottom"}
    intensity_std_grey : float
        Image noise, 8-bit grey levels, >= 0; beyond ``MAX_CALIBRATED_INTENSITY_STD_GREY`` the
        last row's figures are scaled by ``intensity_std_grey /
        MAX_CALIBRATED_INTENSITY_STD_GREY`` (an extrapolation: nothing was measured there).

    Raises
    ------
    ValueError
        For an unknown kind or a negative or non-finite noise.
    """
    if kind not in KEYPOINT_STD_PX:
        raise ValueError(f"keypoint kind must be one of {sorted(KEYPOINT_STD_PX)}, got {kind!r}")
    std = intensity_std_grey
    if not (isinstance(std, int | float) and math.isfinite(std) and std >= 0.0):
        raise ValueError(f"intensity_std_grey must be a finite number >= 0, got {std!r}")
    return _keypoint_std_px(kind, float(std))


@functools.lru_cache(maxsize=64)  # one noise level per run: every detection asks the same
def _keypoint_std_px(kind: str, intensity_std_grey: float) -> tuple[float, float]:
    rows = KEYPOINT_STD_PX[kind]
    top_level, top_along, top_across = rows[-1]
    if intensity_std_grey > top_level:
        scale = intensity_std_grey / top_level
        return top_along * scale, top_across * scale
    # Linear interpolation between the rows (np.interp, in plain floats: a scalar is cheaper
    # without numpy, and this runs for every keypoint of every detection).
    for (lo, along_lo, across_lo), (hi, along_hi, across_hi) in itertools.pairwise(rows):
        if intensity_std_grey <= hi:
            w = (intensity_std_grey - lo) / (hi - lo)
            return along_lo + w * (along_hi - along_lo), across_lo + w * (across_hi - across_lo)
    return top_along, top_across  # a table of one row


def keypoint_cov(kind: str, intensity_std_grey: float, down_uv: np.ndarray) -> np.ndarray:
    """Covariance of a keypoint, px^2, (2, 2): ``keypoint_std_px`` along and across
    ``down_uv``, the image of the downward vertical at the cone (any length, not zero), under
    image noise of ``intensity_std_grey`` 8-bit grey levels."""
    along, across = keypoint_std_px(kind, intensity_std_grey)
    du, dv = float(down_uv[0]), float(down_uv[1])
    norm = math.hypot(du, dv)
    if not norm > 0.0:
        raise ValueError("down_uv must be a non-zero image direction")
    du, dv = du / norm, dv / norm
    a2, c2 = along * along, across * across
    # a2 d d^T + c2 p p^T with p = (-dv, du).
    return np.array(
        [
            [a2 * du * du + c2 * dv * dv, (a2 - c2) * du * dv],
            [(a2 - c2) * du * dv, a2 * dv * dv + c2 * du * du],
        ]
    )


def body_pose_covariance(T_w_b: np.ndarray, noise: NoiseModel) -> np.ndarray:
    """The 6x6 left-perturbation covariance of a body pose with the pose stream's noise.

    The noisy pose (``sim.noise.noisy_pose``) is ``(R_w_b exp(dtheta_b), t_w_b + dp_w)`` with
    ``dp_w ~ N(0, s_p^2 I)`` and ``dtheta_b ~ N(0, s_a^2 I)``, ``s_p = noise.position_std_m``
    and ``s_a = noise.attitude_std_rad``: to first order the right perturbation
    ``T exp(eta^)``, ``eta = [R^T dp_w, dtheta_b]`` with covariance ``diag(s_p^2 I, s_a^2 I)``
    (a rotated isotropic covariance stays isotropic), and ``xi = Ad(T) eta`` (Barfoot &
    Furgale 2014, eq. 12).

    Returns
    -------
    ndarray, shape (6, 6)
    """
    eta = np.diag([noise.position_std_m**2] * 3 + [noise.attitude_std_rad**2] * 3)
    Ad = se3.adjoint(T_w_b)
    return Ad @ eta @ Ad.T


def mount_covariance(noise: NoiseModel) -> np.ndarray:
    """The 6x6 covariance of the declared camera mount: ``diag(s_m^2 I, s_r^2 I)`` with
    ``s_m = noise.extrinsic_std_m`` and ``s_r = noise.extrinsic_std_rad``, the left
    perturbation ``sim.noise.mount_error`` draws."""
    return np.diag([noise.extrinsic_std_m**2] * 3 + [noise.extrinsic_std_rad**2] * 3)
