"""The camera-IMU calibration recovered from a finished run, compared with its truth.

The inputs are what a camera and an IMU record (``vnav.imu_calibration``): each image's
exposure stamp on the camera clock and the apexes the detector found in it, the cone map, and
the IMU's readings stamped on its own clock. Neither the pose stream nor a declared mount goes
in. The truth is the simulator's: ``T_i_c = T_b_i^-1 T_b_c`` of the true mounts (each its
declared one times its ``mount_error``) and the scenario's ``[imu] time_offset_s``. A
recording carries the same inputs (``scenarios.record.reader.imu_calibration_inputs``), blobs
included, so that ``vnav-demo calibrate --imu`` and the run's own calibration make the same two
passes (``ImuCalibrationInputs.solve``) on the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenarios.judge.calibration import calibration_detections
from scenarios.run.records import ImuCalibrationRecord, RunResult
from vnav import se3, so3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection
from vnav.imu_calibration import CalibrationError, ImuCamCalibration, calibrate_camera_imu
from vnav.silhouette import SilhouetteView

__all__ = [
    "ImuCalibrationInputs",
    "calibrate_imu_run",
    "imu_errors_against",
    "imu_inputs_from_run",
    "imu_std",
]


@dataclass(frozen=True)
class ImuCalibrationInputs:
    """Everything ``vnav.imu_calibration.calibrate_camera_imu`` takes, and the truth if known.

    ``apex_uv`` holds the detector's pose-free apexes (about 0.25 px above the true apex);
    ``detections``, where given (one list per image, the same detections clear of the border,
    ``scenarios.judge.calibration.calibration_detections``), lets ``solve`` fit each apex again
    on its blob along the image vertical (``SilhouetteView.apex_keypoint``, unbiased), which
    needs each image's camera pose from a first pass. A finished run (``imu_inputs_from_run``)
    and a recording (``scenarios.record.reader.imu_calibration_inputs``) give the same inputs,
    so that both make the same two passes.

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
    detections : list of N lists of ConeDetection, or None
        The detections ``apex_uv`` comes from, in the same order.
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
    detections: list[list[ConeDetection]] | None = None

    def solve(self) -> ImuCamCalibration:
        """``T_i_c`` and the offset: with ``detections``, two passes (the detector's apexes
        give a first fit and its camera poses; the apexes fitted again on the blobs under those
        poses give the answer, the first fit passed on as ``previous``); without, the one pass
        on ``apex_uv``.

        The detector's apex bias tilts ``R_i_c`` and moves ``t_i_c``; the second pass removes
        it (as ``scenarios.judge.calibration.CalibrationInputs.solve`` does for the camera
        mount).

        Raises
        ------
        vnav.calibration.CalibrationError
            The flight does not determine the calibration, with the reason (a record too short
            to integrate included).
        """
        first = self._solve(self.apex_uv)
        if self.detections is None:
            return first
        return self._solve(self.refitted_apexes(first), previous=first)

    def refitted_apexes(self, first: ImuCamCalibration) -> list[np.ndarray]:
        """Each image's apexes fitted again on its blobs (``SilhouetteView.apex_keypoint``)
        seen from ``first``'s camera pose of that image; the detector's apex where the fit
        gives none, and in an image ``first`` did not use.

        Raises
        ------
        ValueError
            If the inputs carry no ``detections``.
        """
        if self.detections is None:
            raise ValueError("the inputs carry no detections to fit the apexes on again")
        poses = dict(zip(first.image_stamps_cam_s, first.T_w_c, strict=True))
        apex_uv = []
        for stamp, detections, detector_uv in zip(
            self.image_stamps_cam_s, self.detections, self.apex_uv, strict=True
        ):
            T_w_c = poses.get(stamp)
            if T_w_c is None:
                apex_uv.append(detector_uv)
                continue
            points = []
            for d in detections:
                apex = SilhouetteView(d, self.camera, T_w_c).apex_keypoint(TRAFFIC_CONE)
                points.append(d.apex_uv if apex is None else apex)
            apex_uv.append(np.array(points, dtype=np.float64).reshape(-1, 2))
        return apex_uv

    def _solve(
        self, apex_uv: list[np.ndarray], previous: ImuCamCalibration | None = None
    ) -> ImuCamCalibration:
        if len(self.imu_stamps_s) < 2:
            raise CalibrationError(
                f"the flight is too short to calibrate: {len(self.imu_stamps_s)} IMU reading(s)"
            )
        return calibrate_camera_imu(
            self.camera,
            self.image_stamps_cam_s,
            apex_uv,
            self.apex_w,
            self.imu_stamps_s,
            self.gyro_i,
            self.accel_i,
            previous=previous,
        )


def imu_inputs_from_run(result: RunResult) -> ImuCalibrationInputs:
    """The inputs of a finished run with an IMU (``RunResult.imu`` must be set): the
    detector's apexes and the detections they come from (those touching the border left out,
    ``calibration_detections``), the camera's stamps, the cones' apexes, the IMU's readings;
    the truth beside them.

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
    detections = [calibration_detections([d.detection for d in t.detections]) for t in result.ticks]
    imu = result.spec.scene.imu
    assert imu is not None
    T_i_c_true = se3.invert(imu.T_b_i) @ result.ticks[0].T_b_c
    return ImuCalibrationInputs(
        camera=camera,
        image_stamps_cam_s=np.array(stamps),
        apex_uv=[
            np.array([d.apex_uv for d in ds], dtype=np.float64).reshape(-1, 2) for ds in detections
        ],
        apex_w=result.cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
        imu_stamps_s=result.imu.t_s,
        gyro_i=result.imu.gyro_i,
        accel_i=result.imu.accel_i,
        T_i_c_true=T_i_c_true,
        time_offset_true_s=imu.time_offset_s,
        detections=detections,
    )


def imu_std(solved: ImuCamCalibration) -> dict[str, float]:
    """The standard errors of ``solved``: rotation (deg), translation (m), offset (s)."""
    return {
        "rotation_deg": solved.std_rotation_deg,
        "translation_m": solved.std_translation_m,
        "time_offset_s": solved.std_offset_s,
    }


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

    Two passes (``ImuCalibrationInputs.solve``), as ``vnav-demo calibrate --imu`` makes them
    from the run's recording: the detector's pose-free apexes (about 0.25 px above the true
    apex, a bias that tilts ``R_i_c`` and moves ``t_i_c``) give a first fit; the apexes
    re-fitted along the image vertical that its camera poses give (unbiased) give the answer."""
    if result.imu is None:
        return ImuCalibrationRecord(refused="the scenario has no [imu]: nothing to calibrate")
    if not result.ticks:
        return ImuCalibrationRecord(refused="the run has no camera ticks: nothing to calibrate")
    inputs = imu_inputs_from_run(result)
    try:
        solved = inputs.solve()
    except CalibrationError as exc:
        return ImuCalibrationRecord(refused=str(exc), T_i_c_true=inputs.T_i_c_true)
    assert inputs.T_i_c_true is not None and inputs.time_offset_true_s is not None
    return ImuCalibrationRecord(
        T_i_c=solved.T_i_c,
        time_offset_s=solved.time_offset_s,
        reprojection_rms_px=solved.reprojection_rms_px,
        frames_used=solved.frames_used,
        errors=imu_errors_against(solved, inputs.T_i_c_true, inputs.time_offset_true_s),
        std=imu_std(solved),
        T_i_c_true=inputs.T_i_c_true,
    )
