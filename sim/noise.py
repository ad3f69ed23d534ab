"""Sensor noise: what the simulator adds to its exact images and declared camera mount.

The scenario's ``[noise]`` table (``scenarios.spec.Noise``) sets the figures; every draw comes
from a generator seeded by the run's seed. The truth is never touched: these functions return
noisy copies, or, with their noise off, the input itself (not a copy: treat it as
read-only). The estimator is told the same figures (``vnav.sensor_noise.SensorNoise``) and
propagates them into each estimate's covariance.
"""

from __future__ import annotations

import math

import numpy as np

from vnav import se3

__all__ = ["mount_error", "noisy_depth", "noisy_rgb"]


def noisy_rgb(rgb: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """``rgb`` with Gaussian noise of ``std`` 8-bit levels on each colour value, rounded and
    clipped to [0, 255].

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
    std : float
        Standard deviation, levels; 0 returns ``rgb`` itself.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
    """
    if std == 0.0:
        return rgb
    noise = rng.standard_normal(rgb.shape, dtype=np.float32)
    noise *= np.float32(std)
    noise += rgb
    np.rint(noise, out=noise)
    return np.clip(noise, 0.0, 255.0).astype(np.uint8)


def noisy_depth(
    depth_m: np.ndarray,
    std_m: float,
    std_per_m2: float,
    far_m: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Planar depth with Gaussian noise, ``sigma = std_m + std_per_m2 * z**2`` per pixel.

    Pixels with no return (``z >= far_m`` or ``z <= 0``) are left as they are: a sensor reports
    no return there, not a noisy one.

    Parameters
    ----------
    depth_m : ndarray, shape (H, W), float32
    std_m : float
        Noise at zero range, metres.
    std_per_m2 : float
        Growth with the square of the depth, 1/m (stereo: ``sigma_z = z**2 sigma_d / (f b)``).
    far_m : float
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (H, W), same dtype as ``depth_m``
    """
    if std_m == 0.0 and std_per_m2 == 0.0:
        return depth_m
    valid = (depth_m > 0.0) & (depth_m < far_m)
    z = depth_m[valid]
    sigma = std_m + std_per_m2 * z * z
    out = depth_m.copy()
    # A Gaussian draw could cross zero at very short range; a sensor reports no negative depth.
    out[valid] = np.maximum(z + sigma * rng.standard_normal(z.shape, dtype=depth_m.dtype), 1e-6)
    return out


def mount_error(std_m: float, std_deg: float, rng: np.random.Generator) -> np.ndarray:
    """The error on the camera mount the estimator is told: ``T_b_c_declared = E @ T_b_c``.

    ``E = exp([rho, phi]^)``, a left perturbation (docs/CONVENTIONS.md, "Uncertainty"); each
    component of ``rho`` is Gaussian with ``std_m`` metres, each of ``phi`` with ``std_deg``
    degrees. Drawn once per run (a mis-measured mount stays wrong for the whole flight, even
    when the camera slides along the body).

    Returns
    -------
    ndarray, shape (4, 4)
        The identity when both are zero (nothing is drawn).
    """
    if std_m == 0.0 and std_deg == 0.0:
        return np.eye(4)
    xi = np.concatenate([rng.normal(0.0, std_m, 3), rng.normal(0.0, math.radians(std_deg), 3)])
    return se3.exp(xi)
