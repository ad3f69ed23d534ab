"""Rerun recording of a scenario: the entity tree is the frame tree.

Entity tree (docs/CONVENTIONS.md for the frames)::

    world                          ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/body                     Transform3D T_w_b, every camera frame
    world/body/camera              Transform3D T_b_c + Pinhole (true intrinsics, RDF) (static;
                                   T_b_c every frame in a scenario that slides the camera)
    world/body/camera/image        JPEG-compressed RGB
    world/body/camera/depth        planar z-depth, PNG-encoded 16-bit millimetres, every 5th
    world/body/camera/detections   Boxes2D + Points2D (apex, base keypoints)
    world/cones/truth              Points3D of the true base centres (static)
    world/cones/estimate/<method>  Points3D per method, every camera frame
    world/depth_cloud              decimated depth image in world coordinates
    world/trajectory               LineStrips3D of the flown path (static, at the end)
    metrics/error/<method>         Scalars, metres
    metrics/range_m                Scalars, metres
    attitude/rpy_deg, quat_xyzw    roll/pitch/yaw (deg) and quaternion of R_w_b; gimbal_locked
    coordinates/cone0_<frame>      cone 0 in world, body, camera (truth) and its estimate
    description                    TextDocument (markdown)

Transforms are logged parent-from-child (Rerun's default relation), which is exactly vnav's
``T_parent_child``: ``world/body`` gets ``T_w_b``, ``world/body/camera`` gets ``T_b_c``.

The file is written to a temporary name beside the final one and renamed only by
:meth:`Recording.commit`, so an interrupted run never leaves a truncated ``.rrd`` under the
final name.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from vnav import quat
from vnav.camera import PinholeCamera
from vnav.detect import ConeDetection

APPLICATION_ID = "vnav-sim"
DEPTH_LOG_EVERY = 5
"""The depth image is logged every 5th camera frame: a rolled camera's depth image barely
compresses (about 100 KB as PNG) and the viewer shows the latest one in between."""
DEPTH_MANTISSA_BITS = 6
"""Logged depth keeps 6 significant bits (relative step <= 1/64; display only: estimates use
the full float depth)."""
JPEG_QUALITY = 80
DEPTH_MM_MAX = np.iinfo(np.uint16).max

METHOD_COLORS: dict[str, tuple[int, int, int]] = {
    "depth_image": (40, 200, 255),
    "ground_plane": (80, 230, 80),
    "known_height": (230, 80, 230),
    "naive": (255, 40, 40),
}
TRUTH_COLOR = (255, 255, 255)


def depth_for_display_mm(depth_m: np.ndarray) -> np.ndarray:
    """Planar depth in metres -> uint16 millimetres for a PNG, 0 where there is no return.

    Rounded to :data:`DEPTH_MANTISSA_BITS` significant bits (steps of 2**k mm, at most 1/64 of
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


VIEWS: dict[str, int] = {"errors": 0, "coordinates": 1, "attitude": 2}
"""Tabs of the lower right panel, by the name a scenario's ``view`` key uses."""


def blueprint(eye_w=None, look_target_w=None, view: str = "errors") -> rrb.Blueprint:
    """The default layout: 3D world, camera image, depth, error time series, description.

    Parameters
    ----------
    eye_w, look_target_w : array_like, shape (3,), optional
        Where the 3D view's eye starts and what it looks at, world frame (z up).
    view : {"errors", "coordinates", "attitude"}
        The tab shown first below the error plot (see :data:`VIEWS`).
    """
    if view not in VIEWS:
        raise ValueError(f"view must be one of {list(VIEWS)}, got {view!r}")
    eye = None
    if eye_w is not None and look_target_w is not None:
        eye = rrb.EyeControls3D(position=eye_w, look_target=look_target_w, eye_up=[0, 0, 1])
    good = [f"+ /metrics/error/{m}" for m in ("depth_image", "ground_plane", "known_height")]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Tabs(
                    rrb.Spatial2DView(
                        name="camera",
                        origin="world/body/camera",
                        contents=["+ $origin/image", "+ $origin/detections/**"],
                    ),
                    rrb.Spatial2DView(
                        name="depth",
                        origin="world/body/camera",
                        contents=["+ $origin/depth", "+ $origin/detections/**"],
                    ),
                ),
                rrb.TimeSeriesView(name="position error (m)", origin="metrics", contents=good),
                rrb.Tabs(
                    rrb.TimeSeriesView(
                        name="naive error and range (m)",
                        origin="metrics",
                        contents=["+ /metrics/error/naive", "+ /metrics/range_m"],
                    ),
                    rrb.Grid(
                        *[
                            rrb.TimeSeriesView(
                                name=f"cone 0 in {f} (m)", origin=f"coordinates/cone0_{f}"
                            )
                            for f in ("world", "body", "camera", "estimate_world")
                        ],
                        name="cone 0 in each frame",
                    ),
                    rrb.Vertical(
                        rrb.TimeSeriesView(
                            name="roll, pitch, yaw (deg)", origin="attitude/rpy_deg"
                        ),
                        rrb.TimeSeriesView(name="quaternion xyzw", origin="attitude/quat_xyzw"),
                        rrb.TimeSeriesView(name="gimbal lock", origin="attitude/gimbal_locked"),
                        name="attitude",
                    ),
                    active_tab=VIEWS[view],
                ),
                row_shares=[3, 2, 3],
            ),
            rrb.Vertical(
                rrb.Spatial3DView(
                    name="world",
                    origin="world",
                    # The depth image would also be drawn back-projected in 3D; the world-frame
                    # cloud computed by vnav (world/depth_cloud) is the one to look at here.
                    contents=["+ $origin/**", "- /world/body/camera/depth"],
                    eye_controls=eye,
                ),
                rrb.TextDocumentView(name="scenario", origin="description"),
                row_shares=[4, 1],
            ),
            # Plots left, world right: the viewer's start-up notices (top right) then
            # cover a corner of the large 3D view rather than the camera image.
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


FLUSH_EVERY_FRAMES = 50
"""Buffered camera frames are sent to the file in column batches of this many."""


@dataclass
class _FrameBuffer:
    """One camera frame waiting to be sent (see :meth:`Recording.log_frame`)."""

    frame: int
    t_s: float
    t_w_b: np.ndarray
    quat_xyzw: np.ndarray
    encoded: Future[tuple[bytes, bytes | None]]
    """JPEG of the image and PNG of the depth (or None), from the encoder thread."""
    boxes_xywh: np.ndarray
    keypoints_uv: np.ndarray
    estimates_w: dict[str, np.ndarray]
    errors_m: dict[str, float]
    range_m: float | None
    cloud_w: np.ndarray | None
    rpy_deg: np.ndarray
    gimbal_locked: bool
    cone_coords: dict[str, np.ndarray]
    T_b_c: np.ndarray | None


def _time_columns(rows: list[_FrameBuffer]) -> list[rr.TimeColumn]:
    return [
        rr.TimeColumn("frame", sequence=[f.frame for f in rows]),
        rr.TimeColumn("sim_time", duration=[f.t_s for f in rows]),
    ]


class Recording:
    """A scenario's ``.rrd`` file, committed whole or discarded.

    Parameters
    ----------
    path : Path
        Final file name; nothing exists there until :meth:`commit`.
    recording_id : str
        Stable id (e.g. scenario name and seed) so reruns are comparable.
    """

    def __init__(self, path: str | Path, recording_id: str) -> None:
        self.path = Path(path)
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.partial")
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self.rec.save(str(self._tmp))
        self._open = True
        self._frames: list[_FrameBuffer] = []
        self._encoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vnav-encode")

    # ------------------------------------------------------------------ static content
    def log_setup(
        self,
        *,
        camera: PinholeCamera,
        T_b_c: np.ndarray | None,
        cones_w: np.ndarray,
        description_md: str,
        eye_w: np.ndarray | None = None,
        look_target_w: np.ndarray | None = None,
        view: str = "errors",
    ) -> None:
        """Log what does not change over the run: axes, mount, intrinsics, truth, text."""
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if T_b_c is not None:  # a fixed mount; a sliding one is logged by log_frame
            rec.log("world/body/camera", _pose_transform(T_b_c), static=True)
        rec.log(
            "world/body/camera",
            rr.Pinhole(
                image_from_camera=rerun_image_from_camera(camera),
                resolution=[camera.width, camera.height],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=1.0,
            ),
            static=True,
        )
        rec.log(
            "world/cones/truth",
            rr.Points3D(
                cones_w,
                colors=[TRUTH_COLOR],
                radii=0.2,
                labels=[f"cone {i}" for i in range(len(cones_w))],
            ),
            static=True,
        )
        for method, color in METHOD_COLORS.items():
            rec.log(
                f"metrics/error/{method}",
                rr.SeriesLines(colors=[color], names=[method]),
                static=True,
            )
        rec.log(
            "metrics/range_m",
            rr.SeriesLines(colors=[(200, 200, 200)], names=["range"]),
            static=True,
        )
        rec.log(
            "description", rr.TextDocument(description_md, media_type="text/markdown"), static=True
        )
        xyz = [(230, 80, 80), (80, 200, 80), (80, 120, 240)]
        rec.log(
            "attitude/rpy_deg",
            rr.SeriesLines(colors=xyz, names=["roll", "pitch", "yaw"]),
            static=True,
        )
        rec.log(
            "attitude/quat_xyzw",
            rr.SeriesLines(colors=[*xyz, (220, 220, 220)], names=["x", "y", "z", "w"]),
            static=True,
        )
        rec.log(
            "attitude/gimbal_locked",
            rr.SeriesLines(colors=[(255, 200, 0)], names=["gimbal lock"]),
            static=True,
        )
        for frame_name in ("world", "body", "camera", "estimate_world"):
            rec.log(
                f"coordinates/cone0_{frame_name}",
                rr.SeriesLines(colors=xyz, names=[f"{a} ({frame_name})" for a in "xyz"]),
                static=True,
            )
        # Styles, logged once: per-frame rows carry only positions (see _flush).
        for method, color in METHOD_COLORS.items():
            rec.log(
                f"world/cones/estimate/{method}",
                rr.Points3D.from_fields(colors=[color], radii=0.12),
                static=True,
            )
        rec.log(
            "world/depth_cloud",
            rr.Points3D.from_fields(colors=[(150, 150, 200)], radii=0.04),
            static=True,
        )
        rec.log(
            "world/body/camera/detections",
            rr.Boxes2D.from_fields(colors=[(255, 220, 0)]),
            static=True,
        )
        rec.log(
            "world/body/camera/detections/keypoints",
            rr.Points2D.from_fields(radii=2.5),
            static=True,
        )
        rec.send_blueprint(blueprint(eye_w, look_target_w, view))

    # ------------------------------------------------------------------ per camera frame
    def log_frame(
        self,
        *,
        frame: int,
        t_s: float,
        T_w_b: np.ndarray,
        rgb: np.ndarray,
        depth_m: np.ndarray | None,
        detections: Sequence[ConeDetection],
        estimates_w: Mapping[str, np.ndarray],
        errors_m: Mapping[str, float],
        range_m: float | None,
        cloud_w: np.ndarray | None,
        rpy_rad: np.ndarray,
        gimbal_locked: bool,
        cone_coords: Mapping[str, np.ndarray],
        T_b_c: np.ndarray | None = None,
    ) -> None:
        """Queue one camera frame for the ``frame`` and ``sim_time`` timelines.

        Frames are buffered and sent as columns (``send_columns``) every
        :data:`FLUSH_EVERY_FRAMES` frames and at :meth:`commit`: one Arrow batch per entity
        instead of a dozen ``log`` calls per frame, which is what keeps recording cheap next
        to rendering.

        Parameters
        ----------
        T_w_b : ndarray, shape (4, 4)
            Body pose in the world (logged parent-from-child on ``world/body``).
        rgb : ndarray, shape (H, W, 3), uint8
            The camera image (JPEG-encoded here).
        depth_m : ndarray, shape (H, W), or None
            Planar z-depth, metres (logged every :data:`DEPTH_LOG_EVERY` frames).
        detections : sequence of ConeDetection
        estimates_w : mapping of method -> ndarray, shape (K, 3)
            Every estimate of this frame (one row per detection that gave one).
        errors_m : mapping of method -> float
            This frame's mean position error per method (absent: no estimate).
        range_m : float or None
            Mean range of the matched cones, metres.
        cloud_w : ndarray, shape (M, 3), or None
            Decimated depth image in world coordinates.
        rpy_rad : ndarray, shape (3,)
            Roll, pitch, yaw of ``R_w_b`` (``vnav.so3.to_rpy``), radians; logged in degrees.
        gimbal_locked : bool
            Whether those angles are at the gimbal lock.
        cone_coords : mapping of name -> ndarray, shape (3,)
            Cone 0's coordinates in several frames (e.g. ``world``, ``body``, ``camera``).
        T_b_c : ndarray, shape (4, 4), optional
            The camera mount at this frame, when it moves (log_setup was given None).
        """
        # Encoding runs on a worker thread (OpenCV releases the GIL), overlapping with the
        # next frame's rendering; _flush collects the bytes in order.
        encoded = self._encoder.submit(
            _encode, rgb, depth_m if frame % DEPTH_LOG_EVERY == 0 else None
        )
        self._frames.append(
            _FrameBuffer(
                frame=frame,
                t_s=t_s,
                t_w_b=T_w_b[:3, 3].copy(),
                # vnav and Rerun both order quaternions x, y, z, w: no reordering here.
                quat_xyzw=quat.from_matrix(T_w_b[:3, :3]),
                encoded=encoded,
                boxes_xywh=np.array([d.bbox for d in detections], dtype=np.float64).reshape(-1, 4),
                keypoints_uv=np.array(
                    [uv for d in detections for uv in (d.apex_uv, d.base_uv)], dtype=np.float64
                ).reshape(-1, 2),
                estimates_w={
                    m: np.asarray(v, dtype=np.float64).reshape(-1, 3)
                    for m, v in estimates_w.items()
                },
                errors_m=dict(errors_m),
                range_m=range_m,
                cloud_w=None if cloud_w is None else np.asarray(cloud_w, np.float32),
                rpy_deg=np.degrees(np.asarray(rpy_rad, dtype=np.float64)),
                gimbal_locked=bool(gimbal_locked),
                cone_coords={k: np.asarray(v, dtype=np.float64) for k, v in cone_coords.items()},
                T_b_c=None if T_b_c is None else np.array(T_b_c, dtype=np.float64),
            )
        )
        if len(self._frames) >= FLUSH_EVERY_FRAMES:
            self._flush()

    def _flush(self) -> None:
        """Send the buffered frames as one column batch per entity."""
        frames, self._frames = self._frames, []
        if not frames:
            return
        jpegs, pngs = zip(*(f.encoded.result() for f in frames), strict=True)
        mounts = [f for f in frames if f.T_b_c is not None]
        if mounts:
            self.rec.send_columns(
                "world/body/camera",
                indexes=_time_columns(mounts),
                columns=rr.Transform3D.columns(
                    translation=np.array([f.T_b_c[:3, 3] for f in mounts]),
                    quaternion=quat.from_matrix(np.array([f.T_b_c[:3, :3] for f in mounts])),
                ),
            )
        rec = self.rec

        def send(entity: str, rows: list[_FrameBuffer], columns) -> None:
            if rows:
                rec.send_columns(entity, indexes=_time_columns(rows), columns=columns)

        send(
            "world/body",
            frames,
            rr.Transform3D.columns(
                translation=np.array([f.t_w_b for f in frames]),
                quaternion=np.array([f.quat_xyzw for f in frames]),
            ),
        )
        send(
            "world/body/camera/image",
            frames,
            rr.EncodedImage.columns(
                blob=list(jpegs),
                media_type=["image/jpeg"] * len(frames),
            ),
        )
        with_depth = [(f, png) for f, png in zip(frames, pngs, strict=True) if png is not None]
        send(
            "world/body/camera/depth",
            [f for f, _ in with_depth],
            rr.EncodedDepthImage.columns(
                blob=[png for _, png in with_depth],
                media_type=["image/png"] * len(with_depth),
                meter=[1000.0] * len(with_depth),
            ),
        )
        boxes = np.concatenate([f.boxes_xywh for f in frames])
        send(
            "world/body/camera/detections",
            frames,
            rr.Boxes2D.columns(
                # Pixels x .. x+w-1 (OpenCV centres) cover [x - 0.5, x + w - 0.5] in OpenCV
                # coordinates: centre x + (w - 1) / 2, which rerun_uv shifts by 0.5.
                centers=rerun_uv(boxes[:, :2] + (boxes[:, 2:] - 1.0) / 2.0),
                half_sizes=boxes[:, 2:] / 2.0,
            ).partition([len(f.boxes_xywh) for f in frames]),
        )
        send(
            "world/body/camera/detections/keypoints",
            frames,
            rr.Points2D.columns(
                positions=rerun_uv(np.concatenate([f.keypoints_uv for f in frames])),
                # apex magenta, base cyan
                colors=np.tile(
                    [0xFF00FFFF, 0x00FFFFFF], sum(len(f.boxes_xywh) for f in frames)
                ).astype(np.uint32),
            ).partition([len(f.keypoints_uv) for f in frames]),
        )
        for method in METHOD_COLORS:
            points = [f.estimates_w.get(method, np.zeros((0, 3))) for f in frames]
            send(
                f"world/cones/estimate/{method}",
                frames,
                rr.Points3D.columns(
                    positions=np.concatenate(points),
                ).partition([len(p) for p in points]),
            )
            rows = [f for f in frames if method in f.errors_m]
            send(
                f"metrics/error/{method}",
                rows,
                rr.Scalars.columns(scalars=[f.errors_m[method] for f in rows]),
            )
        rows = [f for f in frames if f.range_m is not None]
        send("metrics/range_m", rows, rr.Scalars.columns(scalars=[f.range_m for f in rows]))
        send(
            "attitude/rpy_deg",
            frames,
            rr.Scalars.columns(scalars=np.array([f.rpy_deg for f in frames])),
        )
        send(
            "attitude/quat_xyzw",
            frames,
            rr.Scalars.columns(scalars=np.array([f.quat_xyzw for f in frames])),
        )
        send(
            "attitude/gimbal_locked",
            frames,
            rr.Scalars.columns(scalars=[float(f.gimbal_locked) for f in frames]),
        )
        for name in dict.fromkeys(k for f in frames for k in f.cone_coords):
            rows = [f for f in frames if name in f.cone_coords]
            send(
                f"coordinates/cone0_{name.replace(' ', '_')}",
                rows,
                rr.Scalars.columns(scalars=np.array([f.cone_coords[name] for f in rows])),
            )
        rows = [f for f in frames if f.cloud_w is not None]
        send(
            "world/depth_cloud",
            rows,
            rr.Points3D.columns(
                positions=np.concatenate([f.cloud_w for f in rows]) if rows else np.zeros((0, 3)),
            ).partition([len(f.cloud_w) for f in rows]),
        )

    def log_trajectory(self, positions_w: np.ndarray) -> None:
        """The whole flown path of the body origin, shape (N, 3), static."""
        self.rec.log(
            "world/trajectory",
            rr.LineStrips3D([positions_w], colors=[(255, 200, 0)], radii=0.03),
            static=True,
        )

    # ------------------------------------------------------------------ ending
    def commit(self) -> Path:
        """Finish the file and move it to its final name; return that name."""
        self._close()
        os.replace(self._tmp, self.path)
        return self.path

    def discard(self) -> None:
        """Stop recording and delete the partial file."""
        self._close(flush=False)
        self._tmp.unlink(missing_ok=True)

    def _close(self, *, flush: bool = True) -> None:
        if self._open:
            try:
                if flush:
                    self._flush()
            finally:
                self._encoder.shutdown(wait=True, cancel_futures=True)
            self._open = False
            self.rec.disconnect()  # writes the footer; without it the file cannot be read

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()
        elif self._open:
            self.commit()
