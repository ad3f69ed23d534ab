"""The camera-IMU calibration recovered from a finished run, compared with its truth.

The inputs are what a camera and an IMU record (``vnav.imu_calibration``): each image's
exposure stamp on the camera clock and the apexes the detector found in it, the cone map, and
the IMU's readings stamped on its own clock. Neither the pose stream nor a declared mount goes
in. The truth is the simulator's: ``T_i_c = T_b_i^-1 T_b_c`` of the true mounts (each its
declared one times its ``mount_error``) and the scenario's ``[imu] time_offset_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenarios.run.records import ImuCalibrationRecord, RunResult
from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.imu_calibration import CalibrationError, ImuCamCalibration, calibrate_camera_imu
from vnav.silhouette import SilhouetteView

__all__ = ["ImuCalibrationInputs", "calibrate_imu_run", "imu_errors_against", "imu_inputs_from_run"]


@dataclass(frozen=True)
class ImuCalibrationInputs:
    """Everything ``vnav.imu_calibration.calibrate_camera_imu`` takes, and the truth if known.

    Attributes
    ----------
    camera : PinholeCamera
    image_stamps_cam_s : ndarray, shape (N,)
    apex_uv : list of N arrays of shape (K, 2)
    apex_w : ndarray, shape (C, 3)
    imu_stamps_s : ndarray, shape (M,)
    gyro_i, accel_i : ndarray, shape (M, 3)
    T_i_c_true : ndarray, shape (4, 4), or None
    time_offset_true_s : float or None
        Kalibr's ``timeshift_cam_imu``: ``t_imu = t_cam + offset``.
    """

    camera: PinholeCamera
    image_stamps_cam_s: np.ndarray
    apex_uv: list[np.ndarray]
    apex_w: np.ndarray
    imu_stamps_s: np.ndarray
    gyro_i: np.ndarray
    accel_i: np.ndarray
    T_i_c_true: np.ndarray | None = None
    time_offset_true_s: float | None = None

    def solve(self, previous: ImuCamCalibration | None = None) -> ImuCamCalibration:
        """``calibrate_camera_imu`` on these inputs (``previous``: its ``previous``).

        Raises
        ------
        vnav.calibration.CalibrationError
            The flight does not determine the calibration, with the reason (a record too short
            to integrate included).
        """
        if len(self.imu_stamps_s) < 2:
            raise CalibrationError(
                f"the flight is too short to calibrate: {len(self.imu_stamps_s)} IMU reading(s)"
            )
        return calibrate_camera_imu(
            self.camera,
            self.image_stamps_cam_s,
            self.apex_uv,
            self.apex_w,
            self.imu_stamps_s,
            self.gyro_i,
            self.accel_i,
            previous=previous,
        )


def imu_inputs_from_run(
    result: RunResult, first: ImuCamCalibration | None = None
) -> ImuCalibrationInputs:
    """The inputs of a finished run with an IMU (``RunResult.imu`` must be set): the
    detector's apexes (detections touching the border left out), the camera's stamps, the
    cones' apexes, the IMU's readings; the truth beside them.

    Without ``first`` each apex is the detector's pose-free ``apex_uv`` (about 0.25 px above
    the true apex); with it, the unbiased area fit along the image vertical
    (``SilhouetteView.apex_keypoint``) that ``first``'s camera pose of that image gives (an
    image ``first`` did not use keeps the detector's): ``calibrate_imu_run``'s second pass.

    Raises
    ------
    ValueError
        If the run has no IMU readings or no camera ticks.
    """
    if result.imu is None or not result.ticks:
        raise ValueError("the run has no IMU readings or no camera ticks to calibrate from")
    cam = result.spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    stamps = [t.t_s if t.timing is None else t.timing.stamp_cam_s for t in result.ticks]
    poses = {} if first is None else dict(zip(first.image_stamps_cam_s, first.T_w_c, strict=True))
    apex_uv = []
    for stamp, t in zip(stamps, result.ticks, strict=True):
        T_w_c = poses.get(stamp)
        points = []
        for d in t.detections:
            if d.detection.touches_border:
                continue
            apex = None
            if T_w_c is not None:
                apex = SilhouetteView(d.detection, camera, T_w_c).apex_keypoint(TRAFFIC_CONE)
            points.append(d.detection.apex_uv if apex is None else apex)
        apex_uv.append(np.array(points, dtype=np.float64).reshape(-1, 2))
    imu = result.spec.scene.imu
    assert imu is not None
    T_i_c_true = se3.invert(imu.T_b_i) @ result.ticks[0].T_b_c
    return ImuCalibrationInputs(
        camera=camera,
        image_stamps_cam_s=np.array(stamps),
        apex_uv=apex_uv,
        apex_w=result.cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
        imu_stamps_s=result.imu.t_s,
        gyro_i=result.imu.gyro_i,
        accel_i=result.imu.accel_i,
        T_i_c_true=T_i_c_true,
        time_offset_true_s=imu.time_offset_s,
    )


def imu_errors_against(
    solved: ImuCamCalibration, T_i_c_true: np.ndarray, time_offset_true_s: float
) -> dict[str, float]:
    """The recovered ``T_i_c`` and offset against the truth: rotation (deg), translation (m),
    offset (s), each an absolute error."""
    R_err = solved.T_i_c[:3, :3].T @ T_i_c_true[:3, :3]
    return {
        "rotation_deg": math.degrees(float(np.linalg.norm(so3.log(R_err)))),
        "translation_m": float(np.linalg.norm(solved.T_i_c[:3, 3] - T_i_c_true[:3, 3])),
        "time_offset_s": abs(solved.time_offset_s - time_offset_true_s),
    }


def calibrate_imu_run(result: RunResult) -> ImuCalibrationRecord:
    """``vnav.imu_calibration`` on a finished run, compared with its truth; refused (with the
    reason) when the run has no IMU or the flight does not determine the calibration.

    Two passes, as ``scenarios.judge.calibration.calibrate_run``: the detector's pose-free
    apexes (about 0.25 px above the true apex, a bias that tilts ``R_i_c`` and moves
    ``t_i_c``) give a first fit; the apexes re-fitted along the image vertical that its
    camera poses give (unbiased) give the answer."""
    if result.imu is None:
        return ImuCalibrationRecord(refused="the scenario has no [imu]: nothing to calibrate")
    if not result.ticks:
        return ImuCalibrationRecord(refused="the run has no camera ticks: nothing to calibrate")
    try:
        first = imu_inputs_from_run(result).solve()
        inputs = imu_inputs_from_run(result, first)
        solved = inputs.solve(previous=first)
    except CalibrationError as exc:
        inputs = imu_inputs_from_run(result)
        return ImuCalibrationRecord(refused=str(exc), T_i_c_true=inputs.T_i_c_true)
    assert inputs.T_i_c_true is not None and inputs.time_offset_true_s is not None
    return ImuCalibrationRecord(
        T_i_c=solved.T_i_c,
        time_offset_s=solved.time_offset_s,
        reprojection_rms_px=solved.reprojection_rms_px,
        frames_used=solved.frames_used,
        errors=imu_errors_against(solved, inputs.T_i_c_true, inputs.time_offset_true_s),
        std={
            "rotation_deg": solved.std_rotation_deg,
            "translation_m": solved.std_translation_m,
            "time_offset_s": solved.std_offset_s,
        },
        T_i_c_true=inputs.T_i_c_true,
    )
