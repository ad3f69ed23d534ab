"""``vnav-demo calibrate``: the camera mount and clock offset from a run or its recording.

The inputs are what the estimator had (``vnav.calibration``): the pose stream as it was sent,
each image's exposure stamp on the camera clock, the apexes the detector found, the cone map
and the declared mount. A recording carries them (``scenarios.recording``: ``estimator/*``,
the detections' keypoints, ``world/cones/truth``, the camera's pinhole) and, beside them, the
truth the answer is compared with: the true mount (``world/body/camera``) and the true clock
offset (``truth``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.records import CalibrationRecord, RunResult
from vnav import quat, se3, so3
from vnav.calibration import CalibrationError, CalibrationResult, calibrate_camera
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.silhouette import SilhouetteView

__all__ = [
    "CalibrationInputs",
    "RecordingError",
    "Truth",
    "calibrate_run",
    "command",
    "errors_against",
    "inputs_from_recording",
    "inputs_from_run",
    "to_yaml",
    "write_yaml",
]


class RecordingError(ValueError):
    """A file is not a recording ``calibrate`` can read; the message says what is missing."""


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
        """``calibrate_camera`` on these inputs (raises ``vnav.calibration.CalibrationError``)."""
        return calibrate_camera(
            self.camera,
            self.pose_stamps_s,
            self.T_w_b,
            self.image_stamps_cam_s,
            self.apex_uv,
            self.apex_w,
            self.T_b_c_declared,
        )


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
    detector's apexes only: ``vnav-demo calibrate`` makes the first pass.)
    """
    cam = result.spec.scene.camera
    camera = PinholeCamera.from_fovy(cam.fovy_deg, cam.width, cam.height)
    try:
        first = inputs_from_run(result, camera).solve()
        inputs = inputs_from_run(result, camera, first.T_b_c)
        solved = inputs.solve()
    except CalibrationError as exc:
        return CalibrationRecord(None, None, None, 0, {}, refused=str(exc))
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
    )


def _read(path: Path) -> dict[str, list[dict]]:
    """Every row of the entities ``calibrate`` reads, by entity path."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    from scenarios.viewer import entity

    wanted = {
        "/" + p: []
        for p in (
            entity.POSE_STREAM,
            entity.MOUNT_DECLARED,
            entity.STAMP_CAM,
            entity.KEYPOINTS,
            entity.CAMERA,
            entity.TRUTH,
            entity.TRUTH_VALUES,
        )
    }
    try:
        chunks = list(RrdReader(str(path)).stream().to_chunks())
    except Exception as exc:  # Rerun reports an unreadable file as RuntimeError
        raise RecordingError(f"{path}: not a readable Rerun recording ({exc})") from None
    for chunk in chunks:
        path_of = str(chunk.entity_path)
        if path_of not in wanted:
            continue
        table = pa.Table.from_batches([chunk.to_record_batch()])
        columns = {}
        for name in table.column_names:
            column = table.column(name)
            if pa.types.is_duration(column.type) or pa.types.is_timestamp(column.type):
                column = column.cast(pa.int64())
            columns[name] = column.to_pylist()
        wanted[path_of].extend({k: v[i] for k, v in columns.items()} for i in range(table.num_rows))
    return {k.lstrip("/"): v for k, v in wanted.items()}


def _transforms(rows: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    """``(index values, (N, 4, 4) transforms)`` of the rows with a translation and a timeline
    ``key`` (``"tick"`` or ``"sim_time"``), in index order."""
    rows = [r for r in rows if r.get("Transform3D:translation") and key in r]
    rows.sort(key=lambda r: r[key])
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    for i, r in enumerate(rows):
        T[i, :3, 3] = r["Transform3D:translation"][0]
        T[i, :3, :3] = quat.to_matrix(np.asarray(r["Transform3D:quaternion"][0]), normalize=True)
    return np.array([r[key] for r in rows]), T


def inputs_from_recording(path: str | Path) -> CalibrationInputs:
    """The inputs a recording written by ``vnav-demo run`` carries.

    Raises
    ------
    RecordingError
        If the file is not a recording or lacks what calibration needs (say which).
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    rows = _read(path)
    from scenarios.viewer import entity

    missing = [p for p in (entity.POSE_STREAM, entity.STAMP_CAM, entity.CAMERA) if not rows[p]]
    if missing:
        raise RecordingError(
            f"{path}: the recording lacks {', '.join(missing)} (written by vnav-demo run of "
            "this version)"
        )
    stamps_ns, T_w_b = _transforms(rows[entity.POSE_STREAM], "sim_time")
    stamp_rows = sorted((r for r in rows[entity.STAMP_CAM] if "tick" in r), key=lambda r: r["tick"])
    ticks = [r["tick"] for r in stamp_rows]
    keypoints = {r["tick"]: r for r in rows[entity.KEYPOINTS] if "tick" in r}
    apex_uv = []
    for tick in ticks:
        positions = np.asarray(
            keypoints.get(tick, {}).get("Points2D:positions") or [], dtype=np.float64
        ).reshape(-1, 2)
        apex_uv.append(positions[0::2] - 0.5)  # apex, base, apex, ...; Rerun's +0.5 undone
    pinhole = next(r for r in rows[entity.CAMERA] if r.get("Pinhole:image_from_camera"))
    K = np.asarray(pinhole["Pinhole:image_from_camera"][0], dtype=np.float64).reshape(3, 3).T
    width, height = (int(v) for v in pinhole["Pinhole:resolution"][0])
    camera = PinholeCamera(K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5, width, height)
    cones = [r for r in rows[entity.TRUTH] if r.get("Points3D:positions")]
    if not cones:
        raise RecordingError(f"{path}: the recording has no cone map (world/cones/truth)")
    cones_w = np.asarray(cones[0]["Points3D:positions"], dtype=np.float64).reshape(-1, 3)
    _, mounts = _transforms(rows[entity.MOUNT_DECLARED], "tick")
    truth = None
    true_mount = [r for r in rows[entity.CAMERA] if r.get("Transform3D:translation")]
    offsets = [r for r in rows[entity.TRUTH_VALUES] if "camera_clock_offset_s" in r]
    if true_mount and offsets:
        key = "tick" if "tick" in true_mount[0] else None
        if key is None:
            T_true = np.eye(4)
            T_true[:3, 3] = true_mount[0]["Transform3D:translation"][0]
            T_true[:3, :3] = quat.to_matrix(
                np.asarray(true_mount[0]["Transform3D:quaternion"][0]), normalize=True
            )
        else:
            T_true = _transforms(true_mount, "tick")[1][0]
        truth = Truth(T_true, float(offsets[0]["camera_clock_offset_s"][0]))
    return CalibrationInputs(
        camera=camera,
        pose_stamps_s=stamps_ns * 1e-9,
        T_w_b=T_w_b,
        image_stamps_cam_s=np.array([r["Scalars:scalars"][0] for r in stamp_rows]),
        apex_uv=apex_uv,
        apex_w=cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
        T_b_c_declared=mounts[0] if len(mounts) else np.eye(4),
        truth=truth,
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


def to_yaml(result: CalibrationResult) -> str:
    """The result in the issue's YAML layout (written by hand: four keys need no library)."""
    rows = ",\n  ".join(
        "[" + ", ".join(f"{v:.9f}" for v in row) + "]" for row in se3.check_pose(result.T_b_c)
    )
    return (
        f"T_b_c: [\n  {rows}]\n"
        f"time_offset_s: {result.time_offset_s:.9f}\n"
        f"reprojection_rms_px: {result.reprojection_rms_px:.6f}\n"
        f"frames_used: {result.frames_used}\n"
    )


def write_yaml(result: CalibrationResult, path: str | Path) -> None:
    """Write ``to_yaml`` to ``path`` completely or not at all (a temporary name, synced, then
    renamed over it)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(to_yaml(result))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def command(recording: str, out: str | None) -> int:
    """``vnav-demo calibrate FILE.rrd [--out calib.yaml]``: exit status 0, or 2 with one line
    on stderr for a file that is not a usable recording, an output path that cannot be
    written, or a flight that does not determine the answer."""
    from scenarios.console import error, say

    out_path = None if out is None else Path(out)
    if out_path is not None and not out_path.parent.is_dir():
        error(f"--out {out}: no such directory {str(out_path.parent)!r}")
        return 2
    try:
        inputs = inputs_from_recording(recording)
        solved = inputs.solve()
    except (RecordingError, CalibrationError) as exc:
        error(f"cannot calibrate: {exc}")
        return 2
    say(_table(solved, inputs.truth))
    if out_path is not None:
        try:
            write_yaml(solved, out_path)
        except OSError as exc:
            error(f"--out {out}: {exc.strerror}")
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
