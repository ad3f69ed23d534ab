"""A run as a ROS 2 bag in one MCAP file, written without ROS (``mcap``, ``mcap-ros2-support``).

Foxglove, Rerun (``rerun FILE.mcap``), ``ros2 bag play`` and the ``rosbags`` library read it.
Topics (frames per REP 103 and REP 105, docs/CONVENTIONS.md, "ROS 2 bags (MCAP) and Kalibr"):

- ``/tf`` (``tf2_msgs/msg/TFMessage``): ``map`` -> ``base_link``, the true body pose ``T_w_b``
  at each image;
- ``/tf_static`` (``tf2_msgs/msg/TFMessage``): ``base_link`` -> ``camera_optical_frame``, the
  true mount ``T_b_c``, and, with an ``[imu]``, ``base_link`` -> ``imu_link``, the IMU's
  declared mount ``T_b_i`` (the one an estimator is told; the simulator's IMU sits at the true
  mount, off it by ``[imu.mount_error]``), in one message, once, latched (transient local);
- ``/camera/image_raw`` (``sensor_msgs/msg/Image``): the image as rendered, ``rgb8``;
- ``/camera/camera_info`` (``sensor_msgs/msg/CameraInfo``): ``K``, ``P = [K | 0]``, ``R = I``,
  ``plumb_bob`` with zero distortion;
- ``/camera/depth/image_raw`` (``sensor_msgs/msg/Image``): planar depth, ``16UC1``, millimetres
  (as RGB-D cameras' drivers publish it, and the EuRoC export's depth PNGs hold it: the same
  pixels, ``scenarios.export.base.depth_mm``), 0 where there is no return (the sky, the far
  plane, beyond 65.535 m), which ``depth_image_proc`` reads as "no measurement";
- ``/ground_truth/pose`` (``geometry_msgs/msg/PoseStamped``): ``T_w_b`` in ``map``;
- ``/cones`` (``visualization_msgs/msg/MarkerArray``): the true cones, one ``TRIANGLE_LIST``
  each (the simulator's meshes), latched;
- ``/estimates/<method>`` (``geometry_msgs/msg/PointStamped``): each estimate of a cone's
  base centre, in ``map``;
- ``/imu`` (``sensor_msgs/msg/Imu``), a scenario with an ``[imu]`` only: every reading in
  ``imu_link``, ``angular_velocity`` (rad/s) and ``linear_acceleration`` (the specific force,
  m/s^2), noise and bias included; no orientation (``orientation`` the identity, ROS 2's
  default, and ``orientation_covariance[0] = -1``, as the message's definition asks); the
  other two covariances diagonal, each axis' white-noise variance per reading, Kalibr's
  discrete model ``density^2 * rate_hz`` (what the simulator draws,
  ``vnav.imu.ImuNoiseProcess``; the drifting bias is not in it; an IMU without noise has
  zeros, which ROS reads as "unknown").

A flight that slides the camera on the body (a keyframed ``camera_position_b``) has no
``/tf_static``: its mount goes on ``/tf`` with the body pose at every image (such a flight has
no dynamics, hence no IMU).

Stamps: every message of an image (its ``/tf``, its pose, its camera info, its estimates)
carries the image's exposure stamp on the **camera clock** (as the TUM files do), and each
``/imu`` reading its stamp on the **IMU's clock** (``ImuRecord.t_s``: ``t_imu = t_cam +
time_offset_s``, Kalibr's ``timeshift_cam_imu``; not converted to the camera's, as an
unsynchronised rig's driver stamps it, so that the offset is in the bag for a camera-IMU
calibration to find), both plus ``stamp_origin_s``: a whole number of seconds, 0 unless either
clock reads negative at the start of the flight (the camera's when ``camera_clock_offset_s >
0``: ``t_cam = t_pose - offset``; the IMU's when ``camera_clock_offset_s - time_offset_s >
0``), which ROS time cannot hold. Each message's MCAP ``log_time`` and ``publish_time`` are
that stamp in nanoseconds (the readings are written after the run, the file's index orders
them). The file's metadata record ``vnav_sim`` names the scenario, the seed, the clock
offsets and ``stamp_origin_s``.

The messages are encoded and written, and the file's chunks compressed (zstd at level 1, as
the C++ MCAP writer's default: ``ZSTD_LEVEL``), on a thread of the exporter's own, overlapping
the next tick's rendering; ``on_tick`` checks the images and queues them. An image message is
encoded straight from its pixels (``_image_cdr``: one copy, not the generic encoder's three),
the camera info once (``_restamped``: only its stamp changes).
"""

from __future__ import annotations

import logging
import math
import os
import re
import struct
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
import zstandard
from isal import isal_zlib
from mcap.records import Chunk, ChunkIndex
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter

# The CDR encoder of mcap-ros2-support's own Writer (a module function; that Writer registers
# channels without the ``offered_qos_profiles`` the ros2 profile requires, so the channels are
# registered here through mcap's Writer).
from mcap_ros2._dynamic import serialize_dynamic

from scenarios.export.base import (
    ExportResult,
    TickDepthMm,
    exporter_threads,
    queue_bound,
    tick_depth_mm,
)
from scenarios.export.ros2_msgs import QOS_LATCHED, QOS_VOLATILE, msgdef
from scenarios.scenario.spec import KinematicFlight
from vnav import quat, se3

if TYPE_CHECKING:
    from scenarios.run.records import ImuRecord, RunResult, TickRecord
    from scenarios.scenario.spec import ScenarioSpec
    from sim.config import ImuConfig
    from sim.mesh import Scenery
    from vnav.camera import PinholeCamera

__all__ = [
    "FRAME_BODY",
    "FRAME_CAMERA",
    "FRAME_IMU",
    "FRAME_MAP",
    "IMU_TOPIC",
    "TOPICS",
    "McapExporter",
    "estimates_topic",
    "imu_covariances",
]

logger = logging.getLogger(__name__)

FRAME_MAP = "map"
"""The world frame ``w`` (ENU, z up): REP 105's ``map``."""
FRAME_BODY = "base_link"
"""The body frame ``b`` (FLU): REP 103's ``base_link``."""
FRAME_CAMERA = "camera_optical_frame"
"""The camera's optical frame ``c`` (x right, y down, z forward): REP 103's ``*_optical_frame``."""
FRAME_IMU = "imu_link"
"""The IMU's frame ``i`` (its readings' axes), as ROS drivers name it."""

TOPICS: dict[str, str] = {
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/camera/image_raw": "sensor_msgs/msg/Image",
    "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/camera/depth/image_raw": "sensor_msgs/msg/Image",
    "/ground_truth/pose": "geometry_msgs/msg/PoseStamped",
    "/cones": "visualization_msgs/msg/MarkerArray",
}
"""Every fixed topic and its type (``/estimates/<method>``: ``geometry_msgs/msg/PointStamped``;
``IMU_TOPIC`` with an ``[imu]``)."""
IMU_TOPIC = ("/imu", "sensor_msgs/msg/Imu")
"""The IMU's readings: a scenario with an ``[imu]`` only."""

_LATCHED = {"/tf_static", "/cones"}
_ESTIMATE_TYPE = "geometry_msgs/msg/PointStamped"
_MARKER_TRIANGLE_LIST = 11
_NS_PER_S = 1_000_000_000
ZSTD_LEVEL = 1
"""The zstd level of the file's chunks: the C++ MCAP writer's default (what ``ros2 bag record``
writes with), not the Python writer's 3: a tick's 1.5 MB chunk compressed in 3.2 ms instead
of 4.6 ms, 6% larger."""


def estimates_topic(method: str) -> str:
    """The topic of ``method``'s estimates: ``/estimates/<method>``, a user method
    ``user:name`` as ``/estimates/user/name``, any character a ROS name cannot hold as ``_``."""
    tokens = [re.sub(r"\W|^(?=\d)", "_", t, flags=re.ASCII) for t in method.split(":")]
    return "/estimates/" + "/".join(t or "_" for t in tokens)


class _LevelledWriter(McapWriter):
    """mcap's ``Writer`` whose zstd chunks are compressed at ``ZSTD_LEVEL`` by one compressor
    kept for the file, and checksummed by ISA-L's CRC-32 (the same value as zlib's, in a
    quarter of the time).

    mcap's Python writer has no compression level: it calls ``zstandard.compress`` (level 3, a
    new context for each chunk). Its private ``__finalize_chunk`` (``_Writer__finalize_chunk``
    to a subclass) is replaced here, for this writer only, by the same steps as mcap 1.6's
    with that compressor: the same records, indexes and statistics, the chunk's bytes those
    of another zstd level. Another compression type goes to mcap's own. The writer is used
    from one thread at a time (the compressor is not thread-safe).
    """

    def __init__(self, output: BinaryIO, compression: CompressionType) -> None:
        super().__init__(output, compression=compression)
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)

    def _Writer__finalize_chunk(self) -> None:
        if self._Writer__compression != CompressionType.ZSTD:
            super()._Writer__finalize_chunk()
            return
        builder = self._Writer__chunk_builder
        if not builder or builder.num_messages == 0:
            return
        self._Writer__statistics.chunk_count += 1
        chunk_data = builder.end()
        compressed = self._zstd.compress(chunk_data)
        chunk = Chunk(
            compression="zstd",
            data=compressed,
            message_start_time=builder.message_start_time,
            message_end_time=builder.message_end_time,
            uncompressed_crc=isal_zlib.crc32(chunk_data) if self._Writer__enable_crcs else 0,
            uncompressed_size=len(chunk_data),
        )
        records, stream = self._Writer__record_builder, self._Writer__stream
        self._Writer__flush()
        chunk_start_offset = stream.tell()
        chunk.write(records)
        chunk_index = ChunkIndex(
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            chunk_start_offset=chunk_start_offset,
            chunk_length=records.count,
            message_index_offsets={},
            message_index_length=0,
            compression=chunk.compression,
            compressed_size=len(compressed),
            uncompressed_size=chunk.uncompressed_size,
        )
        self._Writer__flush()
        message_index_start_offset = stream.tell()
        if self._Writer__index_types & IndexType.MESSAGE:
            for channel_id, index in builder.message_indices.items():
                chunk_index.message_index_offsets[channel_id] = (
                    message_index_start_offset + records.count
                )
                index.write(records)
        chunk_index.message_index_length = records.count
        self._Writer__flush()
        self._Writer__chunk_indices.append(chunk_index)
        builder.reset()


class McapExporter:
    """Writes a run as ``<final_name>.mcap`` under ``staging_dir`` as it happens
    (``scenarios.export.base.Exporter``).

    Parameters
    ----------
    staging_dir : Path
        An existing directory; the file is created there (never over an existing one).
    final_name : str, optional
        The file's stem; the scenario's name if not given.
    compression : mcap.writer.CompressionType
        Of the file's chunks (zstd by default; ``LZ4`` writes faster, ``NONE`` fastest).
    """

    name = "mcap"

    def __init__(
        self,
        staging_dir: Path,
        final_name: str | None = None,
        compression: CompressionType = CompressionType.ZSTD,
    ) -> None:
        self._staging_dir = Path(staging_dir)
        self._final_name = final_name
        self.path: Path | None = None
        self._compression = compression
        self._file: BinaryIO | None = None
        self._writer: _LevelledWriter | None = None
        self._schemas: dict[str, tuple[int, Any]] = {}
        self._channels: dict[str, tuple[int, Any]] = {}
        self._sequence: dict[str, int] = {}
        self._camera: PinholeCamera | None = None
        self._camera_info_cdr = b""
        self._T_b_c_static: np.ndarray | None = None
        self._origin_ns = 0
        self._depth_ticks = 0
        self._ticks = 0
        self._spec: ScenarioSpec | None = None
        self._thread: ThreadPoolExecutor | None = None
        self._pending: deque[Future] = deque()

    # -- the run -------------------------------------------------------------------------

    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        """Create the file; write its metadata, the static mount and the cones.

        Raises
        ------
        OSError
            If the file cannot be created (or already exists).
        """
        self.path = self._staging_dir / f"{self._final_name or spec.name}.mcap"
        offset_s = spec.timing.camera_clock_offset_s
        imu = spec.scene.imu
        # The clock that reads furthest behind at the flight's start sets the origin: the
        # camera's reads -offset_s there, the IMU's -offset_s + time_offset_s.
        behind_s = offset_s if imu is None else max(offset_s, offset_s - imu.time_offset_s)
        origin_s = max(0, math.ceil(behind_s))
        self._origin_ns = origin_s * _NS_PER_S
        self._camera = camera
        self._spec = spec
        self._file = open(self.path, "xb")  # closed by finish or abort
        self._writer = _LevelledWriter(self._file, self._compression)
        self._writer.start(profile="ros2", library="vnav-sim (mcap, mcap-ros2-support)")
        metadata = {
            "scenario": spec.name,
            "seed": str(seed),
            "camera_clock_offset_s": repr(offset_s),
            "stamp_origin_s": str(origin_s),
            "stamps": "image exposure on the camera clock + stamp_origin_s",
        }
        if imu is not None:
            metadata["imu_time_offset_s"] = repr(imu.time_offset_s)
            metadata["imu_stamps"] = (
                "reading on the IMU clock (t_imu = t_cam + imu_time_offset_s) + stamp_origin_s"
            )
        self._writer.add_metadata("vnav_sim", metadata)
        for topic, type_name in TOPICS.items():
            self._channel(topic, type_name)
        if imu is not None:
            self._channel(*IMU_TOPIC)
        # The camera info is the same message at every image but for its stamp: encoded once.
        self._camera_info_cdr = self._channels["/camera/camera_info"][1](_camera_info(camera, 0))
        # The flight starts at t_pose = 0, which the camera clock reads as -offset.
        stamp_ns = self._stamp_ns(-offset_s)
        moves_camera = isinstance(spec.flight, KinematicFlight) and spec.flight.moves_camera
        static = []
        if not moves_camera:
            self._T_b_c_static = se3.check_pose(spec.scene.camera.T_b_c, "T_b_c")
            static.append(_transform(stamp_ns, FRAME_BODY, FRAME_CAMERA, self._T_b_c_static))
        if imu is not None:
            static.append(_transform(stamp_ns, FRAME_BODY, FRAME_IMU, imu.T_b_i_declared))
        if static:
            # One message: a latched topic keeps only its last one for a late subscriber.
            self._write("/tf_static", {"transforms": static}, stamp_ns)
        self._write("/cones", _cone_markers(spec, scenery, stamp_ns), stamp_ns)
        self._thread = exporter_threads(1, "vnav-mcap")

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        """Check the image's messages and queue them for the writer thread, all stamped at its
        exposure (camera clock).

        Raises
        ------
        ValueError
            If ``rgb`` is not the camera's (H, W, 3) uint8 image, ``depth_m`` not its (H, W)
            depth, or the mount differs from the static one written at the start.
        OSError
            If writing an earlier tick failed (a full disk...).
        """
        if self._writer is None or self._camera is None or self._thread is None:
            raise ValueError("on_tick before start (or after finish or abort)")
        while self._pending and self._pending[0].done():
            self._pending.popleft().result()
        cam = self._camera
        rgb = np.asarray(rgb)
        if rgb.shape != (cam.height, cam.width, 3) or rgb.dtype != np.uint8:
            raise ValueError(
                f"rgb: expected a ({cam.height}, {cam.width}, 3) uint8 image, got "
                f"{rgb.shape} {rgb.dtype}"
            )
        depth = None
        if depth_m is not None:
            depth = np.asarray(depth_m)
            if depth.shape != (cam.height, cam.width) or not np.issubdtype(
                depth.dtype, np.floating
            ):
                raise ValueError(
                    f"depth_m: expected a ({cam.height}, {cam.width}) float image, got "
                    f"{depth.shape} {depth.dtype}"
                )
            depth = tick_depth_mm(record, depth, self._spec.scene.zfar_m)
        stamp_cam_s = record.t_s if record.timing is None else record.timing.stamp_cam_s
        stamp_ns = self._stamp_ns(stamp_cam_s)
        transforms = [_transform(stamp_ns, FRAME_MAP, FRAME_BODY, record.T_w_b)]
        if self._T_b_c_static is None:
            transforms.append(_transform(stamp_ns, FRAME_BODY, FRAME_CAMERA, record.T_b_c))
        elif not np.allclose(record.T_b_c, self._T_b_c_static, rtol=0.0, atol=1e-9):
            raise ValueError(
                f"tick {record.tick}: the camera mount T_b_c moved from the static mount "
                "written to /tf_static, in a flight that does not slide the camera"
            )
        self._pending.append(
            self._thread.submit(self._write_tick, record, stamp_ns, transforms, rgb, depth)
        )
        while len(self._pending) > queue_bound(rgb, depth_m):
            self._pending.popleft().result()
        self._ticks += 1

    def _write_tick(
        self,
        record: TickRecord,
        stamp_ns: int,
        transforms: list[dict],
        rgb: np.ndarray,
        depth_mm: TickDepthMm | None,
    ) -> None:
        """Write one tick's messages (on the writer thread)."""
        self._write("/tf", {"transforms": transforms}, stamp_ns)
        q_xyzw = quat.from_matrix(record.T_w_b[:3, :3])
        self._write(
            "/ground_truth/pose",
            {
                "header": _header(stamp_ns, FRAME_MAP),
                "pose": {"position": _xyz(record.T_w_b[:3, 3]), "orientation": _q(q_xyzw)},
            },
            stamp_ns,
        )
        camera_info = _restamped(self._camera_info_cdr, stamp_ns)
        self._write_raw("/camera/camera_info", camera_info, stamp_ns)
        self._write_raw("/camera/image_raw", _image_cdr(rgb, "rgb8", stamp_ns), stamp_ns)
        if depth_mm is not None:
            self._write_raw(
                "/camera/depth/image_raw", _image_cdr(depth_mm.get(), "16UC1", stamp_ns), stamp_ns
            )
            self._depth_ticks += 1
        for d in record.detections:
            for method, p_w in d.estimates_w.items():
                topic = estimates_topic(method)
                self._channel(topic, _ESTIMATE_TYPE)
                point = {"header": _header(stamp_ns, FRAME_MAP), "point": _xyz(p_w)}
                self._write(topic, point, stamp_ns)

    def finish(self, result: RunResult) -> ExportResult:
        """Write the file's index and footer and close it, flushed to the disk.

        Raises
        ------
        OSError
            If the file cannot be completed (it is then removed).
        """
        if self._writer is None or self._file is None:
            raise ValueError("finish before start (or after finish or abort)")
        try:
            try:
                while self._pending:
                    self._pending.popleft().result()
            finally:
                self._thread.shutdown(wait=True, cancel_futures=True)
            imu = self._spec.scene.imu if self._spec is not None else None
            if imu is not None and result.imu is not None:
                self._write_imu(imu, result.imu)
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
        except BaseException:
            self.abort()
            raise
        self._writer = self._file = None
        notes = []
        if self._ticks and not self._depth_ticks:
            notes.append("no depth images: the run rendered none")
        if result.spec.scene.imu is None:
            notes.append("no /imu: the scenario has no [imu]")
        else:
            notes.append("/imu is stamped on the IMU's clock, not the camera's")
        note = "; ".join(notes)
        logger.info("wrote %s: %d camera ticks of %s", self.path, self._ticks, result.spec.name)
        return ExportResult(self.name, (self.path.name,), note=note)

    def abort(self) -> None:
        """Stop the writer thread; close and remove the file if it was started."""
        if self._thread is not None:
            self._thread.shutdown(wait=True, cancel_futures=True)
        self._pending.clear()
        if self._file is not None:
            try:
                self._file.close()
            finally:
                self._file = self._writer = None
                if self.path is not None:
                    self.path.unlink(missing_ok=True)

    def _write_imu(self, imu: ImuConfig, record: ImuRecord) -> None:
        """Every reading on ``/imu``, stamped on the IMU's clock."""
        cov_gyro, cov_accel = imu_covariances(imu)
        no_orientation = [-1.0] + [0.0] * 8
        for t_s, gyro_i, accel_i in zip(record.t_s, record.gyro_i, record.accel_i, strict=True):
            stamp_ns = self._stamp_ns(float(t_s))
            message = {
                "header": _header(stamp_ns, FRAME_IMU),
                "orientation": _q((0.0, 0.0, 0.0, 1.0)),
                "orientation_covariance": no_orientation,
                "angular_velocity": _xyz(gyro_i),
                "angular_velocity_covariance": cov_gyro,
                "linear_acceleration": _xyz(accel_i),
                "linear_acceleration_covariance": cov_accel,
            }
            self._write(IMU_TOPIC[0], message, stamp_ns)

    # -- the file ------------------------------------------------------------------------

    def _stamp_ns(self, t_s: float) -> int:
        """A stamp on the camera's or the IMU's clock, seconds, as written: nanoseconds plus
        the origin."""
        return round(t_s * _NS_PER_S) + self._origin_ns

    def _channel(self, topic: str, type_name: str) -> None:
        """Register ``topic`` (and its type's schema) once."""
        assert self._writer is not None
        if topic in self._channels:
            return
        if type_name not in self._schemas:
            text = msgdef(type_name)
            schema_id = self._writer.register_schema(
                type_name, SchemaEncoding.ROS2, text.encode("utf-8")
            )
            self._schemas[type_name] = (schema_id, serialize_dynamic(type_name, text)[type_name])
        schema_id, encode = self._schemas[type_name]
        qos = QOS_LATCHED if topic in _LATCHED else QOS_VOLATILE
        channel_id = self._writer.register_channel(
            topic, MessageEncoding.CDR, schema_id, {"offered_qos_profiles": qos}
        )
        self._channels[topic] = (channel_id, encode)
        self._sequence[topic] = 0

    def _write(self, topic: str, message: dict, stamp_ns: int) -> None:
        self._write_raw(topic, self._channels[topic][1](message), stamp_ns)

    def _write_raw(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """Write a message already encoded (CDR) on ``topic``."""
        assert self._writer is not None
        self._writer.add_message(
            self._channels[topic][0],
            log_time=stamp_ns,
            data=data,
            publish_time=stamp_ns,
            sequence=self._sequence[topic],
        )
        self._sequence[topic] += 1


def imu_covariances(imu: ImuConfig) -> tuple[list[float], list[float]]:
    """``sensor_msgs/Imu``'s ``angular_velocity_covariance`` and
    ``linear_acceleration_covariance`` (row major, x, y, z): diagonal, each axis' variance of a
    reading's white noise in Kalibr's discrete model, ``(density / sqrt(dt))^2 = density^2 *
    rate_hz`` (``vnav.imu.ImuNoise.white_std``; the drifting bias is not in it).

    Returns
    -------
    gyro, accel : list of 9 float
        (rad/s)^2 and (m/s^2)^2.
    """
    std_accel, std_gyro = imu.noise.white_std(1.0 / imu.rate_hz)
    return (
        [float(v) for v in np.diag([std_gyro**2] * 3).ravel()],
        [float(v) for v in np.diag([std_accel**2] * 3).ravel()],
    )


# -- messages, as the dicts mcap-ros2-support encodes -----------------------------------------


def _time(stamp_ns: int) -> dict:
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    return {"sec": sec, "nanosec": nanosec}


def _header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": _time(stamp_ns), "frame_id": frame_id}


def _xyz(p) -> dict:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def _q(q_xyzw) -> dict:
    # ROS messages order quaternions x, y, z, w as vnav does: nothing is reordered.
    return dict(zip("xyzw", map(float, q_xyzw), strict=True))


def _transform(stamp_ns: int, parent: str, child: str, T_parent_child: np.ndarray) -> dict:
    """A ``TransformStamped``: tf2's transform from ``parent`` to ``child`` is the pose of
    ``child`` in ``parent`` (``p_parent = T_parent_child p_child``), the project's ``T_a_b``."""
    T = se3.check_pose(T_parent_child, "T_parent_child")
    return {
        "header": _header(stamp_ns, parent),
        "child_frame_id": child,
        "transform": {"translation": _xyz(T[:3, 3]), "rotation": _q(quat.from_matrix(T[:3, :3]))},
    }


def _camera_info(camera: PinholeCamera, stamp_ns: int) -> dict:
    """``K`` as the project's (OpenCV's pixel-centre convention, which ROS's ``image_geometry``
    shares), no distortion, ``R = I``, ``P = [K | 0]`` (a monocular camera)."""
    K = camera.K
    P = np.hstack([K, np.zeros((3, 1))])
    return {
        "header": _header(stamp_ns, FRAME_CAMERA),
        "height": camera.height,
        "width": camera.width,
        "distortion_model": "plumb_bob",
        "d": [0.0] * 5,
        "k": [float(v) for v in K.ravel()],
        "r": [float(v) for v in np.eye(3).ravel()],
        "p": [float(v) for v in P.ravel()],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


_CDR_LE = b"\x00\x01\x00\x00"
"""The encapsulation header of little-endian plain CDR (what ROS 2 writes)."""


def _cdr_string(text: str, offset: int) -> bytes:
    """A CDR string at ``offset`` (from the end of the encapsulation header): padding to 4,
    its length with the NUL, the bytes, the NUL."""
    raw = text.encode("utf-8") + b"\x00"
    return b"\x00" * (-offset % 4) + struct.pack("<I", len(raw)) + raw


def _restamped(message: bytes, stamp_ns: int) -> bytearray:
    """A copy of a little-endian CDR message that starts with its ``std_msgs/Header`` (as every
    stamped message does) with the header's stamp set to ``stamp_ns``: the stamp's ``int32
    sec`` and ``uint32 nanosec`` are the first 8 bytes after the encapsulation header, whatever
    follows them."""
    if message[: len(_CDR_LE)] != _CDR_LE:
        raise ValueError("message: expected little-endian plain CDR")
    out = bytearray(message)
    struct.pack_into("<iI", out, len(_CDR_LE), *divmod(stamp_ns, _NS_PER_S))
    return out


def _image_cdr(pixels: np.ndarray, encoding: str, stamp_ns: int) -> bytearray:
    """A ``sensor_msgs/Image`` in ``FRAME_CAMERA`` of an (H, W) or (H, W, C) array, rows
    packed (no padding), CDR-encoded: the bytes mcap-ros2-support's encoder makes of the same
    message, with the pixels copied once, by numpy (which lets other threads run meanwhile);
    little-endian (``is_bigendian`` 0) whatever the machine.

    Parameters
    ----------
    pixels : ndarray, shape (H, W) or (H, W, C), uint8 or uint16
    encoding : str
        ``sensor_msgs/Image``'s ``encoding`` (``rgb8``, ``16UC1``).
    stamp_ns : int
    """
    pixels = np.asarray(pixels)
    little = pixels.dtype.newbyteorder("<")
    height, width = pixels.shape[:2]
    step = width * math.prod(pixels.shape[2:]) * pixels.dtype.itemsize
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    out = struct.pack("<iI", sec, nanosec)
    out += _cdr_string(FRAME_CAMERA, len(out))
    out += b"\x00" * (-len(out) % 4) + struct.pack("<II", height, width)
    out += _cdr_string(encoding, len(out))
    out += b"\x00"  # is_bigendian
    out += b"\x00" * (-len(out) % 4) + struct.pack("<II", step, step * height)
    header = _CDR_LE + out
    message = bytearray(len(header) + step * height)
    message[: len(header)] = header
    data = np.frombuffer(message, dtype=little, offset=len(header)).reshape(pixels.shape)
    np.copyto(data, pixels, casting="equiv")
    return message


def _cone_markers(spec: ScenarioSpec, scenery: Scenery, stamp_ns: int) -> dict:
    """One ``TRIANGLE_LIST`` marker per true cone, posed at its base centre in ``map``, its
    points the simulator's mesh of that cone relative to the base centre (each triangle of the
    scene's cone mesh goes to the cone nearest its centroid), coloured per vertex."""
    cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
    mesh = scenery.cones_w
    markers = []
    if len(cones_w):
        corners_w = mesh.vertices[mesh.triangles]  # (M, 3 corners, 3)
        centroids_w = corners_w.mean(axis=1)
        nearest = np.argmin(
            np.linalg.norm(centroids_w[:, None, :2] - cones_w[None, :, :2], axis=2), axis=1
        )
        colors = mesh.colors_rgba[mesh.triangles] / 255.0  # (M, 3, 4)
        for i, base_w in enumerate(cones_w):
            mine = nearest == i
            points = (corners_w[mine] - base_w).reshape(-1, 3)
            rgba = colors[mine].reshape(-1, 4)
            first = rgba[0] if len(rgba) else np.ones(4)
            markers.append(
                {
                    "header": _header(stamp_ns, FRAME_MAP),
                    "ns": "cones",
                    "id": i,
                    "type": _MARKER_TRIANGLE_LIST,
                    "action": 0,
                    "pose": {"position": _xyz(base_w), "orientation": _q((0.0, 0.0, 0.0, 1.0))},
                    "scale": {"x": 1.0, "y": 1.0, "z": 1.0},
                    "color": dict(zip("rgba", map(float, first), strict=True)),
                    "lifetime": {"sec": 0, "nanosec": 0},  # forever
                    "frame_locked": False,
                    "points": [_xyz(p) for p in points],
                    "colors": [dict(zip("rgba", map(float, c), strict=True)) for c in rgba],
                }
            )
    return {"markers": markers}
