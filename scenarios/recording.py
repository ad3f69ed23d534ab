"""Rerun recording of a scenario: the entity tree is the frame tree.

Entity tree (paths declared in ``scenarios.viewer.entity``; frames in docs/CONVENTIONS.md)::

    world                          ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/body                     Transform3D T_w_b, every camera tick
    world/body/camera              Transform3D T_b_c + Pinhole (true intrinsics, RDF) (static;
                                   T_b_c every tick in a scenario that slides the camera)
    world/body/camera/image        JPEG-compressed RGB
    world/body/camera/depth        planar z-depth, PNG-encoded 16-bit millimetres, every 5th
    world/body/camera/detections   Boxes2D + Points2D (apex, base keypoints)
    world/cones/truth              Points3D of the true base centres (static)
    world/cones/estimate/<method>  Points3D per method, every camera tick
    world/depth_cloud              decimated depth image in world coordinates
    world/trajectory               LineStrips3D of the flown path (static, at the end)
    metrics/error/<method>         Scalars, metres
    metrics/range_m                Scalars, metres
    attitude/rpy_deg, quat_xyzw    roll/pitch/yaw (deg) and quaternion of R_w_b; gimbal_locked
    coordinates/cone0_<frame>      cone 0 in world, body, camera (truth) and its estimate
    description                    TextDocument (markdown)

Timelines: ``tick`` (camera tick index) and ``sim_time`` (simulated seconds). Transforms are
logged parent-from-child (Rerun's default relation), which is exactly vnav's
``T_parent_child``: ``world/body`` gets ``T_w_b``, ``world/body/camera`` gets ``T_b_c``.

``Recording`` is a ``scenarios.runner.TickObserver``: it is fed the run's records
(``scenarios.records``) and images, as evo's Rerun bridge is fed its trajectory objects. It
writes to a temporary name; ``scenarios.outputs`` checks the finished file and puts it in
place together with the report.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rerun as rr

from scenarios.records import RunResult, TickRecord
from scenarios.spec import ScenarioSpec
from scenarios.viewer import (
    AXIS_COLORS,
    CONE0_SERIES,
    TRUTH_COLOR,
    blueprint,
    describe,
    entity,
    eye_for,
)
from vnav import quat
from vnav.camera import PinholeCamera, depth_to_world_points
from vnav.methods import METHOD_NAMES, METHODS

__all__ = ["Recording", "depth_for_display_mm", "rerun_image_from_camera", "rerun_uv"]

APPLICATION_ID = "vnav-sim"
DEPTH_LOG_EVERY = 5
"""The depth image is logged every 5th camera tick: a rolled camera's depth image barely
compresses (about 100 KB as PNG) and the viewer shows the latest one in between."""
DEPTH_MANTISSA_BITS = 6
"""Logged depth keeps 6 significant bits (relative step <= 1/64; display only: estimates use
the full float depth)."""
JPEG_QUALITY = 80
DEPTH_MM_MAX = np.iinfo(np.uint16).max


CLOUD_STRIDE_PX = 16
"""Every 16th row and column of the depth image goes into the logged world cloud."""
FLUSH_EVERY_TICKS = 50
"""Buffered camera ticks are sent to the file in column batches of this many."""


def depth_for_display_mm(depth_m: np.ndarray) -> np.ndarray:
    """Planar depth in metres -> uint16 millimetres for a PNG, 0 where there is no return.

    Rounded to ``DEPTH_MANTISSA_BITS`` significant bits (steps of 2**k mm, at most 1/64 of
    the depth), so the far ground compresses; beyond 65.535 m (and the sky) it becomes 0.
    """
    depth_mm = np.nan_to_num(depth_m, nan=0.0, posinf=0.0).astype(np.float32) * 1000.0
    # Round the float32 mantissa (23 bits) to its top bits: integer ops on the bit pattern.
    drop = 23 - DEPTH_MANTISSA_BITS
    bits = depth_mm.view(np.uint32)
    bits += np.uint32(1 << (drop - 1))
    bits &= np.uint32(~((1 << drop) - 1) & 0xFFFFFFFF)
    depth_mm[depth_mm > DEPTH_MM_MAX] = 0.0
    return np.rint(depth_mm).astype(np.uint16)


def _encode(rgb: np.ndarray, depth_m: np.ndarray | None) -> tuple[bytes, bytes | None]:
    """JPEG bytes of an RGB image and PNG bytes of its depth for display (or None)."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("OpenCV could not JPEG-encode the camera image")
    if depth_m is None:
        return jpeg.tobytes(), None
    ok, png = cv2.imencode(".png", depth_for_display_mm(depth_m))
    if not ok:
        raise RuntimeError("OpenCV could not PNG-encode the depth image")
    return jpeg.tobytes(), png.tobytes()


def rerun_uv(uv_opencv: np.ndarray) -> np.ndarray:
    """OpenCV pixel coordinates -> Rerun's.

    OpenCV puts the centre of the top-left pixel at (0, 0); Rerun's pinhole and 2D views put
    it at (0.5, 0.5) (continuous coordinates). Every pixel coordinate bound for Rerun passes
    through here.
    """
    return np.asarray(uv_opencv, dtype=np.float64) + 0.5


def rerun_image_from_camera(camera: PinholeCamera) -> np.ndarray:
    """The (3, 3) intrinsic matrix in Rerun's pixel convention (principal point + 0.5)."""
    K = camera.K.copy()
    K[:2, 2] = rerun_uv(K[:2, 2])
    return K


def _pose_transform(T_parent_child: np.ndarray) -> rr.Transform3D:
    # vnav and Rerun both order quaternions x, y, z, w: no reordering at this border.
    quat_xyzw = quat.from_matrix(T_parent_child[:3, :3])
    return rr.Transform3D(
        translation=T_parent_child[:3, 3],
        quaternion=rr.Quaternion(xyzw=quat_xyzw),
        relation=rr.TransformRelation.ParentFromChild,
    )


@dataclass
class _Buffered:
    """One camera tick waiting to be sent: its record, encoded images and depth cloud."""

    record: TickRecord
    encoded: Future[tuple[bytes, bytes | None]]
    """JPEG of the image and PNG of the depth (or None), from the encoder thread."""
    cloud_w: np.ndarray | None
    """The decimated depth image in world coordinates, float32 (M, 3)."""


def _depth_cloud_w(
    depth_m: np.ndarray, camera: PinholeCamera, T_w_c: np.ndarray, far_m: float
) -> np.ndarray:
    """Every ``CLOUD_STRIDE_PX``-th pixel of the depth image in the world, float32 (M, 3)."""
    return depth_to_world_points(
        depth_m, camera, T_w_c, stride=CLOUD_STRIDE_PX, far_m=far_m
    ).astype(np.float32)


class Recording:
    """A scenario's ``.rrd`` file, finished when the run finishes or deleted if it fails.

    Parameters
    ----------
    path : Path
        Where the file is written (a temporary name: ``scenarios.outputs`` puts it in place).
    recording_id : str
        Rerun's recording id, unique per run; the JSON report names it.
    """

    def __init__(self, path: str | Path, recording_id: str) -> None:
        self.path = Path(path)
        self.recording_id = recording_id
        self.rec: rr.RecordingStream | None = None
        self._buffer: list[_Buffered] = []
        self._encoder: ThreadPoolExecutor | None = None
        self._camera: PinholeCamera | None = None
        self._far_m = np.inf
        self._mount_moves = False
        self._cone0_w = np.zeros(3)

    # ------------------------------------------------------------------ TickObserver
    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera) -> None:
        """Open the file and log what does not change over the run."""
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)
        self.rec.save(str(self.path))
        self._encoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vnav-encode")
        self._camera, self._far_m = camera, spec.scene.zfar_m
        self._mount_moves = spec.flight.moves_camera
        self._cone0_w = np.array(spec.scene.cones_w[0], dtype=np.float64)
        _log_static(self.rec, spec, seed, camera)

    def on_tick(self, record: TickRecord, rgb: np.ndarray, depth_m: np.ndarray | None) -> None:
        """Queue one camera tick; send the queue as columns every ``FLUSH_EVERY_TICKS``.

        Ticks are buffered and sent with ``send_columns``: one Arrow batch per entity instead
        of a dozen ``log`` calls per tick, which is what keeps recording cheap next to
        rendering. Encoding runs on a worker thread (OpenCV releases the GIL), overlapping
        with the next tick's rendering.
        """
        assert self._encoder is not None and self._camera is not None, "start() first"
        logged_depth = depth_m if record.tick % DEPTH_LOG_EVERY == 0 else None
        encoded = self._encoder.submit(_encode, rgb, logged_depth)
        cloud_w = None
        if depth_m is not None:
            # Drawn where the estimator believes the camera is (its pose, noise included).
            cloud_w = _depth_cloud_w(
                depth_m, self._camera, record.T_w_b_est @ record.T_b_c, self._far_m
            )
        self._buffer.append(_Buffered(record, encoded, cloud_w))
        if len(self._buffer) >= FLUSH_EVERY_TICKS:
            self._flush()

    def finish(self, result: RunResult) -> None:
        """Log the flown trajectory and finish the file (its footer is written last)."""
        assert self.rec is not None, "start() first"
        self.rec.log(
            entity.TRAJECTORY,
            rr.LineStrips3D([result.trajectory_w], colors=[(255, 200, 0)], radii=0.03),
            static=True,
        )
        self._close()

    def abort(self) -> None:
        """Stop recording and delete the unfinished file."""
        self._close(flush=False)
        self.path.unlink(missing_ok=True)

    def _close(self, *, flush: bool = True) -> None:
        if self.rec is None:
            return
        try:
            if flush:
                self._flush()
        finally:
            if self._encoder is not None:
                self._encoder.shutdown(wait=True, cancel_futures=True)
            self.rec.disconnect()  # writes the footer; without it the file cannot be read
            self.rec = None

    def _flush(self) -> None:
        """Send the buffered ticks as one column batch per entity."""
        rows, self._buffer = self._buffer, []
        if not rows:
            return
        assert self.rec is not None
        send = _Sender(self.rec)
        images = [r.encoded.result() for r in rows]
        _send_poses(send, rows, self._mount_moves)
        _send_images(send, rows, images)
        _send_detections(send, rows)
        _send_estimates_and_errors(send, rows)
        _send_attitude(send, rows)
        _send_cone0(send, rows, self._cone0_w)
        with_cloud = [r for r in rows if r.cloud_w is not None]
        clouds = [r.cloud_w for r in with_cloud]
        send(
            entity.DEPTH_CLOUD,
            with_cloud,
            rr.Points3D.columns(
                positions=np.concatenate(clouds) if clouds else np.zeros((0, 3)),
            ).partition([len(c) for c in clouds]),
        )


# ---------------------------------------------------------------------- static content


def _log_static(rec: rr.RecordingStream, spec: ScenarioSpec, seed: int, camera) -> None:
    """Axes, mount, intrinsics, truth, description, series styles and the layout."""
    rec.log(entity.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if not spec.flight.moves_camera:  # a sliding mount is logged every tick instead
        rec.log(entity.CAMERA, _pose_transform(spec.scene.camera.T_b_c), static=True)
    rec.log(
        entity.CAMERA,
        rr.Pinhole(
            image_from_camera=rerun_image_from_camera(camera),
            resolution=[camera.width, camera.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=1.0,
        ),
        static=True,
    )
    cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
    rec.log(
        entity.TRUTH,
        rr.Points3D(
            cones_w,
            colors=[TRUTH_COLOR],
            radii=0.2,
            labels=[f"cone {i}" for i in range(len(cones_w))],
        ),
        static=True,
    )
    rec.log(
        entity.DESCRIPTION,
        rr.TextDocument(describe(spec, seed), media_type="text/markdown"),
        static=True,
    )
    _log_styles(rec)
    eye_w, look_target_w = eye_for(spec)
    rec.send_blueprint(blueprint(eye_w, look_target_w, spec.view))


def _log_styles(rec: rr.RecordingStream) -> None:
    """Colours and names, logged once: per-tick rows carry only positions and values."""
    for m in METHODS:
        rec.log(
            entity.error(m.name), rr.SeriesLines(colors=[m.color_rgb], names=[m.name]), static=True
        )
        rec.log(
            entity.estimate(m.name),
            rr.Points3D.from_fields(colors=[m.color_rgb], radii=0.12),
            static=True,
        )
    series = {
        entity.RANGE: ([(200, 200, 200)], ["range"]),
        entity.RPY: (AXIS_COLORS, ["roll", "pitch", "yaw"]),
        entity.QUAT: ([*AXIS_COLORS, (220, 220, 220)], ["x", "y", "z", "w"]),
        entity.GIMBAL_LOCK: ([(255, 200, 0)], ["gimbal lock"]),
    }
    for name in CONE0_SERIES:
        series[entity.cone0(name)] = (AXIS_COLORS, [f"{a} ({name})" for a in "xyz"])
    for path, (colors, names) in series.items():
        rec.log(path, rr.SeriesLines(colors=colors, names=names), static=True)
    rec.log(
        entity.DEPTH_CLOUD,
        rr.Points3D.from_fields(colors=[(150, 150, 200)], radii=0.04),
        static=True,
    )
    rec.log(entity.DETECTIONS, rr.Boxes2D.from_fields(colors=[(255, 220, 0)]), static=True)
    rec.log(entity.KEYPOINTS, rr.Points2D.from_fields(radii=2.5), static=True)


# ---------------------------------------------------------------------- per camera tick


class _Sender:
    """``send(path, rows, columns)``: one column batch on the ``tick`` and ``sim_time``
    timelines of ``rows``; nothing for no rows."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec

    def __call__(self, path: str, rows: list[_Buffered], columns) -> None:
        if rows:
            indexes = [
                rr.TimeColumn("tick", sequence=[r.record.tick for r in rows]),
                rr.TimeColumn("sim_time", duration=[r.record.t_s for r in rows]),
            ]
            self.rec.send_columns(path, indexes=indexes, columns=columns)


def _send_poses(send: _Sender, rows: list[_Buffered], mount_moves: bool) -> None:
    """``T_w_b`` on ``world/body`` and, if it moves, ``T_b_c`` on the camera."""
    poses = {entity.BODY: [r.record.T_w_b for r in rows]}
    if mount_moves:
        poses[entity.CAMERA] = [r.record.T_b_c for r in rows]
    for path, T in poses.items():
        T_parent_child = np.array(T)
        # vnav and Rerun both order quaternions x, y, z, w: no reordering here.
        columns = rr.Transform3D.columns(
            translation=T_parent_child[:, :3, 3],
            quaternion=quat.from_matrix(T_parent_child[:, :3, :3]),
        )
        send(path, rows, columns)


def _send_images(send: _Sender, rows: list[_Buffered], images: list) -> None:
    """The JPEG of every tick and the PNG depth of every ``DEPTH_LOG_EVERY``-th."""
    send(
        entity.IMAGE,
        rows,
        rr.EncodedImage.columns(
            blob=[jpeg for jpeg, _ in images], media_type=["image/jpeg"] * len(rows)
        ),
    )
    with_depth = [(r, png) for r, (_, png) in zip(rows, images, strict=True) if png is not None]
    send(
        entity.DEPTH,
        [r for r, _ in with_depth],
        rr.EncodedDepthImage.columns(
            blob=[png for _, png in with_depth],
            media_type=["image/png"] * len(with_depth),
            meter=[1000.0] * len(with_depth),
        ),
    )


def _send_detections(send: _Sender, rows: list[_Buffered]) -> None:
    """Each detection's box and its apex (magenta) and base (cyan) keypoints."""
    per_tick = [[d.detection for d in r.record.detections] for r in rows]
    counts = [len(dets) for dets in per_tick]
    boxes = np.array([d.bbox for dets in per_tick for d in dets], dtype=np.float64).reshape(-1, 4)
    keypoints = np.array(
        [uv for dets in per_tick for d in dets for uv in (d.apex_uv, d.base_uv)], dtype=np.float64
    ).reshape(-1, 2)
    send(
        entity.DETECTIONS,
        rows,
        rr.Boxes2D.columns(
            # Pixels x .. x+w-1 (OpenCV centres) cover [x - 0.5, x + w - 0.5] in OpenCV
            # coordinates: centre x + (w - 1) / 2, which rerun_uv shifts by 0.5.
            centers=rerun_uv(boxes[:, :2] + (boxes[:, 2:] - 1.0) / 2.0),
            half_sizes=boxes[:, 2:] / 2.0,
        ).partition(counts),
    )
    send(
        entity.KEYPOINTS,
        rows,
        rr.Points2D.columns(
            positions=rerun_uv(keypoints),
            colors=np.tile([0xFF00FFFF, 0x00FFFFFF], sum(counts)).astype(np.uint32),
        ).partition([2 * n for n in counts]),
    )


def _send_estimates_and_errors(send: _Sender, rows: list[_Buffered]) -> None:
    """Per method: its estimates in 3D and its mean error; the mean range of matched cones."""
    for method in METHOD_NAMES:
        points = [r.record.estimates_w(method) for r in rows]
        send(
            entity.estimate(method),
            rows,
            rr.Points3D.columns(positions=np.concatenate(points)).partition(
                [len(p) for p in points]
            ),
        )
        errors = [(r, r.record.mean_error_m(method)) for r in rows]
        errors = [(r, e) for r, e in errors if e is not None]
        send(
            entity.error(method),
            [r for r, _ in errors],
            rr.Scalars.columns(scalars=[e for _, e in errors]),
        )
    ranges = [(r, r.record.mean_range_m()) for r in rows]
    ranges = [(r, x) for r, x in ranges if x is not None]
    send(entity.RANGE, [r for r, _ in ranges], rr.Scalars.columns(scalars=[x for _, x in ranges]))


def _send_attitude(send: _Sender, rows: list[_Buffered]) -> None:
    """Roll, pitch, yaw in degrees, the quaternion and the gimbal-lock flag of ``R_w_b``."""
    records = [r.record for r in rows]
    rpy_deg = np.degrees(np.array([t.rpy_rad for t in records]))
    send(entity.RPY, rows, rr.Scalars.columns(scalars=rpy_deg))
    send(entity.QUAT, rows, rr.Scalars.columns(scalars=np.array([t.quat_xyzw for t in records])))
    send(
        entity.GIMBAL_LOCK,
        rows,
        rr.Scalars.columns(scalars=[float(t.gimbal_locked) for t in records]),
    )


def _send_cone0(send: _Sender, rows: list[_Buffered], cone0_w: np.ndarray) -> None:
    """Cone 0's true base centre in world, body and camera frames, and its depth estimate."""
    series: dict[str, list[tuple[_Buffered, np.ndarray]]] = {name: [] for name in CONE0_SERIES}
    for r in rows:
        for name, p in r.record.coordinates_of(cone0_w).items():
            series[name].append((r, p))
        estimate = r.record.estimate_of_cone(0, "depth_image")
        if estimate is not None:
            series["estimate_world"].append((r, estimate))
    for name, pairs in series.items():
        send(
            entity.cone0(name),
            [r for r, _ in pairs],
            rr.Scalars.columns(scalars=np.array([p for _, p in pairs]).reshape(-1, 3)),
        )
