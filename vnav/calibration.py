"""The camera mount ``T_b_c`` and the camera's clock offset, recovered from a flight.

Inputs are what a real drone logs: the stamped pose stream ``T_w_b(t)`` on the pose clock, each
image's exposure stamp on the camera clock, the cone apexes the detector found in it, and a
map of the cones. The model of an apex pixel (lecture 1's chain, with time):

    uv = project(T_c_b @ T_b_w(t_cam + time_offset_s) @ p_apex_w)

with ``t_pose = t_cam + time_offset_s`` (Kalibr's ``t_imu = t_cam + shift``), the pose looked up
between its samples (``vnav.frames.FrameBuffer``: linear in translation, slerp in rotation).
The unknowns ``x = [xi, time_offset_s]``, ``T_b_c = T_b_c_guess @ exp(xi^)`` (the error in the
camera frame, as ``sim.config.MountError`` defines it), minimise the reprojection error over
the whole flight by Levenberg-Marquardt (Nocedal & Wright, *Numerical Optimization*, 10.3)
with a Jacobian by central differences. Seven parameters need no sparse solver; numpy does it,
and SciPy's ``least_squares`` is the tests' oracle, not a dependency.

Before solving, each detection is matched to a cone: a first mount from PnP on the images
with the most cones (``vnav.multiview``), then, at each round, the apex projected with the
current estimate, mutual nearest within a gate that narrows as the estimate improves.

After solving, the parameters' covariance is the sum of two terms, each for an error the
other misses. (Measured over 20 flights of the ``calibration`` built-in with random mounts, at
20 Hz: ``(J^T J)^-1`` scaled by the residual variance put the truth beyond 3 standard errors
in 13 of them; at least 0.3 px of residual scale hid that, but left the camera's translation
along its axis 2.2 standard errors off on average. With these two terms: 20 of 20, every
parameter's error about 1 standard error RMS.)

- the apexes' own errors, by the cluster-robust ("sandwich") covariance with each image a
  cluster, ``(J^T J)^-1 (sum_g J_g^T r_g r_g^T J_g) (J^T J)^-1 G / (G - 1)`` (Cameron & Miller,
  "A Practitioner's Guide to Cluster-Robust Inference", J. Human Resources 50(2), 2015): an
  apex's vertical error is four times its horizontal one, and the apexes of one image share its
  pose; a single residual variance ``sigma^2 (J^T J)^-1`` is wrong on both counts;
- the intrinsics' error, which no amount of flight averages out, by a consider covariance
  (Tapley, Schutz & Born, *Statistical Orbit Determination*, 2004, ch. 6): the focal length
  taken as known but uncertain by ``FOCAL_SCALE_STD``, its effect on the answer
  ``dx/ds = -(J^T J)^-1 J^T (uv - c)`` (the apexes' pixels scaled about the principal point),
  ``cov += FOCAL_SCALE_STD^2 dx/ds dx/ds^T``. It mostly widens the camera's translation along
  its optical axis, which a focal length error mimics (the cones all 6-14 m away).

A flight whose standard errors exceed ``MAX_STD_*`` (too few cones, no rotation to reveal the
clock offset) is refused with what is missing, not answered with a guess; so is a flight that
does not turn about each of the body's three axes by ``MIN_TURN_DEG``, whatever its standard
errors say: seen from one family of attitudes the mount's weakly determined directions (a
sideways shift against a turn about the camera's vertical, for cones far off) keep whatever
small systematic error the apexes have instead of averaging it out. (The ``multi-cone``
built-in, yawing only: 6-8 mm and 0.06-0.07 deg off, 3.6 standard errors.)
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass

import numpy as np

from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.frames import FrameBuffer
from vnav.least_squares import levenberg_marquardt
from vnav.multiview import REPROJECTION_GATE_PX, camera_pose_from_apexes, unambiguous_pose

logger = logging.getLogger(__name__)

__all__ = ["CalibrationError", "CalibrationResult", "calibrate_camera"]

MIN_OBSERVATIONS = 30
"""Apexes matched over the flight, at least."""

MIN_FRAMES = 5
"""Images with at least one matched apex, at least."""

PIXEL_STD_FLOOR = 0.05
"""The apexes' error assumed at least, px, whatever the residuals (``(J^T J)^-1`` times its
square is added): a fit whose few residuals happen to cancel is not believed beyond a
twentieth of a pixel (a rendered apex's horizontal error is about 0.06 px, its vertical 0.25)."""

FOCAL_SCALE_STD = 2e-4
"""The focal length's relative uncertainty the covariance considers (see the module's
docstring). Measured on the renderer: at the true mount and offset the re-fitted apexes lie
1.5e-4 of their distance from the principal point further out than ``PinholeCamera.from_fovy``
projects them, in u and v alike (a focal length 1.5e-4 short; 20 flights of the
``calibration`` built-in with random mounts)."""

MAX_STD_ROTATION_DEG = 0.025
MAX_STD_TRANSLATION_M = 0.0025
MAX_STD_OFFSET_S = 0.0005
"""The largest standard errors accepted (the largest over the axes): beyond them the flight
does not determine the mount or the offset, and the answer is refused. Half the
``calibration`` built-in's gates (0.05 deg, 5 mm, 1 ms): an answer accepted lies within them
at two standard errors."""

MIN_TURN_DEG = 2.0
"""The body's attitude over the images used must spread by at least this much (RMS, degrees)
about each of its three axes: roll, pitch and yaw."""

OUTLIER_SIGMAS = 4.0
"""Apexes whose reprojection error exceeds this many robust standard deviations are dropped
after the matching rounds (Gaussian 2-D errors: 1 in 3000 beyond 4 sigma)."""

PNP_RMS_PX = 3.0
"""A first mount's PnP pose is kept only if its apexes reproject within this RMS, px."""

GATES_PX = (25.0, 8.0, 4.0)
"""Matching gates of the successive rounds, px: the first tolerates the offset's and the PnP
mount's error, the last only the detector's."""


class CalibrationError(ValueError):
    """The flight does not determine the mount or the clock offset; the message says why."""


@dataclass(frozen=True)
class CalibrationResult:
    """The recovered mount and clock offset, and how well they are determined.

    Attributes
    ----------
    T_b_c : ndarray, shape (4, 4)
        The camera (optical frame) in the body.
    time_offset_s : float
        ``t_pose = t_cam + time_offset_s``.
    reprojection_rms_px : float
        RMS of the final reprojection errors.
    frames_used : int
        Images with at least one matched apex.
    observations_used : int
        Matched apexes.
    std_rotation_deg, std_translation_m, std_offset_s : float
        Standard errors: the mount's rotation (the largest over the three axes), its
        translation (likewise) and the offset.
    covariance : ndarray, shape (7, 7)
        The covariance of ``[xi, time_offset_s]``: ``xi`` the error of ``T_b_c`` in the camera
        frame (``T_b_c_true = T_b_c @ exp(xi^)``, translation first, m and rad), the offset in
        seconds. The standard errors are the square roots of its diagonal.
    """

    T_b_c: np.ndarray
    time_offset_s: float
    reprojection_rms_px: float
    frames_used: int
    observations_used: int
    std_rotation_deg: float
    std_translation_m: float
    std_offset_s: float
    covariance: np.ndarray


def calibrate_camera(
    camera: PinholeCamera,
    pose_stamps_s: np.ndarray,
    T_w_b: np.ndarray,
    image_stamps_cam_s: np.ndarray,
    apex_uv: list[np.ndarray],
    apex_w: np.ndarray,
    T_b_c_guess: np.ndarray,
    *,
    max_offset_s: float = 0.1,
    refuse_undetermined: bool = True,
) -> CalibrationResult:
    """Recover ``T_b_c`` and the camera's clock offset from a flight.

    Parameters
    ----------
    camera : PinholeCamera
    pose_stamps_s : ndarray, shape (M,)
        Pose-clock stamps of the pose stream, increasing.
    T_w_b : ndarray, shape (M, 4, 4)
        The body poses of the stream.
    image_stamps_cam_s : ndarray, shape (N,)
        Each image's exposure stamp on the camera clock.
    apex_uv : list of N arrays of shape (K_i, 2)
        The apexes detected in each image (any order, unmatched).
    apex_w : ndarray, shape (C, 3)
        The map: each cone's apex in the world.
    T_b_c_guess : ndarray, shape (4, 4)
        The declared mount (the starting point; the matching's first round does not need it
        close: PnP gives the first estimate).
    max_offset_s : float
        Images whose stamp +- this falls outside the pose stream are left out, so that every
        offset tried stays inside it.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ValueError
        On malformed input: shapes that do not match, a stamp, apex or pixel that is not
        finite (named), ``max_offset_s`` not a finite number >= 0.
    CalibrationError
        Too few matched apexes or images, or a mount or offset the flight does not determine
        (its standard error above ``MAX_STD_*``): the message names what is missing.
    """
    stamps, T_w_b, t_cam, P = _checked(
        pose_stamps_s, T_w_b, image_stamps_cam_s, apex_uv, apex_w, max_offset_s
    )
    T_b_c_guess = se3.check_pose(T_b_c_guess, "T_b_c_guess")
    problem = _problem(camera, stamps, T_w_b, t_cam, apex_uv, P, T_b_c_guess, max_offset_s)
    x = _fit_gated(problem)
    x = _fit_without_outliers(problem, x)
    return problem.result(x, refuse_undetermined=refuse_undetermined)


def _problem(
    camera: PinholeCamera,
    stamps: np.ndarray,
    T_w_b: np.ndarray,
    t_cam: np.ndarray,
    apex_uv: list[np.ndarray],
    P: np.ndarray,
    T_b_c_guess: np.ndarray,
    max_offset_s: float,
) -> _Problem:
    """The problem of ``calibrate_camera``'s checked inputs: the pose stream in a frame
    buffer, and the images that have apexes and whose stamp +- ``max_offset_s`` lies inside
    the stream, each ``(t_cam_s, uv (K, 2))``."""
    buffer = FrameBuffer(cache_s=max(float(stamps[-1] - stamps[0]) + 1.0, 1.0))
    buffer.set_transform("world", "body", stamps, T_w_b)
    inside = (t_cam - max_offset_s >= stamps[0]) & (t_cam + max_offset_s <= stamps[-1])
    images = [
        (float(t_cam[i]), np.asarray(apex_uv[i], dtype=np.float64).reshape(-1, 2))
        for i in np.flatnonzero(inside)
    ]
    images = [(t, uv) for t, uv in images if len(uv)]
    return _Problem(camera, buffer, images, P, T_b_c_guess, max_offset_s=max_offset_s)


def _fit_gated(problem: _Problem) -> np.ndarray:
    """``x = [xi, offset]`` (7,) from PnP's first mount, matched and solved once per gate of
    ``GATES_PX`` (each round's match made with the previous round's answer).

    Raises
    ------
    CalibrationError
        If a round matches fewer than ``MIN_OBSERVATIONS`` apexes or ``MIN_FRAMES`` images.
    """
    x = np.zeros(7)
    x[:6] = problem.first_mount()
    for gate in GATES_PX:
        problem.match(x, gate)
        if problem.n_observations < MIN_OBSERVATIONS or problem.n_frames < MIN_FRAMES:
            raise CalibrationError(
                f"too few cones seen: {problem.n_observations} apexes matched in "
                f"{problem.n_frames} images (need {MIN_OBSERVATIONS} in {MIN_FRAMES})"
            )
        x = _levenberg_marquardt(problem.residuals, x)
    return x


def _fit_without_outliers(problem: _Problem, x: np.ndarray) -> np.ndarray:
    """``x`` solved again without the outlying apexes (up to twice), which ``problem`` then
    no longer holds."""
    # Outliers (a cone's blob merged with another's, a mismatch the gate let through) would
    # pull a least-squares fit: drop apexes off by more than OUTLIER_SIGMAS robust standard
    # deviations (the median absolute deviation's, 1.4826 MAD) and solve again.
    for _ in range(2):
        norms = np.linalg.norm(problem.residuals(x).reshape(-1, 2), axis=1)
        sigma = max(1.4826 * float(np.median(norms)) / math.sqrt(2.0 * math.log(2.0)), 0.1)
        keep = norms <= OUTLIER_SIGMAS * sigma
        if keep.all():
            break
        problem.keep(keep)
        x = _levenberg_marquardt(problem.residuals, x)
    return x


def _checked(
    pose_stamps_s, T_w_b, image_stamps_cam_s, apex_uv, apex_w, max_offset_s
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``calibrate_camera``'s inputs validated (its Raises): the stamps (M,), the poses
    (M, 4, 4), the image stamps (N,) and the map (C, 3) as float64 arrays."""
    stamps = np.asarray(pose_stamps_s, dtype=np.float64)
    T_w_b = se3.check_transform(T_w_b, "T_w_b")
    if stamps.ndim != 1 or T_w_b.shape != (stamps.size, 4, 4) or stamps.size < 2:
        raise ValueError("pose_stamps_s (M,) and T_w_b (M, 4, 4) must match, M >= 2")
    t_cam = np.asarray(image_stamps_cam_s, dtype=np.float64)
    if t_cam.ndim != 1 or len(apex_uv) != t_cam.size:
        raise ValueError("image_stamps_cam_s (N,) and apex_uv (N arrays) must match")
    P = np.asarray(apex_w, dtype=np.float64).reshape(-1, 3)
    # Checked here, by name: past this point NaN reaches OpenCV's PnP (a cv2.error) or the
    # pose buffer's interval tests (which NaN passes silently).
    for name, values in (("pose_stamps_s", stamps), ("image_stamps_cam_s", t_cam), ("apex_w", P)):
        if not np.isfinite(values).all():
            raise ValueError(f"{name} must be finite; it holds NaN or inf")
    for i, uv in enumerate(apex_uv):
        uv = np.asarray(uv, dtype=np.float64)
        if uv.size and (uv.ndim != 2 or uv.shape[1] != 2):
            raise ValueError(f"apex_uv[{i}] must have shape (K, 2), got {uv.shape}")
        if not np.isfinite(uv).all():
            raise ValueError(f"apex_uv[{i}] must be finite; it holds NaN or inf")
    if isinstance(max_offset_s, bool) or not (
        isinstance(max_offset_s, int | float) and 0.0 <= max_offset_s < math.inf
    ):
        raise ValueError(f"max_offset_s must be a finite number >= 0, got {max_offset_s!r}")
    return stamps, T_w_b, t_cam, P


class _Problem:
    """The matched observations and the residual function of ``x = [xi, offset]``."""

    def __init__(
        self, camera, buffer, images, apex_w, T_b_c_guess, *, max_offset_s: float = math.inf
    ) -> None:
        self.camera, self.buffer, self.images = camera, buffer, images
        self.apex_w, self.T_b_c_guess = apex_w, T_b_c_guess
        self.max_offset_s = max_offset_s
        self.t = np.array([t for t, _ in images])
        self.obs_image = np.zeros(0, dtype=np.int64)
        self.obs_cone = np.zeros(0, dtype=np.int64)
        self.obs_uv = np.zeros((0, 2))
        # The pose stream looked up at the images' stamps under an offset: a Jacobian's six
        # mount columns share the offset, so most evaluations look up the same poses.
        self._T_w_b_at: dict[float, np.ndarray] = {}

    @property
    def n_observations(self) -> int:
        return int(self.obs_image.size)

    @property
    def n_frames(self) -> int:
        return int(np.unique(self.obs_image).size)

    def T_b_c(self, x: np.ndarray) -> np.ndarray:
        return self.T_b_c_guess @ se3.exp(x[:6])

    def first_mount(self) -> np.ndarray:
        """``xi`` of the mount from PnP on the images with the most apexes (up to 5): each gives
        ``T_b_c = T_w_b(t)^-1 T_w_c``; the one nearest the others (a medoid) is kept.

        The apexes are matched to the map by projecting it through the declared mount (a
        mount a few degrees off moves them tens of pixels); only an image where that match
        gives no pose is searched without a prior, every ordered choice of 4 cones."""
        ranked = sorted(range(len(self.images)), key=lambda i: -len(self.images[i][1]))
        mounts = []
        for i in ranked[:5]:
            T_w_c = self._pnp(i)
            if T_w_c is not None:
                mounts.append(se3.invert(self.buffer.lookup("world", "body", self.t[i])) @ T_w_c)
        if not mounts:
            logger.info("calibration: no image gave a PnP pose; starting from the declared mount")
            return np.zeros(6)
        spread = [sum(_distance(a, b) for b in mounts) for a in mounts]
        best = mounts[int(np.argmin(spread))]
        return se3.log(se3.invert(self.T_b_c_guess) @ best)

    def _pnp(self, i: int) -> np.ndarray | None:
        """The camera pose of image ``i`` from its apexes, or None: matched to the map under
        the declared mount, else without a prior (``vnav.multiview.camera_pose_from_apexes``)."""
        t, uv = self.images[i]
        if len(uv) < 4:
            return None
        T_w_c_prior = self.buffer.lookup("world", "body", t) @ self.T_b_c_guess
        for prior in (T_w_c_prior, None):
            try:
                fit, found = camera_pose_from_apexes(
                    self.camera, self.apex_w, uv, T_w_c_prior=prior
                )
                # A cone matched to its neighbour's apex leaves it pixels off; IPPE's second
                # solution, as good a fit, is chosen by the declared mount or refused.
                if fit.rms_px >= PNP_RMS_PX or fit.residuals_px.max() > REPROJECTION_GATE_PX:
                    continue
                fit, _ = unambiguous_pose(self.camera, self.apex_w, uv, fit, found, T_w_c_prior)
            except ValueError:
                continue
            return fit.T_w_c
        return None

    def match(self, x: np.ndarray, gate_px: float) -> None:
        """Match every image's apexes to the map's under ``x``."""
        T_w_c = self._poses(x)
        image, cone, uv = [], [], []
        for i, (_, pixels) in enumerate(self.images):
            for k, c in _mutual_nearest(self.camera, T_w_c[i], self.apex_w, pixels, gate_px):
                image.append(i)
                cone.append(c)
                uv.append(pixels[k])
        self.obs_image = np.array(image, dtype=np.int64)
        self.obs_cone = np.array(cone, dtype=np.int64)
        self.obs_uv = np.array(uv, dtype=np.float64).reshape(-1, 2)

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the observations where ``mask`` is True."""
        self.obs_image = self.obs_image[mask]
        self.obs_cone = self.obs_cone[mask]
        self.obs_uv = self.obs_uv[mask]

    def _poses(self, x: np.ndarray) -> np.ndarray:
        """``T_w_c`` of every image under ``x``, (N, 4, 4)."""
        # The offset held within +-max_offset_s, where every image's pose lies inside the
        # stream: a Levenberg-Marquardt step (or a difference step) beyond it would extrapolate.
        offset = min(max(float(x[6]), -self.max_offset_s), self.max_offset_s)
        T_w_b = self._T_w_b_at.get(offset)
        if T_w_b is None:
            if len(self._T_w_b_at) >= 16:
                self._T_w_b_at.clear()
            T_w_b = self._T_w_b_at[offset] = self.buffer.lookup("world", "body", self.t + offset)
        return T_w_b @ self.T_b_c(x)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Reprojection errors of the matched apexes, (2 K,) px."""
        # ``se3.invert`` less its check: the poses are products of checked rigid transforms.
        T_w_c = self._poses(x)
        Rt = np.swapaxes(T_w_c[:, :3, :3], -1, -2)
        T_c_w = np.zeros_like(T_w_c)
        T_c_w[:, :3, :3] = Rt
        T_c_w[:, :3, 3] = -np.matmul(Rt, T_w_c[:, :3, 3, None])[..., 0]
        T_c_w[:, 3, 3] = 1.0
        T_c_w = T_c_w[self.obs_image]
        p_c = (
            np.einsum("nij,nj->ni", T_c_w[:, :3, :3], self.apex_w[self.obs_cone]) + T_c_w[:, :3, 3]
        )
        z = np.maximum(p_c[:, 2], 1e-6)
        u = self.camera.fx * p_c[:, 0] / z + self.camera.cx
        v = self.camera.fy * p_c[:, 1] / z + self.camera.cy
        return (np.column_stack([u, v]) - self.obs_uv).ravel()

    def _residuals_reference(self, x: np.ndarray) -> np.ndarray:
        """``residuals`` as first written (kept to test it): the pose stream looked up at
        every call, the poses inverted by ``se3.invert``."""
        offset = min(max(float(x[6]), -self.max_offset_s), self.max_offset_s)
        T_w_b = self.buffer.lookup("world", "body", self.t + offset)
        T_c_w = se3.invert(T_w_b @ self.T_b_c(x))[self.obs_image]
        p_c = (
            np.einsum("nij,nj->ni", T_c_w[:, :3, :3], self.apex_w[self.obs_cone]) + T_c_w[:, :3, 3]
        )
        z = np.maximum(p_c[:, 2], 1e-6)
        u = self.camera.fx * p_c[:, 0] / z + self.camera.cx
        v = self.camera.fy * p_c[:, 1] / z + self.camera.cy
        return (np.column_stack([u, v]) - self.obs_uv).ravel()

    def result(self, x: np.ndarray, *, refuse_undetermined: bool = True) -> CalibrationResult:
        r = self.residuals(x)
        rms = float(np.sqrt(np.mean(r**2) * 2.0))  # per apex: sqrt(du^2 + dv^2)
        if abs(float(x[6])) >= self.max_offset_s - 1e-6:
            # Held at its bound, the offset has no derivative: no standard error to give.
            raise CalibrationError(
                f"the flight does not determine the clock offset within +-{self.max_offset_s:g} s "
                "(the answer reached that bound): it needs rotation or faster motion, or the "
                "true offset lies beyond the bound (a larger max_offset_s)"
            )
        cov = self.covariance(x, r)
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        std_rot_deg = math.degrees(float(std[3:6].max()))
        std_t_m, std_offset = float(std[:3].max()), float(std[6])
        missing = []
        turn_deg = self.turn_rms_deg(x)
        if not (turn_deg >= MIN_TURN_DEG).all():
            missing.append(
                "the mount: the flight turns too little about some axis (RMS roll "
                f"{turn_deg[0]:.1f}, pitch {turn_deg[1]:.1f}, yaw {turn_deg[2]:.1f} deg, need "
                f">= {MIN_TURN_DEG:g} each): seen from one family of attitudes, the apexes' "
                "small systematic errors do not average out; fly rolling, pitching and yawing"
            )
        if not std_offset <= MAX_STD_OFFSET_S:
            missing.append(
                f"the clock offset (standard error {std_offset * 1e3:.3g} ms, need <= "
                f"{MAX_STD_OFFSET_S * 1e3:g} ms): the flight needs rotation or faster motion"
            )
        if not std_rot_deg <= MAX_STD_ROTATION_DEG or not std_t_m <= MAX_STD_TRANSLATION_M:
            missing.append(
                f"the mount (standard errors {std_rot_deg:.3g} deg, {std_t_m * 1e3:.3g} mm, need "
                f"<= {MAX_STD_ROTATION_DEG:g} deg, {MAX_STD_TRANSLATION_M * 1e3:g} mm): more "
                "cones, seen from more directions"
            )
        if missing and refuse_undetermined:
            raise CalibrationError("the flight does not determine " + "; nor ".join(missing))
        return CalibrationResult(
            T_b_c=self.T_b_c(x),
            time_offset_s=float(x[6]),
            reprojection_rms_px=rms,
            frames_used=self.n_frames,
            observations_used=self.n_observations,
            std_rotation_deg=std_rot_deg,
            std_translation_m=std_t_m,
            std_offset_s=std_offset,
            covariance=cov,
        )

    def turn_rms_deg(self, x: np.ndarray) -> np.ndarray:
        """The body's attitude spread over the images used, (3,) degrees: the RMS about each
        body axis of its rotation from the middle image's (``so3.log(R_mid^T R)``)."""
        used = np.unique(self.obs_image)
        R = self._poses(x)[used, :3, :3] @ self.T_b_c(x)[:3, :3].T  # R_w_b
        w = so3.log(np.einsum("ji,njk->nik", R[len(R) // 2], R))
        return np.degrees(np.sqrt(np.mean((w - w.mean(axis=0)) ** 2, axis=0)))

    def covariance(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The covariance of ``[xi, offset]`` at the answer ``x`` (``xi`` the mount's error in
        the answer's camera frame, ``CalibrationResult.covariance``), (7, 7): the image-
        clustered sandwich plus the floor plus the focal length's consider term (the module's
        docstring); all inf where ``J^T J`` is singular."""
        local = copy.copy(self)
        local.T_b_c_guess = self.T_b_c(x)
        J = _jacobian(local.residuals, np.r_[np.zeros(6), x[6]])
        try:
            A = np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            return np.full((7, 7), np.inf)
        if not np.isfinite(A).all():
            return np.full((7, 7), np.inf)
        scores = np.zeros((self.t.size, 7))
        np.add.at(scores, self.obs_image, (J * r[:, None]).reshape(-1, 2, 7).sum(axis=1))
        clusters = max(self.n_frames, 2)
        meat = scores.T @ scores * (clusters / (clusters - 1.0))
        projected = (r.reshape(-1, 2) + self.obs_uv - [self.camera.cx, self.camera.cy]).ravel()
        dx_ds = A @ (J.T @ projected)
        return A @ meat @ A + PIXEL_STD_FLOOR**2 * A + FOCAL_SCALE_STD**2 * np.outer(dx_ds, dx_ds)


_STEPS = np.array([1e-6] * 6 + [1e-4])
"""Central-difference steps: metres and radians of the mount, seconds of the offset (the pose
is linear between samples 5 ms apart: a 0.1 ms step stays within one or two pieces)."""


def _jacobian(f, x: np.ndarray) -> np.ndarray:
    columns = []
    for i, h in enumerate(_STEPS):
        e = np.zeros_like(x)
        e[i] = h
        columns.append((f(x + e) - f(x - e)) / (2.0 * h))
    return np.column_stack(columns)


def _levenberg_marquardt(f, x: np.ndarray, iterations: int = 50) -> np.ndarray:
    """Minimise ``|f(x)|^2`` (``vnav.least_squares``), the normal equations from the
    numerical Jacobian, stopping when the step or the gain is negligible."""

    def normal_equations(x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        J = _jacobian(f, x)
        return J.T @ J, J.T @ r

    return levenberg_marquardt(
        f, normal_equations, x, iterations=iterations, gain_tol=1e-12, step_tol=1e-12
    )


def _mutual_nearest(
    camera: PinholeCamera, T_w_c: np.ndarray, apex_w: np.ndarray, uv: np.ndarray, gate_px: float
) -> list[tuple[int, int]]:
    """``(detection, cone)`` pairs: each the other's nearest, within ``gate_px``."""
    T_c_w = se3.invert(T_w_c)
    p_c = apex_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    proj = np.full((len(apex_w), 2), np.inf)
    front = p_c[:, 2] > 0.1
    proj[front] = camera.project(p_c[front])
    d = np.linalg.norm(uv[:, None, :] - proj[None, :, :], axis=2)
    if not len(uv):
        return []
    # Each detection's nearest cone and each cone's nearest detection, every row and column
    # at once (``_mutual_nearest_reference`` is the same, detection by detection).
    k = np.arange(len(uv))
    c = np.argmin(d, axis=1)
    mutual = (d[k, c] <= gate_px) & (np.argmin(d, axis=0)[c] == k)
    return list(zip(k[mutual].tolist(), c[mutual].tolist(), strict=True))


def _mutual_nearest_reference(
    camera: PinholeCamera, T_w_c: np.ndarray, apex_w: np.ndarray, uv: np.ndarray, gate_px: float
) -> list[tuple[int, int]]:
    """``_mutual_nearest`` detection by detection, as the definition reads (kept to test it)."""
    T_c_w = se3.invert(T_w_c)
    p_c = apex_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
    proj = np.full((len(apex_w), 2), np.inf)
    front = p_c[:, 2] > 0.1
    proj[front] = camera.project(p_c[front])
    d = np.linalg.norm(uv[:, None, :] - proj[None, :, :], axis=2)
    pairs = []
    for k in range(len(uv)):
        c = int(np.argmin(d[k]))
        if d[k, c] <= gate_px and int(np.argmin(d[:, c])) == k:
            pairs.append((k, c))
    return pairs


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """A mount-to-mount distance: rotation angle (rad) plus translation (m) over 0.1 m."""
    rot = float(np.linalg.norm(so3.log(a[:3, :3].T @ b[:3, :3])))
    return rot + float(np.linalg.norm(a[:3, 3] - b[:3, 3])) / 0.1
