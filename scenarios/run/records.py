"""What a run saw and computed, camera tick by camera tick: typed records, no simulator.

A scenario's run is a list of ``TickRecord``, one per camera tick, each holding what the
camera saw (the detections), what each method estimated and the ground truth it is compared
with. The runner (``scenarios.run.runner``) makes them, the checks
(``scenarios.judge.checks``) and the report (``scenarios.judge.report``) read them, and the
recording (``scenarios.record.recording``) draws them. This module imports neither MuJoCo
nor Rerun, so judging or reporting a run needs neither.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from vnav import se3
from vnav.detect import ConeDetection

if TYPE_CHECKING:
    from scenarios.scenario.spec import ScenarioSpec
    from vnav.estimators import NoEstimate

__all__ = [
    "Contact",
    "DetectionRecord",
    "ImageTiming",
    "ImuCalibrationRecord",
    "ImuRecord",
    "NavigationRecord",
    "NavigationTick",
    "PoseStream",
    "RunResult",
    "TickRecord",
]


@dataclass(frozen=True)
class DetectionRecord:
    """One detection of one camera tick, with its estimates and their errors.

    Attributes
    ----------
    detection : ConeDetection
        What the detector found in the image.
    estimates_w : dict of str to ndarray, shape (3,)
        Base centre in the world per method that gave an estimate, metres.
    cone_index : int or None
        The true cone it was matched to, or None.
    errors_m : dict of str to float
        Distance of each estimate from the matched cone, metres (empty when unmatched).
    range_m : float or None
        Distance from the camera to the matched cone, metres.
    p_c_true : ndarray, shape (3,), or None
        The matched cone's true base centre in the camera (optical) frame.
    in_contract : bool
        The matched cone is in the accuracy contract's domain (``vnav.methods.CONTRACT_DOMAIN``):
        fully in view, tall enough, at a range within the bounds.
    no_estimate : dict of str to NoEstimate
        Why each method that gave no estimate gave none (``vnav.estimators.NoEstimate``).
    latest_w : ndarray, shape (3,), or None
        The ``depth_image`` estimate made with the newest pose received when the image arrived
        instead of the pose at exposure (what a pipeline ignoring stamps computes), or None.
    latest_error_m : float or None
        Its distance from the matched cone, metres.
    predicted_latest_error_m : float or None
        The first-order prediction of that error from the body's true motion between the
        exposure and the newest pose's stamp: ``|dp| + range |dtheta|`` (``ImageTiming``).
    covariances_w : dict of str to ndarray, shape (3, 3)
        Each estimate's world covariance, m^2 (``vnav.localize``), for the methods in
        ``estimates_w``.
    nees : dict of str to tuple of (float, int)
        Per method with an error: the normalised estimation error squared against the matched
        cone and its degrees of freedom, the covariance's rank (``vnav.uncertainty.nees``).
    depth_under_mask_m : ndarray, shape (area_px,), or None
        The depth image's values under the detection's mask, in the image's dtype and in
        ``detection.pixels_uv()`` order: all the depth any method reads of it, kept (only when
        the run asks, ``scenarios.run.evaluate.evaluate_tick``) so that the run's images can
        be estimated again with another camera mount (``reevaluate``).
    """

    detection: ConeDetection
    estimates_w: dict[str, np.ndarray]
    cone_index: int | None = None
    errors_m: dict[str, float] = field(default_factory=dict)
    range_m: float | None = None
    p_c_true: np.ndarray | None = None
    in_contract: bool = False
    no_estimate: dict[str, NoEstimate] = field(default_factory=dict)
    latest_w: np.ndarray | None = None
    latest_error_m: float | None = None
    predicted_latest_error_m: float | None = None
    covariances_w: dict[str, np.ndarray] = field(default_factory=dict)
    nees: dict[str, tuple[float, int]] = field(default_factory=dict)
    depth_under_mask_m: np.ndarray | None = None


@dataclass(frozen=True)
class ImageTiming:
    """When one image was taken, stamped and received, and which poses the estimator used.

    Times are on the pose clock (the simulator's) unless said otherwise
    (docs/CONVENTIONS.md, "Time and stamps").

    Attributes
    ----------
    stamp_cam_s : float
        The exposure stamp the image carries, on the camera clock.
    exposure_pose_s : float
        That stamp read on the pose clock (``stamp_cam_s + camera_clock_offset_s``): where the
        estimator looked its pose up. It equals the true exposure time.
    arrival_s : float
        When the image reached the estimator.
    latest_pose_s : float or None
        Stamp of the newest pose received by then (None if none had arrived).
    T_w_b_latest : ndarray, shape (4, 4), or None
        That pose (with the scenario's pose noise, as received).
    true_motion_m : float
        How far the body truly moved between ``exposure_pose_s`` and ``latest_pose_s``,
        metres (0 without a latest pose).
    true_motion_rad : float
        How far it truly turned over the same interval, radians.
    """

    stamp_cam_s: float
    exposure_pose_s: float
    arrival_s: float
    latest_pose_s: float | None
    T_w_b_latest: np.ndarray | None
    true_motion_m: float = 0.0
    true_motion_rad: float = 0.0

    @property
    def image_latency_s(self) -> float:
        """Seconds from exposure to arrival."""
        return self.arrival_s - self.exposure_pose_s

    @property
    def latest_minus_exposure_s(self) -> float | None:
        """The newest pose's stamp minus the exposure stamp, seconds: the ``dt`` of the stale
        pose's error ``|v| dt + range |omega| dt`` (negative when the newest pose is older)."""
        return None if self.latest_pose_s is None else self.latest_pose_s - self.exposure_pose_s


@dataclass(frozen=True)
class PoseStream:
    """The pose samples the estimator was sent, as stamped (noise included).

    Attributes
    ----------
    stamps_s : ndarray, shape (N,)
        Pose-clock stamps, increasing.
    T_w_b : ndarray, shape (N, 4, 4)
        The poses sent.
    arrivals_s : ndarray, shape (N,)
        When each reached the estimator.
    """

    stamps_s: np.ndarray
    T_w_b: np.ndarray
    arrivals_s: np.ndarray


@dataclass(frozen=True)
class TickRecord:
    """What one camera tick saw and computed, next to the truth.

    Attributes
    ----------
    tick : int
        Index of the camera tick, from 0.
    t_s : float
        Simulated time, seconds.
    T_w_b : ndarray, shape (4, 4)
        True body pose in the world.
    T_w_b_est : ndarray, shape (4, 4)
        The body pose the estimator was given (the truth plus the scenario's pose noise).
    T_b_c : ndarray, shape (4, 4)
        The true camera mount at this tick (optical frame in the body).
    T_b_c_est : ndarray, shape (4, 4)
        The mount the estimator was told: the declared one (``[camera]``), with the run's
        extrinsic noise (``[noise]``); the truth is ``[camera.mount_error]`` away from it.
    quat_xyzw : ndarray, shape (4,)
        True attitude ``R_w_b`` as a quaternion, scalar last.
    rpy_rad : ndarray, shape (3,)
        Roll, pitch, yaw of ``R_w_b`` (``vnav.so3.to_rpy``), radians.
    gimbal_locked : bool
        Whether those angles are at the gimbal lock.
    cones_in_view : list of int
        True cones fully in view and tall enough to count for the detection rate.
    detections : list of DetectionRecord
    reference_error_m : float or None
        Distance of the body from the flight's reference position (controlled flights).
    timing : ImageTiming or None
        The image's stamps and arrival and the poses used (None for a tick not made by the
        runner's streams, e.g. in a unit test).
    cov_T_w_b_est : ndarray, shape (6, 6), or None
        The covariance the estimator was told for ``T_w_b_est`` (None: exact).
    v_w_b_mps : ndarray, shape (3,), or None
        The body origin's true velocity in the world at ``t_s``, m/s: MuJoCo's (the free
        joint's) in a flight with dynamics, the keyframes' (``sim.flight.KeyframeTrajectory``)
        in a kinematic one; None for a tick not made by the runner.
    """

    tick: int
    t_s: float
    T_w_b: np.ndarray
    T_w_b_est: np.ndarray
    T_b_c: np.ndarray
    T_b_c_est: np.ndarray
    quat_xyzw: np.ndarray
    rpy_rad: np.ndarray
    gimbal_locked: bool
    cones_in_view: list[int]
    detections: list[DetectionRecord]
    reference_error_m: float | None = None
    timing: ImageTiming | None = None
    cov_T_w_b_est: np.ndarray | None = None
    v_w_b_mps: np.ndarray | None = None

    def estimates_w(self, method: str) -> np.ndarray:
        """Every estimate of ``method`` at this tick, one row per detection giving one, (K, 3)."""
        points = [d.estimates_w[method] for d in self.detections if method in d.estimates_w]
        return np.array(points, dtype=np.float64).reshape(-1, 3)

    def mean_error_m(self, method: str) -> float | None:
        """Mean error of ``method`` over the matched detections, metres, or None."""
        errors = [d.errors_m[method] for d in self.detections if method in d.errors_m]
        return float(np.mean(errors)) if errors else None

    def mean_range_m(self) -> float | None:
        """Mean range of the matched cones, metres, or None."""
        ranges = [d.range_m for d in self.detections if d.range_m is not None]
        return float(np.mean(ranges)) if ranges else None

    def coordinates_of(self, p_w: np.ndarray) -> dict[str, np.ndarray]:
        """A world point in the world, body and camera frames (the lecture's chapter 8).

        ``p_b = T_b_w p_w`` and ``p_c = T_c_b p_b``.

        Returns
        -------
        dict with keys ``world``, ``body``, ``camera``, each ndarray, shape (3,)
        """
        p_b = se3.apply(se3.invert(self.T_w_b), p_w)
        p_c = se3.apply(se3.invert(self.T_b_c), p_b)
        return {"world": np.asarray(p_w, dtype=np.float64), "body": p_b, "camera": p_c}

    def estimate_of_cone(self, cone_index: int, method: str) -> np.ndarray | None:
        """``method``'s estimate of the detection matched to cone ``cone_index``, or None."""
        return next(
            (
                d.estimates_w[method]
                for d in self.detections
                if d.cone_index == cone_index and method in d.estimates_w
            ),
            None,
        )


@dataclass(frozen=True)
class CalibrationRecord:
    """The camera mount and clock offset recovered from the run (``vnav.calibration``), or why
    they could not be, and their errors against the truth.

    Attributes
    ----------
    T_b_c : ndarray, shape (4, 4), or None
        The recovered mount (camera in body).
    time_offset_s : float or None
    reprojection_rms_px : float or None
    frames_used : int
    errors : dict of str to float
        ``rotation_deg``, ``translation_m``, ``time_offset_s``: absolute errors against the
        true mount and clock offset (empty when refused).
    refused : str or None
        ``vnav.calibration.CalibrationError``'s message when the flight did not determine them.
    T_b_c_declared, T_b_c_true : ndarray, shape (4, 4), or None
        The mount the estimator was told (calibration's first guess) and the simulator's, which
        the errors are against; kept so that the three can be shown side by side.
    ticks_recovered : list of TickRecord or None
        Every camera tick estimated again with the recovered mount in place of the declared
        one, on the same images and poses (``scenarios.run.evaluate.reevaluate``): what
        calibrating gives the estimates, with their errors, covariances only for the
        several-image methods (``estimate_with_mount``) and so no NEES but the tracker's where
        it is a detection's only estimate. None when refused.
    """

    T_b_c: np.ndarray | None
    time_offset_s: float | None
    reprojection_rms_px: float | None
    frames_used: int
    errors: dict[str, float]
    refused: str | None = None
    T_b_c_declared: np.ndarray | None = None
    T_b_c_true: np.ndarray | None = None
    ticks_recovered: list[TickRecord] | None = None


@dataclass(frozen=True)
class ImuCalibrationRecord:
    """The camera-IMU calibration recovered from the run (``vnav.imu_calibration``), or why it
    could not be, and its errors against the truth.

    Attributes
    ----------
    T_i_c : ndarray, shape (4, 4), or None
        The recovered camera (optical frame) in the IMU frame (Kalibr's ``T_cam_imu`` is its
        inverse).
    time_offset_s : float or None
        The recovered ``t_imu = t_cam + time_offset_s`` (Kalibr's ``timeshift_cam_imu``).
    reprojection_rms_px : float or None
    frames_used : int
    errors : dict of str to float
        ``rotation_deg``, ``translation_m``, ``time_offset_s``: absolute errors against the
        truth (empty when refused).
    std : dict of str to float
        The same three's standard errors as the fit gives them (empty when refused).
    refused : str or None
        ``vnav.calibration.CalibrationError``'s message when the flight did not determine it.
    T_i_c_true : ndarray, shape (4, 4), or None
        The simulator's: ``T_b_i^-1 T_b_c`` of the true mounts.
    """

    T_i_c: np.ndarray | None = None
    time_offset_s: float | None = None
    reprojection_rms_px: float | None = None
    frames_used: int = 0
    errors: dict[str, float] = field(default_factory=dict)
    std: dict[str, float] = field(default_factory=dict)
    refused: str | None = None
    T_i_c_true: np.ndarray | None = None


@dataclass(frozen=True)
class Contact:
    """The first contact between the drone and a cone, as MuJoCo found it.

    Attributes
    ----------
    t_s : float
        Simulated time of the physics step that found it, s.
    cone_index : int
        Which cone (``spec.scene.cones_w``).
    point_w : ndarray, shape (3,)
        The contact point in the world, m.
    """

    t_s: float
    cone_index: int
    point_w: np.ndarray


@dataclass(frozen=True)
class NavigationTick:
    """What the navigating drone knew and planned at one camera tick.

    Attributes
    ----------
    t_s : float
        The tick's simulated time, s.
    position_w_est : ndarray, shape (3,)
        Where the drone thought it was (its estimated pose), m: the plan starts there.
    plan_w : ndarray, shape (K, 3)
        The path planned at this tick, from ``position_w_est`` to the goal, m.
    plan_length_m : float
        Its length, m.
    obstacles_w : ndarray, shape (M, 3)
        The mapped cones' estimated base centres, m (``vnav.navigate``).
    clearance_true_m : ndarray, shape (N,)
        MuJoCo's distance between the drone's collision geometry and each true cone's, m.
    obstacle_methods : tuple of str, length M
        The method that put each obstacle of ``obstacles_w`` in the map (``vnav.obstacle_map``).
    rejected : int
        This tick's estimates the map dropped: their base outside the flight band (the naive
        chain's, in the sky).
    """

    t_s: float
    position_w_est: np.ndarray
    plan_w: np.ndarray
    plan_length_m: float
    obstacles_w: np.ndarray
    clearance_true_m: np.ndarray
    obstacle_methods: tuple[str, ...] = ()
    rejected: int = 0


@dataclass
class NavigationRecord:
    """A navigating flight's outcome (``scenarios.scenario.spec.NavigateFlight``).

    Attributes
    ----------
    ticks : list of NavigationTick
        One per camera tick, in order.
    reached_goal_s : float or None
        When the body origin came within the goal radius of the goal, s (None: never).
    contact : Contact or None
        The first contact with a cone (the flight ends there), or None.
    min_clearance_m : float
        The smallest true clearance over the flight (every physics step's, not only the
        camera ticks'), m.
    path_length_m : float
        The length of the path flown (the true body origin, every physics step), m.
    final_distance_m : float
        The body origin's true distance from the goal when the flight ended, m.
    """

    ticks: list[NavigationTick] = field(default_factory=list)
    reached_goal_s: float | None = None
    contact: Contact | None = None
    min_clearance_m: float = float("inf")
    path_length_m: float = 0.0
    final_distance_m: float = float("nan")

    @property
    def reached_goal(self) -> bool:
        """Whether the drone reached its goal (without touching a cone first)."""
        return self.reached_goal_s is not None

    @property
    def collided(self) -> bool:
        """Whether the drone touched a cone."""
        return self.contact is not None


@dataclass(frozen=True)
class ImuRecord:
    """What a scenario's IMU read over the run (``[imu]``; ``sim.imu.ImuSampler``), and how
    closely MuJoCo's noise-free sensors followed ``vnav.imu``'s chain.

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Each reading's stamp on the IMU's clock, seconds (``t_imu = t_cam + time_offset_s``).
    accel_i : ndarray, shape (N, 3)
        Specific force in the IMU frame, m/s^2, noise and bias included.
    gyro_i : ndarray, shape (N, 3)
        Angular rate in the IMU frame, rad/s, noise and bias included.
    max_discrepancy : float
        The largest relative difference between MuJoCo's noise-free sensors and
        ``vnav.imu.specific_force_i`` / ``angular_rate_i`` fed the body's true motion
        (``sim.imu.imu_discrepancy``), over every physics step of the run.
    steps_checked : int
        The physics states compared (the start and every step after it).
    accel_chain_i, gyro_chain_i : ndarray, shape (N, 3), or None
        What ``vnav.imu``'s chain predicts each reading to be without noise (the true motion
        at the reading's physics step; ``sim.imu.chain_imu_i``): the recording plots it
        beside the readings. None where not kept.
    """

    t_s: np.ndarray
    accel_i: np.ndarray
    gyro_i: np.ndarray
    max_discrepancy: float
    steps_checked: int
    accel_chain_i: np.ndarray | None = None
    gyro_chain_i: np.ndarray | None = None


@dataclass
class RunResult:
    """Everything a finished run produced, before it is judged and written.

    Attributes
    ----------
    spec : ScenarioSpec
    seed : int
    ticks : list of TickRecord
    timing_s : dict of str to float
        Seconds spent per stage on the run's thread (``physics``, with reading each image's
        ground truth, ``streams``, ``render``:
        drawing the scene and waiting for what the OpenGL thread had not rendered yet,
        ``detect``, ``localize``, ``navigate``, ``clearance``, ``log``), ``render_gl``: the
        OpenGL thread's rendering, overlapping the stages, and once per run (``setup``: the
        world, the GL context and the recording's start and finish,
        ``scenarios.run.runner.STAGES``); ``scenarios.pipeline``
        adds ``calibrate`` (the calibration and the second estimate with its mount, 0 when
        none), ``judge`` (the checks), ``total`` (wall seconds from the run's start to its
        report) and ``total_cpu`` (the process's user and system seconds over the same span,
        every thread's, and its export process's); the only figures that depend on the
        machine.
    poses : PoseStream or None
        The pose stream the estimator was sent (set when the run ends).
    calibration : CalibrationRecord or None
        The mount and clock offset recovered from the run, for a scenario that checks them
        (``scenarios.pipeline``).
    navigation : NavigationRecord or None
        A navigating flight's plans and outcome (None for any other flight).
    imu : ImuRecord or None
        The IMU's readings, for a scenario that declares ``[imu]`` (None otherwise).
    imu_calibration : ImuCalibrationRecord or None
        The camera-IMU calibration recovered from the run, for a scenario that checks it
        (``scenarios.pipeline``).
    """

    spec: ScenarioSpec
    seed: int
    ticks: list[TickRecord] = field(default_factory=list)
    timing_s: dict[str, float] = field(default_factory=dict)
    poses: PoseStream | None = None
    calibration: CalibrationRecord | None = None
    navigation: NavigationRecord | None = None
    imu: ImuRecord | None = None
    imu_calibration: ImuCalibrationRecord | None = None

    @property
    def cones_w(self) -> np.ndarray:
        """(N, 3) the true cones' base centres in the world, metres."""
        return np.array(self.spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)

    def with_recovered_mount(self) -> RunResult | None:
        """This run with its ticks estimated again with the camera mount calibration
        recovered (``CalibrationRecord.ticks_recovered``), or None if it was not calibrated or
        calibration was refused. Its statistics (``errors``, ``ranges_for``...) are the
        estimates after calibration, as this run's are before it."""
        c = self.calibration
        if c is None or c.ticks_recovered is None:
            return None
        return RunResult(self.spec, self.seed, c.ticks_recovered, poses=self.poses)

    @property
    def trajectory_w(self) -> np.ndarray:
        """(T, 3) the body origin in the world at every tick, metres."""
        return np.array([t.T_w_b[:3, 3] for t in self.ticks], dtype=np.float64).reshape(-1, 3)

    def _scored(self, method: str, contract_only: bool) -> list[DetectionRecord]:
        return [
            d
            for t in self.ticks
            for d in t.detections
            if method in d.errors_m and (d.in_contract or not contract_only)
        ]

    def errors(self, method: str, *, contract_only: bool = False) -> np.ndarray:
        """Errors of ``method`` over matched detections, metres, shape (K,).

        ``contract_only`` keeps only detections in the accuracy contract's domain.
        """
        return np.array(
            [d.errors_m[method] for d in self._scored(method, contract_only)], dtype=np.float64
        )

    def nees(self, method: str) -> tuple[np.ndarray, np.ndarray]:
        """NEES values of ``method`` over matched detections and their degrees of freedom,
        shapes (K,) and (K,)."""
        pairs = [d.nees[method] for t in self.ticks for d in t.detections if method in d.nees]
        a = np.array(pairs, dtype=np.float64).reshape(-1, 2)
        return a[:, 0], a[:, 1].astype(np.int64)

    def latest_pose_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """The latest-pose ``depth_image`` errors and their first-order predictions, metres,
        over matched detections that have both, shapes (K,) and (K,)."""
        pairs = [
            (d.latest_error_m, d.predicted_latest_error_m)
            for t in self.ticks
            for d in t.detections
            if d.latest_error_m is not None and d.predicted_latest_error_m is not None
        ]
        a = np.array(pairs, dtype=np.float64).reshape(-1, 2)
        return a[:, 0], a[:, 1]

    def ranges_for(self, method: str, *, contract_only: bool = False) -> np.ndarray:
        """Ranges of the detections behind ``errors``, same order, metres."""
        return np.array([d.range_m for d in self._scored(method, contract_only)], dtype=np.float64)
