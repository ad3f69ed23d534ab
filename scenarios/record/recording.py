"""Rerun recording of a scenario: the frames, the drone, what the camera saw and why each
estimate lands where it does.

Entity tree (paths declared in ``scenarios.record.viewer.entity``, frames in ``viewer.FRAME`` and
docs/CONVENTIONS.md; "in F" is the named transform frame an entity is drawn in)::

    world                          in world; ViewCoordinates Z up; world axes (static)
    world/body                     Transform3D T_w_b (world <- body) every tick; body axes
    world/body/drone               the quadrotor's MuJoCo geoms as one mesh, in body (static)
    world/body/camera              Transform3D T_b_c (body <- camera), camera axes, Pinhole
                                   (image -> camera, true intrinsics, RDF) (static; T_b_c
                                   every tick in a scenario that slides the camera)
    world/body/camera/axes, name   in camera: the camera's axes, thin arrows, and its name on a
                                   dot past the tip of z (static)
    world/body/camera/image        in image: JPEG-compressed RGB
    world/body/camera/depth        in image: planar z-depth, PNG 16-bit mm, every 5th tick
    world/body/camera/detections   in image: Boxes2D + Points2D (apex, base keypoints)
    world/body/camera_declared     calibrated runs: Transform3D T_b_c_declared (body <- the
                                   mount the estimator was told), static; its axes (yellow)
    world/body/camera_recovered    calibrated runs: Transform3D T_b_c_recovered (body <- the
                                   mount calibration recovered), static; its axes (cyan)
    world/cones/mesh, truth        in world: the cones' MuJoCo geoms; true base centres
    world/cones/pins, pins/heads   in world: a line from each cone's apex up to PIN_TOP_M and a
                                   head of fixed size on screen, cone 0's named (static)
    world/cones/estimate/<method>  in world: Points3D per method, every tick
    world/cones/error/<method>     in world: segment from the true cone to each estimate
    world/cones/uncertainty/<method>  in world: Ellipsoids3D, each checked estimate's
                                   3-sigma covariance ellipsoid (wireframe)
    world/cones/newest_pose/estimate, error   in world: the depth_image estimate made with the
                                   newest pose at the image's arrival, and its segment from
                                   the true cone (runs with latency only)
    world/rays, rays/ground_hits   in world: camera centre -> base pixel's ray -> z = 0
    world/naive_offset             in world: the drone's position + p_c (the naive mistake)
    world/depth_cloud, trajectory  in world: depth image back-projected; the flown path
    metrics/error/<method>         Scalars, metres (NaN, a gap, where a method gave nothing)
    metrics/allowed/<method>       Scalars: the contract's bound at the matched ranges
    metrics/error_recovered_mount/<method>  calibrated runs: Scalars, metres: the error of the
                                   same images estimated again with the recovered mount
    metrics/newest_pose/error      Scalars, metres: that estimate's error (latency only)
    metrics/range_m                Scalars, metres
    metrics/nees/<method>          Scalars: the mean NEES of the tick's matched estimates
                                   (expected: their degrees of freedom, 3; ground_plane 2)
    metrics/nees_clipped/<method>  Scalars: a mark just under the NEES plot's top where the
                                   tick's NEES is above it (NaN elsewhere)
    attitude/rpy_deg, quat_xyzw    roll/pitch/yaw (deg), sign-continuous quaternion of R_w_b
    attitude/gimbal_lock, quat_sign  StateChange lanes
    coordinates/cone0_<frame>      cone 0 in world, body, camera (truth) and its estimate
    time/<quantity>/pose_samples   sim_time only (latency only): the body's yaw (deg) and
                                   position (m) from every pose sample sent, at its stamp;
    time/<quantity>/exposure       the pose given with each image, at its exposure;
    time/<quantity>/arrival        the newest pose received, at each image's arrival
    state                          TextDocument every tick: poses, p_c -> p_b -> p_w, attitude,
                                   the image's stamps; in a calibrated run the declared, true
                                   and recovered mounts (its rows are sent at the end)
    plots/error_vs_range           image (matplotlib), logged at the end (static)
    plots/depth_scale              the depth colour scale, logged at the end (static)
    plots/legend                   the 3D views' colours named, an image (static)
    moment                         AnyValues (static): camera_tick and sim_time_s the 3D views
                                   are framed for (scenario's show_at_s, else the last tick;
                                   a navigating flight's contact, ``viewer.moment``)
    description                    TextDocument (markdown), logged again at the end with
                                   every check's verdict and what calibration recovered
    estimator/pose_stream          sim_time only: Transform3D T_w_b of every pose sample the
                                   estimator was sent (noise included), at its stamp
    estimator/mount                Transform3D T_b_c the estimator was told, every tick
    estimator/stamp_cam_s          Scalars: the image's exposure stamp on the camera clock
    estimator/masks                AnyValues ``masks``: every detection's blob, exactly
                                   (``pack_masks``; the JPEG is lossy, the blob is what the
                                   apexes are fitted to)
    truth                          AnyValues (static): camera_clock_offset_s and, with an
                                   [imu], imu_time_offset_s (``vnav-demo calibrate`` reads
                                   these and the detections)
    world/navigation/..., metrics/navigation/...   a navigating flight's plan, map, goal,
                                   contact and clearances (``navigation_views``)
    world/body/imu..., imu/...     a run with an [imu]: the IMU frame (true and declared
                                   mounts) and its readings in it, on sim_time at their
                                   stamps (``imu_views``)

Timelines: ``tick`` (camera tick index) and ``sim_time`` (simulated seconds, on the pose
clock). Everything about an image, the image itself first, is logged at its tick and at its
true exposure time (``TickRecord.t_s``), not at its arrival: the recording carries the
scene as the camera saw it. The pose samples and the images' arrivals are logged on
``sim_time`` alone, at their own stamps. Transforms are
logged parent-from-child (Rerun's default relation), which is exactly vnav's
``T_parent_child``, between named frames: ``world/body`` carries ``T_w_b`` from ``body`` to
``world``, ``world/body/camera`` ``T_b_c`` from ``camera`` to ``body`` (the same graph as
``vnav.frames.FrameTree``).

``Recording`` is a ``scenarios.run.runner.TickObserver``: it is fed the run's records
(``scenarios.run.records``) and images, as evo's Rerun bridge is fed its trajectory objects,
and finished by ``scenarios.pipeline`` once the run is judged, with the verdicts. It writes to
a temporary name; ``scenarios.record.outputs`` checks the finished file and puts it in place
together with the report.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import rerun as rr

from scenarios.judge.checks import CheckResult
from scenarios.record.imu_views import log_imu_frames, send_imu
from scenarios.record.navigation_views import send_navigation
from scenarios.record.panel import (
    mount_lines,
    navigation_lines,
    navigation_outcome,
    state_text,
)
from scenarios.record.plots import depth_scale_png, error_against_range_png, legend_png
from scenarios.record.viewer import (
    AXES_NOTE,
    AXIS_COLORS,
    AXIS_LENGTH_M,
    CAMERA_AXES_UI_POINTS,
    CAMERA_NAME_Z_M,
    CONE0_SERIES,
    DECLARED_MOUNT_COLOR,
    DEPTH_CLOUD_COLOR,
    EXPOSURE_POSE_COLOR,
    FRAME,
    IMAGE_PLANE_M,
    MOUNT_AXIS_LENGTH_M,
    NEES_CLIP_MARK,
    NEES_TOP,
    NEWEST_POSE_COLOR,
    NEWEST_POSE_METHOD,
    PIN_COLOR,
    PIN_HEAD_UI_POINTS,
    PIN_LINE_UI_POINTS,
    PIN_TOP_M,
    POSE_SAMPLE_COLOR,
    RAY_COLOR,
    RECOVERED_MOUNT_COLOR,
    STREAM_QUANTITIES,
    TRAJECTORY_COLOR,
    TRUTH_COLOR,
    blueprint,
    checks_summary,
    describe,
    entity,
    eye_for,
    legend_entries,
    moment,
    shown_tick,
)
from scenarios.run.records import CalibrationRecord, PoseStream, RunResult, TickRecord
from scenarios.scenario.builtin import mount_error_text
from scenarios.scenario.spec import NavigateFlight, ScenarioSpec
from vnav import quat, so3
from vnav.camera import PinholeCamera, depth_to_world_points
from vnav.cone import TRAFFIC_CONE
from vnav.detect import ConeDetection
from vnav.methods import (
    METHOD_NAMES,
    METHODS,
    NAIVE,
    PREFERENCE,
    Method,
    active_methods,
    method,
)
from vnav.uncertainty import nees_band

if TYPE_CHECKING:
    from sim.mesh import Scenery, TriangleMesh

__all__ = [
    "Recording",
    "continuous_sign",
    "depth_for_display_mm",
    "nees_off_top",
    "pack_masks",
    "rerun_image_from_camera",
    "rerun_uv",
]

APPLICATION_ID = "vnav-sim"
DEPTH_LOG_EVERY = 5
"""The depth image is logged every 5th camera tick: a rolled camera's depth image barely
compresses (about 100 KB as PNG) and the viewer shows the latest one in between."""
DEPTH_MANTISSA_BITS = 6
"""Logged depth keeps 6 significant bits (relative step <= 1/64; display only: estimates use
the full float depth)."""
JPEG_QUALITY = 80
DEPTH_MM_MAX = np.iinfo(np.uint16).max
DEPTH_METER = 1000.0
"""The logged depth's unit: 1000 per metre (millimetres). Rerun's ``depth_range`` is given in
these raw units, not in metres."""


DEPTH_COLORMAP = "viridis"
"""The depth image's colour map (the same in Rerun and in matplotlib's colour bar)."""
DEPTH_SCALE_STEP_M = 5.0
"""The depth colour scale's top is rounded up to a multiple of this (see ``_depth_scale_m``)."""
RAY_NO_HIT_M = 5.0
"""A viewing ray that never meets the ground (it points up) is drawn this long."""
LINE_UI_POINTS = rr.Radius.ui_points(0.9)
"""Error segments and the naive offset: a width on screen, not in metres, so that they stay
thin in the close-up and visible in the wide view."""
RAY_UI_POINTS = rr.Radius.ui_points(0.7)
MOUNT_ARROW_UI_POINTS = {
    "declared": rr.Radius.ui_points(CAMERA_AXES_UI_POINTS),
    "recovered": rr.Radius.ui_points(0.5 * CAMERA_AXES_UI_POINTS),
}
"""The declared mount's axes are as thick on screen as the true camera's; the recovered
mount's thinner, so that where they coincide with the true axes those stay in sight."""

ELLIPSOID_LINE = rr.Radius.ui_points(1.8)
"""The ellipsoids' three principal ellipses: twice an error segment's width, so that they
show around a cone a few metres away in the wide view."""

CLOUD_STRIDE_PX = 16
"""Every 16th row and column of the depth image goes into the logged world cloud."""
FLUSH_EVERY_TICKS = 50
"""Buffered camera ticks are sent to the file in column batches of this many."""


def depth_for_display_mm(depth_m: np.ndarray) -> np.ndarray:
    """Planar depth in metres -> uint16 millimetres for a PNG.

    Rounded to ``DEPTH_MANTISSA_BITS`` significant bits (steps of 2**k mm, at most 1/64 of
    the depth), so the far ground compresses. Depth beyond 65.535 m and pixels with no return
    (the sky: infinite or NaN) saturate at ``DEPTH_MM_MAX``: drawn as far, not as 0 m, which
    the colour scale would show as nearest.
    """
    depth_mm = np.nan_to_num(depth_m, nan=np.inf, posinf=np.inf).astype(np.float32) * 1000.0
    far = ~(depth_mm <= DEPTH_MM_MAX)
    depth_mm[far] = 0.0
    # Round the float32 mantissa (23 bits) to its top bits: integer ops on the bit pattern.
    drop = 23 - DEPTH_MANTISSA_BITS
    bits = depth_mm.view(np.uint32)
    bits += np.uint32(1 << (drop - 1))
    bits &= np.uint32(~((1 << drop) - 1) & 0xFFFFFFFF)
    depth_mm[far | (depth_mm > DEPTH_MM_MAX)] = DEPTH_MM_MAX
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


def _pose_transform(T_parent_child: np.ndarray, parent: str, child: str) -> rr.Transform3D:
    """``T_parent_child`` between two named frames (Rerun's parent-from-child relation)."""
    # vnav and Rerun both order quaternions x, y, z, w: no reordering at this border.
    quat_xyzw = quat.from_matrix(T_parent_child[:3, :3])
    return rr.Transform3D(
        translation=T_parent_child[:3, 3],
        quaternion=rr.Quaternion(xyzw=quat_xyzw),
        relation=rr.TransformRelation.ParentFromChild,
        child_frame=child,
        parent_frame=parent,
    )


def continuous_sign(quat_xyzw: np.ndarray, previous_xyzw: np.ndarray | None) -> np.ndarray:
    """Each quaternion of a sequence with the sign that keeps the sequence continuous.

    ``q`` and ``-q`` are the same rotation; a canonical form (``w >= 0``) jumps from ``q`` to
    ``-q`` when ``w`` crosses zero. Plotted, that jump looks like a sudden rotation; choosing
    each sign to agree with the previous one (positive dot product) removes it.

    Parameters
    ----------
    quat_xyzw : ndarray, shape (N, 4)
    previous_xyzw : ndarray, shape (4,), or None
        The quaternion just before the first (from an earlier batch), if any.

    Returns
    -------
    ndarray, shape (N, 4)
    """
    out = np.array(quat_xyzw, dtype=np.float64).reshape(-1, 4)
    previous = previous_xyzw
    for i in range(len(out)):
        if previous is not None and float(out[i] @ previous) < 0.0:
            out[i] = -out[i]
        previous = out[i]
    return out


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
    """A scenario's ``.rrd`` file, finished once the run is judged (``finish``, with the
    verdicts) or deleted if the run, its judging or the finish fails (``abort``).

    Parameters
    ----------
    path : Path
        Where the file is written (a temporary name: ``scenarios.record.outputs`` puts it in place).
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
        self._spec: ScenarioSpec | None = None
        self._far_m = np.inf
        self._mount_moves = False
        self._latency = False
        self._cones_w = np.zeros((0, 3))
        self._last_quat: np.ndarray | None = None
        # Per method: the sum of its NEES values, their count and the sum of their degrees of
        # freedom so far in the run (the running mean and its band span flushes).
        self._nees_totals: dict[str, list[float]] = {m: [0.0, 0.0, 0.0] for m in METHOD_NAMES}
        self._depth_p95_m: list[float] = []
        self._state_waits = False
        self._waiting_state: list[tuple[TickRecord, np.ndarray]] = []
        """(record, plotted quaternion) of each tick whose state panel waits for the finish."""

    # ------------------------------------------------------------------ TickObserver
    def start(self, spec: ScenarioSpec, seed: int, camera: PinholeCamera, scenery: Scenery) -> None:
        """Open the file and log what does not change over the run."""
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=self.recording_id)
        self.rec.save(str(self.path))
        self._encoder = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vnav-encode")
        self._spec, self._camera, self._far_m = spec, camera, spec.scene.zfar_m
        self._mount_moves = spec.flight.moves_camera
        # Where nothing arrives late the newest pose is the exposure pose: drawing its estimate
        # again and plotting a pose stream with no gap would only clutter the views.
        self._latency = spec.timing.delivers_late
        self._cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
        self._seed = seed
        # A calibrated run's state panel shows what calibration recovers from the whole flight,
        # known only at the end: its rows wait until then (the records are kept by the run).
        # So does a navigating flight's, which shows the flight's outcome and its map, plans
        # and truth at each tick (``navigation_lines``).
        self._state_waits = spec.checks_calibration or isinstance(spec.flight, NavigateFlight)
        _log_static(self.rec, spec, seed, camera, scenery)
        log_imu_frames(self.rec, spec)
        if self._latency:
            _log_latency_static(self.rec)

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
        if logged_depth is not None:
            sample = logged_depth[::CLOUD_STRIDE_PX, ::CLOUD_STRIDE_PX]
            sample = sample[np.isfinite(sample) & (sample < self._far_m)]
            if sample.size:
                self._depth_p95_m.append(float(np.percentile(sample, 95.0)))
        self._buffer.append(_Buffered(record, encoded, cloud_w))
        if len(self._buffer) >= FLUSH_EVERY_TICKS:
            self._flush()

    def finish(self, result: RunResult, judged: Sequence[CheckResult]) -> None:
        """Log the flown path, the plots, the depth scale, the run's outcome (what calibration
        recovered, the checks' verdicts) and the layout; finish the file.

        Called once the run is judged (``scenarios.pipeline.run``), so that the recording
        holds what the report holds.

        Parameters
        ----------
        result : RunResult
            The whole run, with its ``calibration`` if a check asked for one.
        judged : sequence of CheckResult
            Every check's outcome.
        """
        assert self.rec is not None and self._spec is not None, "start() first"
        self._flush()
        rec = self.rec
        _in_frame(rec, entity.TRAJECTORY, FRAME.WORLD)
        rec.log(
            entity.TRAJECTORY,
            rr.LineStrips3D([result.trajectory_w], colors=[TRAJECTORY_COLOR], radii=0.03),
            static=True,
        )
        rec.log(
            entity.ERROR_VS_RANGE,
            rr.EncodedImage(
                contents=error_against_range_png(result, result.with_recovered_mount()),
                media_type="image/png",
            ),
            static=True,
        )
        _log_run_inputs(rec, result, self._latency)
        _log_outcome(rec, self._spec, self._seed, result, judged)
        if result.calibration is not None:
            _log_mounts(rec, result.calibration)
            _send_recovered_mount_errors(rec, result)
        send_navigation(rec, result)
        send_imu(rec, result)
        self._send_waiting_state(result)
        self._log_depth_scale_and_legend(result)
        self._send_layout(result, judged)
        self._close()

    def _log_depth_scale_and_legend(self, result: RunResult) -> None:
        """The depth image's colour range and its scale bar, and the 3D views' legend."""
        depth_max_m = _depth_scale_m(result, self._depth_p95_m)
        self.rec.log(
            entity.DEPTH,
            rr.EncodedDepthImage.from_fields(
                colormap=DEPTH_COLORMAP, depth_range=[0.0, DEPTH_METER * float(depth_max_m)]
            ),
            static=True,
        )
        self.rec.log(
            entity.DEPTH_SCALE,
            rr.EncodedImage(
                contents=depth_scale_png(float(depth_max_m), DEPTH_COLORMAP),
                media_type="image/png",
            ),
            static=True,
        )
        mounts = result.calibration is not None
        imu = self._spec.scene.imu
        self.rec.log(
            entity.LEGEND,
            rr.EncodedImage(
                contents=legend_png(
                    legend_entries(
                        latency=self._latency,
                        mounts=mounts,
                        navigation=_map_method(result),
                        imu_declared=imu is not None and not imu.mount_error.is_zero,
                    ),
                    AXES_NOTE,
                ),
                media_type="image/png",
            ),
            static=True,
        )

    def _send_layout(self, result: RunResult, judged: Sequence[CheckResult]) -> None:
        """The instant the 3D views are framed for (``entity.MOMENT``) and the blueprint."""
        mounts = result.calibration is not None
        shown = result.ticks[shown_tick(self._spec, result)] if result.ticks else None
        if shown is not None:
            # Where the 3D views are framed (or a navigating flight's contact): a screenshot
            # (scripts/screenshots.sh) moves the viewer's time cursor here.
            camera_tick, sim_time_s = moment(self._spec, result)
            self.rec.log(
                entity.MOMENT,
                rr.AnyValues(camera_tick=camera_tick, sim_time_s=sim_time_s),
                static=True,
            )
        eye_w, look_target_w = eye_for(self._spec, result)
        close_up_cone_w = self._spec.scene.cones_w[0] if self._spec.close_up == "cone" else None
        self.rec.send_blueprint(
            blueprint(
                eye_w,
                look_target_w,
                self._spec.view,
                T_w_b=shown.T_w_b if shown is not None else None,
                close_up_cone_w=close_up_cone_w,
                error_top_m=_error_tops_m(result, self._latency),
                cone0_top_m=_cone0_top_m(result, self._cones_w[0]),
                latency=self._latency,
                verdict=checks_summary(judged),
                mounts_T_w_c=shown.T_w_b @ shown.T_b_c if mounts and shown is not None else None,
                navigation=result.navigation is not None,
                imu=result.imu is not None,
            )
        )

    def _send_waiting_state(self, result: RunResult) -> None:
        """The state panel of the ticks that waited for the run's end, with the mounts block
        of a calibrated run, in column batches of ``FLUSH_EVERY_TICKS``."""
        assert self.rec is not None and self._spec is not None
        waiting, self._waiting_state = self._waiting_state, []
        mounts = None
        if result.calibration is not None:
            mounts = mount_lines(result.calibration, self._spec.timing.camera_clock_offset_s)
        navigation = _navigation_blocks(result)
        send = _Sender(self.rec)
        for i in range(0, len(waiting), FLUSH_EVERY_TICKS):
            batch = waiting[i : i + FLUSH_EVERY_TICKS]
            texts = [
                state_text(r, q, self._cones_w[0], mounts, navigation.get(r.tick)) for r, q in batch
            ]
            send.records(entity.STATE, [r for r, _ in batch], _state_columns(texts))

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
        assert self.rec is not None and self._camera is not None
        send = _Sender(self.rec)
        images = [r.encoded.result() for r in rows]
        quats = continuous_sign(np.array([r.record.quat_xyzw for r in rows]), self._last_quat)
        self._last_quat = quats[-1]
        _send_poses(send, rows, self._mount_moves)
        _send_estimator_inputs(send, rows)
        _send_images(send, rows, images)
        _send_detections(send, rows)
        _send_estimates(send, rows, self._cones_w)
        _send_errors(send, rows)
        _send_uncertainty(send, rows, self._nees_totals)
        _send_rays(send, rows, self._camera, self._far_m)
        _send_attitude(send, rows, quats)
        _send_cone0(send, rows, self._cones_w[0])
        if self._latency:
            _send_newest_pose(send, rows, self._cones_w)
            _send_stream_markers(self.rec, rows)
        plotted = [(r.record, q) for r, q in zip(rows, quats, strict=True)]
        if self._state_waits:
            self._waiting_state += plotted
        else:
            texts = [state_text(record, q, self._cones_w[0]) for record, q in plotted]
            send(entity.STATE, rows, _state_columns(texts))
        with_cloud = [r for r in rows if r.cloud_w is not None]
        clouds = [r.cloud_w for r in with_cloud]
        send(
            entity.DEPTH_CLOUD,
            with_cloud,
            rr.Points3D.columns(
                positions=np.concatenate(clouds) if clouds else np.zeros((0, 3)),
            ).partition([len(c) for c in clouds]),
        )


def _map_method(result: RunResult) -> str | None:
    """The method a navigating flight's map takes, or None for any other flight."""
    flight = result.spec.flight
    return flight.estimate if isinstance(flight, NavigateFlight) else None


def _navigation_blocks(result: RunResult) -> dict[int, list[str]]:
    """A navigating flight's state-panel block per camera tick index (empty for any other)."""
    nav, flight = result.navigation, result.spec.flight
    if nav is None or not isinstance(flight, NavigateFlight):
        return {}
    goal_w = np.asarray(flight.goal_w, dtype=np.float64)
    dropped = np.cumsum([k.rejected for k in nav.ticks])
    return {
        record.tick: navigation_lines(
            nav_tick,
            record,
            nav,
            result.cones_w,
            estimate=flight.estimate,
            goal_w=goal_w,
            clearance_m=flight.clearance_m,
            dropped=int(n_dropped),
        )
        for record, nav_tick, n_dropped in zip(result.ticks, nav.ticks, dropped, strict=True)
    }


def _state_columns(texts: list[str]) -> rr.ComponentColumnList:
    """``TextDocument`` columns of the state panel's markdown, one per tick."""
    return rr.TextDocument.columns(text=texts, media_type=["text/markdown"] * len(texts))


def _depth_scale_m(result: RunResult, depth_p95_m: list[float]) -> float:
    """Top of the depth colour scale: 1.5 times the 90th percentile of the cones' ranges, so
    the colours resolve the cones and their surroundings (the far ground saturates); without
    a matched cone, the 95th percentile of the logged depths. Rounded up to 5 m."""
    ranges = [d.range_m for t in result.ticks for d in t.detections if d.range_m is not None]
    if ranges:
        top_m = 1.5 * float(np.percentile(ranges, 90.0))
    else:
        top_m = max(depth_p95_m, default=DEPTH_SCALE_STEP_M)
    return DEPTH_SCALE_STEP_M * float(np.ceil(top_m / DEPTH_SCALE_STEP_M))


def _names() -> list[str]:
    """The run's methods' names: the built-ins', then any user's function's (``vnav.plugin``),
    whose estimates, error segments and error plots are drawn as a built-in's."""
    return [m.name for m in active_methods()]


def _error_tops_m(result: RunResult, newest_pose: bool = False) -> dict[str, float | None]:
    """Top of each method's error plot: a little above its largest error or bound (so the
    grey bound stays in view), or None if the method gave no estimate; and of the range plot
    (key ``entity.RANGE``). With ``newest_pose`` the ``NEWEST_POSE_METHOD`` plot also holds
    the newest-pose estimate's errors."""
    tops: dict[str, float | None] = {}
    for m in active_methods():  # a user's function too (vnav.plugin)
        errors = result.errors(m.name)
        if newest_pose and m.name == NEWEST_POSE_METHOD:
            errors = np.concatenate([errors, result.latest_pose_errors()[0]])
        if not errors.size:
            tops[m.name] = None
            continue
        top = float(errors.max())
        if m.bound is not None:
            top = max(top, float(m.bound.allowed_m(result.ranges_for(m.name)).max()))
        tops[m.name] = _axis_top(top)
    ranges = [d.range_m for t in result.ticks for d in t.detections if d.range_m is not None]
    tops[entity.RANGE] = _axis_top(max(ranges)) if ranges else None
    return tops


def _cone0_top_m(result: RunResult, cone0_w: np.ndarray) -> float | None:
    """Top of the cone-0 coordinate plots (their axes run from minus this): one scale for
    the three frames and the estimate, so that the same point reads the same in each."""
    extents = [
        float(np.abs(p).max())
        for t in result.ticks
        for p in t.coordinates_of(cone0_w).values()
        if np.all(np.isfinite(p))
    ]
    return _axis_top(max(extents)) if extents else None


def _axis_top(x: float) -> float:
    """Top of a plot's y axis from 0 that shows ``x`` and reads: a little above 1 or 2 times
    a power of ten at or above ``x``, so that a labelled tick sits inside the plot.

    The viewer labels no tick at the very top, and its ticks are powers of ten, labelled only
    where they are some 20 pixels apart: a top of 0.0575 m left a 60-pixel plot with only "0",
    and so would 0.56 (ticks at 0.1 too close to label, 1 beyond the top)."""
    if x <= 0.0:
        return 1.0
    scale = 10.0 ** math.floor(math.log10(x))
    round_x = next(f * scale for f in (1.0, 2.0, 10.0) if f * scale >= x * (1 - 1e-12))
    return 1.12 * round_x


# ---------------------------------------------------------------------- static content


def _in_frame(rec: rr.RecordingStream, path: str, frame: str) -> None:
    """Draw the entity at ``path`` in the named transform frame ``frame``."""
    rec.log(path, rr.CoordinateFrame(frame), static=True)


def _mesh(mesh: TriangleMesh) -> rr.Mesh3D:
    return rr.Mesh3D(
        vertex_positions=mesh.vertices.astype(np.float32),
        triangle_indices=mesh.triangles,
        vertex_normals=mesh.normals.astype(np.float32),
        vertex_colors=mesh.colors_rgba,
    )


def _log_mounts(rec: rr.RecordingStream, calibration: CalibrationRecord) -> None:
    """A calibrated run's declared and recovered camera mounts beside the true one, each a
    named frame on the body (``T_b_c_declared``, ``T_b_c_recovered``) with its axes drawn in
    one colour and named once (the declared mount on its x axis, the recovered one on its y
    axis: the true camera is named on its optical axis z), static."""
    mounts = (
        (
            entity.CAMERA_DECLARED,
            entity.CAMERA_DECLARED_AXES,
            FRAME.CAMERA_DECLARED,
            calibration.T_b_c_declared,
            DECLARED_MOUNT_COLOR,
            "declared",
            ["declared", "", ""],
        ),
        (
            entity.CAMERA_RECOVERED,
            entity.CAMERA_RECOVERED_AXES,
            FRAME.CAMERA_RECOVERED,
            calibration.T_b_c,
            RECOVERED_MOUNT_COLOR,
            "recovered",
            ["", "recovered", ""],
        ),
    )
    for path, axes_path, frame, T_b_c, color, which, labels in mounts:
        if T_b_c is None:  # calibration refused: nothing recovered to draw
            continue
        rec.log(path, _pose_transform(T_b_c, FRAME.BODY, frame), static=True)
        _in_frame(rec, axes_path, frame)
        rec.log(
            axes_path,
            rr.Arrows3D(
                vectors=MOUNT_AXIS_LENGTH_M[frame] * np.eye(3),
                colors=[color],
                radii=MOUNT_ARROW_UI_POINTS[which],
                # One label per mount, at the middle of one axis, a different axis for each:
                # the two mounts are centimetres apart and their labels would otherwise pile up.
                labels=labels,
                show_labels=True,
            ),
            static=True,
        )


def _send_recovered_mount_errors(rec: rr.RecordingStream, result: RunResult) -> None:
    """A calibrated run's ticks estimated again with the recovered mount: per method, the mean
    error of each tick's matched detections (NaN, a gap, where none), plotted with the run's
    own in the recovered mount's colour."""
    recovered = result.with_recovered_mount()
    if recovered is None:
        return
    send = _Sender(rec)
    for m in METHODS:
        rec.log(
            entity.error_recovered(m.name),
            rr.SeriesLines(
                colors=[RECOVERED_MOUNT_COLOR], names=[f"{m.name} error, recovered mount"]
            ),
            static=True,
        )
        errors = [t.mean_error_m(m.name) for t in recovered.ticks]
        send.records(
            entity.error_recovered(m.name),
            recovered.ticks,
            rr.Scalars.columns(scalars=[np.nan if e is None else e for e in errors]),
        )


def recovered_mount_text(result: RunResult) -> str:
    """Markdown: what the declared mount's error does to the estimates, and what the
    recovered mount gives on the same images (empty for a run not calibrated)."""
    recovered = result.with_recovered_mount()
    if recovered is None:
        return ""
    lines = []
    for m in METHODS:
        if m.bound is None:
            continue
        before, after = result.errors(m.name), recovered.errors(m.name)
        if before.size and after.size:
            lines.append(
                f"- {m.name}: mean {float(np.mean(before)):.3f} m with the declared mount, "
                f"{float(np.mean(after)):.3f} m with the recovered one"
            )
    error = result.spec.scene.camera.mount_error
    return (
        "## Before and after calibration\n\nThe declared mount is the true one with the "
        f"scenario's mount error ({mount_error_text(error)}): every estimate made through it "
        "is off by what that error swings the cone through, beyond the methods' bounds. The "
        "same images estimated again with the recovered mount (cyan in the error plots, "
        "crosses in error against range):\n\n" + "\n".join(lines)
    )


def calibration_text(c: CalibrationRecord) -> str:
    """Markdown: the mount and clock offset recovered from the run, and their errors."""
    if c.refused is not None:
        return f"## Calibration\n\nRefused: {c.refused}"
    rows = "\n".join("    " + " ".join(f"{v:9.5f}" for v in row) for row in c.T_b_c)
    e = c.errors
    return (
        "## Calibration\n\nRecovered from the flight (``vnav.calibration``): camera mount "
        f"T_b_c\n\n{rows}\n\nclock offset t_pose = t_cam + {1e3 * c.time_offset_s:.3f} ms, "
        f"reprojection RMS {c.reprojection_rms_px:.3f} px over {c.frames_used} images. Against "
        f"the truth: rotation {e['rotation_deg']:.4f} deg, translation "
        f"{1e3 * e['translation_m']:.2f} mm, offset {1e3 * e['time_offset_s']:.3f} ms."
    )


def _log_static(
    rec: rr.RecordingStream,
    spec: ScenarioSpec,
    seed: int,
    camera: PinholeCamera,
    scenery: Scenery,
) -> None:
    """Frames and their axes, the meshes, mount, intrinsics, truth, description, styles."""
    _log_world_and_body(rec, scenery)
    _log_camera_model(rec, spec, camera)
    _log_camera_axes(rec)
    _log_world_contents(rec, spec, scenery)
    rec.log(
        entity.DESCRIPTION,
        rr.TextDocument(describe(spec, seed), media_type="text/markdown"),
        static=True,
    )
    _log_styles(rec)


def _log_world_and_body(rec: rr.RecordingStream, scenery: Scenery) -> None:
    """The world's and the body's frames with their axes, and the drone's mesh in the body.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The recording, logged to statically.
    scenery : Scenery
        The scene's meshes; ``drone_b`` is drawn in the body frame.
    """
    rec.log(
        entity.WORLD,
        rr.ViewCoordinates.RIGHT_HAND_Z_UP,
        rr.CoordinateFrame(FRAME.WORLD),
        rr.TransformAxes3D(AXIS_LENGTH_M[FRAME.WORLD], show_frame=True),
        static=True,
    )
    rec.log(
        entity.BODY, rr.TransformAxes3D(AXIS_LENGTH_M[FRAME.BODY], show_frame=True), static=True
    )
    _in_frame(rec, entity.DRONE, FRAME.BODY)
    rec.log(entity.DRONE, _mesh(scenery.drone_b), static=True)


def _log_camera_model(rec: rr.RecordingStream, spec: ScenarioSpec, camera: PinholeCamera) -> None:
    """The camera's fixed mount ``T_b_c`` and its pinhole, and the image entities in it.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The recording, logged to statically.
    spec : ScenarioSpec
        The scenario: its declared mount, and whether its flight slides the camera.
    camera : PinholeCamera
        The intrinsics (OpenCV pixel-centre convention, converted for Rerun).
    """
    if not spec.flight.moves_camera:  # a sliding mount is logged every tick instead
        rec.log(
            entity.CAMERA,
            _pose_transform(spec.scene.camera.T_b_c, FRAME.BODY, FRAME.CAMERA),
            static=True,
        )
    rec.log(
        entity.CAMERA,
        rr.Pinhole(
            image_from_camera=rerun_image_from_camera(camera),
            resolution=[camera.width, camera.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=IMAGE_PLANE_M,
            child_frame=FRAME.IMAGE,
            parent_frame=FRAME.CAMERA,
        ),
        static=True,
    )
    for path in (entity.IMAGE, entity.DEPTH, entity.DETECTIONS, entity.KEYPOINTS):
        _in_frame(rec, path, FRAME.IMAGE)


def _log_camera_axes(rec: rr.RecordingStream) -> None:
    """The camera's axes, drawn thin, and its name past the tip of its optical axis.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The recording, logged to statically.
    """
    # The camera's axes thin and its name past the tip of its optical axis
    # (``CAMERA_NAME_Z_M``), where the world's and the body's axes are thick and named at
    # their origins: 15 cm from the body's origin, the camera's name there sat on the body's.
    _in_frame(rec, entity.CAMERA_AXES, FRAME.CAMERA)
    rec.log(
        entity.CAMERA_AXES,
        rr.Arrows3D(
            vectors=AXIS_LENGTH_M[FRAME.CAMERA] * np.eye(3),
            colors=AXIS_COLORS,
            radii=rr.Radius.ui_points(CAMERA_AXES_UI_POINTS),
        ),
        static=True,
    )
    _in_frame(rec, entity.CAMERA_NAME, FRAME.CAMERA)
    rec.log(
        entity.CAMERA_NAME,
        rr.Points3D(
            [[0.0, 0.0, CAMERA_NAME_Z_M]],
            colors=[AXIS_COLORS[2]],
            radii=rr.Radius.ui_points(1.5),
            labels=["camera"],
            show_labels=True,
        ),
        static=True,
    )


def _log_world_contents(rec: rr.RecordingStream, spec: ScenarioSpec, scenery: Scenery) -> None:
    """What lives in the world frame: its entities named in it, the cone meshes and truth."""
    world_paths = [
        entity.CONES,
        entity.TRUTH,
        entity.CONE_PINS,
        entity.CONE_PIN_HEADS,
        entity.RAYS,
        entity.GROUND_HITS,
        entity.NAIVE_OFFSET,
        entity.DEPTH_CLOUD,
    ]
    world_paths += [entity.estimate(m) for m in _names()]
    world_paths += [entity.error_segment(m) for m in _names()]
    world_paths += [entity.ellipsoid(m) for m in PREFERENCE]
    for path in world_paths:
        _in_frame(rec, path, FRAME.WORLD)
    rec.log(entity.CONES, _mesh(scenery.cones_w), static=True)
    cones_w = np.array(spec.scene.cones_w, dtype=np.float64).reshape(-1, 3)
    rec.log(entity.TRUTH, rr.Points3D(cones_w, colors=[TRUTH_COLOR], radii=0.05), static=True)
    _log_pins(rec, cones_w)


def _log_pins(rec: rr.RecordingStream, cones_w: np.ndarray) -> None:
    """Each cone's pin: a line from its apex to ``PIN_TOP_M`` and a head of fixed size on
    screen, so that a cone a few pixels tall is found from afar; only cone 0, the one the
    state panel and the coordinate plots follow, is named (eight names from afar pile up)."""
    apex_w = cones_w + np.array([0.0, 0.0, TRAFFIC_CONE.height_m])
    top_w = cones_w.copy()
    top_w[:, 2] = PIN_TOP_M
    rec.log(
        entity.CONE_PINS,
        rr.LineStrips3D(
            [np.array([a, t]) for a, t in zip(apex_w, top_w, strict=True)],
            colors=[PIN_COLOR],
            radii=rr.Radius.ui_points(PIN_LINE_UI_POINTS),
        ),
        static=True,
    )
    rec.log(
        entity.CONE_PIN_HEADS,
        rr.Points3D(
            top_w,
            colors=[PIN_COLOR],
            radii=rr.Radius.ui_points(PIN_HEAD_UI_POINTS),
            labels=["cone 0"] + [""] * (len(top_w) - 1),
            show_labels=True,
        ),
        static=True,
    )


def _log_styles(rec: rr.RecordingStream) -> None:
    """Colours, names and sizes, logged once: per-tick rows carry only positions and values."""
    for m in active_methods():
        rec.log(
            entity.error(m.name),
            rr.SeriesLines(colors=[m.color_rgb], names=[f"{m.name} error"]),
            static=True,
        )
        rec.log(
            entity.allowed(m.name),
            rr.SeriesLines(colors=[(150, 150, 150)], names=["contract's bound"]),
            static=True,
        )
        rec.log(
            entity.estimate(m.name),
            rr.Points3D.from_fields(colors=[m.color_rgb], radii=0.08),
            static=True,
        )
        rec.log(
            entity.error_segment(m.name),
            rr.LineStrips3D.from_fields(colors=[m.color_rgb], radii=LINE_UI_POINTS),
            static=True,
        )
        if m.images != "user":  # a user's function claims no covariance: no NEES, no ellipsoid
            _log_uncertainty_styles(rec, m)
    series = {
        entity.RANGE: ([(200, 200, 200)], ["range"]),
        entity.RPY: (AXIS_COLORS, ["roll", "pitch", "yaw"]),
        entity.QUAT: ([*AXIS_COLORS, (220, 220, 220)], ["x", "y", "z", "w"]),
    }
    for name in CONE0_SERIES:
        series[entity.cone0(name)] = (AXIS_COLORS, [f"{a} ({name})" for a in "xyz"])
    for path, (colors, names) in series.items():
        rec.log(path, rr.SeriesLines(colors=colors, names=names), static=True)
    _log_state_lanes(rec)
    _log_3d_styles(rec)


def _log_uncertainty_styles(rec: rr.RecordingStream, m: Method) -> None:
    """Method ``m``'s NEES series (each, mean, the marks above the plot, the band) and its
    ellipsoids, styled once."""
    rec.log(
        entity.nees(m.name),
        rr.SeriesLines(colors=[m.color_rgb], names=[f"{m.name} NEES"], widths=[0.7]),
        static=True,
    )
    rec.log(
        entity.nees_mean(m.name),
        rr.SeriesLines(colors=[m.color_rgb], names=[f"{m.name} mean NEES"], widths=[2.5]),
        static=True,
    )
    rec.log(
        entity.nees_clipped(m.name),
        rr.SeriesPoints(
            colors=[m.color_rgb],
            markers=["up"],
            marker_sizes=[6.0],
            names=[f"{m.name} NEES above {NEES_TOP:g}"],
        ),
        static=True,
    )
    rec.log(
        entity.nees_band(m.name),
        rr.SeriesLines(
            colors=[(160, 160, 160)] * 2,
            names=["95% band, low", "95% band, high"],
            widths=[1.0, 1.0],
        ),
        static=True,
    )
    if m.bound is not None:
        rec.log(
            entity.ellipsoid(m.name),
            rr.Ellipsoids3D.from_fields(
                colors=[m.color_rgb], line_radii=ELLIPSOID_LINE, fill_mode="MajorWireframe"
            ),
            static=True,
        )


def _log_state_lanes(rec: rr.RecordingStream) -> None:
    """The discrete flags' lanes: their values, labels and colours."""
    rec.log(
        entity.GIMBAL_LOCK,
        rr.StateConfiguration(
            values=["free", "locked"],
            # "lock" fits a short stretch (the gimbal-lock built-in ends with half a second
            # of it); a longer word was cut at the stretch's end.
            labels=["no lock", "lock"],
            colors=[0x3A7D44FF, 0xD04040FF],
        ),
        static=True,
    )
    rec.log(
        entity.QUAT_SIGN,
        rr.StateConfiguration(
            values=["w>=0", "w<0"],
            labels=["q plotted as is (w >= 0)", "q plotted as -q (w < 0): same rotation"],
            colors=[0x4060A0FF, 0x8050A0FF],
        ),
        static=True,
    )


def _log_3d_styles(rec: rr.RecordingStream) -> None:
    """Colours and sizes of the 3D and image entities logged every tick."""
    rec.log(
        entity.DEPTH_CLOUD,
        rr.Points3D.from_fields(colors=[DEPTH_CLOUD_COLOR], radii=0.04),
        static=True,
    )
    rec.log(
        entity.RAYS,
        rr.LineStrips3D.from_fields(colors=[RAY_COLOR], radii=RAY_UI_POINTS),
        static=True,
    )
    rec.log(
        entity.GROUND_HITS,
        rr.Points3D.from_fields(colors=[RAY_COLOR], radii=0.06),
        static=True,
    )
    rec.log(
        entity.NAIVE_OFFSET,
        rr.LineStrips3D.from_fields(colors=[method(NAIVE).color_rgb], radii=LINE_UI_POINTS),
        static=True,
    )
    rec.log(entity.DETECTIONS, rr.Boxes2D.from_fields(colors=[(255, 220, 0)]), static=True)
    rec.log(entity.KEYPOINTS, rr.Points2D.from_fields(radii=2.5), static=True)


def _log_latency_static(rec: rr.RecordingStream) -> None:
    """Frames and styles of what only a run with latency draws: the newest-pose estimate and
    the pose stream against the image stamps."""
    for path in (entity.NEWEST_ESTIMATE, entity.NEWEST_ERROR_SEGMENT):
        _in_frame(rec, path, FRAME.WORLD)
    rec.log(
        entity.NEWEST_ESTIMATE,
        rr.Points3D.from_fields(colors=[NEWEST_POSE_COLOR], radii=0.08),
        static=True,
    )
    rec.log(
        entity.NEWEST_ERROR_SEGMENT,
        rr.LineStrips3D.from_fields(colors=[NEWEST_POSE_COLOR], radii=LINE_UI_POINTS),
        static=True,
    )
    rec.log(
        entity.NEWEST_ERROR,
        rr.SeriesLines(colors=[NEWEST_POSE_COLOR], names=["newest-pose error"]),
        static=True,
    )
    for quantity in STREAM_QUANTITIES:
        n = _STREAM_WIDTH[quantity]
        # Yaw is one grey line; position has the x, y, z colours of every other plot.
        colors = [POSE_SAMPLE_COLOR] if n == 1 else AXIS_COLORS
        names = ["yaw"] if n == 1 else ["x", "y", "z"]
        rec.log(
            entity.stream(quantity, "pose_samples"),
            rr.SeriesLines(colors=colors, names=[f"pose samples: {x}" for x in names]),
            # Small dots on the line: the samples are discrete, 1 / pose_rate_hz apart.
            rr.SeriesPoints(colors=colors, markers=["circle"] * n, marker_sizes=[1.5] * n),
            static=True,
        )
        # A cross of a circle's size reads thinner: drawn larger so the two weigh alike.
        for series, color, marker, size, what in (
            ("exposure", EXPOSURE_POSE_COLOR, "circle", 5.0, "pose at the exposure stamp"),
            ("arrival", NEWEST_POSE_COLOR, "cross", 7.0, "newest pose at arrival"),
        ):
            rec.log(
                entity.stream(quantity, series),
                rr.SeriesPoints(
                    colors=[color] * n,
                    markers=[marker] * n,
                    marker_sizes=[size] * n,
                    names=[f"{what}: {x}" for x in names],
                ),
                static=True,
            )


# ---------------------------------------------------------------------- per camera tick


class _Sender:
    """``send(path, rows, columns)``: one column batch on the ``tick`` and ``sim_time``
    timelines of ``rows``; nothing for no rows. ``send.records(path, records, columns)``: the
    same for tick records."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec

    def __call__(self, path: str, rows: list[_Buffered], columns) -> None:
        self.records(path, [r.record for r in rows], columns)

    def records(self, path: str, records: list[TickRecord], columns) -> None:
        if records:
            indexes = [
                rr.TimeColumn("tick", sequence=[t.tick for t in records]),
                rr.TimeColumn("sim_time", duration=[t.t_s for t in records]),
            ]
            self.rec.send_columns(path, indexes=indexes, columns=columns)


def _send_poses(send: _Sender, rows: list[_Buffered], mount_moves: bool) -> None:
    """``T_w_b`` on ``world/body`` and, if it moves, ``T_b_c`` on the camera."""
    poses = {entity.BODY: ([r.record.T_w_b for r in rows], FRAME.WORLD, FRAME.BODY)}
    if mount_moves:
        poses[entity.CAMERA] = ([r.record.T_b_c for r in rows], FRAME.BODY, FRAME.CAMERA)
    for path, (T, parent, child) in poses.items():
        columns = _transform_columns(
            np.array(T), child_frame=[child] * len(rows), parent_frame=[parent] * len(rows)
        )
        send(path, rows, columns)


def _transform_columns(T_parent_child: np.ndarray, **more) -> object:
    """``Transform3D`` columns of a stack of poses (N, 4, 4); vnav and Rerun both order
    quaternions x, y, z, w: no reordering here."""
    return rr.Transform3D.columns(
        translation=T_parent_child[:, :3, 3],
        quaternion=quat.from_matrix(T_parent_child[:, :3, :3]),
        **more,
    )


def _log_run_inputs(rec: rr.RecordingStream, result: RunResult, latency: bool) -> None:
    """At the end of a run: the pose stream as the estimator received it and the true clock
    offsets (what ``vnav-demo calibrate`` reads beside the detections)."""
    if result.poses is not None:
        if latency:
            _send_pose_samples(rec, result.poses)
        rec.send_columns(
            entity.POSE_STREAM,
            indexes=[rr.TimeColumn("sim_time", duration=result.poses.stamps_s)],
            columns=_transform_columns(result.poses.T_w_b),
        )
    truth = {"camera_clock_offset_s": result.spec.timing.camera_clock_offset_s}
    if result.spec.scene.imu is not None:
        # What ``vnav-demo calibrate --imu`` judges its clock offset against.
        truth["imu_time_offset_s"] = result.spec.scene.imu.time_offset_s
    rec.log(entity.TRUTH_VALUES, rr.AnyValues(**truth), static=True)


def _log_outcome(
    rec: rr.RecordingStream,
    spec: ScenarioSpec,
    seed: int,
    result: RunResult,
    judged: Sequence[CheckResult],
) -> None:
    """Once the run is judged: the scenario's description again, now with every check's
    verdict and, when the run was calibrated, what calibration recovered (a static row
    replaces the one logged at the start)."""
    text = describe(spec, seed, judged)
    if result.navigation is not None:
        nav = result.navigation
        text += (
            f"\n\n## Navigation: {navigation_outcome(nav)}\n\nOn "
            f"{_map_method(result)}'s map; smallest true clearance {nav.min_clearance_m:.3f} m, "
            f"flew {nav.path_length_m:.2f} m."
        )
    if result.calibration is not None:
        text += "\n\n" + calibration_text(result.calibration)
        if (before_after := recovered_mount_text(result)) != "":
            text += "\n\n" + before_after
    rec.log(entity.DESCRIPTION, rr.TextDocument(text, media_type="text/markdown"), static=True)


def _send_estimator_inputs(send: _Sender, rows: list[_Buffered]) -> None:
    """The mount the estimator was told and each image's stamp on the camera clock: with the
    pose stream and the detections, what ``vnav-demo calibrate`` needs."""
    send(
        entity.MOUNT_DECLARED,
        rows,
        _transform_columns(np.array([r.record.T_b_c_est for r in rows])),
    )
    stamps = [
        r.record.t_s if r.record.timing is None else r.record.timing.stamp_cam_s for r in rows
    ]
    send(entity.STAMP_CAM, rows, rr.Scalars.columns(scalars=stamps))
    packed = [pack_masks([d.detection for d in r.record.detections]) for r in rows]
    send(
        entity.MASKS,
        rows,
        rr.AnyValues.columns(masks=np.concatenate(packed)).partition([p.size for p in packed]),
    )


def pack_masks(detections: Sequence[ConeDetection]) -> np.ndarray:
    """The blobs of one image's detections as bytes, (B,) uint8: per detection its ``bbox``
    ``x, y, w, h`` as little-endian uint16, then its ``h x w`` mask row by row, one bit a
    pixel (``np.packbits``, padded to a byte). ``scenarios.record.reader.unpack_masks`` reads
    them back; ``vnav.detect.detection_from_mask`` makes each detection again.

    A blob costs about a tenth of its pixels in bytes: a recording's JPEG image is lossy
    (at quality 80 its orange spreads by a pixel: the detector run on it finds each apex
    1.7 px higher), the blob is exactly what the detector found."""
    parts = [np.zeros(0, dtype=np.uint8)]
    for d in detections:
        parts.append(np.asarray(d.bbox, dtype="<u2").view(np.uint8))
        parts.append(np.packbits(np.asarray(d.mask, dtype=bool).ravel()))
    return np.concatenate(parts)


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
            meter=[DEPTH_METER] * len(with_depth),
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


def _strips(segments: list[list[np.ndarray]]) -> rr.ComponentColumnList:
    """LineStrips3D columns: one list of (2, 3) segments per tick.

    Strips of one shape go to Rerun as one (N, k, 3) array: it converts that in one piece,
    where a list of arrays is converted strip by strip (0.2 ms each, 8 per detection), into
    the same Arrow array (a test compares them)."""
    flat = [s for tick in segments for s in tick]
    strips: list[np.ndarray] | np.ndarray = flat
    if flat and all(np.shape(s) == np.shape(flat[0]) for s in flat):
        strips = np.array(flat)
    return rr.LineStrips3D.columns(strips=strips).partition([len(t) for t in segments])


def _send_estimates(send: _Sender, rows: list[_Buffered], cones_w: np.ndarray) -> None:
    """Per method: its estimates, and a segment from the matched true cone to each."""
    for name in _names():
        points = [r.record.estimates_w(name) for r in rows]
        send(
            entity.estimate(name),
            rows,
            rr.Points3D.columns(positions=np.concatenate(points)).partition(
                [len(p) for p in points]
            ),
        )
        segments = [
            [
                np.array([cones_w[d.cone_index], d.estimates_w[name]])
                for d in r.record.detections
                if d.cone_index is not None and name in d.estimates_w
            ]
            for r in rows
        ]
        send(entity.error_segment(name), rows, _strips(segments))


ELLIPSOID_SIGMA = 3.0
"""The drawn ellipsoid's half-axes, in standard deviations: 3 sigma holds 97% of a 3-D
Gaussian's mass."""


def ellipsoid_axes(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``ELLIPSOID_SIGMA``-sigma half-sizes (3,) and the rotation (3, 3) of a covariance's
    ellipsoid: its eigenvectors as a right-handed frame, the square roots of its eigenvalues
    along them (a rank-deficient covariance gives a flat ellipsoid)."""
    eigenvalues, vectors = np.linalg.eigh(cov)
    if np.linalg.det(vectors) < 0.0:
        vectors[:, 2] *= -1.0
    return ELLIPSOID_SIGMA * np.sqrt(np.maximum(eigenvalues, 0.0)), vectors


def ellipsoids_axes(covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``ellipsoid_axes`` of a stack of covariances (N, 3, 3) at once: half-sizes (N, 3) and
    rotations (N, 3, 3). numpy decomposes a stack matrix by matrix with the same LAPACK
    routines, so each is ``ellipsoid_axes``'s to the last bit (a test compares them)."""
    covs = np.asarray(covs, dtype=np.float64).reshape(-1, 3, 3)
    if not len(covs):
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    eigenvalues, vectors = np.linalg.eigh(covs)
    vectors[np.linalg.det(vectors) < 0.0, :, 2] *= -1.0
    return ELLIPSOID_SIGMA * np.sqrt(np.maximum(eigenvalues, 0.0)), vectors


def _send_uncertainty(
    send: _Sender, rows: list[_Buffered], nees_totals: dict[str, list[float]]
) -> None:
    """Per checked method, each estimate's covariance ellipsoid; per method, the mean NEES of
    the tick's matched estimates (NaN, a gap, where it has none) and the mean over the run so
    far with its 95% chi-square band (``vnav.uncertainty.nees_band``), which the ``consistent``
    check judges at the last tick; ``nees_totals`` carries the sums from flush to flush."""
    for name in PREFERENCE:
        per_tick = [
            [
                (d.estimates_w[name], d.covariances_w[name])
                for d in r.record.detections
                if name in d.covariances_w
            ]
            for r in rows
        ]
        flat = [e for tick in per_tick for e in tick]
        # Every ellipsoid of the batch in one decomposition (``ellipsoid_axes`` one by one).
        half_sizes, rotations = ellipsoids_axes(np.array([cov for _, cov in flat]))
        send(
            entity.ellipsoid(name),
            rows,
            rr.Ellipsoids3D.columns(
                centers=np.array([c for c, _ in flat]).reshape(-1, 3),
                half_sizes=half_sizes,
                quaternions=quat.from_matrix(rotations),
            ).partition([len(t) for t in per_tick]),
        )
    for name in METHOD_NAMES:
        totals = nees_totals[name]
        values, running, bands = [], [], []
        for r in rows:
            scored = [d.nees[name] for d in r.record.detections if name in d.nees]
            values.append(float(np.mean([v for v, _ in scored])) if scored else np.nan)
            totals[0] += sum(v for v, _ in scored)
            totals[1] += len(scored)
            totals[2] += sum(dof for _, dof in scored)
            if totals[1] and math.isfinite(totals[0]):
                running.append(totals[0] / totals[1])
                bands.append(nees_band(totals[2] / totals[1], int(totals[1]), 0.95))
            else:
                running.append(np.nan)
                bands.append((np.nan, np.nan))
        send(entity.nees(name), rows, rr.Scalars.columns(scalars=values))
        send(entity.nees_clipped(name), rows, rr.Scalars.columns(scalars=nees_off_top(values)))
        send(entity.nees_mean(name), rows, rr.Scalars.columns(scalars=running))
        send(entity.nees_band(name), rows, rr.Scalars.columns(scalars=np.array(bands)))


def nees_off_top(values: Sequence[float]) -> list[float]:
    """Per NEES value, ``NEES_CLIP_MARK`` if it is above the NEES plot's top (``NEES_TOP``),
    else NaN (no mark): above the top a value would leave the plot unmarked."""
    return [NEES_CLIP_MARK if v > NEES_TOP else np.nan for v in values]


def _send_errors(send: _Sender, rows: list[_Buffered]) -> None:
    """Per method its mean error and the contract's bound at the matched ranges (NaN, drawn
    as a gap, at a tick where the method matched nothing); the mean range of matched cones."""
    for m in active_methods():
        errors, allowed = [], []
        for r in rows:
            scored = [d for d in r.record.detections if m.name in d.errors_m]
            errors.append(np.mean([d.errors_m[m.name] for d in scored]) if scored else np.nan)
            if m.bound is not None:
                ranges = np.array([d.range_m for d in scored], dtype=np.float64)
                allowed.append(np.mean(m.bound.allowed_m(ranges)) if scored else np.nan)
        send(entity.error(m.name), rows, rr.Scalars.columns(scalars=errors))
        if m.bound is not None:
            send(entity.allowed(m.name), rows, rr.Scalars.columns(scalars=allowed))
    ranges = [r.record.mean_range_m() for r in rows]
    send(
        entity.RANGE,
        rows,
        rr.Scalars.columns(scalars=[np.nan if x is None else x for x in ranges]),
    )


def _ray_segments(
    record: TickRecord, camera: PinholeCamera, far_m: float
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The ray from the (estimated) camera centre through each detection's base pixel, to
    where it meets the ground z = 0; and those ground points."""
    if not record.detections:
        return [], []
    T_w_c = record.T_w_b_est @ record.T_b_c
    o_w = T_w_c[:3, 3]
    uv = np.array([d.detection.base_uv for d in record.detections])
    d_w = camera.rays(uv) @ T_w_c[:3, :3].T
    strips, hits = [], []
    for d in d_w:
        # o + s d meets z = 0 at s = -o_z / d_z, in front of the camera and before the far plane.
        s = -o_w[2] / d[2] if d[2] < 0.0 else np.inf
        if 0.0 < s <= far_m:
            hit = o_w + s * d
            hits.append(hit)
            strips.append(np.array([o_w, hit]))
        else:
            strips.append(np.array([o_w, o_w + RAY_NO_HIT_M * d]))
    return strips, hits


def _send_rays(send: _Sender, rows: list[_Buffered], camera: PinholeCamera, far_m: float) -> None:
    """Viewing rays and ground hits; the naive estimate's offset drawn from the drone."""
    rays = [_ray_segments(r.record, camera, far_m) for r in rows]
    send(entity.RAYS, rows, _strips([strips for strips, _ in rays]))
    hits = [np.array(h).reshape(-1, 3) for _, h in rays]
    send(
        entity.GROUND_HITS,
        rows,
        rr.Points3D.columns(positions=np.concatenate(hits)).partition([len(h) for h in hits]),
    )
    # naive = t_w_b + p_c: the segment from the drone to it is p_c, taken as a world offset.
    offsets = [
        [np.array([r.record.T_w_b_est[:3, 3], p]) for p in r.record.estimates_w(NAIVE)]
        for r in rows
    ]
    send(entity.NAIVE_OFFSET, rows, _strips(offsets))


def _send_attitude(send: _Sender, rows: list[_Buffered], quats: np.ndarray) -> None:
    """Roll, pitch, yaw in degrees, the sign-continuous quaternion and the state lanes."""
    records = [r.record for r in rows]
    rpy_deg = np.degrees(np.array([t.rpy_rad for t in records]))
    send(entity.RPY, rows, rr.Scalars.columns(scalars=rpy_deg))
    send(entity.QUAT, rows, rr.Scalars.columns(scalars=quats))
    send(
        entity.GIMBAL_LOCK,
        rows,
        rr.StateChange.columns(state=["locked" if t.gimbal_locked else "free" for t in records]),
    )
    send(
        entity.QUAT_SIGN,
        rows,
        rr.StateChange.columns(state=["w<0" if q[3] < 0.0 else "w>=0" for q in quats]),
    )


def _send_cone0(send: _Sender, rows: list[_Buffered], cone0_w: np.ndarray) -> None:
    """Cone 0's true base centre in world, body and camera frames, and the first-preferred
    method's estimate of it (``vnav.methods.PREFERENCE``)."""
    series: dict[str, list[tuple[_Buffered, np.ndarray]]] = {name: [] for name in CONE0_SERIES}
    for r in rows:
        for name, p in r.record.coordinates_of(cone0_w).items():
            series[name].append((r, p))
        estimate = r.record.estimate_of_cone(0, PREFERENCE[0])
        if estimate is not None:
            series["estimate_world"].append((r, estimate))
    for name, pairs in series.items():
        send(
            entity.cone0(name),
            [r for r, _ in pairs],
            rr.Scalars.columns(scalars=np.array([p for _, p in pairs]).reshape(-1, 3)),
        )


def _send_newest_pose(send: _Sender, rows: list[_Buffered], cones_w: np.ndarray) -> None:
    """The newest-pose ``depth_image`` estimates, their segments from the true cones and their
    mean error per tick (NaN, a gap, where there is none)."""
    newest = [[d for d in r.record.detections if d.latest_w is not None] for r in rows]
    points = [np.array([d.latest_w for d in ds], dtype=np.float64).reshape(-1, 3) for ds in newest]
    send(
        entity.NEWEST_ESTIMATE,
        rows,
        rr.Points3D.columns(positions=np.concatenate(points)).partition([len(p) for p in points]),
    )
    # latest_w is only made for a matched detection: every one has a true cone.
    segments = [[np.array([cones_w[d.cone_index], d.latest_w]) for d in ds] for ds in newest]
    send(entity.NEWEST_ERROR_SEGMENT, rows, _strips(segments))
    errors = []
    for ds in newest:
        scored = [d.latest_error_m for d in ds if d.latest_error_m is not None]
        errors.append(np.mean(scored) if scored else np.nan)
    send(entity.NEWEST_ERROR, rows, rr.Scalars.columns(scalars=errors))


_STREAM_WIDTH = {"yaw_deg": 1, "position_m": 3}
"""Scalars per sample of each pose-stream quantity."""


def _stream_values(T_w_b: np.ndarray) -> dict[str, np.ndarray]:
    """The pose-stream quantities of body poses (N, 4, 4): yaw in degrees (N,), as the
    attitude plot reads it (``so3.to_rpy``), and the position in metres (N, 3)."""
    T_w_b = np.asarray(T_w_b, dtype=np.float64).reshape(-1, 4, 4)
    yaw_deg = np.degrees(so3.to_rpy(T_w_b[:, :3, :3], warn=False)[:, 2])
    return {"yaw_deg": yaw_deg, "position_m": T_w_b[:, :3, 3]}


def _send_on_sim_time(
    rec: rr.RecordingStream, series: str, stamps_s: list[float] | np.ndarray, T_w_b: np.ndarray
) -> None:
    """One pose-stream series: each quantity of the poses ``T_w_b`` at ``stamps_s`` on the
    ``sim_time`` timeline alone (a pose sample or an arrival has no tick)."""
    if not len(stamps_s):
        return
    index = [rr.TimeColumn("sim_time", duration=np.asarray(stamps_s, dtype=np.float64))]
    for quantity, values in _stream_values(T_w_b).items():
        rec.send_columns(
            entity.stream(quantity, series),
            indexes=index,
            columns=rr.Scalars.columns(scalars=values),
        )


def _send_stream_markers(rec: rr.RecordingStream, rows: list[_Buffered]) -> None:
    """At each image's exposure the pose the estimator was given; at its arrival the newest
    pose received by then (what a pipeline ignoring stamps would have used)."""
    timed = [r.record for r in rows if r.record.timing is not None]
    _send_on_sim_time(
        rec,
        "exposure",
        [t.timing.exposure_pose_s for t in timed],
        np.array([t.T_w_b_est for t in timed]),
    )
    newest = [t.timing for t in timed if t.timing.T_w_b_latest is not None]
    _send_on_sim_time(
        rec,
        "arrival",
        [t.arrival_s for t in newest],
        np.array([t.T_w_b_latest for t in newest]),
    )


def _send_pose_samples(rec: rr.RecordingStream, poses: PoseStream) -> None:
    """Every pose sample the estimator was sent, at its stamp, as one column batch."""
    _send_on_sim_time(rec, "pose_samples", poses.stamps_s, poses.T_w_b)
