"""The camera mount and clock offset recovered from a finished run, compared with its truth.

The inputs are what the estimator had (``vnav.calibration``): the pose stream as it was sent,
each image's exposure stamp on the camera clock, the detections (their blobs), the cone map
and the declared mount; the truth beside them is what the simulator knows and the estimator
does not (the true mount, the true clock offset). A recording carries the same inputs
(``scenarios.record.reader.calibration_inputs``), blobs included, so that ``vnav-demo
calibrate`` and the run's own calibration make the same two passes (``CalibrationInputs.solve``)
on the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenarios.run.evaluate import reevaluate
from scenarios.run.records import CalibrationRecord, RunResult, TickRecord
from vnav import so3
from vnav.calibration import CalibrationError, CalibrationResult, calibrate_camera
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection
from vnav.frames import ExtrapolationError, FrameBuffer
from vnav.localize import Localizer
from vnav.methods import active_methods
from vnav.plugin import second_pass_methods
from vnav.sensor_noise import mount_covariance
from vnav.silhouette import SilhouetteView

__all__ = [
    "CalibrationInputs",
    "Truth",
    "calibrate_run",
    "calibration_detections",
    "errors_against",
    "estimate_with_mount",
    "inputs_from_run",
]


@dataclass(frozen=True)
class Truth:
    """What the simulator knows and the estimator does not."""

    T_b_c: np.ndarray
    time_offset_s: float


@dataclass(frozen=True)
class CalibrationInputs:
    """Everything ``vnav.calibration.calibrate_camera`` takes, and the truth if known.

    ``apex_uv`` holds the detector's pose-free apexes (about 0.25 px above the true apex);
    ``detections``, where given (one list per image, the same detections clear of the
    border), lets ``solve`` fit each apex again on its blob along the image vertical
    (``SilhouetteView.apex_keypoint``, unbiased), which needs a mount and an offset first.
    """

    camera: PinholeCamera
    pose_stamps_s: np.ndarray
    T_w_b: np.ndarray
    image_stamps_cam_s: np.ndarray
    apex_uv: list[np.ndarray]
    apex_w: np.ndarray
    T_b_c_declared: np.ndarray
    truth: Truth | None = None
    detections: list[list[ConeDetection]] | None = None

    def solve(self) -> CalibrationResult:
        """The mount and offset: with ``detections``, two passes (the detector's apexes give a
        first mount and offset; the apexes fitted again on the blobs under them give the
        answer); without, the one pass on ``apex_uv``.

        Raises
        ------
        vnav.calibration.CalibrationError
            The flight does not determine the mount or the offset, with the reason; a flight
            too short to calibrate says so: fewer than two pose samples, or a clock offset
            the solver's search took outside the flight's pose stream (the offset, unknown
            to the images of a short flight, wandered further than the flight lasts).
        """
        if self.detections is None:
            return self._solve(self.apex_uv)
        # The first pass only starts the second: not refused for its standard errors, which
        # the detector's biased apexes make larger than the answer's.
        first = self._solve(self.apex_uv, refuse_undetermined=False)
        return self._solve(self.refitted_apexes(first.T_b_c, first.time_offset_s))

    def refitted_apexes(self, T_b_c: np.ndarray, time_offset_s: float) -> list[np.ndarray]:
        """Each image's apexes fitted again on the blobs (``SilhouetteView.apex_keypoint``)
        seen from ``T_w_b(t_cam + time_offset_s) @ T_b_c``, the pose stream looked up where
        the calibration puts the exposure; the detector's apex where the fit gives none.
        An image outside the pose stream keeps the detector's apexes (the solver leaves
        it out)."""
        assert self.detections is not None
        stamps = np.asarray(self.pose_stamps_s, dtype=np.float64)
        buffer = FrameBuffer(cache_s=max(float(stamps[-1] - stamps[0]) + 1.0, 1.0))
        buffer.set_transform("world", "body", stamps, self.T_w_b)
        t_pose = np.asarray(self.image_stamps_cam_s, dtype=np.float64) + time_offset_s
        apex_uv = []
        for t, detections, detector_uv in zip(t_pose, self.detections, self.apex_uv, strict=True):
            if not stamps[0] <= t <= stamps[-1]:
                apex_uv.append(detector_uv)
                continue
            T_w_c = buffer.lookup("world", "body", float(t)) @ T_b_c
            points = []
            for d in detections:
                apex = SilhouetteView(d, self.camera, T_w_c).apex_keypoint(TRAFFIC_CONE)
                points.append(d.apex_uv if apex is None else apex)
            apex_uv.append(np.array(points, dtype=np.float64).reshape(-1, 2))
        return apex_uv

    def _solve(
        self, apex_uv: list[np.ndarray], *, refuse_undetermined: bool = True
    ) -> CalibrationResult:
        n_poses, n_images = len(self.pose_stamps_s), len(self.image_stamps_cam_s)
        if n_poses < 2:
            raise CalibrationError(
                f"the flight is too short to calibrate: {n_poses} pose sample(s) and "
                f"{n_images} image(s)"
            )
        try:
            return calibrate_camera(
                self.camera,
                self.pose_stamps_s,
                self.T_w_b,
                self.image_stamps_cam_s,
                apex_uv,
                self.apex_w,
                self.T_b_c_declared,
                refuse_undetermined=refuse_undetermined,
            )
        except ExtrapolationError:
            span_s = float(self.pose_stamps_s[-1] - self.pose_stamps_s[0])
            raise CalibrationError(
                f"the flight ({span_s:.3g} s, {n_images} images) does not determine the clock "
                "offset: the solver's estimate left the pose stream"
            ) from None


def calibration_detections(detections: list[ConeDetection]) -> list[ConeDetection]:
    """The detections calibration uses: those clear of the image border (a cut-off blob's
    apex may be cut off too)."""
    return [d for d in detections if not d.touches_border]


def inputs_from_run(result: RunResult, camera: PinholeCamera) -> CalibrationInputs:
    """The inputs of a finished run (``RunResult.poses`` must be set): the detector's apexes
    and the detections they come from (``calibration_detections``)."""
    if result.poses is None or not result.ticks:
        raise ValueError("the run has no pose stream or no camera ticks to calibrate from")
    stamps = [t.t_s if t.timing is None else t.timing.stamp_cam_s for t in result.ticks]
    detections = [calibration_detections([d.detection for d in t.detections]) for t in result.ticks]
    return CalibrationInputs(
        camera=camera,
        pose_stamps_s=result.poses.stamps_s,
        T_w_b=result.poses.T_w_b,
        image_stamps_cam_s=np.array(stamps),
        apex_uv=[
            np.array([d.apex_uv for d in ds], dtype=np.float64).reshape(-1, 2) for ds in detections
        ],
        apex_w=result.cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
        T_b_c_declared=result.ticks[0].T_b_c_est,
        truth=Truth(result.ticks[0].T_b_c, result.spec.timing.camera_clock_offset_s),
        detections=detections,
    )


def calibrate_run(result: RunResult) -> CalibrationRecord:
    """``vnav.calibration`` on a finished run, compared with its truth.

    Two passes (``CalibrationInputs.solve``): the detector's pose-free apexes give a first
    mount and offset; the apexes re-fitted on their blobs under them (unbiased) give the
    answer, as ``vnav-demo calibrate`` does from the recording. Then every tick is estimated
    again with the recovered mount (``estimate_with_mount``): the estimates after
    calibration, beside the run's own, made with the declared mount.
    """
    cam = result.spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    inputs = inputs_from_run(result, camera)
    mounts = {
        "T_b_c_declared": inputs.T_b_c_declared,
        "T_b_c_true": None if inputs.truth is None else inputs.truth.T_b_c,
    }
    try:
        solved = inputs.solve()
    except CalibrationError as exc:
        return CalibrationRecord(None, None, None, 0, {}, refused=str(exc), **mounts)
    assert inputs.truth is not None
    errors = errors_against(solved, inputs.truth)
    return CalibrationRecord(
        solved.T_b_c,
        solved.time_offset_s,
        solved.reprojection_rms_px,
        solved.frames_used,
        {
            "rotation_deg": errors["rotation_deg"],
            "translation_m": errors["translation_mm"] * 1e-3,
            "time_offset_s": errors["time_offset_ms"] * 1e-3,
        },
        **mounts,
        ticks_recovered=estimate_with_mount(result, camera, solved.T_b_c),
    )


def estimate_with_mount(
    result: RunResult, camera: PinholeCamera, T_b_c: np.ndarray
) -> list[TickRecord]:
    """Every tick of ``result`` estimated again with the camera mount ``T_b_c`` in place of
    the declared one, by a new ``vnav.localize.Localizer`` configured as the run's (camera,
    far plane, the noise it is told, the declared mount's covariance), on the same detections,
    depth and poses (``scenarios.run.evaluate.reevaluate``). A user's function
    (``vnav.plugin``) is called again, with the recovered mount as its ``T_b_c``, by a second
    estimator of its own (``PluginEstimator.second_pass``): the run's calls, failures and
    diagnosis stay those of the declared mount; a function stopped for its time limit in the
    run is not called again.

    Only the estimates' errors are read from this pass (the report's ``recovered_mount``
    statistics, the recording's errors and error-against-range crosses): the single-image
    methods' covariances and every NEES are not computed (``Localizer(with_covariance=
    False)``), so its records have no NEES and covariances only for the several-image
    methods (the apex tracker refuses an estimate by its own)."""
    spec = result.spec
    methods = second_pass_methods(active_methods())
    localizer = Localizer(
        camera, far_m=spec.scene.zfar_m, noise=spec.noise, methods=methods, with_covariance=False
    )
    return reevaluate(
        result.ticks, result.cones_w, localizer, T_b_c, cov_T_b_c=mount_covariance(spec.noise)
    )


def errors_against(result: CalibrationResult, truth: Truth) -> dict[str, float]:
    """The recovered mount and offset against the truth: rotation (deg), translation (mm),
    offset (ms)."""
    R_err = result.T_b_c[:3, :3].T @ truth.T_b_c[:3, :3]
    return {
        "rotation_deg": math.degrees(float(np.linalg.norm(so3.log(R_err)))),
        "translation_mm": 1e3 * float(np.linalg.norm(result.T_b_c[:3, 3] - truth.T_b_c[:3, 3])),
        "time_offset_ms": 1e3 * abs(result.time_offset_s - truth.time_offset_s),
    }
