"""Rerun recording of a scenario: the entity tree is the frame tree.

Entity tree (docs/CONVENTIONS.md for the frames)::

    world                          ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/ground                   a grid on z = 0 (static)
    world/body                     Transform3D T_w_b, every camera frame
    world/body/camera              Transform3D T_b_c + Pinhole (true intrinsics, RDF) (static)
    world/body/camera/image        JPEG-compressed RGB
    world/body/camera/depth        planar z-depth, PNG-encoded 16-bit millimetres
    world/body/camera/detections   Boxes2D + Points2D (apex, base keypoints)
    world/cones/truth              Points3D of the true base centres (static)
    world/cones/estimate/<method>  Points3D per method, every camera frame
    world/depth_cloud              decimated depth image in world coordinates
    world/trajectory               LineStrips3D of the flown path (static, at the end)
    metrics/error/<method>         Scalars, metres
    metrics/range_m                Scalars, metres
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
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from vnav import quat
from vnav.camera import PinholeCamera
from vnav.detect import ConeDetection

APPLICATION_ID = "vnav-sim"
JPEG_QUALITY = 80
DEPTH_MM_MAX = np.iinfo(np.uint16).max

METHOD_COLORS: dict[str, tuple[int, int, int]] = {
    "depth_image": (40, 200, 255),
    "ground_plane": (80, 230, 80),
    "known_height": (230, 80, 230),
    "naive": (255, 40, 40),
}
TRUTH_COLOR = (255, 255, 255)


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


def _ground_grid(half_size_m: float, spacing_m: float) -> list[np.ndarray]:
    ticks = np.arange(-half_size_m, half_size_m + 1e-9, spacing_m)
    strips = []
    for x in ticks:
        strips.append(np.array([[x, -half_size_m, 0.0], [x, half_size_m, 0.0]]))
        strips.append(np.array([[-half_size_m, x, 0.0], [half_size_m, x, 0.0]]))
    return strips


def blueprint() -> rrb.Blueprint:
    """The default layout: 3D world, the camera's view, error time series, description."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="world", origin="world"),
            rrb.Vertical(
                rrb.Spatial2DView(name="camera", origin="world/body/camera"),
                rrb.TimeSeriesView(name="errors (m)", origin="metrics"),
                rrb.TextDocumentView(name="scenario", origin="description"),
                row_shares=[3, 2, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


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

    # ------------------------------------------------------------------ static content
    def log_setup(
        self,
        *,
        camera: PinholeCamera,
        T_b_c: np.ndarray,
        cones_w: np.ndarray,
        description_md: str,
        ground_half_size_m: float = 30.0,
    ) -> None:
        """Log what does not change over the run: axes, mount, intrinsics, truth, text."""
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(
            "world/ground",
            rr.LineStrips3D(
                _ground_grid(ground_half_size_m, 5.0), colors=[(90, 90, 90)], radii=0.01
            ),
            static=True,
        )
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
                radii=0.12,
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
        rec.send_blueprint(blueprint())

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
    ) -> None:
        """Log one camera frame on both timelines (``frame`` and ``sim_time``).

        Parameters
        ----------
        estimates_w : mapping of method -> ndarray, shape (K, 3)
            Every estimate of this frame (one row per detection that gave one).
        errors_m : mapping of method -> float
            This frame's mean position error per method (absent: no estimate).
        """
        rec = self.rec
        rec.set_time("frame", sequence=frame)
        rec.set_time("sim_time", duration=t_s)
        rec.log("world/body", _pose_transform(T_w_b))

        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("OpenCV could not JPEG-encode the camera image")
        rec.log(
            "world/body/camera/image",
            rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"),
        )
        if depth_m is not None:
            depth_mm = np.clip(
                np.nan_to_num(depth_m, nan=0.0, posinf=0.0) * 1000.0, 0, DEPTH_MM_MAX
            ).astype(np.uint16)
            ok, png = cv2.imencode(".png", depth_mm)
            if not ok:
                raise RuntimeError("OpenCV could not PNG-encode the depth image")
            rec.log(
                "world/body/camera/depth",
                rr.EncodedDepthImage(png.tobytes(), media_type="image/png", meter=1000.0),
            )

        if detections:
            mins = rerun_uv([d.bbox[:2] for d in detections]) - 0.5
            sizes = np.array([d.bbox[2:] for d in detections], dtype=np.float64)
            keypoints = np.concatenate([[d.apex_uv, d.base_uv] for d in detections])
            rec.log(
                "world/body/camera/detections",
                rr.Boxes2D(
                    mins=mins,
                    sizes=sizes,
                    colors=[(255, 220, 0)],
                    labels=[f"{d.area_px} px" for d in detections],
                ),
            )
            rec.log(
                "world/body/camera/detections/keypoints",
                rr.Points2D(
                    rerun_uv(keypoints),
                    radii=2.5,
                    colors=[(255, 0, 255), (0, 255, 255)] * len(detections),
                ),
            )
        else:
            rec.log("world/body/camera/detections", rr.Clear(recursive=True))

        for method in METHOD_COLORS:
            points = estimates_w.get(method)
            if points is not None and len(points):
                rec.log(
                    f"world/cones/estimate/{method}",
                    rr.Points3D(points, colors=[METHOD_COLORS[method]], radii=0.08),
                )
            else:
                rec.log(f"world/cones/estimate/{method}", rr.Clear(recursive=False))
            if method in errors_m:
                rec.log(f"metrics/error/{method}", rr.Scalars(errors_m[method]))
        if range_m is not None:
            rec.log("metrics/range_m", rr.Scalars(range_m))
        if cloud_w is not None:
            rec.log("world/depth_cloud", rr.Points3D(cloud_w, colors=[(150, 150, 200)], radii=0.03))

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
        self._close()
        self._tmp.unlink(missing_ok=True)

    def _close(self) -> None:
        if self._open:
            self._open = False
            self.rec.disconnect()  # writes the footer; without it the file cannot be read

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.discard()
        elif self._open:
            self.commit()
