"""Sensor noise: what the simulator adds to its exact poses, images and declared camera mount.

Every function reads its figures from the one declaration, ``vnav.noise_model.NoiseModel``
(the scenario's ``[noise]`` table); every draw comes from a generator seeded by the run's seed.
The truth is never touched: these functions return noisy copies, or, with their noise off, the
input itself (not a copy: treat it as read-only). The estimator is told the same ``NoiseModel``
and propagates it into each estimate's covariance (``vnav.sensor_noise``, ``vnav.covariance``).
"""

from __future__ import annotations

import numpy as np

from vnav import se3, so3
from vnav.noise_model import NoiseModel

__all__ = ["mount_error", "noisy_depth", "noisy_pose", "noisy_rgb"]


def noisy_pose(T_w_b: np.ndarray, noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """One pose sample as the estimator receives it: ``(R_w_b exp(dtheta_b), t_w_b + dp_w)``,
    each component of ``dp_w`` Gaussian with ``noise.position_std_m`` (world axes), of
    ``dtheta_b`` with ``noise.attitude_std_deg`` (body axes).

    Returns
    -------
    ndarray, shape (4, 4)
        ``T_w_b`` itself when the pose stream has no noise (nothing is drawn).
    """
    if not noise.noisy("pose"):
        return T_w_b
    dp_w = rng.normal(0.0, noise.position_std_m, 3)
    dtheta_b = rng.normal(0.0, noise.attitude_std_rad, 3)
    return se3.make(T_w_b[:3, :3] @ so3.exp(dtheta_b), T_w_b[:3, 3] + dp_w)


def noisy_rgb(rgb: np.ndarray, noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """``rgb`` with Gaussian noise of ``noise.intensity_std_grey`` 8-bit grey levels on each
    colour value, rounded and clipped to [0, 255].

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
    noise : NoiseModel
        Its image figure; 0 returns ``rgb`` itself.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
    """
    if not noise.noisy("image"):
        return rgb
    noise_grey = rng.standard_normal(rgb.shape, dtype=np.float32)
    noise_grey *= np.float32(noise.intensity_std_grey)
    noise_grey += rgb
    np.rint(noise_grey, out=noise_grey)
    return np.clip(noise_grey, 0.0, 255.0).astype(np.uint8)


def noisy_depth(
    depth_m: np.ndarray, noise: NoiseModel, far_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Planar depth with Gaussian noise, ``sigma = noise.depth_std_at(z)`` per pixel
    (``depth_std_m + depth_std_per_m2 * z**2``; stereo: ``sigma_z = z**2 sigma_d / (f b)``).

    Pixels with no return (``z >= far_m`` or ``z <= 0``) are left as they are: a sensor reports
    no return there, not a noisy one.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W), float32
    noise : NoiseModel
        Its depth figures; both 0 return ``depth_m`` itself.
    far_m : float
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (H, W), same dtype as ``depth_m``
    """
    if not noise.noisy("depth"):
        return depth_m
    valid = (depth_m > 0.0) & (depth_m < far_m)
    z = depth_m[valid]
    sigma = noise.depth_std_at(z)
    out = depth_m.copy()
    # A Gaussian draw could cross zero at very short range; a sensor reports no negative depth.
    out[valid] = np.maximum(z + sigma * rng.standard_normal(z.shape, dtype=depth_m.dtype), 1e-6)
    return out


def mount_error(noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """The error on the camera mount the estimator is told: ``T_b_c_declared = E @ T_b_c``.

    ``E = exp([rho, phi]^)``, a left perturbation (docs/CONVENTIONS.md, "Uncertainty"); each
    component of ``rho`` is Gaussian with ``noise.extrinsic_std_m`` metres, each of ``phi``
    with ``noise.extrinsic_std_deg`` degrees. Drawn once per run (a mis-measured mount stays
    wrong for the whole flight, even when the camera slides along the body).

    Returns
    -------
    ndarray, shape (4, 4)
        The identity when both are zero (nothing is drawn).
    """
    if not noise.noisy("mount"):
        return np.eye(4)
    xi = np.concatenate(
        [rng.normal(0.0, noise.extrinsic_std_m, 3), rng.normal(0.0, noise.extrinsic_std_rad, 3)]
    )
    return se3.exp(xi)
