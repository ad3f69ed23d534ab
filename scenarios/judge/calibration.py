"""The camera mount and clock offset recovered from a finished run, compared with its truth.

The inputs are what the estimator had (``vnav.calibration``): the pose stream as it was sent,
each image's exposure stamp on the camera clock, the apexes the detector found, the cone map
and the declared mount; the truth beside them is what the simulator knows and the estimator
does not (the true mount, the true clock offset). A recording carries the same inputs
(``scenarios.record.reader.calibration_inputs``).
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
from vnav.frames import ExtrapolationError
from vnav.localize import Localizer
from vnav.methods import active_methods
from vnav.plugin import second_pass_methods
from vnav.sensor_noise import mount_covariance
from vnav.silhouette import SilhouetteView

__all__ = [
    "CalibrationInputs",
    "Truth",
    "calibrate_run",
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
    """Everything ``vnav.calibration.calibrate_camera`` takes, and the truth if known."""

    camera: PinholeCamera
    pose_stamps_s: np.ndarray
    T_w_b: np.ndarray
    image_stamps_cam_s: np.ndarray
    apex_uv: list[np.ndarray]
    apex_w: np.ndarray
    T_b_c_declared: np.ndarray
    truth: Truth | None = None

    def solve(self) -> CalibrationResult:
        """``calibrate_camera`` on these inputs.

        Raises
        ------
        vnav.calibration.CalibrationError
            The flight does not determine the mount or the offset, with the reason; a flight
            too short to calibrate says so: fewer than two pose samples, or a clock offset
            the solver's search took outside the flight's pose stream (the offset, unknown
            to the images of a short flight, wandered further than the flight lasts).
        """
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
                self.apex_uv,
                self.apex_w,
                self.T_b_c_declared,
            )
        except ExtrapolationError:
            span_s = float(self.pose_stamps_s[-1] - self.pose_stamps_s[0])
            raise CalibrationError(
                f"the flight ({span_s:.3g} s, {n_images} images) does not determine the clock "
                "offset: the solver's estimate left the pose stream"
            ) from None


def inputs_from_run(
    result: RunResult, camera: PinholeCamera, T_b_c: np.ndarray | None = None
) -> CalibrationInputs:
    """The inputs of a finished run (``RunResult.poses`` must be set).

    Without ``T_b_c`` each apex is the detector's pose-free ``apex_uv`` (about 0.25 px above
    the true apex); with it, the unbiased area fit along the image vertical that the body pose
    and this mount give (``SilhouetteView.apex_keypoint``): ``calibrate_run``'s second pass.
    """
    if result.poses is None or not result.ticks:
        raise ValueError("the run has no pose stream or no camera ticks to calibrate from")
    stamps = [t.t_s if t.timing is None else t.timing.stamp_cam_s for t in result.ticks]
    apex_uv = []
    for t in result.ticks:
        points = []
        for d in t.detections:
            if d.detection.touches_border:
                continue
            apex = None
            if T_b_c is not None:
                view = SilhouetteView(d.detection, camera, t.T_w_b_est @ T_b_c)
                apex = view.apex_keypoint(TRAFFIC_CONE)
            points.append(d.detection.apex_uv if apex is None else apex)
        apex_uv.append(np.array(points, dtype=np.float64).reshape(-1, 2))
    return CalibrationInputs(
        camera=camera,
        pose_stamps_s=result.poses.stamps_s,
        T_w_b=result.poses.T_w_b,
        image_stamps_cam_s=np.array(stamps),
        apex_uv=apex_uv,
        apex_w=result.cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
        T_b_c_declared=result.ticks[0].T_b_c_est,
        truth=Truth(result.ticks[0].T_b_c, result.spec.timing.camera_clock_offset_s),
    )


def calibrate_run(result: RunResult) -> CalibrationRecord:
    """``vnav.calibration`` on a finished run, compared with its truth.

    Two passes: the detector's pose-free apexes give a first mount; the apexes re-fitted along
    the image vertical that mount gives (unbiased) give the answer. (A recording holds the
    detector's apexes only: ``vnav-demo calibrate`` makes the first pass.) Then every tick is
    estimated again with the recovered mount (``estimate_with_mount``): the estimates after
    calibration, beside the run's own, made with the declared mount.
    """
    cam = result.spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    first_pass = inputs_from_run(result, camera)
    mounts = {
        "T_b_c_declared": first_pass.T_b_c_declared,
        "T_b_c_true": None if first_pass.truth is None else first_pass.truth.T_b_c,
    }
    try:
        first = first_pass.solve()
        inputs = inputs_from_run(result, camera, first.T_b_c)
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
    run is not called again."""
    spec = result.spec
    methods = second_pass_methods(active_methods())
    localizer = Localizer(camera, far_m=spec.scene.zfar_m, noise=spec.noise, methods=methods)
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
