"""Reading a recording written by ``vnav-demo run`` back: its rows by entity, and the inputs
a camera calibration needs (``scenarios.judge.calibration.CalibrationInputs``).

The entity paths are the recording's (``scenarios.record.viewer.entity``): the pose stream as
it was sent and every detection's blob (``estimator/*``), ``world/cones/truth``, the camera's
pinhole and, beside them, the truth: the true mount (``world/body/camera``) and the true clock
offset (``truth``). The detections are made again from their blobs
(``vnav.detect.detection_from_mask``), exactly as the run had them. A run with an ``[imu]`` also
holds the IMU's mounts (``imu_mount_declared``) and readings: the inputs of a camera-IMU
calibration (``imu_calibration_inputs``), with its true clock offset (``truth``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.judge.calibration import CalibrationInputs, Truth, calibration_detections
from scenarios.judge.imu_calibration import ImuCalibrationInputs
from scenarios.record.viewer import entity
from vnav import quat, se3
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection, detection_from_mask

__all__ = [
    "RecordingError",
    "calibration_inputs",
    "imu_calibration_inputs",
    "imu_mount_declared",
    "read_rows",
    "unpack_masks",
]


class RecordingError(ValueError):
    """A file is not a recording ``calibrate`` can read; the message says what is missing."""


_CALIBRATION_ENTITIES = (
    entity.POSE_STREAM,
    entity.MOUNT_DECLARED,
    entity.STAMP_CAM,
    entity.MASKS,
    entity.CAMERA,
    entity.TRUTH,
    entity.TRUTH_VALUES,
)


def read_rows(path: Path, entities: tuple[str, ...]) -> dict[str, list[dict]]:
    """Every row of ``entities`` (entity paths without the leading ``/``), by entity path.

    Raises
    ------
    RecordingError
        If the file is not a readable Rerun recording.
    """
    import pyarrow as pa
    from rerun.chunk import RrdReader
    from rerun.error_utils import RerunWarning

    wanted: dict[str, list[dict]] = {"/" + p: [] for p in entities}
    try:
        # A file without Rerun's footer (cut short, or of an older version) is read by a scan
        # of the whole file, after a two-line warning on stderr: the scan finds what it holds,
        # and what it lacks is said below, in one line.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RerunWarning)
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


def unpack_masks(packed: np.ndarray, image_size: tuple[int, int]) -> list[ConeDetection]:
    """One image's detections made again from ``scenarios.record.recording.pack_masks``'s
    bytes (``vnav.detect.detection_from_mask``).

    Raises
    ------
    ValueError
        If the bytes end inside a detection or a blob does not fit the image.
    """
    packed = np.asarray(packed, dtype=np.uint8).ravel()
    detections, at = [], 0
    while at < packed.size:
        if at + 8 > packed.size:
            raise ValueError("the masks end inside a detection's box")
        x, y, w, h = (int(v) for v in packed[at : at + 8].view("<u2"))
        n_bytes = (w * h + 7) // 8
        if at + 8 + n_bytes > packed.size:
            raise ValueError("the masks end inside a detection's blob")
        bits = np.unpackbits(packed[at + 8 : at + 8 + n_bytes], count=w * h)
        detections.append(
            detection_from_mask(bits.reshape(h, w).astype(bool), (x, y, w, h), image_size)
        )
        at += 8 + n_bytes
    return detections


@dataclass(frozen=True)
class _Images:
    """What a recording holds of the camera: its intrinsics, each image's stamp on the camera
    clock and detections (made again from their blobs, those clear of the border), the map's
    apexes."""

    camera: PinholeCamera
    stamps_cam_s: np.ndarray
    detections: list[list[ConeDetection]]
    apex_w: np.ndarray

    @property
    def apex_uv(self) -> list[np.ndarray]:
        """The detector's apexes, (K, 2) per image."""
        return [
            np.array([d.apex_uv for d in ds], dtype=np.float64).reshape(-1, 2)
            for ds in self.detections
        ]


def _images(path: Path, rows: dict[str, list[dict]], needed: tuple[str, ...]) -> _Images:
    """The camera's part of a recording's ``rows`` (``read_rows`` of at least
    ``entity.STAMP_CAM``, ``MASKS``, ``CAMERA`` and ``TRUTH``).

    Raises
    ------
    RecordingError
        If an entity of ``needed`` is missing, a blob is cut, or there is no cone map.
    """
    missing = [p for p in needed if not rows[p]]
    if missing:
        raise RecordingError(
            f"{path}: the recording lacks {', '.join(missing)} (written by vnav-demo run of "
            "this version)"
        )
    stamp_rows = sorted((r for r in rows[entity.STAMP_CAM] if "tick" in r), key=lambda r: r["tick"])
    pinhole = next(r for r in rows[entity.CAMERA] if r.get("Pinhole:image_from_camera"))
    K = np.asarray(pinhole["Pinhole:image_from_camera"][0], dtype=np.float64).reshape(3, 3).T
    width, height = (int(v) for v in pinhole["Pinhole:resolution"][0])
    camera = PinholeCamera(K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5, width, height)
    masks = {r["tick"]: r.get("masks") or [] for r in rows[entity.MASKS] if "tick" in r}
    detections = []
    for r in stamp_rows:
        try:
            found = unpack_masks(
                np.asarray(masks.get(r["tick"], []), dtype=np.uint8), (width, height)
            )
        except ValueError as exc:
            raise RecordingError(f"{path}: tick {r['tick']}: {exc}") from None
        detections.append(calibration_detections(found))
    cones = [r for r in rows[entity.TRUTH] if r.get("Points3D:positions")]
    if not cones:
        raise RecordingError(f"{path}: the recording has no cone map (world/cones/truth)")
    cones_w = np.asarray(cones[0]["Points3D:positions"], dtype=np.float64).reshape(-1, 3)
    return _Images(
        camera=camera,
        stamps_cam_s=np.array([r["Scalars:scalars"][0] for r in stamp_rows]),
        detections=detections,
        apex_w=cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m]),
    )


def _true_camera_mount(rows: dict[str, list[dict]]) -> np.ndarray | None:
    """(4, 4) the true camera mount ``T_b_c`` (``world/body/camera``), or None."""
    true_mount = [r for r in rows[entity.CAMERA] if r.get("Transform3D:translation")]
    if not true_mount:
        return None
    if "tick" not in true_mount[0]:
        return _static_transform(true_mount[0])
    return _transforms(true_mount, "tick")[1][0]


def _truth_value(rows: dict[str, list[dict]], name: str) -> float | None:
    """One of the static ``truth`` values, or None where the recording lacks it."""
    found = [r for r in rows[entity.TRUTH_VALUES] if name in r]
    return None if not found else float(found[0][name][0])


def calibration_inputs(path: str | Path) -> CalibrationInputs:
    """The inputs a recording written by ``vnav-demo run`` carries, with its detections
    made again from their blobs (``CalibrationInputs.detections``: ``solve`` re-fits their
    apexes as the run's own calibration does).

    Raises
    ------
    RecordingError
        If the file is not a recording or lacks what calibration needs (say which).
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    rows = read_rows(path, _CALIBRATION_ENTITIES)
    images = _images(
        path, rows, (entity.POSE_STREAM, entity.STAMP_CAM, entity.MASKS, entity.CAMERA)
    )
    stamps_ns, T_w_b = _transforms(rows[entity.POSE_STREAM], "sim_time")
    _, mounts = _transforms(rows[entity.MOUNT_DECLARED], "tick")
    truth = None
    T_true = _true_camera_mount(rows)
    offset_s = _truth_value(rows, "camera_clock_offset_s")
    if T_true is not None and offset_s is not None:
        truth = Truth(T_true, offset_s)
    return CalibrationInputs(
        camera=images.camera,
        pose_stamps_s=stamps_ns * 1e-9,
        T_w_b=T_w_b,
        image_stamps_cam_s=images.stamps_cam_s,
        apex_uv=images.apex_uv,
        apex_w=images.apex_w,
        T_b_c_declared=mounts[0] if len(mounts) else np.eye(4),
        truth=truth,
        detections=images.detections,
    )


_IMU_CALIBRATION_ENTITIES = (
    entity.STAMP_CAM,
    entity.MASKS,
    entity.CAMERA,
    entity.TRUTH,
    entity.TRUTH_VALUES,
    entity.IMU,
    entity.IMU_ANGULAR_RATE,
    entity.IMU_SPECIFIC_FORCE,
)


def _imu_series(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_s (M,), values (M, 3))`` of an IMU entity's readings, in stamp order: the
    ``sim_time`` column holds each reading's stamp on the IMU clock, in whole nanoseconds."""
    rows = sorted(
        (r for r in rows if "sim_time" in r and r.get("Scalars:scalars")),
        key=lambda r: r["sim_time"],
    )
    stamps_s = np.array([r["sim_time"] for r in rows], dtype=np.int64) * 1e-9
    values = np.array([r["Scalars:scalars"] for r in rows], dtype=np.float64).reshape(-1, 3)
    return stamps_s, values


def imu_calibration_inputs(path: str | Path) -> ImuCalibrationInputs:
    """The inputs of a camera-IMU calibration (``vnav.imu_calibration``) a recording of a run
    with an ``[imu]`` carries: each image's stamp on the camera clock and its detections made
    again from their blobs (``ImuCalibrationInputs.solve`` re-fits their apexes as the run's
    own calibration does), the map's apexes, and the IMU's readings at their stamps on its own
    clock; with the truth where the recording holds it (``T_i_c = T_b_i^-1 T_b_c`` of the true
    mounts, ``world/body/imu`` and ``world/body/camera``, and ``truth``'s
    ``imu_time_offset_s``). Neither the pose stream nor a declared mount is read.

    The stamps are read back to the nanosecond (Rerun's ``sim_time``), the intrinsics and the
    true mounts in single precision: the answer agrees with the run's own to those digits.

    Raises
    ------
    RecordingError
        If the file is not a recording, has no IMU readings, or lacks what calibration needs
        (say which).
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    rows = read_rows(path, _IMU_CALIBRATION_ENTITIES)
    t_gyro_s, gyro_i = _imu_series(rows[entity.IMU_ANGULAR_RATE])
    t_accel_s, accel_i = _imu_series(rows[entity.IMU_SPECIFIC_FORCE])
    if not len(t_gyro_s) and not len(t_accel_s):
        raise RecordingError(
            f"{path}: the recording has no IMU readings: run a scenario with [imu]"
        )
    if not np.array_equal(t_gyro_s, t_accel_s):
        raise RecordingError(
            f"{path}: the recording's angular rates ({len(t_gyro_s)}) and specific forces "
            f"({len(t_accel_s)}) are not read at the same stamps"
        )
    images = _images(path, rows, (entity.STAMP_CAM, entity.MASKS, entity.CAMERA))
    T_i_c_true = None
    T_b_c = _true_camera_mount(rows)
    imu_mounts = [r for r in rows[entity.IMU] if r.get("Transform3D:translation")]
    if T_b_c is not None and imu_mounts:
        T_i_c_true = se3.invert(_static_transform(imu_mounts[-1])) @ T_b_c
    return ImuCalibrationInputs(
        camera=images.camera,
        image_stamps_cam_s=images.stamps_cam_s,
        apex_uv=images.apex_uv,
        apex_w=images.apex_w,
        imu_stamps_s=t_gyro_s,
        gyro_i=gyro_i,
        accel_i=accel_i,
        T_i_c_true=T_i_c_true,
        time_offset_true_s=_truth_value(rows, "imu_time_offset_s"),
        detections=images.detections,
    )


def _static_transform(row: dict) -> np.ndarray:
    """(4, 4) a static ``Transform3D`` row's parent-from-child transform."""
    T = np.eye(4)
    T[:3, 3] = row["Transform3D:translation"][0]
    T[:3, :3] = quat.to_matrix(np.asarray(row["Transform3D:quaternion"][0]), normalize=True)
    return T


def imu_mount_declared(path: str | Path) -> np.ndarray | None:
    """(4, 4) the IMU's declared mount ``T_b_i`` in a recording of a run with an ``[imu]``: the
    mount an estimator is told (``world/body/imu_declared``, or ``world/body/imu`` where the
    scenario has no ``[imu.mount_error]``: declared and true are then one,
    ``scenarios.record.imu_views``); None for a run without an IMU.

    Raises
    ------
    RecordingError
        If the file is not a readable Rerun recording.
    """
    rows = read_rows(Path(path), (entity.IMU, entity.IMU_DECLARED))
    for key in (entity.IMU_DECLARED, entity.IMU):
        mounts = [r for r in rows[key] if r.get("Transform3D:translation")]
        if mounts:
            return _static_transform(mounts[-1])
    return None
