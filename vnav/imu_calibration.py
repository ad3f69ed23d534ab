"""Camera-IMU calibration from a flight, as Kalibr does: ``T_i_c`` and the clock offset.

The inputs are the camera's images (each one's exposure stamp on the camera clock and the cone
apexes the detector found in it), a map of the cones (the calibration target: it fixes the
world frame, z up, so gravity is known in it) and the IMU's readings stamped on its own clock.
Neither the pose stream nor a declared mount is used: the answer comes from the images and the
IMU alone. The unknowns are Kalibr's (Furgale, Rehder & Siegwart, "Unified temporal and spatial
calibration for multi-sensor systems", IROS 2013): the camera in the IMU frame ``T_i_c``
(Kalibr reports ``T_cam_imu``, its inverse, ``ImuCamCalibration.T_c_i``), the clock offset
``time_offset_s`` in Kalibr's ``timeshift_cam_imu`` convention, ``t_imu = t_cam +
time_offset_s``, and the gyroscope's and accelerometer's biases (constant over the flight).

1. **Camera poses.** Each image's camera pose ``T_w_c`` from PnP on its apexes
   (``vnav.multiview.camera_pose_from_apexes``), the previous image's pose narrowing the
   matching; an image whose apexes do not give a pose within ``PNP_RMS_PX`` is left out.
2. **Closed-form start.** The rotation between consecutive images, from PnP, is the camera's
   turn ``phi_c = log(R_w_c(k)^T R_w_c(k+1))``; the gyroscope integrated on SO(3) over the same
   interval of its own clock gives the IMU's, ``phi_i``, and ``phi_c = R_c_i phi_i`` (a
   rotation vector seen in another frame). The clock offset comes first, because a rotation's
   *angle* does not depend on the frame it is seen in: the offset maximises the normalised
   cross-correlation of the camera's and the IMU's rotation angles over the flight (Kalibr's
   ``findTimeshiftCameraImuPrior`` correlates the angular speeds' norms the same way), refined
   by a parabola through the peak. Then ``R_c_i`` aligns the matched rotation vectors in the
   least-squares sense (Kabsch, Acta Cryst. A32, 1976; Horn, JOSA A 4, 1987: the SVD of the
   cross-covariance, its determinant forced to +1). A flight that turns about fewer than two
   axes does not determine it and is refused (Kalibr warns of the same: "not enough
   excitation"). The translation's start is linear: with rotations and offset fixed, the
   accelerometer integrated twice gives the IMU's path up to a position and velocity per
   window, and ``p_w_c = p_w_i + R_w_i t_i_c`` is linear in those and ``t_i_c``.
3. **Least squares on the apexes' reprojection error** (Kalibr's batch estimate, with the
   IMU's own integrated motion in place of its B-spline): the flight is cut into windows of
   ``window_s`` seconds; in each, the IMU's pose is the gyroscope and accelerometer integrated
   on SO(3) from that window's unknown attitude, velocity and position (9 numbers), so that
   the camera's pose at image ``k`` is ``T_w_i(t_k + time_offset_s) @ T_i_c``. All windows and
   the 13 calibration unknowns (``R_i_c``, ``t_i_c``, the offset, both biases) minimise the
   apexes' reprojection error by Levenberg-Marquardt (Nocedal & Wright, *Numerical
   Optimization*, 10.3), with a Jacobian by central differences (each window's columns at once:
   a window's unknowns move only its own images). Outliers are then dropped as in
   ``vnav.calibration`` and the fit repeated.

What is observable: the rotation ``R_i_c`` from the rotation rates (any flight that turns
about two axes); the offset from the rates' changes (angular acceleration); the translation
``t_i_c`` only through the accelerometer: the IMU's acceleration differs from the camera's by
the lever arm's tangential and centripetal terms (``vnav.imu.point_acceleration_w``), so it
needs angular acceleration and rate, and its precision is the weakest of the three. The
standard errors come from a covariance of three terms, as ``vnav.calibration``'s, each for an
error the others miss. (Measured on 20 held-out flights of the ``imu`` built-in, noise-free
IMU, ``benchmarks.calibrate.imu_held_out``: ``(J^T J)^-1`` scaled by the residual variance put
the truth beyond 3 standard errors in 16 of them, up to 5.2; on seeds 0-12 the translation
along the IMU's z axis was 1.5-3.8 mm off, always the same way, at 0.7-0.9 mm of standard
error. The apexes' errors,
linearised through the fit, reproduce each flight's error to 0.2 mm; they are independent from
image to image, but a smooth field over the image, which the same flight meets again whatever
the mounts, carries the error: a cubic in the pixel's position fitted to them alone gives most
of it, 2.7 and 3.0 of 3.2 and 3.8 mm on two of the flights. With the three terms: 20 of 20
within 3 standard errors, at most 2.2; ``python -m benchmarks calibrate --only-imu``.)

- the apexes' own errors, by the cluster-robust ("sandwich") covariance with each image a
  cluster (Cameron & Miller, "A Practitioner's Guide to Cluster-Robust Inference", J. Human
  Resources 50(2), 2015), plus ``vnav.calibration.PIXEL_STD_FLOOR`` squared times ``(J^T
  J)^-1``;
- the focal length, known to ``vnav.calibration.FOCAL_SCALE_STD`` only, by a consider
  covariance (Tapley, Schutz & Born, *Statistical Orbit Determination*, 2004, ch. 6):
  ``dx/ds = (J^T J)^-1 J^T (uv - c)``, ``cov += FOCAL_SCALE_STD^2 dx/ds dx/ds^T``;
- the apexes' bias as a smooth field over the image, which no number of images averages out
  (the flight sees the same cones from the same places), by the same consider covariance over
  the fields of ``apex_bias_fields`` (every monomial of the pixel's position up to the cube,
  along u and along v), each coefficient of ``APEX_BIAS_STD_PX``.

The covariance is of ``[phi, t_i_c, offset]`` with every window's unknowns and both biases
marginalised out (``ImuCamCalibration.covariance``); an answer whose standard errors exceed
``MAX_STD_*`` is refused with what is missing.

numpy and OpenCV (through ``vnav.multiview``) only; SciPy is the tests' oracle.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass

import numpy as np

from vnav import _validate as _v
from vnav import se3, so3
from vnav.calibration import FOCAL_SCALE_STD, PIXEL_STD_FLOOR, CalibrationError
from vnav.camera import PinholeCamera
from vnav.imu import GRAVITY_W
from vnav.least_squares import levenberg_marquardt
from vnav.multiview import camera_pose_from_apexes, camera_pose_from_points

logger = logging.getLogger(__name__)

__all__ = [
    "CalibrationError",
    "ImuCamCalibration",
    "ImuIntegral",
    "apex_bias_fields",
    "calibrate_camera_imu",
    "rotation_from_rates",
    "time_offset_from_rates",
]

PNP_RMS_PX = 3.0
"""An image's PnP pose is kept only if its apexes reproject within this RMS, px."""

TRACK_GATE_PX = 30.0
"""An apex is matched to the cone the previous image's pose projects within this, px (a turn
of 1 rad/s moves the image by about 25 px between images 50 ms apart)."""

MIN_IMAGES = 20
"""Images with a PnP pose inside the IMU's record, at least."""

MIN_WINDOW_IMAGES = 4
"""A window keeps its images only if it has at least this many (9 unknowns of its own)."""

MIN_RATE_DEG_S = 2.0
"""The IMU must turn at least this fast, RMS over the flight, about each of two axes (the second
largest singular value of its mean rates between images): less, and ``R_i_c`` is not
determined (Kalibr's "not enough excitation")."""

MAX_STD_ROTATION_DEG = 0.1
MAX_STD_TRANSLATION_M = 0.01
MAX_STD_OFFSET_S = 0.002
"""The largest standard errors accepted (``vnav.calibration``'s): beyond them the flight does
not determine ``T_i_c`` or the offset, and the answer is refused."""

OUTLIER_SIGMAS = 4.0
"""Apexes whose reprojection error exceeds this many robust standard deviations are dropped
(as ``vnav.calibration`` does)."""

GAIN_TOL = 1e-6

_GAUSS_3 = (
    (0.5 - 0.5 * math.sqrt(0.6), 5.0 / 18.0),
    (0.5, 8.0 / 18.0),
    (0.5 + 0.5 * math.sqrt(0.6), 5.0 / 18.0),
)
"""Gauss-Legendre's three nodes and weights on [0, 1]."""

APEX_BIAS_DEGREE = 3
"""The apexes' bias field the covariance considers: every monomial ``x^a y^b`` with ``a + b <=``
this, of the pixel's position from the principal point over the image's half width and half
height (``x, y`` in [-1, 1]), along u and along v (``apex_bias_fields``)."""

APEX_BIAS_STD_PX = 0.13
"""Each of those fields' coefficient's standard deviation, px, as the covariance considers it
(see the module's docstring). Measured: the apexes the calibration uses (re-fitted on their
blobs, ``scenarios.judge.imu_calibration``) against the true apexes projected from the true
camera poses, the fields fitted to their differences by least squares, on 13 held-out flights of
the ``imu`` built-in at 1280 x 960 (``benchmarks.calibrate.imu_held_out``, seeds 0-12): the
coefficients' RMS over fields and flights is 0.134 px (0.01-0.24 px each)."""

OFFSET_GRID_S = 0.0005
"""The cross-correlation's grid step, seconds (refined by a parabola through the peak)."""


@dataclass(frozen=True)
class ImuCamCalibration:
    """The camera-IMU calibration recovered from a flight.

    Attributes
    ----------
    T_i_c : ndarray, shape (4, 4)
        The camera (optical frame) in the IMU frame.
    time_offset_s : float
        Kalibr's ``timeshift_cam_imu``: ``t_imu = t_cam + time_offset_s``.
    gyro_bias_i : ndarray, shape (3,)
        The gyroscope's bias, IMU axes, rad/s (constant over the flight).
    accel_bias_i : ndarray, shape (3,)
        The accelerometer's bias, IMU axes, m/s^2.
    reprojection_rms_px : float
        RMS of the final reprojection errors, per apex.
    frames_used, observations_used : int
        Images and apexes in the final fit.
    std_rotation_deg, std_translation_m, std_offset_s : float
        Standard errors of the rotation (the largest over its three axes), the translation
        (likewise) and the offset.
    T_i_c_start : ndarray, shape (4, 4)
        The closed-form start (rotation by Kabsch, translation linear).
    time_offset_start_s : float
        The cross-correlation's offset.
    image_stamps_cam_s : ndarray, shape (K,)
        The stamps of the images in the final fit.
    T_w_c : ndarray, shape (K, 4, 4)
        Their camera poses as the fit gives them (the IMU's motion through ``T_i_c``).
    covariance : ndarray, shape (7, 7)
        The covariance of ``[phi, t_i_c, time_offset_s]``: ``phi`` the rotation's error in the
        answer's camera frame, ``R_i_c_true = R_i_c @ exp(phi^)`` (rad), ``t_i_c``'s in the IMU
        frame (m), the offset's (s). The standard errors are the square roots of its diagonal.
    """

    T_i_c: np.ndarray
    time_offset_s: float
    gyro_bias_i: np.ndarray
    accel_bias_i: np.ndarray
    reprojection_rms_px: float
    frames_used: int
    observations_used: int
    std_rotation_deg: float
    std_translation_m: float
    std_offset_s: float
    T_i_c_start: np.ndarray
    time_offset_start_s: float
    image_stamps_cam_s: np.ndarray
    T_w_c: np.ndarray
    covariance: np.ndarray

    @property
    def T_c_i(self) -> np.ndarray:
        """(4, 4) the IMU in the camera frame: Kalibr's ``T_cam_imu``."""
        return se3.invert(self.T_i_c)


# ------------------------------------------------------------------------------ IMU integration


class ImuIntegral:
    """The IMU's readings integrated on SO(3) from the first one: ``G(t) = R_i0_i(t)``,
    ``V(t) = int G (f - b_a)``, ``P(t) = int V``, evaluated at any time of its record.

    Between readings ``j`` and ``j + 1`` the rate (minus the gyroscope bias) is the cubic
    through the four readings around them, ``j - 1`` to ``j + 2`` (the nearest four at the
    record's ends), and the IMU turns by its integral (``G_{j+1} = G_j exp(int omega)``; the
    turn's axis moving within an interval, the coning term, left out): the rate is right to
    fourth order in the reading interval, where the readings' mean (the trapezoid) leaves an
    attitude error of ``dt^2 / 12`` times the change of angular acceleration, which on a
    flight that rocks at a few hertz reads as millimetres of lever arm. The specific
    force rotated into the first IMU frame, ``a = G (f - b_a)``, is linear between readings,
    so that ``V`` and ``P`` are integrated exactly (trapezoid and its cubic). An IMU whose
    attitude at ``t0`` is ``R_w_i0``, velocity ``v0`` and position ``p0`` (world) then moves
    as

        R_w_i(t) = R_w_i0 G(t),   v_w(t) = v0 + g (t - t0) + R_w_i0 (V(t) - V(t0)),
        p_w(t) = p0 + v0 (t - t0) + g (t - t0)^2 / 2 + R_w_i0 (P(t) - P(t0) - V(t0) (t - t0))

    (the preintegration of Lupton & Sukkarieh, IEEE T-RO 2012, and Forster et al., IEEE T-RO
    2017, written from a fixed start; here ``G`` is relative to the first reading, so the
    attitude ``R_w_i0`` is the IMU's at the first reading).

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        The readings' stamps on the IMU clock, increasing, N >= 2.
    gyro_i : ndarray, shape (N, 3)
        rad/s.
    accel_i : ndarray, shape (N, 3)
        m/s^2.
    gyro_bias_i, accel_bias_i : array_like, shape (3,)
        Subtracted from every reading.

    Raises
    ------
    ValueError
        On shapes that do not match, non-finite values or stamps that do not increase.
    """

    def __init__(
        self,
        t_s: np.ndarray,
        gyro_i: np.ndarray,
        accel_i: np.ndarray,
        gyro_bias_i: object = (0.0, 0.0, 0.0),
        accel_bias_i: object = (0.0, 0.0, 0.0),
    ) -> None:
        t = _v.scalar_or_array(t_s, "t_s")
        gyro = _v.vector(gyro_i, "gyro_i")
        accel = _v.vector(accel_i, "accel_i")
        if t.ndim != 1 or t.size < 2 or gyro.shape != (t.size, 3) or accel.shape != gyro.shape:
            raise ValueError(
                "t_s (N,), gyro_i (N, 3) and accel_i (N, 3) must match, N >= 2; got "
                f"{t.shape}, {gyro.shape}, {accel.shape}"
            )
        if not (np.diff(t) > 0.0).all():
            raise ValueError("t_s must increase")
        b_g = _v.vector(gyro_bias_i, "gyro_bias_i", batched=False)
        b_a = _v.vector(accel_bias_i, "accel_bias_i", batched=False)
        self.t_s = t
        self.gyro_i, self.accel_i = gyro, accel
        self._bias_terms: tuple[np.ndarray, np.ndarray] | None = None
        dt = np.diff(t)
        # The rate over interval j as a polynomial in x = (t - t_j) / dt_j through the nearest
        # four readings (all of them, fewer than four), coefficients (N - 1, 4, 3).
        m = min(4, t.size)
        first = np.clip(np.arange(t.size - 1) - 1, 0, t.size - m)
        nodes = first[:, None] + np.arange(m)
        x = (t[nodes] - t[:-1, None]) / dt[:, None]
        vander = x[:, :, None] ** np.arange(m)
        self._rate_poly = np.linalg.solve(vander, gyro[nodes] - b_g)
        self._powers = np.arange(1, m + 1)
        steps = so3.exp(self._turn(np.arange(t.size - 1), np.ones(t.size - 1)))
        # G_{j+1} = G_j steps_j from G_0 = I: the running product by a prefix scan (Hillis &
        # Steele, CACM 1986), log2(N) stacked products instead of N small ones in Python.
        scan = steps.copy()
        k = 1
        while k < len(scan):
            scan[k:] = scan[:-k] @ scan[k:]
            k *= 2
        G = np.empty((t.size, 3, 3))
        G[0] = np.eye(3)
        G[1:] = scan
        self._G = G
        a = np.einsum("nij,nj->ni", G, accel - b_a)
        self._a = a
        da = a[1:] - a[:-1]
        V = np.zeros((t.size, 3))
        V[1:] = np.cumsum(0.5 * (a[1:] + a[:-1]) * dt[:, None], axis=0)
        P = np.zeros((t.size, 3))
        P[1:] = np.cumsum(
            V[:-1] * dt[:, None] + (a[:-1] / 2.0 + da / 6.0) * dt[:, None] ** 2, axis=0
        )
        self._V, self._P = V, P

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``G (K, 3, 3)``, ``V (K, 3)`` and ``P (K, 3)`` at the times ``t_s`` (K,), which
        must lie in the record (not checked: the caller keeps them inside)."""
        t = np.asarray(t_s, dtype=np.float64)
        j = np.clip(np.searchsorted(self.t_s, t, side="right") - 1, 0, self.t_s.size - 2)
        s = (t - self.t_s[j])[:, None]
        dt = (self.t_s[j + 1] - self.t_s[j])[:, None]
        G = self._G[j] @ so3.exp(self._turn(j, s[:, 0] / dt[:, 0]))
        a0 = self._a[j]
        slope = (self._a[j + 1] - a0) / dt
        V = self._V[j] + a0 * s + slope * s**2 / 2.0
        P = self._P[j] + self._V[j] * s + a0 * s**2 / 2.0 + slope * s**3 / 6.0
        return G, V, P

    def _turn(self, j: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The rotation vectors from reading ``j`` (K,) to the fraction ``x`` (K,) of the
        interval after it, (K, 3) rad: the rate's polynomial integrated, ``phi(x)``, plus the
        first term of Bortz's rotation vector equation for a turning axis (the coning term,
        ``1/2 int phi x omega``; Bortz, IEEE T-AES 1971), by 3-point Gauss-Legendre."""
        dt = self.t_s[j + 1] - self.t_s[j]
        c = self._rate_poly[j]
        p = self._powers

        def phi(u: np.ndarray) -> np.ndarray:  # int_0^u of the rate, in dt units
            return np.einsum("kp,kpc->kc", u[:, None] ** p / p, c)

        def rate(u: np.ndarray) -> np.ndarray:
            return np.einsum("kp,kpc->kc", u[:, None] ** (p - 1), c)

        coning = np.zeros((len(j), 3))
        for node, weight in _GAUSS_3:
            u = node * x
            coning += weight * x[:, None] * np.cross(phi(u), rate(u))
        return dt[:, None] * phi(x) + 0.5 * dt[:, None] ** 2 * coning

    def bias_terms(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``int G`` and ``int int G`` from the first reading to each of ``t_s`` (K,), (K, 3, 3)
        each: an accelerometer bias ``db`` more moves ``V`` by ``-int G db`` and ``P`` by
        ``-int int G db`` (``G`` taken linear between readings)."""
        t = self.t_s
        if self._bias_terms is None:
            G, dt = self._G, np.diff(t)[:, None, None]
            GI = np.zeros_like(G)
            GI[1:] = np.cumsum(0.5 * (G[1:] + G[:-1]) * dt, axis=0)
            GII = np.zeros_like(G)
            GII[1:] = np.cumsum(
                GI[:-1] * dt + (G[:-1] / 2.0 + (G[1:] - G[:-1]) / 6.0) * dt**2, axis=0
            )
            self._bias_terms = (GI, GII)
        GI, GII = self._bias_terms
        t_s = np.asarray(t_s, dtype=np.float64)
        j = np.clip(np.searchsorted(t, t_s, side="right") - 1, 0, t.size - 2)
        s = (t_s - t[j])[:, None, None]
        dt = (t[j + 1] - t[j])[:, None, None]
        G0 = self._G[j]
        slope = (self._G[j + 1] - G0) / dt
        gi = GI[j] + G0 * s + slope * s**2 / 2.0
        gii = GII[j] + GI[j] * s + G0 * s**2 / 2.0 + slope * s**3 / 6.0
        return gi, gii

    def turns_i(self, t0_s: np.ndarray, t1_s: np.ndarray) -> np.ndarray:
        """The IMU's rotation vectors from ``t0_s`` to ``t1_s`` (each (K,)), in the IMU frame at
        ``t0_s``: ``log(G(t0)^T G(t1))``, (K, 3) rad."""
        G0, _, _ = self.at(t0_s)
        G1, _, _ = self.at(t1_s)
        return so3.log(np.einsum("kji,kjl->kil", G0, G1))


def apex_bias_fields(camera: PinholeCamera, uv: np.ndarray) -> np.ndarray:
    """The apexes' bias fields at the pixels ``uv`` (N, 2): for each monomial ``x^a y^b``,
    ``a + b <= APEX_BIAS_DEGREE`` (``x = (u - cx) / (width / 2)``, ``y = (v - cy) / (height /
    2)``), the field along u and the field along v, each flattened as the residuals are,
    ``[u0, v0, u1, v1, ...]``: (2 M, 2 N), M the monomials."""
    xy = (np.asarray(uv, dtype=np.float64) - [camera.cx, camera.cy]) / [
        camera.width / 2.0,
        camera.height / 2.0,
    ]
    fields = []
    for a in range(APEX_BIAS_DEGREE + 1):
        for b in range(APEX_BIAS_DEGREE + 1 - a):
            m = xy[:, 0] ** a * xy[:, 1] ** b
            zero = np.zeros_like(m)
            fields.append(np.column_stack([m, zero]).ravel())
            fields.append(np.column_stack([zero, m]).ravel())
    return np.array(fields)


# ------------------------------------------------------------------------------ closed form


def time_offset_from_rates(
    t0_cam_s: np.ndarray,
    t1_cam_s: np.ndarray,
    angle_c_rad: np.ndarray,
    integral: ImuIntegral,
    max_offset_s: float,
) -> float:
    """The clock offset ``t_imu = t_cam + offset`` that best lines up the camera's rotation
    angles with the gyroscope's: the peak of their normalised cross-correlation over offsets
    in ``[-max_offset_s, max_offset_s]`` (a grid of ``8 OFFSET_GRID_S``, then one of
    ``OFFSET_GRID_S`` about its best), refined by a parabola
    through the peak and its neighbours (Kalibr's ``findTimeshiftCameraImuPrior`` correlates the
    norms of the angular velocities likewise).

    Parameters
    ----------
    t0_cam_s, t1_cam_s : ndarray, shape (K,)
        Each interval's start and end on the camera clock; every ``t + offset`` tried must lie
        in the IMU's record.
    angle_c_rad : ndarray, shape (K,)
        The camera's rotation angle over each interval (a rotation's angle is the same in
        every frame).
    integral : ImuIntegral
    max_offset_s : float

    Returns
    -------
    float
        The offset, seconds.

    Raises
    ------
    CalibrationError
        If the angles do not vary (no rotation, or a steady one: nothing to correlate).
    """
    c = np.asarray(angle_c_rad, dtype=np.float64)
    c = c - c.mean()
    if not np.linalg.norm(c) > 1e-9:
        raise CalibrationError(
            "not enough excitation: the camera's rotation does not change over the flight, so "
            "nothing reveals the camera-IMU clock offset (fly turns that start and stop)"
        )

    def score(offsets: np.ndarray) -> np.ndarray:
        out = np.empty(offsets.size)
        for m, d in enumerate(offsets):
            a = np.linalg.norm(integral.turns_i(t0_cam_s + d, t1_cam_s + d), axis=1)
            a = a - a.mean()
            out[m] = float(a @ c) / max(float(np.linalg.norm(a) * np.linalg.norm(c)), 1e-300)
        return out

    # A coarse grid first (the correlation's peak is as wide as a turn, tens of ms), then the
    # fine grid around its best.
    coarse_s = 8 * OFFSET_GRID_S
    n = round(max_offset_s / coarse_s)
    coarse = np.arange(-n, n + 1) * coarse_s
    best = float(coarse[int(np.argmax(score(coarse)))])
    lo = max(best - coarse_s, -max_offset_s)
    hi = min(best + coarse_s, max_offset_s)
    fine = np.arange(lo, hi + 0.5 * OFFSET_GRID_S, OFFSET_GRID_S)
    values = score(fine)
    m = int(np.argmax(values))
    if 0 < m < fine.size - 1:
        y0, y1, y2 = values[m - 1 : m + 2]
        curvature = y0 - 2.0 * y1 + y2
        if curvature < 0.0:
            return float(fine[m] + 0.5 * (y0 - y2) / curvature * OFFSET_GRID_S)
    return float(fine[m])


def rotation_from_rates(omega_c: np.ndarray, omega_i: np.ndarray) -> np.ndarray:
    """``R_c_i`` minimising ``sum_k |omega_c[k] - R_c_i omega_i[k]|^2``: the same rotation
    rates seen by the camera and by the IMU, aligned (Kabsch 1976; Horn 1987).

    ``H = sum_k omega_i[k] omega_c[k]^T = U S V^T`` gives ``R_c_i = V diag(1, 1, det(V U^T))
    U^T``.

    Parameters
    ----------
    omega_c, omega_i : ndarray, shape (K, 3)
        Mean angular velocities over the same intervals (a turn's rotation vector over its
        duration), rad/s, in the camera's and the IMU's frame.

    Returns
    -------
    ndarray, shape (3, 3)

    Raises
    ------
    ValueError
        On shapes that do not match or non-finite values.
    CalibrationError
        If the rates do not span two axes (the second singular value of ``omega_i`` over
        ``sqrt(K)``, an RMS rate, is below ``MIN_RATE_DEG_S``): a rotation about one axis
        leaves ``R_c_i`` free about it.
    """
    a = _v.vector(omega_c, "omega_c")
    b = _v.vector(omega_i, "omega_i")
    if a.ndim != 2 or a.shape != b.shape:
        raise ValueError(f"omega_c and omega_i must both be (K, 3); got {a.shape} and {b.shape}")
    spread = np.linalg.svd(b / math.sqrt(max(len(b), 1)), compute_uv=False)
    second = math.degrees(float(spread[1])) if len(spread) > 1 else 0.0
    if not second >= MIN_RATE_DEG_S:
        raise CalibrationError(
            "not enough excitation: the flight turns about fewer than two axes (the IMU's "
            f"rate is {second:.3g} deg/s RMS about the second axis, need >= "
            f"{MIN_RATE_DEG_S:g} deg/s), so the camera-IMU rotation is not determined"
        )
    H = b.T @ a
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)))])
    return Vt.T @ D @ U.T


# ------------------------------------------------------------------------------ the solver


def _checked_apexes(apex_uv: list[np.ndarray]) -> list[np.ndarray]:
    """Each image's apexes as a float (K, 2) array.

    Raises
    ------
    ValueError
        If one is not (K, 2) or holds NaN or inf (named by its index).
    """
    uvs = []
    for i, uv in enumerate(apex_uv):
        uv = np.asarray(uv, dtype=np.float64)
        if uv.size and (uv.ndim != 2 or uv.shape[1] != 2):
            raise ValueError(f"apex_uv[{i}] must have shape (K, 2), got {uv.shape}")
        if not np.isfinite(uv).all():
            raise ValueError(f"apex_uv[{i}] must be finite; it holds NaN or inf")
        uvs.append(uv.reshape(-1, 2))
    return uvs


def calibrate_camera_imu(
    camera: PinholeCamera,
    image_stamps_cam_s: np.ndarray,
    apex_uv: list[np.ndarray],
    apex_w: np.ndarray,
    imu_stamps_s: np.ndarray,
    gyro_i: np.ndarray,
    accel_i: np.ndarray,
    *,
    max_offset_s: float = 0.1,
    window_s: float = 3.0,
    gravity_w: object = GRAVITY_W,
    previous: ImuCamCalibration | None = None,
) -> ImuCamCalibration:
    """Recover ``T_i_c`` and the camera-IMU clock offset from a flight (see the module).

    Parameters
    ----------
    camera : PinholeCamera
    image_stamps_cam_s : ndarray, shape (N,)
        Each image's exposure stamp on the camera clock.
    apex_uv : list of N arrays of shape (K_n, 2)
        The apexes detected in each image (any order, unmatched).
    apex_w : ndarray, shape (C, 3)
        The map: each cone's apex in the world (z up).
    imu_stamps_s : ndarray, shape (M,)
        The readings' stamps on the IMU clock, increasing.
    gyro_i, accel_i : ndarray, shape (M, 3)
        The readings, rad/s and m/s^2.
    max_offset_s : float
        The offset is searched within +- this; images whose stamp +- this falls outside the
        IMU's record are left out.
    window_s : float
        The length of the windows over which the IMU's readings alone carry its pose.
    gravity_w : array_like, shape (3,)
        Gravity in the map's world frame, m/s^2.
    previous : ImuCamCalibration, optional
        An earlier calibration of the same flight (e.g. on the detector's raw apexes): its
        camera poses match each image's apexes to the map (saving the search where nothing
        else predicts the pose); the answer is made again from the closed form.

    Returns
    -------
    ImuCamCalibration

    Raises
    ------
    ValueError
        On malformed input (shapes, NaN or inf, named; ``max_offset_s`` or ``window_s`` not
        positive).
    CalibrationError
        Too few images with a pose; a flight that does not turn about two axes; standard
        errors above ``MAX_STD_*``: the message says what is missing.
    """
    t_cam = _v.scalar_or_array(image_stamps_cam_s, "image_stamps_cam_s")
    if t_cam.ndim != 1 or len(apex_uv) != t_cam.size:
        raise ValueError("image_stamps_cam_s (N,) and apex_uv (N arrays) must match")
    P = _v.vector(apex_w, "apex_w")
    if P.ndim != 2:
        raise ValueError(f"apex_w must have shape (C, 3), got {P.shape}")
    for name, value in (("max_offset_s", max_offset_s), ("window_s", window_s)):
        if isinstance(value, bool) or not (isinstance(value, int | float) and 0 < value < 1e3):
            raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
    uvs = _checked_apexes(apex_uv)
    g_w = _v.vector(gravity_w, "gravity_w", batched=False)
    integral = ImuIntegral(imu_stamps_s, gyro_i, accel_i)
    t_imu = integral.t_s
    inside = (t_cam - max_offset_s >= t_imu[0]) & (t_cam + max_offset_s <= t_imu[-1])
    known = (
        {}
        if previous is None
        else dict(zip(previous.image_stamps_cam_s, previous.T_w_c, strict=True))
    )
    views = _camera_poses(
        camera, P, [(float(t_cam[i]), uvs[i]) for i in np.flatnonzero(inside)], known
    )
    if len(views) < MIN_IMAGES:
        raise CalibrationError(
            f"too few images with a camera pose: {len(views)} inside the IMU's record (need "
            f"{MIN_IMAGES}; each needs 4 cones' apexes)"
        )
    problem = _Problem(camera, P, views, integral, g_w, max_offset_s, window_s)
    if len(problem.views) < MIN_IMAGES:
        raise CalibrationError(
            f"too few images with a camera pose in runs of {MIN_WINDOW_IMAGES} or more: "
            f"{len(problem.views)} (need {MIN_IMAGES})"
        )
    x = problem.start()
    x_start = x.copy()
    x = problem.solve(x)
    for _ in range(2):
        norms = np.linalg.norm(problem.residuals(x).reshape(-1, 2), axis=1)
        sigma = max(1.4826 * float(np.median(norms)) / math.sqrt(2.0 * math.log(2.0)), 0.1)
        keep = norms <= OUTLIER_SIGMAS * sigma
        if keep.all():
            break
        problem.keep(keep)
        x = problem.solve(x)
    return problem.result(x, x_start)


@dataclass(frozen=True)
class _View:
    """An image with a PnP pose: its camera-clock stamp, pose and matched apexes."""

    t_cam_s: float
    T_w_c: np.ndarray
    cones: np.ndarray
    uv: np.ndarray


def _camera_poses(
    camera: PinholeCamera,
    apex_w: np.ndarray,
    images: list[tuple[float, np.ndarray]],
    known: dict[float, np.ndarray],
) -> list[_View]:
    """PnP on each image's apexes. A pose ``known`` for its stamp, then the previous images'
    poses (constant velocity, then no motion) predict this one's, which matches the apexes to
    the map (mutual nearest within ``TRACK_GATE_PX``) for a single PnP; without them, or when
    none gives a good pose, ``camera_pose_from_apexes`` searches."""
    views: list[_View] = []
    last: list[np.ndarray] = []
    for t, uv in images:
        if len(uv) < 4:
            last = []
            continue
        priors = [known[t]] if t in known else []
        if len(last) == 2:
            priors.append(last[1] @ se3.invert(last[0]) @ last[1])
        if last:
            priors.append(last[-1])
        fit, matches = None, {}
        for prior in priors:
            matches = _mutual_nearest(camera, prior, apex_w, uv, TRACK_GATE_PX)
            if len(matches) < 4:
                continue
            ks = sorted(matches)
            try:
                fit = camera_pose_from_points(camera, apex_w[[matches[k] for k in ks]], uv[ks])
            except ValueError:
                continue
            if fit.rms_px < PNP_RMS_PX:
                break
            fit = None
        if fit is None:
            try:
                fit, matches = camera_pose_from_apexes(
                    camera, apex_w, uv, T_w_c_prior=priors[0] if priors else None
                )
            except ValueError:
                last = []
                continue
        if fit.rms_px >= PNP_RMS_PX:
            last = []
            continue
        ks = sorted(matches)
        views.append(_View(t, fit.T_w_c, np.array([matches[k] for k in ks]), uv[ks]))
        last = [*last[-1:], fit.T_w_c]
    return views


def _mutual_nearest(
    camera: PinholeCamera, T_w_c: np.ndarray, apex_w: np.ndarray, uv: np.ndarray, gate_px: float
) -> dict[int, int]:
    """Detection index -> map index: each the other's nearest, within ``gate_px``, as the
    camera at ``T_w_c`` sees the map."""
    T_c_w = se3.invert(T_w_c)
    p_c = apex_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    proj = np.full((len(apex_w), 2), np.inf)
    front = p_c[:, 2] > 0.1
    proj[front] = camera.project(p_c[front])
    d = np.linalg.norm(uv[:, None, :] - proj[None, :, :], axis=2)
    pairs = {}
    for k in range(len(uv)):
        c = int(np.argmin(d[k]))
        if d[k, c] <= gate_px and int(np.argmin(d[:, c])) == k:
            pairs[k] = c
    return pairs


_N_GLOBAL = 13
"""``[phi_ic (3), t_i_c (3), offset (1), gyro bias (3), accel bias (3)]``."""
_N_WINDOW = 9
"""``[phi (3): R_w_i0 = exp(phi) R_w_i0_start, p (3), v (3)]`` at the window's centre."""
_STEPS_GLOBAL = np.array([1e-7] * 6 + [1e-5] + [1e-7] * 3 + [1e-6] * 3)
_STEPS_WINDOW = np.array([1e-7] * 3 + [1e-6] * 6)
"""Forward-difference steps: radians, metres, seconds, rad/s, m/s^2 (globals); radians,
metres, m/s (each window's)."""


class _Problem:
    """The views, their windows and the residual function of ``x = [globals, windows]``."""

    def __init__(self, camera, apex_w, views, integral, g_w, max_offset_s, window_s) -> None:
        self.camera, self.apex_w, self.views = camera, apex_w, views
        self.integral, self.g_w = integral, g_w
        self.max_offset_s = max_offset_s
        self.t = np.array([v.t_cam_s for v in views])
        # Windows: runs of images at most window_s long, broken at gaps in the images.
        gap_s = 3.0 * float(np.median(np.diff(self.t)))
        window = np.zeros(len(views), dtype=np.int64)
        start = self.t[0]
        for k in range(1, len(views)):
            w = window[k - 1]
            if self.t[k] - start > window_s or self.t[k] - self.t[k - 1] > gap_s:
                w += 1
                start = self.t[k]
            window[k] = w
        counts = np.bincount(window)
        keep = counts[window] >= MIN_WINDOW_IMAGES
        self.views = [v for v, k in zip(views, keep, strict=True) if k]
        self.t = self.t[keep]
        _, self.window = np.unique(window[keep], return_inverse=True)
        self.n_windows = int(self.window.max()) + 1 if self.window.size else 0
        self.obs_image = np.concatenate(
            [np.full(len(v.cones), k) for k, v in enumerate(self.views)]
        ).astype(np.int64)
        self.obs_cone = np.concatenate([v.cones for v in self.views]).astype(np.int64)
        self.obs_uv = np.concatenate([v.uv for v in self.views]).reshape(-1, 2)
        self.R_i_c0 = np.eye(3)
        self.R_w_i0 = np.tile(np.eye(3), (self.n_windows, 1, 1))
        self.t_centre = np.zeros(self.n_windows)
        # The readings integrated with each gyroscope bias lately asked for (the Jacobian's
        # three bias columns and the current estimate: a few, each an integration).
        self._integrals: dict[bytes, ImuIntegral] = {np.zeros(3).tobytes(): integral}

    # -------------------------------------------------------------------------- model

    @property
    def n_observations(self) -> int:
        return int(self.obs_image.size)

    def keep(self, mask: np.ndarray) -> None:
        self.obs_image = self.obs_image[mask]
        self.obs_cone = self.obs_cone[mask]
        self.obs_uv = self.obs_uv[mask]

    def _integral_for(self, b_g: np.ndarray) -> ImuIntegral:
        """The readings integrated with the gyroscope bias ``b_g`` (kept for the few biases
        asked for lately: each of the bias's Jacobian columns costs one integration)."""
        key = np.ascontiguousarray(b_g, dtype=np.float64).tobytes()
        found = self._integrals.pop(key, None)
        if found is None:
            base = self.integral
            found = ImuIntegral(base.t_s, base.gyro_i, base.accel_i, gyro_bias_i=b_g)
        self._integrals[key] = found  # the newest last
        while len(self._integrals) > 5:
            del self._integrals[next(iter(self._integrals))]
        return found

    def poses(self, x: np.ndarray) -> np.ndarray:
        """``T_w_c`` of every view under ``x``, (K, 4, 4)."""
        g = x[:_N_GLOBAL]
        R_i_c = self.R_i_c0 @ so3.exp(g[0:3])
        t_i_c = g[3:6]
        offset = min(max(float(g[6]), -self.max_offset_s), self.max_offset_s)
        b_g, b_a = g[7:10], g[10:13]
        integral = self._integral_for(b_g)
        w = x[_N_GLOBAL:].reshape(self.n_windows, _N_WINDOW)
        R_w_i0 = so3.exp(w[:, 0:3]) @ self.R_w_i0
        p0, v0 = w[:, 3:6], w[:, 6:9]
        tau = self.t + offset
        G, _, Pi = integral.at(tau)
        _, Vc, Pc = integral.at(self.t_centre)
        # The accelerometer's bias enters V and P linearly: int G b_a and its integral.
        _, gii = integral.bias_terms(tau)
        gic, giic = integral.bias_terms(self.t_centre)
        k = self.window
        s = (tau - self.t_centre[k])[:, None]
        dV_c = Vc[k] - np.einsum("kij,j->ki", gic[k], b_a)
        dP = (Pi - np.einsum("kij,j->ki", gii, b_a)) - (
            Pc[k] - np.einsum("kij,j->ki", giic[k], b_a)
        )
        local = dP - dV_c * s
        p_w_i = (
            p0[k] + v0[k] * s + 0.5 * self.g_w * s**2 + np.einsum("kij,kj->ki", R_w_i0[k], local)
        )
        R_w_i = R_w_i0[k] @ G
        T = np.zeros((len(tau), 4, 4))
        T[:, :3, :3] = R_w_i @ R_i_c
        T[:, :3, 3] = p_w_i + R_w_i @ t_i_c
        T[:, 3, 3] = 1.0
        return T

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Reprojection errors of the matched apexes, (2 K,) px."""
        return self._residuals_from(self.poses(x))

    def _residuals_from(self, T_w_c: np.ndarray) -> np.ndarray:
        T = T_w_c[self.obs_image]
        d = self.apex_w[self.obs_cone] - T[:, :3, 3]
        p_c = np.einsum("nji,nj->ni", T[:, :3, :3], d)
        z = np.maximum(p_c[:, 2], 1e-6)
        u = self.camera.fx * p_c[:, 0] / z + self.camera.cx
        v = self.camera.fy * p_c[:, 1] / z + self.camera.cy
        return (np.column_stack([u, v]) - self.obs_uv).ravel()

    # -------------------------------------------------------------------------- start

    def start(self) -> np.ndarray:
        """The closed-form start: the offset by cross-correlation, ``R_i_c`` by Kabsch, each
        window's attitude from the camera's, then ``t_i_c`` and each window's position and
        velocity by linear least squares."""
        R_w_c = np.array([v.T_w_c[:3, :3] for v in self.views])
        p_w_c = np.array([v.T_w_c[:3, 3] for v in self.views])
        # Consecutive images of one window (no gap between them).
        pair = np.flatnonzero(self.window[1:] == self.window[:-1])
        t0, t1 = self.t[pair], self.t[pair + 1]
        turns_c = so3.log(np.einsum("kji,kjl->kil", R_w_c[pair], R_w_c[pair + 1]))
        offset = time_offset_from_rates(
            t0, t1, np.linalg.norm(turns_c, axis=1), self.integral, self.max_offset_s
        )
        turns_i = self.integral.turns_i(t0 + offset, t1 + offset)
        dt = (t1 - t0)[:, None]
        R_c_i = rotation_from_rates(turns_c / dt, turns_i / dt)
        self.R_i_c0 = R_c_i.T
        # Each window's IMU attitude at the first reading, R_w_i0 = R_w_c R_c_i G(tau)^T, the
        # chordal mean over its images.
        G, _, _ = self.integral.at(self.t + offset)
        each = R_w_c @ R_c_i @ np.transpose(G, (0, 2, 1))
        self.R_w_i0 = np.array(
            [
                so3.nearest_rotation(each[self.window == w].sum(axis=0))
                for w in range(self.n_windows)
            ]
        )
        self.t_centre = np.array(
            [
                0.5 * (self.t[self.window == w].min() + self.t[self.window == w].max()) + offset
                for w in range(self.n_windows)
            ]
        )
        x = np.zeros(_N_GLOBAL + _N_WINDOW * self.n_windows)
        x[6] = offset
        # p_w_c = p0 + v0 s + g s^2 / 2 + R_w_i0 local(tau) + R_w_i(tau) t_i_c: linear in
        # (t_i_c, p0, v0 per window) once the rotations and offset are fixed.
        base = self.poses(x)  # t_i_c = 0, p0 = v0 = 0: the motion's known part
        R_w_i = base[:, :3, :3] @ self.R_i_c0.T
        n = len(self.views)
        A = np.zeros((3 * n, 3 + 6 * self.n_windows))
        s = self.t + offset - self.t_centre[self.window]
        for k in range(n):
            rows = slice(3 * k, 3 * k + 3)
            A[rows, 0:3] = R_w_i[k]
            c = 3 + 6 * self.window[k]
            A[rows, c : c + 3] = np.eye(3)
            A[rows, c + 3 : c + 6] = s[k] * np.eye(3)
        b = (p_w_c - base[:, :3, 3]).ravel()
        # Normal equations by einsum (one thread; see normal_equations).
        sol = _solve_spd(np.einsum("ki,kj->ij", A, A), np.einsum("ki,k->i", A, b))
        x[3:6] = sol[0:3]
        w = x[_N_GLOBAL:].reshape(self.n_windows, _N_WINDOW)
        w[:, 3:6] = sol[3:].reshape(-1, 6)[:, 0:3]
        w[:, 6:9] = sol[3:].reshape(-1, 6)[:, 3:6]
        logger.info("imu calibration start: offset %.4f s, t_i_c %s m", offset, np.round(x[3:6], 4))
        return x

    # -------------------------------------------------------------------------- solve

    def jacobian(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals' derivatives at ``x`` (``r`` its residuals) by forward differences:
        ``J_g`` (2 K, 13) for the globals and ``J_w`` (2 K, 9) for the window unknowns, each
        row's column for its own image's window (a window's unknowns move only its images)."""
        J_g = np.empty((r.size, _N_GLOBAL))
        for i, h in enumerate(_STEPS_GLOBAL):
            e = np.zeros_like(x)
            e[i] = h
            J_g[:, i] = (self.residuals(x + e) - r) / h
        J_w = np.empty((r.size, _N_WINDOW))
        for j, h in enumerate(_STEPS_WINDOW):
            e = np.zeros_like(x)
            e[_N_GLOBAL + j :: _N_WINDOW] = h
            J_w[:, j] = (self.residuals(x + e) - r) / h
        return J_g, J_w

    def normal_equations(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``J^T J`` and ``J^T r`` at ``x`` (``r`` its residuals), ``J`` by forward differences.

        Each window unknown's column is taken for every window at once (a window's unknowns
        move only its own images' residuals), so a Jacobian costs ``13 + 9`` evaluations
        whatever the number of windows; the products are formed block by block with
        ``einsum``, which runs on one thread (threaded BLAS would wait for a busy core:
        docs/CONVENTIONS.md, Performance and threads)."""
        J_g, J_w = self.jacobian(x, r)
        n = x.size
        A = np.zeros((n, n))
        g = np.zeros(n)
        A[:_N_GLOBAL, :_N_GLOBAL] = np.einsum("ki,kj->ij", J_g, J_g)
        g[:_N_GLOBAL] = np.einsum("ki,k->i", J_g, r)
        row_window = np.repeat(self.window[self.obs_image], 2)
        for w in range(self.n_windows):
            rows = row_window == w
            c = slice(_N_GLOBAL + _N_WINDOW * w, _N_GLOBAL + _N_WINDOW * (w + 1))
            Jw, Jg, rw = J_w[rows], J_g[rows], r[rows]
            A[c, c] = np.einsum("ki,kj->ij", Jw, Jw)
            A[:_N_GLOBAL, c] = np.einsum("ki,kj->ij", Jg, Jw)
            A[c, :_N_GLOBAL] = A[:_N_GLOBAL, c].T
            g[c] = np.einsum("ki,k->i", Jw, rw)
        return A, g

    def covariance(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The covariance of ``[phi, t_i_c, offset]`` at the answer ``x`` (``r`` its
        residuals), (7, 7): ``phi`` the rotation's error in the answer's camera frame
        (``R_i_c_true = R_i_c exp(phi^)``), ``t_i_c``'s in the IMU frame, the offset's; the
        image-clustered sandwich plus the floor plus the consider terms of the focal length
        and the apexes' bias field (the module's docstring). All inf where ``J^T J`` is
        singular."""
        local = copy.copy(self)
        local.R_i_c0 = self.R_i_c0 @ so3.exp(x[0:3])
        x_local = x.copy()
        x_local[0:3] = 0.0
        J_g, J_w = local.jacobian(x_local, r)
        # The full Jacobian: each window's columns hold its own images' rows only.
        n = x.size
        J = np.zeros((r.size, n))
        J[:, :_N_GLOBAL] = J_g
        row_window = np.repeat(self.window[self.obs_image], 2)
        for w in range(self.n_windows):
            rows = row_window == w
            J[rows, _N_GLOBAL + _N_WINDOW * w : _N_GLOBAL + _N_WINDOW * (w + 1)] = J_w[rows]
        try:
            A = _solve_spd(np.einsum("ki,kj->ij", J, J), np.eye(n))
        except np.linalg.LinAlgError:
            return np.full((7, 7), np.inf)
        if not np.isfinite(A).all():
            return np.full((7, 7), np.inf)
        # Only the 7 calibration rows of (J^T J)^-1 J^T are needed.
        AJ = np.einsum("ij,kj->ik", A[:7], J)  # (7, 2 K)
        scores = np.zeros((len(self.views), 7))
        np.add.at(scores, self.obs_image, (AJ.T * r[:, None]).reshape(-1, 2, 7).sum(axis=1))
        clusters = max(int(np.unique(self.obs_image).size), 2)
        cov = np.einsum("ki,kj->ij", scores, scores) * (clusters / (clusters - 1.0))
        cov += PIXEL_STD_FLOOR**2 * A[:7, :7]
        centred = r.reshape(-1, 2) + self.obs_uv - [self.camera.cx, self.camera.cy]
        dx_ds = AJ @ centred.ravel()
        cov += FOCAL_SCALE_STD**2 * np.outer(dx_ds, dx_ds)
        fields = apex_bias_fields(self.camera, self.obs_uv)  # (F, 2 K)
        dx_db = np.einsum("ik,fk->if", AJ, fields)
        cov += APEX_BIAS_STD_PX**2 * np.einsum("if,jf->ij", dx_db, dx_db)
        return 0.5 * (cov + cov.T)

    def solve(self, x: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Levenberg-Marquardt (``vnav.least_squares``) on the sparse normal equations,
        stopping when an iteration lowers the cost by less than ``GAIN_TOL``."""
        return levenberg_marquardt(
            self.residuals,
            self.normal_equations,
            x,
            iterations=iterations,
            gain_tol=GAIN_TOL,
            solve=_solve_spd,
        )

    def result(self, x: np.ndarray, x_start: np.ndarray) -> ImuCamCalibration:
        r = self.residuals(x)
        rms = float(np.sqrt(np.mean(r**2) * 2.0))
        offset = float(x[6])
        if abs(offset) >= self.max_offset_s - 1e-6:
            raise CalibrationError(
                f"the flight does not determine the camera-IMU clock offset within "
                f"+-{self.max_offset_s:g} s (the answer reached that bound)"
            )
        cov = self.covariance(x, r)
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        std_rot_deg = math.degrees(float(std[0:3].max()))
        std_t_m, std_offset = float(std[3:6].max()), float(std[6])
        missing = []
        if not std_rot_deg <= MAX_STD_ROTATION_DEG:
            missing.append(
                f"the rotation (standard error {std_rot_deg:.3g} deg, need <= "
                f"{MAX_STD_ROTATION_DEG:g} deg): the flight needs turns about every axis"
            )
        if not std_t_m <= MAX_STD_TRANSLATION_M:
            missing.append(
                f"the translation (standard error {std_t_m * 1e3:.3g} mm, need <= "
                f"{MAX_STD_TRANSLATION_M * 1e3:g} mm): the flight needs faster turns (the lever "
                "arm shows in the accelerometer through angular acceleration and rate)"
            )
        if not std_offset <= MAX_STD_OFFSET_S:
            missing.append(
                f"the clock offset (standard error {std_offset * 1e3:.3g} ms, need <= "
                f"{MAX_STD_OFFSET_S * 1e3:g} ms): the flight needs turns that start and stop"
            )
        if missing:
            raise CalibrationError("the flight does not determine " + "; nor ".join(missing))
        return ImuCamCalibration(
            T_i_c=self._T_i_c(x),
            time_offset_s=offset,
            gyro_bias_i=x[7:10].copy(),
            accel_bias_i=x[10:13].copy(),
            reprojection_rms_px=rms,
            frames_used=int(np.unique(self.obs_image).size),
            observations_used=self.n_observations,
            std_rotation_deg=std_rot_deg,
            std_translation_m=std_t_m,
            std_offset_s=std_offset,
            covariance=cov,
            T_i_c_start=self._T_i_c(x_start),
            time_offset_start_s=float(x_start[6]),
            image_stamps_cam_s=self.t.copy(),
            T_w_c=self.poses(x),
        )

    def _T_i_c(self, x: np.ndarray) -> np.ndarray:
        return se3.make(self.R_i_c0 @ so3.exp(x[0:3]), x[3:6])


def _solve_spd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` for a symmetric positive-definite ``A`` by OpenCV's Cholesky, which runs on
    one thread (numpy's LAPACK may start threaded BLAS, which waits for a busy core:
    docs/CONVENTIONS.md, Performance and threads).

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``A`` is not positive definite.
    """
    import cv2

    ok, x = cv2.solve(A, b.reshape(len(A), -1), flags=cv2.DECOMP_CHOLESKY)
    if not ok:
        raise np.linalg.LinAlgError("the normal equations are not positive definite")
    return x.reshape(b.shape)
