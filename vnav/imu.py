"""What an IMU on the body reads: the rigid-body chain, the noise model and the Allan deviation.

An IMU measures, in its own frame ``i``, the **specific force** (the acceleration of its own
position relative to free fall: it reads ``+g`` up at rest) and the **angular rate** (MIT
16.485 VNAV, lecture 1: "An IMU measures accelerations in a body frame"). On a rigid body
whose origin ``b`` moves with acceleration ``a_w``, angular velocity ``omega`` and angular
acceleration ``alpha``, a point at the lever arm ``r_w = R_w_b t_b_i`` accelerates by

    a_i_w = a_w + alpha_w x r_w + omega_w x (omega_w x r_w)

(the transport theorem for a point fixed on the body: tangential plus centripetal terms; e.g.
Kane & Levinson, "Dynamics: Theory and Applications", 1985, ch. 2, or Siciliano et al.,
"Robotics: Modelling, Planning and Control", 2009, section 3.1), so that the IMU reads

    f_i = R_i_w (a_i_w - g_w),        omega_i = R_i_b omega_b

with ``g_w`` the gravity vector (``(0, 0, -9.81)`` in the world, ENU). The mount ``T_b_i`` is
the IMU frame in the body frame (docs/CONVENTIONS.md); the gyroscope's reading does not depend
on where on the body it sits, the accelerometer's does.

Noise follows Kalibr's IMU noise model (ethz-asl/kalibr wiki, "IMU Noise Model"), per axis,
independently: a reading is the truth plus a bias ``b`` and white noise ``n``. The four
figures are continuous-time densities in Kalibr's units (``ImuNoise``); sampled every ``dt``
seconds, the white noise has the standard deviation ``density / sqrt(dt)`` and the bias walks
by a Gaussian step of ``random_walk * sqrt(dt)`` per sample.

``allan_deviation`` is the overlapping Allan deviation of IEEE Std 952-1997 (Annex C), by
which those figures are read off a static recording: a white noise of density ``N`` has
``sigma(tau) = N / sqrt(tau)``, a random walk of strength ``K`` has
``sigma(tau) = K sqrt(tau / 3)``.

numpy only: this module never imports MuJoCo (the simulator's sensors are checked against it
in ``sim.imu`` and the tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from vnav import _validate as _v
from vnav import se3

__all__ = [
    "GRAVITY_W",
    "ImuNoise",
    "ImuNoiseProcess",
    "allan_deviation",
    "angular_rate_i",
    "fit_allan_noise",
    "point_acceleration_w",
    "specific_force_i",
]

GRAVITY_W = np.array([0.0, 0.0, -9.81])
"""Gravity in the world frame (ENU, z up), m/s^2: the simulator's (``models/quadrotor.xml``)."""


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (..., 3) arrays, written out (``np.cross`` is slow on small
    arrays)."""
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def point_acceleration_w(
    a_w: ArrayLike, omega_w: ArrayLike, alpha_w: ArrayLike, r_w: ArrayLike
) -> np.ndarray:
    """Acceleration of a point fixed on a rigid body, from the body origin's motion.

    ``a_point_w = a_w + alpha_w x r_w + omega_w x (omega_w x r_w)`` (tangential and
    centripetal terms of the transport theorem; see the module's references).

    Parameters
    ----------
    a_w : array_like, shape (..., 3)
        Acceleration of the body origin in the world, m/s^2.
    omega_w : array_like, shape (..., 3)
        Angular velocity of the body, world axes, rad/s.
    alpha_w : array_like, shape (..., 3)
        Angular acceleration of the body, world axes, rad/s^2.
    r_w : array_like, shape (..., 3)
        The point minus the body origin (the lever arm), world axes, m.

    Returns
    -------
    ndarray, shape (..., 3)
        m/s^2, world axes.

    Raises
    ------
    ValueError
        If an argument is not (..., 3) or holds NaN or inf.
    """
    a_w = _v.vector(a_w, "a_w")
    omega_w = _v.vector(omega_w, "omega_w")
    alpha_w = _v.vector(alpha_w, "alpha_w")
    r_w = _v.vector(r_w, "r_w")
    return a_w + _cross(alpha_w, r_w) + _cross(omega_w, _cross(omega_w, r_w))


def specific_force_i(
    T_w_b: ArrayLike,
    T_b_i: ArrayLike,
    a_w: ArrayLike,
    omega_b: ArrayLike,
    alpha_b: ArrayLike,
    gravity_w: ArrayLike = GRAVITY_W,
) -> np.ndarray:
    """What a noise-free accelerometer on the mount ``T_b_i`` reads: ``f_i = R_i_w (a_i_w - g_w)``.

    The acceleration ``a_i_w`` is taken at the IMU's own position ``t_w_b + R_w_b t_b_i``
    (``point_acceleration_w``); at rest (or hovering) the reading is ``-g`` in the IMU frame,
    ``+9.81`` m/s^2 along the world's up axis.

    Parameters
    ----------
    T_w_b : array_like, shape (..., 4, 4)
        The body pose in the world.
    T_b_i : array_like, shape (4, 4)
        The IMU mount: the IMU frame in the body frame.
    a_w : array_like, shape (..., 3)
        Acceleration of the body origin in the world, m/s^2.
    omega_b : array_like, shape (..., 3)
        Angular velocity of the body, body axes, rad/s (MuJoCo's free joint's ``qvel[3:6]``).
    alpha_b : array_like, shape (..., 3)
        Its time derivative, body axes, rad/s^2 (``qacc[3:6]``). As ``d(R_w_b omega_b)/dt =
        R_w_b alpha_b`` (the term ``omega x omega`` vanishes), ``alpha_w = R_w_b alpha_b``.
    gravity_w : array_like, shape (3,)
        Gravity in the world, m/s^2 (default ``GRAVITY_W``).

    Returns
    -------
    ndarray, shape (..., 3)
        The specific force in the IMU frame, m/s^2.

    Raises
    ------
    ValueError
        If a transform is not rigid, or a vector is not (..., 3) or holds NaN or inf.
    """
    T_w_b = se3.check_transform(T_w_b, "T_w_b")
    T_b_i = se3.check_transform(T_b_i, "T_b_i")
    if T_b_i.shape != (4, 4):
        raise ValueError(f"T_b_i must have shape (4, 4); got shape {T_b_i.shape}")
    g_w = _v.vector(gravity_w, "gravity_w", batched=False)
    omega_b = _v.vector(omega_b, "omega_b")
    alpha_b = _v.vector(alpha_b, "alpha_b")
    R_w_b = T_w_b[..., :3, :3]
    # Vectors in body axes to world axes, row-wise: v_w = R_w_b v_b.
    r_w = np.einsum("...jk,k->...j", R_w_b, T_b_i[:3, 3])
    omega_w = np.einsum("...jk,...k->...j", R_w_b, omega_b)
    alpha_w = np.einsum("...jk,...k->...j", R_w_b, alpha_b)
    a_i_w = point_acceleration_w(a_w, omega_w, alpha_w, r_w)
    # f_i = R_i_w (a_i_w - g) = R_b_i^T R_w_b^T (a_i_w - g).
    f_b = np.einsum("...kj,...k->...j", R_w_b, a_i_w - g_w)
    return f_b @ T_b_i[:3, :3]


def angular_rate_i(T_b_i: ArrayLike, omega_b: ArrayLike) -> np.ndarray:
    """What a noise-free gyroscope on the mount ``T_b_i`` reads: ``omega_i = R_i_b omega_b``.

    Parameters
    ----------
    T_b_i : array_like, shape (4, 4)
        The IMU mount (its translation does not matter: every point of a rigid body turns at
        the same rate).
    omega_b : array_like, shape (..., 3)
        Angular velocity of the body, body axes, rad/s.

    Returns
    -------
    ndarray, shape (..., 3)
        rad/s, IMU axes.

    Raises
    ------
    ValueError
        If ``T_b_i`` is not a rigid (4, 4) transform, or ``omega_b`` is not (..., 3) or holds
        NaN or inf.
    """
    T_b_i = se3.check_transform(T_b_i, "T_b_i")
    if T_b_i.shape != (4, 4):
        raise ValueError(f"T_b_i must have shape (4, 4); got shape {T_b_i.shape}")
    omega_b = _v.vector(omega_b, "omega_b")
    # Row-wise omega_i = R_b_i^T omega_b.
    return omega_b @ T_b_i[:3, :3]


# ------------------------------------------------------------------------------ noise model

MAX_NOISE_DENSITY = 10.0
"""Largest noise density or random walk accepted (in its unit): far beyond any real IMU."""


@dataclass(frozen=True)
class ImuNoise:
    """Kalibr's IMU noise figures, continuous time, in Kalibr's units (its ``imu.yaml`` keys).

    Attributes
    ----------
    accelerometer_noise_density : float
        White noise density of each accelerometer axis, m/s^2/sqrt(Hz).
    accelerometer_random_walk : float
        Bias random walk of each accelerometer axis, m/s^3/sqrt(Hz).
    gyroscope_noise_density : float
        White noise density of each gyroscope axis, rad/s/sqrt(Hz).
    gyroscope_random_walk : float
        Bias random walk of each gyroscope axis, rad/s^2/sqrt(Hz).

    Each is a finite number in [0, ``MAX_NOISE_DENSITY``]; all zero (the default) is a perfect
    IMU.

    Raises
    ------
    ValueError
        Naming the field, on a value that is not such a number.
    """

    accelerometer_noise_density: float = 0.0
    accelerometer_random_walk: float = 0.0
    gyroscope_noise_density: float = 0.0
    gyroscope_random_walk: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"ImuNoise.{f.name} must be a number, got {value!r}")
            if not (math.isfinite(value) and 0.0 <= value <= MAX_NOISE_DENSITY):
                raise ValueError(
                    f"ImuNoise.{f.name} must be in [0, {MAX_NOISE_DENSITY:g}], got {value!r}"
                )
            object.__setattr__(self, f.name, float(value))

    @property
    def is_zero(self) -> bool:
        """No noise and no bias drift: the readings are the truth."""
        return not any(getattr(self, f.name) for f in fields(self))

    def white_std(self, dt_s: float) -> tuple[float, float]:
        """Discrete-time white-noise standard deviations ``density / sqrt(dt_s)``.

        Returns
        -------
        (float, float)
            Accelerometer (m/s^2) and gyroscope (rad/s), per axis and sample.
        """
        dt_s = _positive(dt_s, "dt_s")
        s = 1.0 / math.sqrt(dt_s)
        return self.accelerometer_noise_density * s, self.gyroscope_noise_density * s

    def bias_step_std(self, dt_s: float) -> tuple[float, float]:
        """Discrete-time bias random-walk steps ``random_walk * sqrt(dt_s)``.

        Returns
        -------
        (float, float)
            Accelerometer (m/s^2) and gyroscope (rad/s), per axis and sample.
        """
        dt_s = _positive(dt_s, "dt_s")
        s = math.sqrt(dt_s)
        return self.accelerometer_random_walk * s, self.gyroscope_random_walk * s


def _positive(value: float, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


class ImuNoiseProcess:
    """The errors added to an IMU's readings, sample after sample (Kalibr's discrete model).

    At sample ``k`` (every ``dt_s`` seconds), per axis::

        error[k] = bias[k] + sigma_d w[k],      bias[k + 1] = bias[k] + sigma_bd v[k]

    ``sigma_d = density / sqrt(dt_s)``, ``sigma_bd = random_walk * sqrt(dt_s)``, ``w`` and
    ``v`` independent standard normals; the biases start at zero. Each sample draws 12 normals
    from ``rng`` in one call, in the order white accelerometer, white gyroscope, accelerometer
    bias step, gyroscope bias step (x, y, z each), so ``next()`` called ``n`` times and
    ``series(n)`` give the same numbers.

    Parameters
    ----------
    noise : ImuNoise
    dt_s : float
        The sampling period, seconds (``1 / rate_hz``).
    rng : numpy.random.Generator
        Nothing is drawn when ``noise.is_zero``.

    Attributes
    ----------
    bias_accel_i, bias_gyro_i : ndarray, shape (3,)
        The biases the next sample carries, IMU axes, m/s^2 and rad/s.
    """

    def __init__(self, noise: ImuNoise, dt_s: float, rng: np.random.Generator) -> None:
        if not isinstance(noise, ImuNoise):
            raise ValueError(f"noise must be an ImuNoise, got {type(noise).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.noise = noise
        self.dt_s = _positive(dt_s, "dt_s")
        self.rng = rng
        white_a, white_g = noise.white_std(self.dt_s)
        walk_a, walk_g = noise.bias_step_std(self.dt_s)
        self._scale = np.repeat([white_a, white_g, walk_a, walk_g], 3)
        self.bias_accel_i = np.zeros(3)
        self.bias_gyro_i = np.zeros(3)

    def series(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The errors of the next ``n`` samples.

        Returns
        -------
        accel_error_i : ndarray, shape (n, 3)
            m/s^2.
        gyro_error_i : ndarray, shape (n, 3)
            rad/s.

        Raises
        ------
        ValueError
            If ``n`` is not a non-negative integer.
        """
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise ValueError(f"n must be a non-negative integer, got {n!r}")
        n = int(n)
        if self.noise.is_zero:
            return np.zeros((n, 3)), np.zeros((n, 3))
        draws = self.rng.standard_normal((n, 12))
        draws *= self._scale
        # Sample k carries the bias after k steps: the cumulative sum of the steps before it.
        steps = draws[:, 6:]
        walked = np.cumsum(steps, axis=0)
        bias_a = self.bias_accel_i + np.vstack([np.zeros(3), walked[:-1, :3]])[:n]
        bias_g = self.bias_gyro_i + np.vstack([np.zeros(3), walked[:-1, 3:]])[:n]
        if n:
            self.bias_accel_i = self.bias_accel_i + walked[-1, :3]
            self.bias_gyro_i = self.bias_gyro_i + walked[-1, 3:]
        return bias_a + draws[:, 0:3], bias_g + draws[:, 3:6]

    def next(self) -> tuple[np.ndarray, np.ndarray]:
        """The errors of the next sample: ``(accel_error_i (3,), gyro_error_i (3,))``."""
        a, g = self.series(1)
        return a[0], g[0]


# ------------------------------------------------------------------------------ Allan deviation


def allan_deviation(samples: ArrayLike, dt_s: float, taus: ArrayLike) -> np.ndarray:
    """Overlapping Allan deviation of a rate signal (IEEE Std 952-1997, Annex C).

    With ``theta`` the running integral of the samples (``theta_k = dt_s * sum_{j<k} y_j``)
    and the cluster time ``tau = m dt_s``::

        sigma^2(tau) = sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (N - 2m))

    over every ``k`` from 0 to ``N - 2m`` (every cluster start, hence "overlapping"). This is
    half the mean square difference of consecutive averages over ``tau``; a white noise of
    density ``N`` gives ``N / sqrt(tau)``, a random walk of strength ``K`` ``K sqrt(tau / 3)``.

    Parameters
    ----------
    samples : array_like, shape (N,) or (N, C)
        The readings, one row per sample at a steady rate (e.g. ``(N, 3)``: three axes).
    dt_s : float
        Sampling period, seconds.
    taus : array_like, shape (T,)
        Cluster times, seconds; each is rounded to the nearest multiple ``m dt_s`` (the result
        is that cluster's), with ``1 <= m <= (N - 1) / 2``.

    Returns
    -------
    ndarray, shape (T,) or (T, C)
        The Allan deviation at each tau, in the samples' unit.

    Raises
    ------
    ValueError
        If ``samples`` is not (N,) or (N, C) finite numbers, ``dt_s`` is not positive, or a tau
        is below ``dt_s / 2`` or longer than half the record.
    """
    y = _v.scalar_or_array(samples, "samples")
    if y.ndim not in (1, 2) or y.shape[0] < 3:
        raise ValueError(f"samples must have shape (N,) or (N, C) with N >= 3; got shape {y.shape}")
    dt_s = _positive(dt_s, "dt_s")
    tau_arr = _v.scalar_or_array(taus, "taus")
    if tau_arr.ndim != 1:
        raise ValueError(f"taus must have shape (T,); got shape {tau_arr.shape}")
    n = y.shape[0]
    m_max = (n - 1) // 2
    ms = np.rint(tau_arr / dt_s).astype(np.int64)
    bad = (ms < 1) | (ms > m_max)
    if bad.any():
        tau = float(tau_arr[np.argmax(bad)])
        raise ValueError(
            f"taus must lie in [{dt_s:g}, {m_max * dt_s:g}] s (one sample to half the record of "
            f"{n} samples at {dt_s:g} s); got {tau:g}"
        )
    # The running integral in float64, from zero: theta has N + 1 entries.
    theta = np.zeros((n + 1, *y.shape[1:]))
    np.cumsum(y, axis=0, out=theta[1:])
    theta *= dt_s
    out = np.empty((len(ms), *y.shape[1:]))
    for j, m in enumerate(ms):
        d = theta[2 * m :] - 2.0 * theta[m:-m] + theta[: -2 * m]
        tau = m * dt_s
        out[j] = np.sqrt(np.einsum("k...,k...->...", d, d) / (2.0 * tau**2 * d.shape[0]))
    return out


def fit_allan_noise(taus: ArrayLike, adev: ArrayLike) -> tuple[float, float]:
    """The white-noise density ``N`` and random walk ``K`` whose Allan variance
    ``N^2 / tau + K^2 tau / 3`` fits ``adev`` best.

    A linear least-squares fit of ``(N^2, K^2)`` to the Allan variance, each tau weighted by
    the inverse of its variance (relative errors: a cluster time's estimate scatters in
    proportion to itself), the noise terms' combination that IEEE Std 952-1997 (Annex C)
    fits to a measured Allan variance.

    Parameters
    ----------
    taus : array_like, shape (T,)
        Cluster times, seconds (as ``allan_deviation`` used them: multiples of ``dt_s``).
    adev : array_like, shape (T,)
        The Allan deviation at each.

    Returns
    -------
    (float, float)
        ``N`` (unit/sqrt(Hz)) and ``K`` (unit/s/sqrt(Hz)); each 0 if the fit makes its square
        negative.

    Raises
    ------
    ValueError
        If the arrays are not (T,) alike with T >= 2, or hold a non-positive or non-finite
        value.
    """
    tau = _v.scalar_or_array(taus, "taus")
    sigma = _v.scalar_or_array(adev, "adev")
    if tau.ndim != 1 or tau.shape != sigma.shape or tau.size < 2:
        raise ValueError(
            f"taus and adev must have the same shape (T,), T >= 2; got {tau.shape} and "
            f"{sigma.shape}"
        )
    if (tau <= 0.0).any() or (sigma <= 0.0).any():
        raise ValueError("taus and adev must be positive")
    avar = sigma**2
    # Each row divided by its expected scatter: relative to the value, and growing as
    # sqrt(tau / record) as fewer independent clusters fit in the record.
    weight = 1.0 / (avar * np.sqrt(tau))
    design = np.column_stack([1.0 / tau, tau / 3.0]) * weight[:, None]
    coef, *_ = np.linalg.lstsq(design, avar * weight, rcond=None)
    n2, k2 = (max(float(c), 0.0) for c in coef)
    return math.sqrt(n2), math.sqrt(k2)
