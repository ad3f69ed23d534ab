"""``vnav-demo calibrate FILE.rrd [--out calib.yaml]``: the camera mount and clock offset
from a recording (``scenarios.record.reader``, ``vnav.calibration``), printed with their
standard errors and, where the recording holds the truth, their errors; written as Kalibr's
camchain YAML (``scenarios.export.kalibr``), referred to the IMU (``T_cam_imu``) when the
recording's run had one."""

from __future__ import annotations

import argparse
from pathlib import Path

from scenarios.commands.console import error, say
from scenarios.export.kalibr import ImuExtrinsics, camchain_yaml
from scenarios.judge.calibration import Truth, errors_against
from scenarios.record.outputs import OutputError, write_atomic
from scenarios.record.reader import RecordingError, calibration_inputs, imu_mount_declared
from vnav import se3
from vnav.calibration import CalibrationError, CalibrationResult
from vnav.camera import PinholeCamera

__all__ = ["command", "to_yaml", "write_yaml"]


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
    text = to_yaml(result, camera, imu)
    write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def command(args: argparse.Namespace) -> int:
    """``vnav-demo calibrate FILE.rrd [--out calib.yaml]``: exit status 0, or 2 with one line
    on stderr for a file that is not a usable recording, an output path that cannot be
    written, or a flight that does not determine the answer."""
    recording, out = args.recording, args.out
    out_path = None if out is None else Path(out)
    if out_path is not None and not out_path.parent.is_dir():
        error(f"--out {out}: no such directory {str(out_path.parent)!r}")
        return 2
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
