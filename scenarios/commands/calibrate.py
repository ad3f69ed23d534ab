"""``vnav-demo calibrate FILE.rrd [--out calib.yaml] [--imu]``: the camera mount and clock
offset from a recording (``scenarios.record.reader``, ``vnav.calibration``), printed with their
standard errors and, where the recording holds the truth, their errors; written as Kalibr's
camchain YAML (``scenarios.export.kalibr``), referred to the IMU (``T_cam_imu``, its declared
mount) when the recording's run had one.

With ``--imu`` the camera is calibrated against the IMU instead (``vnav.imu_calibration``,
the two passes of ``scenarios.judge.imu_calibration.ImuCalibrationInputs.solve``, as the run's
own ``calibration_imu_*`` checks make them): ``T_i_c`` and Kalibr's ``timeshift_cam_imu``
(``t_imu = t_cam + offset``) from the images and the IMU's readings alone, written as the
camchain's ``T_cam_imu`` and ``timeshift_cam_imu``."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from scenarios.commands.console import error, say
from scenarios.export.kalibr import ImuExtrinsics, camchain_yaml, imu_camchain_yaml
from scenarios.judge.calibration import Truth, errors_against
from scenarios.judge.imu_calibration import ImuCalibrationInputs, imu_errors_against
from scenarios.record.outputs import OutputError, write_atomic
from scenarios.record.reader import (
    RecordingError,
    calibration_inputs,
    imu_calibration_inputs,
    imu_mount_declared,
)
from vnav import se3
from vnav.calibration import CalibrationError, CalibrationResult
from vnav.camera import PinholeCamera
from vnav.imu_calibration import ImuCamCalibration

__all__ = ["command", "imu_to_yaml", "to_yaml", "write_yaml"]

IMU_SOURCE = (
    "calibrated: T_cam_imu and timeshift_cam_imu recovered from the images and the IMU's "
    "readings alone (vnav.imu_calibration, vnav-demo calibrate --imu)"
)
"""What ``cam0.vnav_sim.imu_extrinsics`` says of a camera-IMU calibration's figures."""


def to_yaml(
    result: CalibrationResult, camera: PinholeCamera, imu: ImuExtrinsics | None = None
) -> str:
    """The result as Kalibr's camchain YAML (``scenarios.export.kalibr``): ``cam0`` with the
    camera's intrinsics, ``T_cam_body`` (the inverse of ``T_b_c``) and ``timeshift_cam_body``
    (``time_offset_s``), and the project's figures under ``cam0.vnav_sim``: ``T_b_c``,
    ``time_offset_s``, ``reprojection_rms_px``, ``frames_used``, ``observations_used`` and the
    standard errors; with ``imu``, Kalibr's ``T_cam_imu`` and ``timeshift_cam_imu`` too."""
    return camchain_yaml(
        camera,
        result.T_b_c,
        result.time_offset_s,
        {
            "T_b_c": se3.check_pose(result.T_b_c, "T_b_c"),
            "time_offset_s": result.time_offset_s,
            "reprojection_rms_px": result.reprojection_rms_px,
            "frames_used": result.frames_used,
            "observations_used": result.observations_used,
            "std_rotation_deg": result.std_rotation_deg,
            "std_translation_m": result.std_translation_m,
            "std_offset_s": result.std_offset_s,
        },
        imu,
    )


def write_yaml(
    result: CalibrationResult,
    camera: PinholeCamera,
    path: str | Path,
    imu: ImuExtrinsics | None = None,
) -> None:
    """Write ``to_yaml`` to ``path`` completely or not at all
    (``scenarios.record.outputs.write_atomic``).

    Raises
    ------
    scenarios.record.outputs.OutputError
        If the file cannot be written; ``path`` is then as it was.
    """
    _write_text(to_yaml(result, camera, imu), path)


def imu_to_yaml(result: ImuCamCalibration, camera: PinholeCamera) -> str:
    """A camera-IMU calibration as Kalibr's camchain YAML (``scenarios.export.kalibr.
    imu_camchain_yaml``): ``cam0`` with the camera's intrinsics, ``T_cam_imu`` (the inverse of
    ``T_i_c``) and ``timeshift_cam_imu`` (``time_offset_s``), and under ``cam0.vnav_sim``:
    ``T_i_c``, ``time_offset_s``, ``reprojection_rms_px``, ``frames_used``,
    ``observations_used``, the standard errors, the biases the fit recovered and
    ``imu_extrinsics`` (``IMU_SOURCE``: they were calibrated)."""
    return imu_camchain_yaml(
        camera,
        result.T_i_c,
        result.time_offset_s,
        {
            "T_i_c": se3.check_pose(result.T_i_c, "T_i_c"),
            "time_offset_s": result.time_offset_s,
            "reprojection_rms_px": result.reprojection_rms_px,
            "frames_used": result.frames_used,
            "observations_used": result.observations_used,
            "std_rotation_deg": result.std_rotation_deg,
            "std_translation_m": result.std_translation_m,
            "std_offset_s": result.std_offset_s,
            "gyro_bias_i": np.asarray(result.gyro_bias_i, dtype=np.float64),
            "accel_bias_i": np.asarray(result.accel_bias_i, dtype=np.float64),
            "imu_extrinsics": IMU_SOURCE,
        },
    )


def _write_text(text: str, path: str | Path) -> None:
    """``text`` into ``path`` completely or not at all (``write_atomic``).

    Raises
    ------
    scenarios.record.outputs.OutputError
        If the file cannot be written; ``path`` is then as it was.
    """
    write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def command(args: argparse.Namespace) -> int:
    """``vnav-demo calibrate FILE.rrd [--out calib.yaml] [--imu]``: exit status 0, or 2 with
    one line on stderr for a file that is not a usable recording (with ``--imu``: one without
    IMU readings), an output path that cannot be written, or a flight that does not determine
    the answer."""
    recording, out = args.recording, args.out
    out_path = None if out is None else Path(out)
    if out_path is not None and not out_path.parent.is_dir():
        error(f"--out {out}: no such directory {str(out_path.parent)!r}")
        return 2
    if getattr(args, "imu", False):
        return _imu_command(recording, out, out_path)
    try:
        inputs = calibration_inputs(recording)
        solved = inputs.solve()
        # No camera-IMU calibration yet: the IMU's declared mount (ImuExtrinsics.declared).
        T_b_i = imu_mount_declared(recording) if out_path is not None else None
    except (RecordingError, CalibrationError) as exc:
        error(f"cannot calibrate: {exc}")
        return 2
    except ValueError as exc:  # what vnav refuses in the recording's numbers
        error(f"cannot calibrate: {recording}: {exc}")
        return 2
    say(_table(solved, inputs.truth))
    if out_path is not None:
        try:
            imu = None if T_b_i is None else ImuExtrinsics.declared(T_b_i)
            write_yaml(solved, inputs.camera, out_path, imu)
        except OutputError as exc:
            error(f"--out {out}: cannot write: {exc.strerror}")
            return 2
        say(f"wrote {out_path}")
    return 0


def _imu_command(recording: str, out: str | None, out_path: Path | None) -> int:
    """``calibrate --imu``: the camera-IMU calibration of ``recording``, printed and, with
    ``out_path``, written; 0, or 2 with one line on stderr."""
    try:
        inputs = imu_calibration_inputs(recording)
        solved = inputs.solve()
    except (RecordingError, CalibrationError) as exc:
        error(f"cannot calibrate: {exc}")
        return 2
    except ValueError as exc:  # what vnav refuses in the recording's numbers
        error(f"cannot calibrate: {recording}: {exc}")
        return 2
    say(_imu_table(solved, inputs))
    if out_path is not None:
        try:
            _write_text(imu_to_yaml(solved, inputs.camera), out_path)
        except OutputError as exc:
            error(f"--out {out}: cannot write: {exc.strerror}")
            return 2
        say(f"wrote {out_path}")
    return 0


def _table(result: CalibrationResult, truth: Truth | None) -> str:
    """The answer, its standard errors and, with the truth, its errors, in 80 columns."""
    lines = ["camera mount T_b_c (optical frame in the body):"]
    lines += ["  " + " ".join(f"{v:9.5f}" for v in row) for row in result.T_b_c]
    lines.append(f"clock offset: t_pose = t_cam + {1e3 * result.time_offset_s:.3f} ms")
    lines.append(
        f"reprojection RMS {result.reprojection_rms_px:.3f} px over "
        f"{result.observations_used} apexes in {result.frames_used} images"
    )
    lines.append(
        f"standard errors: rotation {result.std_rotation_deg:.4f} deg, translation "
        f"{1e3 * result.std_translation_m:.2f} mm, offset {1e3 * result.std_offset_s:.3f} ms"
    )
    if truth is not None:
        e = errors_against(result, truth)
        lines.append(
            f"against the truth: rotation {e['rotation_deg']:.4f} deg, translation "
            f"{e['translation_mm']:.2f} mm, offset {e['time_offset_ms']:.3f} ms"
        )
    return "\n".join(lines)


def _imu_table(result: ImuCamCalibration, inputs: ImuCalibrationInputs) -> str:
    """The camera-IMU answer, its standard errors and, with the truth, its errors, in 80
    columns."""
    lines = ["camera in the IMU frame T_i_c (Kalibr's T_cam_imu is its inverse):"]
    lines += ["  " + " ".join(f"{v:9.5f}" for v in row) for row in result.T_i_c]
    sign = "-" if result.time_offset_s < 0.0 else "+"
    lines.append(
        f"clock offset (timeshift_cam_imu): t_imu = t_cam {sign} "
        f"{1e3 * abs(result.time_offset_s):.3f} ms"
    )
    lines.append(
        f"reprojection RMS {result.reprojection_rms_px:.3f} px over "
        f"{result.observations_used} apexes in {result.frames_used} images"
    )
    lines.append(
        f"standard errors: rotation {result.std_rotation_deg:.4f} deg, translation "
        f"{1e3 * result.std_translation_m:.2f} mm, offset {1e3 * result.std_offset_s:.3f} ms"
    )
    if inputs.T_i_c_true is not None and inputs.time_offset_true_s is not None:
        e = imu_errors_against(result, inputs.T_i_c_true, inputs.time_offset_true_s)
        lines.append(
            f"against the truth: rotation {e['rotation_deg']:.4f} deg, translation "
            f"{1e3 * e['translation_m']:.2f} mm, offset {1e3 * e['time_offset_s']:.3f} ms"
        )
    return "\n".join(lines)
